"""A scripted simulated subject behind an emulated controller: it does whatever the recorder prompts.

On ``go`` with a trial slot it plays that simulated trial through a DeviceEmulator (after ``prepare``
it holds the grasp, after ``stop`` the hand is empty). It can also drop the link once (``drop_at``),
be unplugged for good (``unplug_at``) or ignore some cues (``lazy``). URL form for ``handover record``:
``subject://?seed=0&lab=B&speed=1.0|max&drop=300,900&unplug=2000&lazy=2&fault=crc=0.01`` (``lab``: whose hand
and people, ``firmware_io.sim.lab``; a recording says it in its meta, ``ScriptedSubject.meta``)
"""

from __future__ import annotations

import threading
from collections.abc import Iterable

import numpy as np

from firmware_io.emulator.device import DeviceEmulator, FaultPlan
from firmware_io.frame_timing import NOMINAL_PERIOD_S
from firmware_io.layout import SensorLayout
from firmware_io.sim import ACTIONS, POSES, simulate_protocol
from firmware_io.sim.idle import idle_rng, plan_stretch, render_hold
from firmware_io.sim.lab import Lab, get_lab
from firmware_io.sim.paper_protocol import hand_sensor
from firmware_io.transports.base import DeviceUnavailable, ParsedURL, Transport, TransportError
from firmware_io.transports.emulated import SUBJECT_SCHEME, EmulatedTransport, SubjectTransport

__all__ = ["ScriptedSubject"]


class _LiveFrames:
    """``frames[i]`` as the emulator reads it: asks the subject for the next frame."""

    def __init__(self, subject: ScriptedSubject) -> None:
        self._subject = subject

    def __getitem__(self, index: int) -> np.ndarray:
        return self._subject.next_frame()


class _LiveSource:
    """The part of a Recording a DeviceEmulator reads, for a one-frame loop whose frame is live."""

    n_frames = 1

    def __init__(self, subject: ScriptedSubject, layout: SensorLayout, period: float) -> None:
        self.layout = layout
        self.timestamps = np.zeros(1)
        self.frames = _LiveFrames(subject)
        self._period = period

    def sample_interval(self) -> float:
        return self._period


