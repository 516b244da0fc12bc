"""Bytes <-> frames, NumPy only: ``layout`` (the pads), ``wire`` (the DSACON32m protocol and stream
parser), ``transports`` (byte links by URL), ``client`` (a controller read as frames), ``emulator``,
``sim`` (the simulated hand), ``recordings`` (files, importers, recording subjects), ``commands``."""

from firmware_io.layout import LayoutError, MatrixInfo, SensorLayout
from firmware_io.recordings.recording import ACTIONS, Recording, RecordingError, Trial

__all__ = ["ACTIONS", "LayoutError", "MatrixInfo", "Recording", "RecordingError", "SensorLayout", "Trial"]
