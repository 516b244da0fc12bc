"""The lean detection daemon: ring buffer, trigger, ONNX inference, sinks. Never imports scikit-learn."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("tactile-handover")
except PackageNotFoundError:  # running from a checkout without install
    __version__ = "0.0.0+checkout"
