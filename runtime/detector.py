"""The detector: frames in, decisions out. The daemon's hot path with nothing of the service around it.

``feed(frame)`` returns a ``Decision`` when the frame ends a window, else None. No I/O, no thread, no
config file, no sink: the daemon turns decisions into events, and replays, benchmarks and tests feed
recorded frames to a Detector directly, so what they measure is what the service decides. Around the
model, ``Windows`` says which frames end a window (and where early heads may answer sooner) and
``ReportRule`` which decided class is reported; which trigger the settings make is
``runtime.trigger_settings``' decision.
"""

from __future__ import annotations

import contextlib
import time
from collections import deque
from dataclasses import dataclass
from enum import IntEnum
from typing import TYPE_CHECKING, Protocol

import numpy as np

from firmware_io.frame_timing import NOMINAL_PERIOD_S, NOMINAL_RATE_HZ
from firmware_io.layout import SensorLayout
from runtime.arm_motion import ArmMotion, arm_frames
from runtime.config import Config, ContinuousConfig, ControlConfig, SceneConfig, TriggerConfig
from runtime.decision import ContinuousDecision
from runtime.early import EarlyRule
from runtime.frame_rate import FrameClock
from runtime.health import Health, one_line
from runtime.listeners import DecisionTimings
from runtime.output_check import output_problem
from runtime.ring import RingBuffer
from runtime.scene import scene_pads
from runtime.trigger import ContinuousTrigger, ThresholdTrigger
from runtime.trigger_settings import TriggerSettings, build_trigger, resolve_trigger

if TYPE_CHECKING:
    from firmware_io.client import Frame
    from runtime.model import LoadedModel

__all__ = ["REHEARSAL_LEAD_S", "Decision", "Detector", "ReportRule", "Run", "Trigger", "Windows"]

REHEARSAL_LEAD_S = 0.001
"""How long before a frame that runs the model the model is rehearsed (``Detector.rehearsal_at``):
close enough that the caches stay warm, wide enough for the frames' arrival jitter."""


class Trigger(Protocol):
    """What starts a window: ``ThresholdTrigger``, ``OnsetTrigger`` (runtime/onset.py) or ``ContinuousTrigger``."""

    window: int
    pre_frames: int

    def update(self, row: np.ndarray, number: int) -> int: ...

    def reset(self) -> None: ...

    def set_grasp(self, closed: bool) -> None: ...


class Run(IntEnum):
    """What ``Windows.runs_at`` answers when no early head runs (a head answers with its index, 0 and up)."""

    FULL = -1
    """The full model on the window ending at this frame."""
    DORMANT = -2
    """The window ending at this frame held a frame of the arm's motion: judged dormant, the model not run."""


FULL, DORMANT = Run.FULL, Run.DORMANT  # module constants: no enum lookup per frame


@dataclass(slots=True)
class Decision:
    """The model's answer on the window ending at ``frame``, and what of it is reported.

    ``report`` is the class index to report, or -1 (continuous mode between reports, a class outside
    ``scene.events``). ``problem`` is set instead when the model broke its output contract or failed
    on this window: the caller takes the model out of service (the detector keeps it until told)."""

    frame: Frame
    model: LoadedModel
    first: int
    """The device number of the window's first frame."""
    label: int
    scores: np.ndarray
    """float32 ``[1, n_classes]``."""
    report: int
    timings: DecisionTimings
    latency_us: float
    """From the window's last frame's arrival (``Frame.received``) to the model's answer."""
    missed: bool
    """Later than one model period."""
    problem: str | None = None

    @property
    def cls(self) -> str | None:
        """The reported class, or None."""
        return self.model.meta.classes[self.report] if self.report >= 0 else None


