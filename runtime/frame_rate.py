"""The device's frame rate against the model's: one owner for how a stream is fed to a model.

Why: T frames at the wrong rate span another stretch of time than the model learnt. The stream's period
is measured from the device time stamps (the median over ``BLOCK`` gaps of ``SPAN`` frames, which
alternating jitter does not throw), and:

- a faster stream (below ``FASTER`` x the model's period) is decimated by a phase accumulator on the
  *measured* period (stamps jitter too much to use one by one); admitted frames are numbered
  consecutively, events still name device frames;
- a slower one (above ``SLOWER`` x) is fed as it comes, with a one-line health problem;
- a gap of more than ``RESTART_PERIODS`` or a step back of more than one period (a reboot) breaks the
  stream: ``on_restart`` is called and the history is forgotten, as after a reconnect.

Lost frames are counted once per block; each kind of rate line is logged once per model period.
"""

from __future__ import annotations

import itertools
import logging
import statistics
from collections.abc import Callable

import numpy as np

__all__ = ["BLOCK", "FrameClock", "fed_as_it_comes", "log"]

log = logging.getLogger("handover.daemon")

FASTER = 0.8
"""A stream whose period is below this x the model's is decimated (jitter alone never gets there)."""
SLOWER = 1.25
"""A stream whose period is above this x the model's gets a health warning."""
FASTEST = 0.125
"""Stamps that say the stream is more than 8x faster than the model's rate are not believed (a
broken device clock would otherwise leave out nearly every frame): a health warning, frames fed
as they come."""


def fed_as_it_comes(stream_rate_hz: float, model_rate_hz: float) -> bool:
    """Whether a stream at ``stream_rate_hz`` reaches a model trained at ``model_rate_hz`` frame by frame,
    neither decimated nor warned about (a candidate in shadow is fed the serving model's frames)."""
    return FASTER <= model_rate_hz / stream_rate_hz <= SLOWER


BLOCK = 32
"""Gaps per estimate of the stream's period (about a second at the SDH-2's 32 Hz)."""
SPAN = 4
"""Frames per span of the period estimate (smooths any jitter pattern shorter than this)."""
HISTORY = 256
"""Device frame numbers of the last admitted frames kept (to name a window's first device frame)."""
RESTART_PERIODS = 10
"""A gap of more than this many stream periods (about 0.3 s at 32 Hz) breaks the stream."""
SOURCE = "rate"
"""The health problem's source (resolved when the stream is back at the model's rate)."""


