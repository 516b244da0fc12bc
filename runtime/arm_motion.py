"""The robot's word on its arm: while the arm moves, and a settle time after it stops, nothing is reported.

A moving arm loads the held object like a person pulling or pushing, and the robot knows when it moves
(``arm moving``/``arm still`` on the control socket, ROS 2 ``<ns>/arm`` or joint velocities,
``set_arm_moving``). The one rule: the arm counts as moving from the frame of ``arm moving`` until
``settle_frames`` after ``arm still``; a window holding any of those frames is judged dormant (the model
does not run; continuous mode's rule sees an idle hand). Dormant rather than a stricter score test: it
needs no dormant class and costs nothing. The settle time (``arm_settle_s``) covers the object ringing
after the stop (docs/DORMANT.md, results/streams.md). A lost ``arm still`` must not deafen the daemon:
``arm moving`` holds at most ``max_move_frames`` (``arm_max_move_s``) unless repeated.

Thread use: ``request`` from any thread; ``update`` from the hot path only.
"""

from __future__ import annotations

import logging
import math
from collections import deque

__all__ = ["ArmMotion", "JointSpeed", "arm_frames", "log"]

log = logging.getLogger("handover.daemon")

NEVER = -(1 << 62)


def arm_frames(rate_hz: float, settle_s: float, max_move_s: float) -> tuple[int, int]:
    """``(settle_frames, max_move_frames)`` at the model's frame rate (``[control] arm_settle_s``, ``arm_max_move_s``)."""
    return max(0, math.ceil(settle_s * rate_hz - 1e-9)), max(1, math.ceil(max_move_s * rate_hz - 1e-9))


class ArmMotion:
    """Which frames the arm counts as moving in (the robot's messages plus the settle time)."""

    def __init__(self, settle_frames: int, max_move_frames: int) -> None:
        self.configure(settle_frames, max_move_frames)
        self._requests: deque[bool] = deque(maxlen=64)
        self.moving = False
        """The robot's last word (True between ``arm moving`` and ``arm still``)."""
        self.last_motion = NEVER
        """The last frame number that counts as moving (the settle time included; may lie ahead)."""
        self._since = NEVER
        self.dropped = 0
        """Windows judged dormant because they held frames of the arm's motion (counted by the detector that judges them)."""
        self._last = NEVER
        """The frame number of the previous ``update``."""

    def request(self, moving: bool) -> None:
        """The robot's word; applied at the next frame (thread-safe: one deque append)."""
        self._requests.append(bool(moving))

    def configure(self, settle_frames: int, max_move_frames: int) -> None:
        """New settings (a reload, a model at another rate); the robot's last word is kept."""
        if settle_frames < 0 or max_move_frames < 1:
            raise ValueError("settle_frames must be >= 0 and max_move_frames >= 1")
        self.settle_frames, self.max_move_frames = int(settle_frames), int(max_move_frames)

    def update(self, number: int) -> None:
        """Hot path, once per admitted frame ``number`` (the model's frame count)."""
        if self._last != NEVER and number <= self._last:
            # the count starts afresh (a new device client): carry the span over as if this frame followed
            # the last one; in the old count a past move would hold every window until the new one passed it
            shift = number - self._last - 1
            self._since = max(NEVER, self._since + shift)
            self.last_motion = max(NEVER, self.last_motion + shift)
        self._last = number
        while self._requests:
            moving = self._requests.popleft()
            if moving:
                self._since = number  # a repeated 'arm moving' renews the span
            elif self.moving:
                self.last_motion = number - 1 + self.settle_frames
            self.moving = moving
        if not self.moving:
            return
        if number - self._since >= self.max_move_frames:
            self.moving = False
            self.last_motion = number - 1 + self.settle_frames
            log.warning("the robot said 'arm moving' %d frames ago and nothing since: taken as still (send 'arm "
                        "still' when it stops, or repeat 'arm moving' while it moves; [arm] max_move_s)",
                        self.max_move_frames)
            return
        self.last_motion = number


class JointSpeed:
    """The arm's motion read from joint states (``sensor_msgs/JointState`` on ``[ros2] joint_states``).

    Moving while any joint is faster than ``threshold`` (the velocities, else the position change over
    time: many drivers publish positions only). Answers only on a change, repeating ``moving`` every
    ``renew_s`` so a long move is not taken for a lost ``arm still``. Non-finite values are ignored.
    """

    def __init__(self, threshold: float, renew_s: float = 1.0) -> None:
        self.threshold = float(threshold)
        self.renew_s = float(renew_s)
        self.moving: bool | None = None
        self._said_at = float("-inf")
        self._prev: tuple[list[float], float] | None = None

    def update(self, positions: list[float], velocities: list[float], stamp_s: float) -> bool | None:
        """One message; the word to send (True: moving, False: still) or None (nothing new)."""
        if stamp_s < self._said_at:
            # the clock went back (a bag played in a loop, sim time reset): 'moving' must still be
            # renewed, or the daemon takes the arm as still after arm_max_move_s while it moves
            self._said_at = float("-inf")
        finite_v = [abs(v) for v in velocities if math.isfinite(v)]
        if finite_v:
            speed = max(finite_v)
        else:
            prev, self._prev = self._prev, (list(positions), stamp_s)
            if prev is None or stamp_s <= prev[1] or len(prev[0]) != len(positions):
                return None
            moves = [abs(a - b) for a, b in zip(positions, prev[0], strict=True) if math.isfinite(a) and math.isfinite(b)]
            if not moves:
                return None
            speed = max(moves) / (stamp_s - prev[1])
        moving = speed > self.threshold
        if moving == self.moving and not (moving and stamp_s - self._said_at >= self.renew_s):
            return None
        self.moving, self._said_at = moving, stamp_s
        return moving
