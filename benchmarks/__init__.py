"""The benchmarks and studies that produce the committed results/: run from a checkout with
``./dev bench [NAME]`` (``python -m benchmarks``). Not installed (pyproject.toml installs
firmware_io, runtime and trainer only); they use the installed package, nothing in it imports them."""
