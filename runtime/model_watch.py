"""Model hot-swap: watch the model folder, validate new ``.onnx`` files off the hot path.

A file is considered once it is complete (not a dotfile, ``*.tmp`` or ``*.part``; the same size, times
and inode on two polls) and refused when a symlink, writable by others or owned by another user. It is
checked, warmed up in this thread and only then offered for a swap; a rejected file is not retried
until it changes (or ``rescan()``). The valid file that arrived last by mtime serves (not ctime: a no-op
``chmod`` sets that); when it leaves the folder the newest remaining one serves, or none. To roll back:
remove the newer file, or ``touch`` the older one.
"""

from __future__ import annotations

import errno
import logging
import os
import re
import stat
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from runtime.background import Background
from runtime.model import ModelContractError, ModelUnreadableError
from runtime.output_check import DEFAULT_BUDGET_FRACTION
from runtime.quarantine import QuarantineStore, file_key

__all__ = ["ModelWatcher", "Rejection", "folder_problem", "is_candidate_name", "log"]

log = logging.getLogger("handover.models")

IGNORED_SUFFIXES = (".tmp", ".part", ".partial", ".swp")
SETTLE_S = 10.0
"""A file that is not (yet) a whole model and was modified less than this long ago is taken as
still being copied in place (a copy may pause for seconds, so two equal polls do not prove it
complete): one info line, retried on every poll, rejected only once it has stayed unreadable and
unchanged this long. A file renamed into place complete is never in this state."""


@dataclass(frozen=True)
class FileState:
    """What a poll sees of one file; equal states on two polls mean the file is complete."""

    path: Path
    size: int
    mtime_ns: int
    ctime_ns: int
    inode: int
    mode: int
    uid: int


    @property
    def arrival(self) -> tuple[int, str]:
        """Order of arrival in the folder (the newest modified sorts last)."""
        return (self.mtime_ns, self.path.name)

    def same_file(self, other: FileState | None) -> bool:
        """The same version of the same file (its mode or owner may have changed since)."""
        return other is not None and (self.path, self.inode, self.size, self.mtime_ns) == (
            other.path, other.inode, other.size, other.mtime_ns)


NEVER: tuple[int, str] = (-1, "")
MEASURED_MS = re.compile(r"\d+\.\d+ ms")
"""A duration in a rejection's reason (the warm-up's measured median, the budget it missed): it differs
on every weighing of one file, so it does not make the reason a new one."""


@dataclass(frozen=True)
class Rejection:
    path: Path
    reason: str
    repeat: bool = False
    """This version of the file was rejected for this reason before (a reload or a new device weighed
    it again): not logged again, nor counted again."""


def is_candidate_name(name: str) -> bool:
    """``*.onnx`` that is not a dotfile or a temporary name."""
    if name.startswith(".") or not name.endswith(".onnx"):
        return False
    return not any(name.endswith(s) for s in IGNORED_SUFFIXES)


def folder_problem(folder: str | Path, key: str = "model.folder") -> str | None:
    """Why a model folder (the config's ``key``) can never be read (a file, no permission), or None. A
    folder that does not exist yet is not a problem here: the daemon waits for it to appear."""
    path = Path(folder)
    if not path.exists():
        return None
    if not path.is_dir():
        return f"{key}: {path} is not a folder (point {key} at the folder the models are dropped in)"
    try:
        with os.scandir(path):
            pass
    except OSError as exc:
        return f"{key}: cannot read {path} ({exc.strerror or exc}); give the service user read access"
    return None


def folder_error(folder: Path, exc: OSError, key: str = "model.folder") -> str:
    """The line for a model folder the watcher cannot list: what is wrong and what to do."""
    what = "shadow folder" if key == "model.shadow" else "model folder"
    if exc.errno == errno.ENOENT:
        return (f"{what} {folder} does not exist (deleted or renamed?): create it (mkdir -p, readable by "
                f"the service user) or fix {key} and reload; models dropped there are then picked up")
    return folder_problem(folder, key) or f"{what} {folder}: {exc.strerror or exc}; check {key}"


def permission_problem(st: FileState, service_uid: int | None = None) -> str | None:
    """Why a file must not be trusted, or None."""
    uid = os.geteuid() if service_uid is None else service_uid
    if not stat.S_ISREG(st.mode):
        return "not a regular file (symlinks and devices are refused)"
    if st.mode & (stat.S_IWGRP | stat.S_IWOTH):
        return (f"writable by group or others (mode {stat.S_IMODE(st.mode):o}, e.g. copied under umask 002): "
                f"run chmod 644 {st.path} (or install -m 644 when copying)")
    if st.uid not in (uid, 0):
        return f"owned by uid {st.uid}, not by the service user (uid {uid}) or root"
    return None


