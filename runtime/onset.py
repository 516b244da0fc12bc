"""The onset trigger: start the window when the *person* acts on a settled grasp, not when the hand closes.

Why: on a live robot the hand's own grasp crosses the paper's 15 % threshold before the person acts.
This trigger measures each pad's summed pressure against a baseline that follows the settled grasp:

- ``open``: the scene reads (almost) nothing;
- ``settling``: contact, but still moving; arms once every pad changed by less than ``settle_change``
  for ``settle_frames`` frames in a row, or by less than twice that for three times as long and by
  less than a quarter of it per frame on average (``NOISY_SETTLE``; and ``refractory_frames`` after the
  last trigger);
- ``armed``: Holt's linear tracker (level + trend per pad, ``tau_frames``) follows creep and drift (real
  pads creep far more than the simulator's); fires when a pad departs from the prediction by ``change``
  of its level (at least ``change x floor``), read as a change of force where the grasp compresses the
  rubber (``RUBBER_HILL_N``). A departure where no pad rose (letting go, re-seating),
  on a point contact (``MIN_CONTACT_TAXELS``) or with the grasp on one finger (``MIN_GRASP_FINGERS``)
  goes back to ``settling`` without firing.

The window is dated from where the departure began, not where it crossed ``change``: from the first
frame it passed ``START_SHARE`` of ``change``, at most ``back_frames`` before the trigger frame (a slow
hold crosses 12 % several frames after it began; a firm pull crosses both in one frame).

``set_grasp`` (the robot's word): ``closed`` arms at once, ``open`` disarms until the hand is seen empty,
so a lost message never deafens the trigger. ``update(row, number)`` returns the frame at which a window
is due, or -1, like ``ThresholdTrigger``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["COMPRESSION_CAP", "MIN_GRASP_FINGERS", "RUBBER_HILL_N", "OnsetTrigger", "compression"]

OPEN, SETTLING, ARMED = "open", "settling", "armed"
TREND_GAIN = 0.25
"""The trend takes this share of the level's correction (Holt's beta)."""
NOISY_SETTLE = (2, 3, 0.25)
"""A held grasp on a noisy hand moves by about ``settle_change`` from frame to frame on sensor noise alone
(simulated lab B), so it may never pass the strict test; a grasp that changed by less than the first
times ``settle_change`` for the second times ``settle_frames`` has settled too (a closing hand moves more),
if its net change over the span stayed under the third times ``settle_change`` per frame (for at most
that many frames): noise swings back and forth, a hand squeezing steadily does not (without this test, a squeeze of
1-4 % per frame armed mid-squeeze and fired on the hand's own grasp). Chosen by the rule in
docs/TRIGGER_DEFAULTS.md."""
START_SHARE = 0.5
"""A departure that fires is dated from the first frame of its run at or above this share of ``change`` (at
most ``back_frames`` back): the window then holds the start of a slow departure, and its early heads answer
sooner. Chosen with ``trigger.back_frames`` by the rule in docs/TRIGGER_DEFAULTS.md."""
RELEASE_RISE = 1.0
"""A departure whose largest rise is below this share of ``change`` counts as a release: the hand
letting go or re-seating its grasp (one pad losing pressure while another wobbles up), not a person.
Chosen by the rule of results/streams.md, which gives the candidates and their scores."""
MIN_CONTACT_TAXELS = 3
"""A departure on a pad touched by fewer loaded taxels than this is a point contact (an edge of the
object rolling or slipping on a pad), not a person acting through the object the hand holds: it goes
back to settling without firing. Physical grounds: a hand-over grasp loads a pad over an area; the
validation rule was indifferent to it (results/streams.md)."""
MIN_GRASP_FINGERS = 2
"""A departure fires only if, when the trigger armed, the settled grasp touched pads of at least this
many fingers (a pad with ``MIN_CONTACT_TAXELS`` loaded taxels or more; at most the scene's fingers).
Why: a hand-over starts from an object *held* between opposing fingers; a load on one finger's pads
alone is something pressing on it (a calibration rig, a probe), not an object in the hand. Counted on
the settled grasp, not at the departure: a tap pushes the object off the fingers on one side in the very
frame it fires. Limitation: an object hanging from one finger (a hook grasp) never fires. How it was
chosen: results/streams.md."""


RUBBER_CEILING = 3553.0 / 4095.0
"""Share of full scale where the DSA 9205's rubber saturates (measured: saturated taxels top out at
3505-3567 counts, median 3553; firmware_io/sim/constants.py)."""
RUBBER_HILL_N = 1.7
"""The rubber's Hill exponent (fitted to calibration weights, ibid.). A reading r responds to a relative
change of force by ``n (1 - r / ceiling)`` times it: expansive for a light grasp, compressive above
``1 - 1/n`` of the ceiling, where a person's added force moves the counts little (a firm grasp on a
sensitive pad: a hold barely moves a pad already near saturation). There a departure is scaled back to
a change of force; below, the trigger reads counts as before (factor 1, the defaults' calibration)."""
COMPRESSION_CAP = 2510.0 / 3553.0
"""The grasp's level is read as at most this share of the ceiling: the highest calibration weight's
peak (2510 counts), the end of the range the curve was fitted on (the factor stays <= 2.0, so the
noise of a saturated pad is not blown up past what the fit can vouch for)."""


def compression(row: np.ndarray, starts: np.ndarray, fullscale: float) -> np.ndarray:
    """Per pad, how much the rubber compresses a relative change of force at this grasp (>= 1).

    The pad's level is its reading-weighted mean taxel (the taxels that carry its sum)."""
    r = np.asarray(row, dtype=np.float64)
    total = np.add.reduceat(r, starts)
    mean = np.add.reduceat(r * r, starts) / np.maximum(total, 1.0)
    share = np.minimum(mean / (RUBBER_CEILING * fullscale), COMPRESSION_CAP)
    return np.maximum(1.0, 1.0 / (RUBBER_HILL_N * (1.0 - share)))


class OnsetTrigger:
    """Fires when a pad's pressure leaves the settled grasp's baseline by ``change`` of it."""

    def __init__(
        self,
        pad_sizes: tuple[int, ...] | list[int],
        fullscale: float,
        change: float,
        floor: float,
        contact: float,
        tau_frames: float,
        settle_frames: int,
        settle_change: float,
        refractory_frames: int = 16,
        window: int = 15,
        pre_frames: int = 0,
        pad_fingers: tuple[int, ...] | list[int] | None = None,
        back_frames: int = 0,
    ) -> None:
        if not 0.0 < change < 1.0:
            raise ValueError("change must be in (0, 1)")
        if back_frames < 0 or pre_frames + back_frames >= window:
            raise ValueError("pre_frames + back_frames must be smaller than the window")
        if settle_frames < 1 or tau_frames < 1.0:
            raise ValueError("settle_frames and tau_frames must be at least 1")
        sizes = np.asarray(pad_sizes, dtype=np.int64)
        self._starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.intp)
        n = len(sizes)
        fingers = list(range(n)) if pad_fingers is None else [int(f) for f in pad_fingers]
        if len(fingers) != n:
            raise ValueError("pad_fingers must name one finger per pad")
        self._fingers = np.asarray(fingers, dtype=np.int64)
        """The finger of each pad (None: every pad a finger of its own)."""
        self.min_fingers = min(MIN_GRASP_FINGERS, len(set(fingers)))
        """Fingers the settled grasp must touch (``MIN_GRASP_FINGERS``, at most the scene's fingers)."""
        self.change = float(change)
        self.floor = float(floor * fullscale)
        """Pad pressure (summed counts) below which a pad's change is measured against this instead."""
        self.fullscale = float(fullscale)
        self.contact = float(contact * fullscale)
        """Summed scene pressure below which the hand counts as empty."""
        self.alpha = 1.0 / float(tau_frames)
        self.settle_frames = int(settle_frames)
        self.settle_change = float(settle_change)
        self._noisy_change = NOISY_SETTLE[0] * self.settle_change
        self._noisy_frames = NOISY_SETTLE[1] * self.settle_frames
        self._noisy_drift = NOISY_SETTLE[2] * self.settle_change
        self.refractory_frames = int(refractory_frames)
        self.window = int(window)
        self.pre_frames = int(pre_frames)
        self.back_frames = int(back_frames)
        self._date_level = self.change * START_SHARE
        self._since = -1
        """The first frame of the current run at or above ``START_SHARE`` of ``change`` (-1: none)."""
        self.back = 0
        """Frames the last trigger's window was dated back (at most ``back_frames``)."""
        self._p = np.zeros(n, dtype=np.float64)
        self._prev = np.zeros(n, dtype=np.float64)
        self._held_from = np.zeros(n, dtype=np.float64)
        """The pads' pressure where the current ``held`` span began (its net change must stay small)."""
        self._base = np.zeros(n, dtype=np.float64)
        self._trend = np.zeros(n, dtype=np.float64)
        """Per-frame change of the settled grasp (creep): zero when the trigger arms, tracked while armed."""
        self._dev = np.zeros(n, dtype=np.float64)
        self._error = np.zeros(n, dtype=np.float64)
        self._scale = np.zeros(n, dtype=np.float64)
        self._gain = np.ones(n, dtype=np.float64)
        """Per pad, ``compression`` of the settled grasp: a departure in counts times this is one in force."""
        self._request: bool | None = None
        self.reset()

    def reset(self) -> None:
        """Back to ``open`` with no history (after a reconnect or a model change)."""
        self.state = OPEN
        self.robot_open = False
        """The robot said its grasp is released: no self-arming until the hand is seen empty."""
        self.quiet = 0
        self.held = 0
        """Frames in a row every pad changed by less than ``NOISY_SETTLE[0] x settle_change``."""
        self.last_trigger = -(1 << 62)
        self.level = 0.0
        self.releases = 0
        """Departures in which every pad lost pressure (the hand letting go): not fired."""
        self.point_contacts = 0
        """Departures on a pad touched by fewer than ``MIN_CONTACT_TAXELS`` taxels: not fired."""
        self.grasp_fingers = 0
        """Fingers the settled grasp touched when the trigger last armed."""
        self.not_held = 0
        """Departures while the settled grasp touched fewer than ``min_fingers`` fingers: not fired."""

    def set_grasp(self, closed: bool) -> None:
        """The robot's word on its grasp; applied at the next ``update`` (call from the hot path's thread)."""
        self._request = bool(closed)

    def update(self, row: np.ndarray, number: int) -> int:
        """Feed one frame's scene columns; return the frame number a window ends at, or -1."""
        p = self._p
        np.add.reduceat(row, self._starts, out=p, dtype=np.float64)
        if self._request is not None:
            self._apply_request(row, p, number)
        if p.sum() < self.contact:
            self.state, self.robot_open, self.quiet, self.level = OPEN, False, 0, 0.0
            return -1
        if self.state == OPEN:
            if self.robot_open:
                return -1
            self._start_settling(p)
            return -1
        if self.state == SETTLING:
            self._settle(row, p, number)
            return -1
        return self._watch(row, p, number)

    def _apply_request(self, row: np.ndarray, p: np.ndarray, number: int) -> None:
        closed, self._request = self._request, None
        if closed and number - self.last_trigger < self.refractory_frames:
            self.robot_open = False  # the interaction that fired goes on: arm once it settled, as without the message
            if self.state != SETTLING:
                self._start_settling(p)
        elif closed:
            self.robot_open = False
            if self.state != ARMED:  # armed already: keep the baseline (a repeated message must not deafen it)
                self._arm(row, p)
        else:
            self.robot_open = True
            self.state = OPEN

    def _start_settling(self, p: np.ndarray) -> None:
        self.state = SETTLING
        self._since = -1
        self.quiet = self.held = 0
        self._prev[:] = p
        self._trend[:] = 0.0

    def _settle(self, row: np.ndarray, p: np.ndarray, number: int) -> None:
        np.maximum(self._prev, self.floor, out=self._scale)
        np.subtract(p, self._prev, out=self._dev)
        np.abs(self._dev, out=self._dev)
        self.level = float((self._dev / self._scale).max())
        self.quiet = self.quiet + 1 if self.level < self.settle_change else 0
        if self.level >= self._noisy_change:
            self.held = 0
        elif self.held == 0:
            self._held_from[:] = self._prev
            self.held = 1
        else:
            self.held += 1
        self._prev[:] = p
        settled = self.quiet >= self.settle_frames or (self.held >= self._noisy_frames and self._held_still(p))
        if settled and number - self.last_trigger >= self.refractory_frames:
            self._arm(row, p)

    def _held_still(self, p: np.ndarray) -> bool:
        """Whether the grasp's net change over the ``held`` span is under ``NOISY_SETTLE``'s drift per frame
        (counted over at most the test's frames, however long the refractory time kept it waiting); if not,
        the span starts again here (a steady squeeze never passes)."""
        net = np.abs(p - self._held_from) / np.maximum(self._held_from, self.floor)
        if float(net.max()) < self._noisy_drift * min(self.held, self._noisy_frames):
            return True
        self.held = 0
        return False

    def _arm(self, row: np.ndarray, p: np.ndarray) -> None:
        """Watch the settled grasp ``p`` from here; count the fingers it touches (``MIN_GRASP_FINGERS``)."""
        self.state = ARMED
        self._since = -1
        self._base[:] = p
        self._trend[:] = 0.0
        self._gain[:] = compression(row, self._starts, self.fullscale)
        loaded = np.add.reduceat(row > 0, self._starts) >= MIN_CONTACT_TAXELS
        self.grasp_fingers = len(np.unique(self._fingers[loaded]))

    def _contact_taxels(self, row: np.ndarray) -> int:
        """Loaded taxels of the pad that departed most from the settled grasp (only when it fires)."""
        k = int(np.argmax(np.abs(self._dev)))
        stop = self._starts[k + 1] if k + 1 < len(self._starts) else len(row)
        return int(np.count_nonzero(row[self._starts[k]:stop]))

    def _watch(self, row: np.ndarray, p: np.ndarray, number: int) -> int:
        base, trend = self._base, self._trend
        base += trend  # the prediction for this frame
        np.maximum(base, self.floor, out=self._scale)
        error = self._error
        np.subtract(p, base, out=error)
        np.divide(error, self._scale, out=self._dev)
        self._dev *= self._gain
        rise = float(self._dev.max())
        self.level = max(rise, -float(self._dev.min()))
        if self.level < self._date_level:
            self._since = -1
        elif self._since < 0:
            self._since = number
        if self.level < self.change:
            base += self.alpha * error  # creep and drift: follow slow changes of the settled grasp
            trend += TREND_GAIN * self.alpha * error
            return -1
        back = min(number - self._since, self.back_frames)
        self._start_settling(p)
        if rise < RELEASE_RISE * self.change:  # no pad rose: the hand lets go or re-seats, nobody pulled
            self.releases += 1
            return -1
        if self._contact_taxels(row) < MIN_CONTACT_TAXELS:  # a point contact rolling on a pad
            self.point_contacts += 1
            return -1
        if self.grasp_fingers < self.min_fingers:  # something pressing on one finger: no object held
            self.not_held += 1
            return -1
        self.last_trigger, self.back = number, back
        return number + self.window - 1 - self.pre_frames - back