class Windows:
    """The frames at which open windows end, in order (the trigger fixes each one as it fires).

    The one place that decides when the model runs (``runs_at``): ``Detector.feed`` applies its answer,
    the rehearsal asks it about the next frame. A window that held a frame of the robot's arm moving
    (runtime.arm_motion) is judged dormant, the model not run. With a model's early heads (``early``:
    runtime.early) a window may be answered before its end: ``answered_early`` applies the rule to a
    head's answer and closes the window when it reports."""

    __slots__ = ("T", "_due", "_previous", "early", "every_frame")

    def __init__(self) -> None:
        self._due: deque[int] = deque()
        self.early: EarlyRule | None = None
        """The early heads' report rule of the serving model and scene (None: the full window only)."""
        self.T = 0
        self.every_frame = False
        """Every frame ends a window (continuous mode: the trigger opens it at that frame)."""
        self._previous = -1
        """The label of the oldest window's last early head (-1: none yet)."""

    def open(self, due: int) -> None:
        """The trigger fired: a window ends at frame ``due``."""
        self._due.append(due)

    def ends(self, number: int) -> bool:
        """Whether frame ``number`` ends the oldest open window (a frame past it drops that window)."""
        due = self._due
        if due and number >= due[0]:
            self._previous = -1
            return due.popleft() == number
        return False

    def runs_at(self, number: int, count: int, last_motion: int) -> Run | int | None:
        """What runs at frame ``number`` with ``count`` frames in the ring and the arm's motion up to frame
        ``last_motion`` (``ArmMotion.last_motion``): ``Run.FULL``, an early head's index (into
        ``early.points``), ``Run.DORMANT``, or None. Asks, changes nothing: ``ends`` then drops the window."""
        T, due = self.T, self._due
        if count < T or not (due or self.every_frame):
            return None
        end = number if self.every_frame else due[0]
        if number == end:
            return FULL if last_motion < number - T + 1 else DORMANT
        if number > end:  # the oldest window's last frame never came: dropped here, the next one's heads may answer
            end = due[1] if len(due) > 1 else number
        if self.early is None or number >= end:
            return None
        head = self.early.index_of(number - end + T)
        return head if head >= 0 and last_motion < end - T + 1 else None  # an arm move: judged at its end

    def answered_early(self, head: int, label: int, scores: np.ndarray) -> bool:
        """Whether head ``head``'s answer is reported now; if so the window is closed (one report per event)."""
        report = self.early.report_now(head, label, scores, self._previous)
        self._previous = label
        if report:
            self._due.popleft()
            self._previous = -1
        return report

    def clear(self) -> int:
        """Drop the open windows (the stream broke, the model changed); how many there were."""
        n = len(self._due)
        self._due.clear()
        self._previous = -1
        return n

    def __len__(self) -> int:
        return len(self._due)


class ReportRule:
    """Which decided class is reported: one in ``events``, and in continuous mode only when
    ``ContinuousDecision`` confirms it (one report per interaction)."""

    __slots__ = ("_reported", "continuous")

    def __init__(self, classes: tuple[str, ...], events: tuple[str, ...],
                 continuous: ContinuousDecision | None = None) -> None:
        self.continuous = continuous
        self._reported = tuple(c in events for c in classes)

    def judge(self, label: int, scores: np.ndarray) -> int:
        """The class index to report for this decision (``scores``: its row), or -1."""
        if self.continuous is not None:
            label = self.continuous.update(label, scores)
        return label if label >= 0 and self._reported[label] else -1

    def judge_dormant(self) -> None:
        """A window judged dormant without running the model (runtime.arm_motion): continuous mode's rule
        sees an idle hand; nothing is reported."""
        if self.continuous is not None:
            self.continuous.update(self.continuous.dormant)

    def reset(self) -> None:
        if self.continuous is not None:
            self.continuous.reset()


