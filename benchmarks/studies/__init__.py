"""Studies that answered a question of past work, kept to reproduce their results/ files.

Not part of the installed package (pyproject.toml installs firmware_io, runtime and trainer only):
run them from a checkout, e.g. ``./dev bench slip_diagnosis --out results``. They use the
installed package; nothing in it imports them.
"""