class FrameClock:
    """Admits a device's frames at the model's period; counts lost frames; warns on slow streams."""

    def __init__(self, model_period_ms: float, health=None, on_restart: Callable[[], None] | None = None) -> None:
        self.health = health
        self.on_restart = on_restart
        """Called when a gap breaks the stream (before the frame after the gap is fed)."""
        self._told: set[str] = set()
        """The kinds of rate line already logged for this model period."""
        self.model_period_ms = float(model_period_ms)
        self._gaps = [0.0] * BLOCK
        self._breaks = [False] * BLOCK
        self._numbers = np.zeros(HISTORY, dtype=np.int64)
        self.dropped = 0
        """Frames the device sent but we never saw (gaps in device time), over the daemon's life."""
        self.decimated = 0
        """Frames of a stream faster than the model's rate left out to feed it at its period."""
        self.reset()

    def reset(self) -> None:
        """Forget the stream (a reconnect: time stamps and numbers start afresh)."""
        self._last_ts: int | None = None
        self._n_gaps = 0
        self.stream_period_ms: float | None = None
        """The measured period of the device's stream (median of the last block of gaps), or None."""
        self.step = 1.0
        """Model frames per device frame (1: every frame is admitted)."""
        self._phase = 0.0
        self.renumber = False
        """True once frames were decimated: admitted frames carry consecutive numbers from then on."""
        self.number = -1
        self.admitted = 0
        self.slow = False
        """The stream's rate is a health problem (slower than the model's, or stamps not believed)."""

    def set_model_period(self, model_period_ms: float) -> None:
        """A model with another sample rate serves: re-decide from the measured period."""
        if float(model_period_ms) != self.model_period_ms:
            self._told.clear()
            self._phase = 0.0
        self.model_period_ms = float(model_period_ms)
        if self.stream_period_ms is not None:
            self._decide(self.stream_period_ms)

    def admit(self, number: int, ts_ms: int) -> int:
        """The frame number to feed this frame under, or -1 when it falls between model periods."""
        last, self._last_ts = self._last_ts, ts_ms
        if last is not None:
            gap, period = ts_ms - last, self.stream_period_ms or self.model_period_ms
            broken = gap > RESTART_PERIODS * period or gap < -period
            if broken:
                self._restart(gap)
            if not broken or (gap > 0 and self.stream_period_ms is None):  # a stream far slower than
                self._gap(gap, broken)  # the model's is all breaks by the model's period: measure it
        if self.step < 1.0:
            self._phase += self.step
            if self._phase < 1.0:
                self.decimated += 1
                return -1
            self._phase -= 1.0
        if self.renumber:
            self.number += 1
        else:
            self.number = number
        self._numbers[self.admitted % HISTORY] = number
        self.admitted += 1
        return self.number

    def counters(self) -> dict[str, int]:
        return {"frames_dropped": self.dropped, "frames_decimated": self.decimated}

    @property
    def period_ms(self) -> float:
        """The device's frame period as far as known: the measured one, the model's until it is measured."""
        return self.stream_period_ms or self.model_period_ms

    def deadline_s(self) -> float:
        """How long a decision may take: until the next admitted frame, by the stream's *measured*
        period (the device frames a decimation passes over included); the model's period only until
        the stream is measured. Why measured: a model's ``sample_rate_hz`` is what its file claims
        (1 Hz made 86 ms decisions at 32 Hz count as on time); the time stamps are what arrives."""
        if self.stream_period_ms is None:
            return self.model_period_ms / 1000.0
        return self.stream_period_ms / (self.step if self.step < 1.0 else 1.0) / 1000.0

    def device_number(self, back: int) -> int:
        """The device number of the frame admitted ``back`` admitted frames before the newest."""
        if not 0 <= back < min(self.admitted, HISTORY):
            return -1
        return int(self._numbers[(self.admitted - 1 - back) % HISTORY])

    def window_first(self, last_number: int, length: int) -> int:
        """The device number of the first frame of the ``length``-frame window ending at the newest."""
        if not self.renumber:
            return last_number - length + 1
        first = self.device_number(length - 1)
        return first if first >= 0 else last_number - length + 1

    def _restart(self, gap: int) -> None:
        self._phase = 0.0
        what = "back" if gap < 0 else "ahead"
        self._tell("restart", f"device time jumped {abs(gap) / 1000.0:.1f} s {what} (a pause, a stall or a device "
                              "reboot): the frame history restarts there (logged once; every break restarts it)")
        if self.on_restart is not None:
            self.on_restart()

    def _gap(self, gap: float, broken: bool = False) -> None:
        self._gaps[self._n_gaps] = gap
        self._breaks[self._n_gaps] = broken
        self._n_gaps += 1
        if self._n_gaps == BLOCK:
            self._n_gaps = 0
            self._block()

    def _block(self) -> None:
        """A block of gaps is complete: the stream's period, and the frames lost in the block."""
        # plain Python on 32 numbers: a third of NumPy's time warm, far less on the cold caches of a
        # frame that may be the one completing a window (this runs on the hot path once a block)
        gaps = self._gaps
        ends = list(itertools.accumulate(gaps))
        spans = [ends[SPAN - 1]] + [ends[i + SPAN] - ends[i] for i in range(BLOCK - SPAN)]
        period = statistics.median(spans) / SPAN
        if period <= 0:
            return  # repeated stamps: no rate to measure
        # stamps jitter up to ~0.8 period; a lost frame adds one
        lost = [g for g, broken in zip(gaps, self._breaks, strict=True) if g > 1.9 * period and not broken]
        if lost:
            room = max(0, round(ends[-1] / period) - BLOCK)
            self.dropped += min(room, sum(round(g / period) for g in lost) - len(lost))
        self._decide(period)

    def _decide(self, period_ms: float) -> None:
        was_step, was_off = self.step, self.slow
        self.stream_period_ms = period_ms
        ratio = period_ms / self.model_period_ms
        self.step = ratio if FASTEST <= ratio < FASTER else 1.0
        if self.step < 1.0:
            self.renumber = True  # from now on the trigger counts model frames
        stream_hz, model_hz = _hz(1000.0 / period_ms), _hz(1000.0 / self.model_period_ms)
        if self.step < 1.0 and was_step == 1.0:
            self._tell("decimate", f"device streams at {stream_hz} Hz, the model was trained at {model_hz} Hz: "
                                   f"frames are decimated to the model's period (about 1 in {1.0 / self.step:.1f} "
                                   "classified)")
        problem = None
        if ratio > SLOWER:
            problem = (f"device streams at {stream_hz} Hz, slower than the {model_hz} Hz the model was trained "
                       f"at: its windows span {ratio:.1f}x their trained time and decisions may be wrong; set the "
                       f"device's rate to {model_hz} Hz or train a model at {stream_hz} Hz")
        elif ratio < FASTEST:
            problem = (f"device streams at {stream_hz} Hz by its time stamps, more than {1 / FASTEST:.0f}x the "
                       f"{model_hz} Hz of the model's sample_rate_hz: one of them is wrong (a model exported with a "
                       "wrong rate, or a broken device clock); frames are fed as they come and decisions are held "
                       "to the stream's period")
        self.slow = problem is not None
        if problem and not was_off:
            self._tell("slow" if ratio > SLOWER else "absurd", problem)
            if self.health is not None:
                self.health.report_error(problem, SOURCE)
        elif was_off and not problem and self.health is not None:
            self.health.resolve(SOURCE)

    def _tell(self, kind: str, line: str) -> None:
        """Log ``line`` unless a line of this kind was logged already for this model period."""
        if kind not in self._told:
            self._told.add(kind)
            log.warning("%s", line)


def _hz(rate: float) -> str:
    """A rate for a log line: 71, 31.2, 0.33."""
    return f"{rate:.0f}" if rate >= 100 else f"{rate:.3g}"
