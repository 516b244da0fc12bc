"""One window through onnxruntime with its buffers bound once (the daemon's decision).

``InferenceSession.run`` checks and converts its feed dict, makes new output arrays and wraps them
on every call, a few per cent of a decision of the default graph (results/latency.md). Here the
input is a fixed staging array bound once (the ring's window is copied into it: 15 x 234 floats, well
under a microsecond) and the outputs are preallocated arrays bound once; a run is one
``run_with_iobinding``. Answers are copies, so a caller may keep them past the next run.

A side effect worth having: onnxruntime's kernels sum in an order that depends on where the input
starts in memory (a ring window's offset changed the scores' last bits); the staging array sits at
one 64-byte aligned address, so one window gives one answer, bit for bit, wherever the ring holds it.

One caller at a time holds the binding (a non-blocking lock: the daemon's loop in service); a caller
that finds it taken, a batch, a window of another dtype or no array at all (a nested list, which
``session.run`` converts), or a graph whose outputs do not fit the preallocated shapes gets ``None``
and uses ``session.run``, whose answer the output contract check then judges with its own message.
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np

_FLOAT32 = np.dtype(np.float32)
_ALIGN = 64


def _aligned(shape: tuple[int, ...]) -> np.ndarray:
    """Zeros of float32 ``shape`` starting on a 64-byte boundary (what a fresh large numpy array gets)."""
    n = int(np.prod(shape))
    raw = np.zeros(n + _ALIGN // 4, dtype=np.float32)
    start = (-raw.ctypes.data % _ALIGN) // 4
    return raw[start : start + n].reshape(shape)


class BoundRun:
    """``run(window)`` for a ``[1, T, C]`` float32 window; ``None`` where the binding does not apply."""

    def __init__(self, session: Any, input_name: str, output_names: tuple[str, str], shape: tuple[int, int],
                 n_classes: int) -> None:
        import onnxruntime as ort

        self._lock = threading.Lock()
        self.stage = _aligned((1, *shape))
        self.labels = np.zeros(1, dtype=np.int64)
        self.scores = np.zeros((1, n_classes), dtype=np.float32)
        binding = session.io_binding()
        binding.bind_input(input_name, "cpu", 0, np.float32, self.stage.shape, self.stage.ctypes.data)
        label_name, scores_name = output_names
        binding.bind_output(label_name, "cpu", 0, np.int64, self.labels.shape, self.labels.ctypes.data)
        binding.bind_output(scores_name, "cpu", 0, np.float32, self.scores.shape, self.scores.ctypes.data)
        self._run = session.run_with_iobinding
        self._binding = binding
        # made once (None makes a default one per run, about 1 us) and saying "no graph capture": without
        # the entry, onnxruntime's wrapper looks it up, fails and catches the error on every run (about 30 us)
        self._options = ort.RunOptions()
        self._options.add_run_config_entry("gpu_graph_id", "-1")
        # a failed bound run is caught and handed to session.run, whose answer the output check judges in
        # one line; onnxruntime would print its own multi-line ERROR (with colour codes) to stderr first
        self._options.log_severity_level = 4
        self.broken = False
        """Set when a bound run failed (a graph whose outputs do not fit): the binding is not tried again."""

    def end(self) -> None:
        """End a run under way (from another thread: onnxruntime checks the flag between nodes and loop
        steps); every later run fails at once."""
        self._options.terminate = True

    def run(self, window: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        if (self.broken or not isinstance(window, np.ndarray) or window.shape != self.stage.shape
                or window.dtype != _FLOAT32 or not self._lock.acquire(False)):
            return None
        try:
            self.stage[...] = window  # same shape, checked above
            self._run(self._binding, self._options)
            return self.labels.copy(), self.scores.copy()
        except Exception:  # session.run gives the caller the graph's own error or output
            self.broken = not self._options.terminate  # an ended run: the caller says so itself
            return None
        finally:
            self._lock.release()
