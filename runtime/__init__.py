"""The lean detection daemon: ring buffer, trigger, ONNX inference, sinks. Never imports scikit-learn."""

import os

# onnxruntime collects usage telemetry at import unless told not to: it keeps a device id and a
# SQLite store that grows with every process under ~/.cache/Microsoft/DeveloperTools. A service that runs for months
# on a lab's robot does not; set here, before any import of it. Setting ORT_DISABLE_TELEMETRY=0
# in the environment keeps onnxruntime's default.
os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")

from importlib.metadata import PackageNotFoundError, version

__all__ = ["__version__"]

try:
    __version__ = version("tactile-handover")
except PackageNotFoundError:  # running from a checkout without install
    __version__ = "0.0.0+checkout"
