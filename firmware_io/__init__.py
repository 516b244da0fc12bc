"""Bytes <-> frames: DSACON32m protocol, transports, emulator, layout, recordings, simulated hand. NumPy only."""

from firmware_io.layout import LayoutError, MatrixInfo, SensorLayout
from firmware_io.recording import ACTIONS, Recording, RecordingError, Trial

__all__ = ["ACTIONS", "LayoutError", "MatrixInfo", "Recording", "RecordingError", "SensorLayout", "Trial"]
