"""A quick look at a trial in the terminal: one unicode sparkline of each pad's summed pressure.

Right after a trial the investigator sees whether the subject touched the pads that should
feel the action, without leaving the recording session. numpy only.
"""

from __future__ import annotations

import numpy as np

from firmware_io.layout import SensorLayout

__all__ = ["pad_name", "pad_sums", "sparkline", "trial_view"]

BLOCKS = " ▁▂▃▄▅▆▇█"


def sparkline(values: np.ndarray, width: int = 60, top: float | None = None) -> str:
    """``values`` squeezed to ``width`` columns (max of each bin) and drawn with block characters.

    ``top`` is the value drawn as a full block (default: the series' own maximum), so several
    sparklines can share one scale. Zero draws a space.
    """
    v = np.asarray(values, dtype=np.float64).ravel()
    if v.size == 0 or width < 1:
        return ""
    if v.size > width:
        edges = np.linspace(0, v.size, width + 1).astype(int)
        v = np.maximum.reduceat(v, edges[:-1])
    top = float(v.max()) if top is None else float(top)
    if top <= 0:
        return BLOCKS[0] * len(v)
    level = np.clip(np.ceil(v / top * (len(BLOCKS) - 1)), 0, len(BLOCKS) - 1).astype(int)
    return "".join(BLOCKS[i] for i in level)


def pad_name(layout: SensorLayout, index: int) -> str:
    """``f1 distal`` style names (finger = matrix // 2, as in the sensor layout)."""
    return f"f{index // 2} {'prox' if layout.is_proximal(index) else 'dist'}"


def pad_sums(frames: np.ndarray, layout: SensorLayout) -> np.ndarray:
    """Summed taxel values of each pad per frame: float64 ``[n_frames, n_pads]``."""
    f = np.asarray(frames, dtype=np.float64)
    return np.stack([f[:, layout.matrix_slice(i)].sum(axis=1) for i in range(layout.n_matrices)], axis=1)


def trial_view(frames: np.ndarray, layout: SensorLayout, trigger_frame: int = -1, width: int = 60) -> str:
    """One line per pad: name, sparkline on a shared scale, peak sum and peak taxel.

    A caret line marks ``trigger_frame`` (when there is one) on the same time axis: the recorder passes
    the frame training cuts at, so the look shows the case ``handover train`` will get.
    """
    frames = np.asarray(frames)
    if frames.size == 0:
        return "(no frames)"
    sums = pad_sums(frames, layout)
    top = float(sums.max())
    n = len(frames)
    cols = min(width, n)
    lines = []
    for i in range(layout.n_matrices):
        peak_taxel = int(frames[:, layout.matrix_slice(i)].max())
        lines.append(f"{pad_name(layout, i):>8} |{sparkline(sums[:, i], cols, top):<{cols}}| "
                     f"sum {sums[:, i].max():>7.0f}  max {peak_taxel:>4}")
    if 0 <= trigger_frame < n:
        pos = min(cols - 1, int(trigger_frame * cols / n))
        lines.append(f"{'trigger':>8}  {' ' * pos}^ frame {trigger_frame}")
    return "\n".join(lines)
