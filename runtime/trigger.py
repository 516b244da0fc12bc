"""When to classify: a threshold trigger with hysteresis and refractory time, or continuously.

The paper starts a window when any taxel of the used pads exceeds about 15 % of full scale. One
interaction is one trigger: the trigger re-arms only after the level stayed below the off level for
``rearm_frames`` frames, never within ``refractory_frames`` of the last one. ``update(row, number)``
returns the frame at which a window is due (trigger frame + T - 1 - pre_frames), or -1.
"""

from __future__ import annotations

import numpy as np

from firmware_io.trigger_level import is_trigger_level
from runtime.trigger_settings import DEFAULT_HYSTERESIS, PAPER_FRACTION

__all__ = ["ContinuousTrigger", "ThresholdTrigger"]


class ThresholdTrigger:
    """Fires when max(scene taxels) crosses ``on``; re-arms once it stayed below ``off`` for
    ``rearm_frames`` frames; never fires within ``refractory_frames`` of the last trigger."""

    def __init__(
        self,
        n_channels: int,
        fullscale: float,
        fraction: float = PAPER_FRACTION,
        hysteresis: float = DEFAULT_HYSTERESIS,
        refractory_frames: int = 16,
        window: int = 15,
        pre_frames: int = 0,
        baseline: bool = False,
        baseline_alpha: float = 0.0156,
        rearm_frames: int = 1,
    ) -> None:
        if not is_trigger_level(fraction):
            raise ValueError("fraction must be in (0, 1)")
        if not 0.0 <= hysteresis < fraction:
            raise ValueError("hysteresis must be in [0, fraction)")
        if pre_frames >= window:
            raise ValueError("pre_frames must be smaller than the window")
        if rearm_frames < 1:
            raise ValueError("rearm_frames must be at least 1")
        self.on_level = float(fraction * fullscale)
        self.off_level = float((fraction - hysteresis) * fullscale)
        self.refractory_frames = int(refractory_frames)
        self.window = int(window)
        self.pre_frames = int(pre_frames)
        self.rearm_frames = int(rearm_frames)
        self.baseline_mode = bool(baseline)
        self.baseline_alpha = float(baseline_alpha)
        self._baseline = np.zeros(n_channels, dtype=np.float32)
        self._diff = np.zeros(n_channels, dtype=np.float32)
        self._baseline_ready = False
        self.reset()

    def reset(self) -> None:
        """Back to armed, with no history (after a reconnect or a model change)."""
        self.armed = True
        self.quiet = 0
        """Frames in a row below the off level while disarmed."""
        self.last_trigger = -(1 << 62)
        self.level = 0.0
        self._baseline_ready = False
        self.fired = 0

    def set_grasp(self, closed: bool) -> None:
        """The robot's grasp does not move a fixed level: ignored."""

    def update(self, row: np.ndarray, number: int) -> int:
        """Feed one frame's scene columns; return the frame number a window ends at, or -1."""
        if self.baseline_mode:
            if not self._baseline_ready:
                self._baseline[:] = row
                self._baseline_ready = True
            np.subtract(row, self._baseline, out=self._diff)
            level = float(self._diff.max())
        else:
            level = float(row.max())
        self.level = level
        due = -1
        if self.armed:
            if level >= self.on_level and number - self.last_trigger >= self.refractory_frames:
                self.armed = False
                self.quiet = 0
                self.last_trigger = number
                self.fired += 1
                due = number + self.window - 1 - self.pre_frames
        elif level < self.off_level:
            self.quiet += 1
            if self.quiet >= self.rearm_frames:
                self.armed, self.quiet = True, 0
        else:
            self.quiet = 0
        if self.baseline_mode and self.armed and due < 0:
            # Track the grasp's own pressure only while nothing is happening.
            self._diff *= self.baseline_alpha
            self._baseline += self._diff
        return due


class ContinuousTrigger:
    """Every frame ends a window once the ring holds T frames (models with a dormant class). The daemon
    reports only what its report rule (runtime.decision) confirms."""

    def __init__(self, window: int) -> None:
        self.window = int(window)
        self.pre_frames = 0
        self.level = 0.0

    def reset(self) -> None:
        """Nothing to forget: no state carries from one frame to the next."""

    def set_grasp(self, closed: bool) -> None:
        """Every frame is classified whatever the grasp: ignored."""

    def update(self, row: np.ndarray, number: int) -> int:
        return number