class Detector:
    """Frames in, decisions out (module docstring). Not thread-safe, except ``set_grasp`` and ``set_arm_moving``."""

    def __init__(self, scene: SceneConfig | None = None, trigger: TriggerConfig | None = None,
                 continuous: ContinuousConfig | None = None, health: Health | None = None,
                 control: ControlConfig | None = None) -> None:
        self.scene = scene or SceneConfig()
        self.trigger_config = trigger or TriggerConfig()
        self.continuous = continuous or ContinuousConfig()
        self.control = control or ControlConfig()
        """Read for the arm's settle and longest move times (``arm_settle_s``, ``arm_max_move_s``)."""
        self.layout: SensorLayout | None = None
        self.model: LoadedModel | None = None
        self.ring: RingBuffer | None = None
        self.trigger: Trigger | None = None
        self.trigger_settings: TriggerSettings | None = None
        self.rule: ReportRule | None = None
        self._continuous: ContinuousDecision | None = None
        """Continuous mode's report rule (kept with the trigger: its state survives a reload)."""
        self.windows = Windows()
        self.period_s = NOMINAL_PERIOD_S
        """The serving model's sample period (the nominal one until a model is served)."""
        self.frame_clock = FrameClock(1000.0 * self.period_s, health, on_restart=self.restart)
        """Feeds the model at its trained period: decimates faster streams, warns on slower ones."""
        self.latest_frame: Frame | None = None
        """The newest frame (the ROS 2 sink's pad images read it from their own thread)."""
        self._number = -1
        """The model's count of the newest admitted frame."""
        self._key: tuple | None = None
        """What the trigger and report rule were built from: the same key keeps them, and their state."""
        self._grasp: deque[tuple[bool, str]] = deque(maxlen=64)
        self.grasp_request: tuple[bool, str] | None = None
        """The latest ``set_grasp`` call: (closed, source)."""
        self.grasp_closed: bool | None = None
        """The robot's last word on its grasp, applied; None before any."""
        self.arm = ArmMotion(*self._arm_frames())
        """Which frames the robot's arm counts as moving in (``set_arm_moving``; runtime.arm_motion)."""
        self.arm_request: tuple[bool, str] | None = None
        """The latest ``set_arm_moving`` call: (moving, source)."""

    @classmethod
    def from_config(cls, cfg: Config, health: Health | None = None) -> Detector:
        """A detector with the settings of ``cfg`` (its scene, trigger, continuous and control sections)."""
        return cls(cfg.scene, cfg.trigger, cfg.continuous, health, cfg.control)

    # -- settings, layout, model -------------------------------------------------------------------
    def configure(self, scene: SceneConfig, trigger: TriggerConfig, continuous: ContinuousConfig,
                  control: ControlConfig | None = None) -> None:
        """New settings (a reload): the history is kept unless the scene changed."""
        same_scene = scene == self.scene
        self.scene, self.trigger_config, self.continuous = scene, trigger, continuous
        self.control = control or self.control
        self.rebuild(keep_history=same_scene)

    def fit(self, layout: SensorLayout) -> None:
        """The device's layout (at each connect): a new one rebuilds the hot path, the same one only
        forgets the history (a reconnected stream is not continuous: its time stamps start afresh)."""
        if layout != self.layout:
            self.layout = layout
            self.rebuild(keep_history=False)
        else:
            self.restart()
        self.frame_clock.reset()

    def swap(self, model: LoadedModel | None, layout: SensorLayout | None = None) -> None:
        """Serve ``model`` (one reference assignment; the caller checked it fits the scene: runtime.scene),
        or none (its windows are dropped). ``layout``: the device's, when it is new to the detector."""
        if layout is not None and layout != self.layout:
            self.layout, self.ring = layout, None
        self.model = model
        if model is None:
            self.windows.clear()
            return
        period_s = 1.0 / float(model.meta.sample_rate_hz or NOMINAL_RATE_HZ)
        same_rate = period_s == self.period_s  # frames kept at another rate would splice two time scales
        self.period_s = period_s
        self.frame_clock.set_model_period(1000.0 * period_s)
        self.rebuild(keep_history=same_rate)

    def set_grasp(self, closed: bool, source: str = "") -> None:
        """The robot's grasp has settled (``closed``) or is released. Thread-safe: only queued, applied
        at the next frame (the onset trigger arms on the settled grasp at once, or disarms)."""
        request = (bool(closed), str(source))
        self.grasp_request = request
        self._grasp.append(request)

    def set_arm_moving(self, moving: bool, source: str = "") -> None:
        """The robot's arm moves (``True``) or has stopped. Thread-safe: only queued, applied at the next
        frame (runtime.arm_motion: a window holding a frame of the motion or its settle time is dormant)."""
        self.arm_request = (bool(moving), str(source))
        self.arm.request(moving)

    def restart(self) -> None:
        """The stream is not continuous (a reconnect, a long gap in device time): forget its history."""
        if self.ring is not None:
            self.ring.reset()
        if self.trigger is not None:
            self.trigger.reset()
        if self.rule is not None:
            self.rule.reset()
        self.windows.clear()

    def counters(self) -> dict[str, int | bool]:
        """The frame clock's counts, the robot's last word on its arm and the windows its motion judged dormant."""
        return {**self.frame_clock.counters(), "arm_moving": self.arm.moving, "arm_windows": self.arm.dropped}

    @property
    def window_open(self) -> bool:
        """Whether a trigger has fired and its window's last frame is still to come."""
        return bool(self.windows)

    @property
    def window_s(self) -> float:
        """How long one window of the serving model takes to arrive at the stream's rate (0: no model)."""
        if self.model is None:
            return 0.0
        step = self.frame_clock.step
        return self.model.meta.T * self.frame_clock.period_ms / 1000.0 / (step if step < 1.0 else 1.0)

    # -- the hot path ------------------------------------------------------------------------------
    def feed(self, frame: Frame) -> Decision | None:
        """One frame: ring, trigger, and the model if this frame ends a window."""
        number = self.frame_clock.admit(frame.number, frame.timestamp_ms)  # the model's frame count; -1: skip
        if number < 0:
            return None
        self.latest_frame, self._number = frame, number
        ring = self.ring
        if ring is None:  # no layout yet
            return None
        ring.push(frame.values, number)
        if self._grasp:
            self._apply_grasp()
        self.arm.update(number)
        due = self.trigger.update(ring.latest(), number)
        model = self.model
        if model is None:
            return None
        windows = self.windows
        if due >= 0:
            windows.open(due)
        run = windows.runs_at(number, ring.count, self.arm.last_motion)
        windows.ends(number)  # a window this frame ends or passed is dropped (an early head's report closes its own)
        if run is None:
            return None
        if run is DORMANT:  # the arm moved during the window: the model does not run
            self.arm.dropped += 1
            self.rule.judge_dormant()
            return None
        return self._decide(model, frame, run)

    # -- keeping the next decision warm ------------------------------------------------------------
    def rehearsal_at(self) -> float | None:
        """When (``time.perf_counter``) to ``rehearse``: ``REHEARSAL_LEAD_S`` before the next frame is
        due, if that frame runs the model; else None. A decision that follows a whole period asleep
        finds the graph's code and data cold (results/latency.md says what a rehearsal buys)."""
        frame = self.latest_frame
        if frame is None or self._next_run() is None:
            return None
        return frame.received + self.frame_clock.period_ms / 1000.0 - REHEARSAL_LEAD_S

    def rehearse(self) -> None:
        """What the next frame will run (the full window or an early head), once now on the newest
        window, its answer dropped. Nothing else changes; a failure is left to that decision to report."""
        run, model = self._next_run(), self.model
        if run is None or model is None:
            return
        window = self.ring.window(model.meta.T)
        with contextlib.suppress(Exception):  # the decision itself meets it and takes the model out of service
            model.run_trusted(window) if run is FULL else model.run_head(run, window)

    def _next_run(self) -> Run | int | None:
        """What ``feed`` will run at the next model frame (``Windows.runs_at``), or None. Only the ring as
        it holds now counts (the rehearsal runs on its newest window); news the next frame brings (a
        window the trigger opens, the robot's 'arm moving') is not known yet."""
        if self.model is None or self.ring is None:
            return None
        run = self.windows.runs_at(self._number + 1, self.ring.count, self.arm.last_motion)
        return None if run is DORMANT else run

    def _decide(self, model: LoadedModel, frame: Frame, head: Run | int = FULL) -> Decision | None:
        """The model (or early head ``head``) on the window ending at ``frame``, checked; each stage
        stamped. None when an early head's answer is not safe yet (``Windows.answered_early``)."""
        clock = time.perf_counter
        started = clock()
        meta = model.meta
        window = self.ring.window(meta.T)  # a float32 [1, T, C] view of the ring: no copy
        windowed = clock()
        seen = meta.T if head is FULL else model.early.points[head]
        first = self.frame_clock.window_first(frame.number, seen)
        problem = None
        try:
            labels, scores = model.run_trusted(window) if head is FULL else model.run_head(head, window)
        except Exception as exc:  # a graph that fails on real frames only
            labels, scores = np.zeros(1, np.int64), np.zeros((1, meta.n_classes), np.float32)
            problem = f"inference failed on frames {frame.number - seen + 1}..{frame.number}: {one_line(exc)}"
        decided = clock()
        if problem is None and (bad := output_problem(labels, scores, meta.n_classes)):
            problem = f"{bad} (frames {frame.number - seen + 1}..{frame.number})"
        stamps = DecisionTimings(frame.received, started, windowed, decided, clock())
        latency_us = (decided - frame.received) * 1e6
        if problem is not None:
            return Decision(frame, model, first, -1, scores, -1, stamps, latency_us, False, problem)
        label = int(labels[0])
        if head is not FULL and not self.windows.answered_early(head, label, scores[0]):
            return None
        report = self.rule.judge(label, scores[0])
        return Decision(frame, model, first, label, scores, report, stamps, latency_us,
                        latency_us > self.frame_clock.deadline_s() * 1e6)

    def _apply_grasp(self) -> None:
        while self._grasp:
            closed, _source = self._grasp.popleft()
            self.grasp_closed = closed
            self.trigger.set_grasp(closed)

    # -- fitting the hot path (never per frame) ----------------------------------------------------
    def rebuild(self, keep_history: bool) -> None:
        """Ring, trigger and report rule for the current layout, scene and model; with ``keep_history`` the
        ring keeps its frames and the same trigger (same settings) its state."""
        if self.layout is None:
            return
        pads = scene_pads(self.scene, self.model, self.layout)
        cols = self.layout.columns(pads)
        meta = self.model.meta if self.model is not None else None
        T = int(meta.T) if meta else 15
        settings = resolve_trigger(self.trigger_config, meta.trigger if meta else None)
        self.trigger_settings = settings
        capacity = max(64, 2 * (T + settings.pre_frames))
        ring = self.ring
        if ring is None or not keep_history or not np.array_equal(ring.columns, cols):
            self.ring = RingBuffer(cols, capacity)
        elif ring.capacity < capacity:
            self.ring = ring.resized(capacity)
        mode = self.scene.mode
        fullscale = float(meta.fullscale) if meta else self.layout.fullscale
        inputs = (settings, tuple(self.layout.pad_sizes(pads)), fullscale, T, 1.0 / self.period_s,
                  tuple(self.layout.pad_fingers(pads)))  # build_trigger's arguments
        key = (mode, self.continuous if mode == "continuous" else None, cols.tobytes(),
               meta.classes if meta else None, meta.dormant_class if meta else None, inputs)
        # the same trigger and report rule (a reload that changed other sections, a model of the same kind
        # swapped in) keep their state, e.g. the onset trigger's settled grasp
        if not (keep_history and self.trigger is not None and key == self._key):
            self._new_trigger(inputs, meta, keep_history)
        self._key = key
        self.rule = ReportRule(tuple(meta.classes) if meta else (), self.scene.events, self._continuous)
        self.arm.configure(*self._arm_frames())
        self.windows.clear()
        self.windows.early, self.windows.T = self._early_rule(), T
        self.windows.every_frame = isinstance(self.trigger, ContinuousTrigger)

    def _early_rule(self) -> EarlyRule | None:
        """The serving model's early heads under the scene's ``early_events`` (trigger mode only). Only a
        reported event is answered early: a head that reads the window as dormant (or as a class the scene
        does not report) leaves it to the next head, and to the full model at T."""
        model = self.model
        if model is None or model.early is None or self.scene.mode != "trigger":
            return None
        early = self.scene.events if self.scene.early_events is None else self.scene.early_events
        return EarlyRule(model.early, model.meta.classes, frozenset(c for c in early if c in self.scene.events))

    def _arm_frames(self) -> tuple[int, int]:
        return arm_frames(1.0 / self.period_s, self.control.arm_settle_s, self.control.arm_max_move_s)

    def _new_trigger(self, inputs: tuple, meta, keep_history: bool) -> None:
        """A trigger (and continuous mode's ``ContinuousDecision``) for ``build_trigger``'s ``inputs``; a threshold trigger takes over the
        old one's arming, an onset trigger the robot's closed grasp."""
        old = self.trigger
        self._continuous = None
        if self.scene.mode == "continuous":
            self.trigger = ContinuousTrigger(inputs[3])
            if meta is not None and meta.dormant_class in meta.classes:
                cc = self.continuous
                self._continuous = ContinuousDecision(
                    len(meta.classes), list(meta.classes).index(meta.dormant_class), confirm_frames=cc.confirm_frames,
                    min_margin=cc.min_margin, rearm_frames=cc.rearm_frames, gap_frames=cc.gap_frames, vote=cc.vote)
            return
        self.trigger = build_trigger(*inputs)
        if isinstance(old, ThresholdTrigger) and isinstance(self.trigger, ThresholdTrigger) and keep_history:
            self.trigger.armed, self.trigger.last_trigger, self.trigger.quiet = old.armed, old.last_trigger, old.quiet
        elif keep_history and self.grasp_closed:
            self.trigger.set_grasp(True)  # a new trigger on the same settled grasp