class ScriptedSubject:
    """A simulated person and an emulated controller; ``connect`` opens a link (a DSAClient source)."""

    def __init__(
        self,
        seed: int = 0,
        *,
        speed: float | None = 1.0,
        faults: FaultPlan | None = None,
        drop_at: Iterable[int] = (),
        unplug_at: int | None = None,
        unplug_idle: int = 0,
        lazy: Iterable[int] = (),
        trial_seconds: float = 3.0,
        layout: SensorLayout | None = None,
        lab: Lab | str | None = None,
    ) -> None:
        self.seed = int(seed)
        self.lab = get_lab(lab)
        self.layout = layout or SensorLayout.sdh2()
        self.trial_seconds = max(float(trial_seconds), 1.5)
        self.drop_at = set(int(k) for k in drop_at)
        self.unplug_at = unplug_at
        self.unplug_idle = int(unplug_idle)
        """Unplugged for good when cued for this idle stretch (1-based; 0: never): at ``speed=max``
        a frame count lands wherever the machine's speed puts it, a stretch does not."""
        self.lazy = set(int(k) for k in lazy)
        self.emitted = 0
        self.connections = 0
        self.unplugged = False
        self.performed: list[dict] = []
        self._gos = 0
        self._attempts: dict[tuple, int] = {}
        self._segment: np.ndarray | None = None
        self._pos = 0
        self._empty = np.zeros(self.layout.n_taxels, dtype=np.uint16)
        self._idle = self._empty
        """What the hand reads between actions: empty, or the placed object's grasp."""
        self._pending: tuple[np.ndarray, int] | None = None
        self._pending_key: tuple = ()
        self._pending_attempt = 0
        self._lock = threading.Lock()
        self._idles = 0
        self._sensor = None
        self.emulator = DeviceEmulator(_LiveSource(self, self.layout, NOMINAL_PERIOD_S), speed=speed, loop=True,
                                       faults=faults, seed=self.seed)

    @classmethod
    def from_url(cls, url: str | ParsedURL) -> ScriptedSubject:
        """The subject a ``subject://`` URL describes, its options read and checked by its transport
        (``SubjectTransport``, in the one registry of schemes)."""
        parsed = url if isinstance(url, ParsedURL) else ParsedURL(url)
        if parsed.scheme != SUBJECT_SCHEME:
            raise TransportError(f"{parsed.url}: not a {SUBJECT_SCHEME}:// URL")
        return cls(**SubjectTransport.url_settings(parsed, {}))

    @property
    def meta(self) -> dict:
        """What a recording of this subject says about its source (the recorder copies it into its meta)."""
        return {"synthetic": True, **self.lab.meta}

    # -- the device side ---------------------------------------------------------------------------
    def connect(self) -> Transport:
        """A fresh link to the emulated controller (what a reconnect gets); refused once unplugged."""
        if self.unplugged:
            raise DeviceUnavailable(f"{SUBJECT_SCHEME}://: the device is unplugged")
        self.connections += 1
        lab = f"&lab={self.lab.name}" if self.lab.key else ""  # a recording's sessions say whose hand it was
        return EmulatedTransport(self.emulator, f"{SUBJECT_SCHEME}://?seed={self.seed}{lab}")

    def next_frame(self) -> np.ndarray:
        """The frame the controller sends now (called by the emulator once per frame)."""
        with self._lock:
            self.emitted += 1
            if self.emitted in self.drop_at:
                self.emulator.disconnected = True
            if self.unplug_at is not None and self.emitted >= self.unplug_at:
                self.unplugged = True
                self.emulator.disconnected = True
            if self._segment is not None and self._pos < len(self._segment):
                values = self._segment[self._pos]
                self._pos += 1
                return values
            return self._idle

    # -- the person side -----------------------------------------------------------------------------
    def cue(self, kind: str, slot) -> dict | None:
        """The recorder's prompt; returns annotations for the trial on ``go``.

        ``prepare`` ("place the object"): the object is placed and the hand holds it (the trial's
        grasp, as the simulated protocol's trials start); ``go``: the subject acts; ``stop``: the
        hand is emptied for the next placement."""
        if kind == "prepare":
            self._prepare(slot)
            return None
        if kind == "idle":
            return self._idle_stretch(slot)
        if kind == "stop":
            with self._lock:
                self._segment, self._idle = None, self._empty
            return None
        if kind != "go":
            return None
        self._gos += 1
        key, attempt = self._pending_key, self._pending_attempt
        if self._pending is None or key != (slot.pose, slot.object, slot.action, slot.run):
            self._prepare(slot)  # go without prepare: place and act at once
            key, attempt = self._pending_key, self._pending_attempt
        frames, onset = self._pending
        if self._gos in self.lazy:  # holds the object, does nothing
            self.performed.append({"slot": key, "attempt": attempt, "acted": False})
            return {"synthetic": True, "scripted_subject": {"seed": self.seed, "acted": False}}
        with self._lock:
            self._segment, self._pos = frames, 0
        self.performed.append({"slot": key, "attempt": attempt, "acted": True, "onset": onset})
        played = {"lab": self.lab.name, "object": self.lab.object_for(slot.object)} if self.lab.key else {}
        return {"synthetic": True, "onset": onset, "scripted_subject": {"seed": self.seed, "acted": True, **played}}

    def _idle_stretch(self, slot) -> dict:
        """Act out an idle stretch (``firmware_io.recordings.idle_stretches.IdleSlot``): the simulated
        hand does what the recorder prompted, nobody touches the object; afterwards the hand stays as
        the stretch left it (holding, or open after a release)."""

        self._idles += 1
        if self.unplug_idle and self._idles >= self.unplug_idle:
            with self._lock:
                self.unplugged = True
                self.emulator.disconnected = True
        seconds = float(slot.seconds) + 1.0  # the capture starts a frame or two after the cue
        if slot.source == "open":
            frames = np.zeros((int(np.ceil(seconds / NOMINAL_PERIOD_S)), self.layout.n_taxels), dtype=np.uint16)
        else:
            rng = idle_rng(self.seed, "recorded", self._idles)
            if self._sensor is None:
                self._sensor = hand_sensor(self.seed, lab=self.lab)
            frames = render_hold(plan_stretch(rng, slot.source, seconds, lab=self.lab), self._sensor, rng)
        if frames.shape[1] != self.layout.n_taxels:
            raise ValueError("the simulated hand's layout differs from the subject's")
        with self._lock:
            self._segment, self._pos = frames, 0
            self._idle = self._empty if slot.source in ("release", "open") else frames[-1]
        self.performed.append({"idle": slot.source, "index": int(slot.index)})
        return {"synthetic": True, "scripted_subject": {"seed": self.seed, "idle": slot.source}}

    def _prepare(self, slot) -> None:
        """Place the object: the next attempt of this slot is drawn and its grasp held until go."""
        key = (slot.pose, slot.object, slot.action, slot.run)
        attempt = self._attempts.get(key, 0) + 1
        self._attempts[key] = attempt
        frames, onset = self._render(slot, attempt)
        self._pending, self._pending_key, self._pending_attempt = (frames, onset), key, attempt
        with self._lock:
            self._segment, self._idle = None, frames[0]

    def _render(self, slot, attempt: int) -> tuple[np.ndarray, int]:
        """One simulated trial of this slot; every attempt is a new draw (a person never repeats exactly)."""

        pose = slot.pose if slot.pose in POSES else POSES[0]
        obj = self.lab.object_for(slot.object)
        action = slot.action if slot.action in ACTIONS else "hold"
        rec = simulate_protocol(seed=self.seed + 1000 * (attempt - 1), n_subjects=1, runs=int(slot.run),
                                poses=[pose], objects=[obj], actions=[action],
                                duration=self.trial_seconds + 0.5, lab=self.lab)[0]
        trial = rec.trials[-1]
        frames, _ = rec.trial_frames(trial)
        if rec.layout.n_taxels != self.layout.n_taxels:
            raise ValueError("the simulated hand's layout differs from the subject's")
        return frames.copy(), int(trial.extra.get("onset", -1))
