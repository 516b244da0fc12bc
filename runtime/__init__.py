"""The lean detection daemon: ring buffer, trigger, ONNX inference, sinks. Never imports scikit-learn."""

import os

# onnxruntime (1.32 on Linux) collects usage telemetry at import unless told not to: it keeps a
# device id and a growing SQLite store under ~/.cache/Microsoft/DeveloperTools, and at exit it
# waits on that store's lock while another onnxruntime process holds it (a SIGTERM'd daemon took
# 1-2 s to exit). A service on a lab's robot does neither; set here, before any import of it.
# Setting ORT_DISABLE_TELEMETRY=0 in the environment keeps onnxruntime's default.
os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("tactile-handover")
except PackageNotFoundError:  # running from a checkout without install
    __version__ = "0.0.0+checkout"