class ModelWatcher:
    """Polls a folder; the newest valid model ends up in ``pending`` for the main loop to ``take()``."""

    def __init__(
        self,
        folder: str | Path,
        loader: Callable[[Path], Any],
        check: Callable[[Any], str | None] | None = None,
        poll_interval: float = 1.0,
        decision_budget: float | None = DEFAULT_BUDGET_FRACTION,
        on_reject: Callable[[Rejection], None] | None = None,
        service_uid: int | None = None,
        quarantine: QuarantineStore | None = None,
        said: dict[Path, tuple[tuple[int, int, int], str]] | None = None,
        after_reject: str | None = None,
        key: str = "model.folder",
    ) -> None:
        self.folder, self.key = Path(folder), key
        """The folder and the config key that names it (in the lines about the folder)."""
        self.after_reject = after_reject
        """What a rejection line says happens next (None: the model folder's words on what serves)."""
        self.loader = loader
        self.check = check
        self.poll_interval = float(poll_interval)
        self.decision_budget = decision_budget
        """Fraction of the sample period one warm-up decision may take (None: not timed)."""
        self.on_reject = on_reject
        self.service_uid = service_uid
        self.quarantined = quarantine if quarantine is not None else QuarantineStore()
        """File versions taken out of service at run time: never loaded again until they change."""
        self.said = said if said is not None else {}
        """The rejection last logged per file (its version and reason): a daemon reloaded for months
        logs a broken file once per version and reason, not once per reload. Pass the same dict to the
        watcher that replaces this one."""
        self._accepted_states: dict[Path, FileState] = {}
        self._skipped: set[FileState] = set()
        """Files passed over only because a newer one was chosen (candidates again after a quarantine)."""
        self._reconsider = False
        self._settling: set[FileState] = set()
        self.pending: Any = None
        """A validated, warmed-up model waiting for the main loop (set by the watcher thread)."""
        self.current: FileState | None = None
        """The file of the model last accepted (the one serving, once taken)."""
        self.rejections: list[Rejection] = []
        self.accepted: list[Path] = []
        self._previous: dict[Path, FileState] = {}
        self._tried: set[FileState] = set()
        self._lock = threading.Lock()
        self._loop = Background("model-watch", lambda: self.poll(), lambda: self.poll_interval, log, "model watcher poll failed")
        self._folder_error_logged = False
        self.unreadable_names: set[str] = set()
        """Candidate names with control characters: each said once (in repr) and never read."""
        self._rescan: bool | None = None
        self._listed = False
        """Whether the last scan could list the folder (a folder that cannot be read withdraws nothing)."""
        self.withdrawn = False
        """The serving file left the folder and no file there can serve: the main loop serves none
        (``take_withdrawal``)."""
        self._left = False
        """The serving file left and nothing has served since: withdrawn once every file there is weighed (a
        file changed in place is weighed polls later, when it is stable)."""

    def rescan(self, keep_current: bool) -> None:
        """Try every file again at the next poll (the scene changed, so a rejection may no longer
        hold). ``keep_current=False``: the model in use no longer serves, so an earlier file may."""
        self._rescan = keep_current

    # -- scanning -------------------------------------------------------------------------------
    def _list(self) -> dict[Path, FileState]:
        out: dict[Path, FileState] = {}
        try:
            entries = list(os.scandir(self.folder))
        except OSError as exc:
            if not self._folder_error_logged:
                log.error("%s", folder_error(self.folder, exc, self.key))
                self._folder_error_logged = True
            self._listed = False
            return out
        self._folder_error_logged = False
        self._listed = True
        for entry in entries:
            if not is_candidate_name(entry.name):
                continue
            if not entry.name.isprintable():  # every line about the file would print it: a newline forges lines
                if entry.name not in self.unreadable_names:
                    self.unreadable_names.add(entry.name)
                    log.error("model folder %s: the file %r has control characters in its name and is not read; "
                              "rename it", self.folder, entry.name)
                continue
            try:
                st = entry.stat(follow_symlinks=False)
            except OSError:
                continue
            path = Path(entry.path)
            out[path] = FileState(path, st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino, st.st_mode, st.st_uid)
        return out

    def poll(self, require_stable: bool = True) -> Any:
        """One scan. Returns the newly accepted model (also stored in ``pending``) or None.

        With ``require_stable=False`` (startup: nobody should be copying while the service
        starts, and waiting a poll would delay READY) files are taken as they are.
        """
        self._apply_rescan()
        if self._reconsider:  # set by the main loop; applied here, in the polling thread
            self._reconsider = False
            self._tried -= self._skipped
            self._skipped.clear()
            self.current = None
        now = self._list()
        if self._listed:  # forget files that left (list(): a replaced watcher may still be finishing a poll)
            for path in list(self.said):
                if path not in now:
                    self.said.pop(path, None)
        gone = self._listed and self.current is not None and not self.current.same_file(now.get(self.current.path))
        if gone:
            self._serving_file_left()
        stable = [s for p, s in now.items() if not require_stable or self._previous.get(p) == s]
        self._previous = now
        fresh = [s for s in stable if s not in self._tried]
        fresh.sort(key=lambda s: s.arrival, reverse=True)
        current = self.current.arrival if self.current is not None else NEVER
        accepted = None
        for st in fresh:
            self._tried.add(st)
            if accepted is not None:
                log.info("model %s: superseded by %s, dropped after it; not loaded", st.path.name, accepted[0].path.name)
                self._skipped.add(st)
                continue
            if st.arrival < current:
                log.info("model %s: dropped before the model in use; not loaded", st.path.name)
                self._skipped.add(st)
                continue
            model = self._validate(st)
            if model is not None:
                accepted = (st, model)
        if accepted is None:
            if self._left and len(stable) == len(now):  # every file there was weighed: none can serve
                self._left = False
                with self._lock:
                    self.withdrawn = True
            return None
        st, model = accepted
        if self.current is not None:  # passed over for a newer one: weighed again if that one leaves
            self._skipped.add(self.current)
        self.current, self._left = st, False
        self._accepted_states[st.path] = st
        self.accepted.append(st.path)
        with self._lock:
            self.pending, self.withdrawn = model, False
        return model

    def _serving_file_left(self) -> None:
        """The file of the model in use is no longer what the folder holds: weigh again every file
        passed over for it (files rejected on their own stay rejected)."""
        log.warning("model %s is no longer in %s (removed, replaced, or the folder switched): the newest valid file "
                    "the folder holds now serves", self.current.path.name, self.folder)
        self._tried -= self._skipped
        self._skipped.clear()
        self.current, self._left = None, True

    def take_withdrawal(self) -> bool:
        """Whether the serving model was withdrawn (once): the main loop then serves none."""
        with self._lock:
            withdrawn, self.withdrawn = self.withdrawn, False
        return withdrawn

    def _apply_rescan(self) -> None:
        keep, self._rescan = self._rescan, None
        if keep is None:
            return
        self._tried = {self.current} if keep and self.current is not None else set()
        self._skipped.clear()
        if not keep:
            self.current = None

    def _validate(self, st: FileState) -> Any:
        problem = permission_problem(st, self.service_uid)
        if problem is not None:
            return self._reject(st, problem)
        earlier = self.quarantined.reason(file_key(st.path, st.size, st.mtime_ns, st.inode))
        if earlier is not None:
            return self._reject(st, f"taken out of service earlier ({earlier}); replace the file to try again")
        try:
            model = self.loader(st.path)
        except ModelUnreadableError as exc:
            if time.time() - st.mtime_ns / 1e9 < SETTLE_S:
                return self._settle(st, exc)
            return self._reject(st, str(exc))
        except Exception as exc:  # the contract's own errors and anything a broken file can raise
            return self._reject(st, str(exc) or type(exc).__name__)
        if self.check is not None:
            problem = self.check(model)
            if problem is not None:
                return self._reject(st, problem)
        try:
            model.warm_up(budget_fraction=self.decision_budget)
        except ModelContractError as exc:  # wrong answers on realistic windows, or too slow
            return self._reject(st, str(exc).removeprefix(f"model {st.path}: "))
        except Exception as exc:
            return self._reject(st, f"warm-up inference failed: {exc}")
        log.info("model %s accepted (id %s)", st.path.name, getattr(model, "model_id", "?"))
        return model

    def _settle(self, st: FileState, exc: Exception) -> None:
        """A young file that is not a whole model yet: one info line, tried again on the next poll."""
        self._tried.discard(st)
        if st not in self._settling:
            self._settling.add(st)
            log.info("model %s: not a whole model yet (%s); taken as still being copied, retried until it has "
                     "been unchanged %.0f s", st.path.name, str(exc).removeprefix(f"model {st.path}: "), SETTLE_S)
        return None

    def _reject(self, st: FileState, reason: str) -> None:
        version, same = (st.inode, st.size, st.mtime_ns), MEASURED_MS.sub("… ms", reason)
        rejection = Rejection(st.path, reason, repeat=self.said.get(st.path) == (version, same))
        self.said[st.path] = (version, same)
        if rejection.repeat:
            log.debug("model %s rejected again: %s", st.path.name, reason)
        else:
            self.rejections.append(rejection)
            serving = self.after_reject or (
                "the model in use keeps serving" if self.current is not None
                else "no model serves yet: the newest valid file in the folder will, or the next valid one dropped")
            log.error("model %s rejected: %s; %s", st.path.name, reason, serving)
        if self.on_reject is not None:
            self.on_reject(rejection)
        return None

    def quarantine_file(self, path: Path, reason: str) -> None:
        """Never load this version of ``path`` again (also after a restart, when the store has a file)."""
        st = self._accepted_states.get(Path(path))
        if st is None:  # not loaded by this watcher (e.g. served by the caller): the file as it is now
            self.quarantined.quarantine_file(path, reason)
            return
        self._tried.add(st)
        self.quarantined.add(file_key(st.path, st.size, st.mtime_ns, st.inode), reason)

    def reconsider_older(self) -> None:
        """The model in use was taken out of service and none is left in memory: on the next poll,
        files passed over for a newer one are candidates again (the newest valid one serves)."""
        self._reconsider = True

    def take(self) -> Any:
        """The pending model (once), or None. Called by the main loop between two windows."""
        with self._lock:
            model, self.pending = self.pending, None
        return model

    # -- background thread ----------------------------------------------------------------------
    def start(self) -> None:
        self._loop.start()

    def stop(self, timeout: float = 1.0) -> None:
        self._loop.stop(timeout)
