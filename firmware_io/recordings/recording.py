"""Recording files: raw frames of one subject or session with their labelled trials.

Format (``.hrec``): an uncompressed ZIP (NumPy ``.npz`` layout) with three members,

- ``header.json``: ``{"format": "handover-recording", "version": 1, "layout": {...},
  "trials": [...], "meta": {...}, "n_frames": N, "n_taxels": C}``
- ``frames.npy``: uint16 ``[N, C]``, taxel values in wire order
- ``timestamps.npy``: float64 ``[N]``, seconds, strictly increasing

ZIP members carry CRC-32, so a truncated or corrupted file is detected on read. Writing goes
to a temporary file in the same folder, is fsynced and then renamed over the target, so a
crash never leaves a half-written file under the final name.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import stat
import tempfile
import zipfile
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from firmware_io.errors import HandoverError
from firmware_io.frame_timing import NOMINAL_PERIOD_S
from firmware_io.layout import SensorLayout
from firmware_io.recordings import arm_marks, idle_stretches
from firmware_io.recordings.bounded_zip import LimitError, first_line, quote, read_json, read_npy

__all__ = [
    "ACTIONS", "MAX_NAME_CHARS", "SUFFIX", "Recording", "RecordingError", "Trial", "find_recordings", "load_all", "name_problem",
    "remove_stale_temps"
]

FORMAT_NAME = "handover-recording"
FORMAT_VERSION = 1
SUFFIX = ".hrec"

ACTIONS = ("pull", "push", "hold", "bump")
"""The paper's four interaction events, in the order used for class indices."""
MAX_NAME_CHARS = 64
"""The longest subject, object, pose or action of a trial: a subject id names its file (``subject_ID.hrec``),
and training keeps each name once per case (a 4 MB id multiplied a run's peak memory by 4.5)."""


def name_problem(kind: str, value: object) -> str | None:
    """Why ``value`` cannot be a subject, object, pose or action name, or None. Printable, because names
    are printed and written into reports (an ESC in one cleared a terminal)."""
    if not isinstance(value, str) or not 0 < len(value) <= MAX_NAME_CHARS or not value.isprintable():
        return f"{kind} must be a name of 1 to {MAX_NAME_CHARS} printable characters, got {quote(value)}"
    return None


MAX_RUN = 2**31 - 1
"""The largest run number: training keeps runs as 64-bit integers (10**30 was an OverflowError)."""


class RecordingError(HandoverError, ValueError):
    """A recording file that cannot be read or written; the message names the file."""


@dataclass(frozen=True)
class Trial:
    """One labelled trial: frames ``first`` .. ``last`` (both inclusive) of the recording."""

    subject: str
    object: str
    pose: str
    action: str
    run: int
    first: int
    last: int
    extra: dict = field(default_factory=dict, compare=False)
    """Free-form annotations, e.g. the simulator's event onset frame (``onset``)."""

    @property
    def n_frames(self) -> int:
        return self.last - self.first + 1

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> Trial:
        return cls(
            subject=str(d["subject"]),
            object=str(d["object"]),
            pose=str(d["pose"]),
            action=str(d["action"]),
            run=int(d["run"]),
            first=int(d["first"]),
            last=int(d["last"]),
            extra=dict(d.get("extra", {})),
        )


@dataclass
class Recording:
    """Frames, timestamps, layout and trials of one file."""

    layout: SensorLayout
    frames: np.ndarray
    timestamps: np.ndarray
    trials: list[Trial] = field(default_factory=list)
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.frames = np.ascontiguousarray(self.frames, dtype=np.uint16)
        self.timestamps = np.ascontiguousarray(self.timestamps, dtype=np.float64)
        problem = self.problem()
        if problem:
            raise RecordingError(problem)

    def problem(self) -> str | None:
        """Why this recording is inconsistent, or None."""
        f, t = self.frames, self.timestamps
        if f.ndim != 2:
            return f"frames must be 2-D [n_frames, n_taxels], got shape {f.shape}"
        if f.shape[1] != self.layout.n_taxels:
            return f"frames have {f.shape[1]} taxels but the layout has {self.layout.n_taxels}"
        if t.shape != (f.shape[0],):
            return f"{t.shape[0] if t.ndim == 1 else t.shape} timestamps for {f.shape[0]} frames"
        if len(t) > 1 and not np.all(np.diff(t) > 0):
            return "timestamps are not strictly increasing"
        if not np.all(np.isfinite(t)):
            return "timestamps contain NaN or infinity"
        for i, tr in enumerate(self.trials):
            if not 0 <= tr.first <= tr.last < f.shape[0]:
                return f"trial {i} spans frames {tr.first}..{tr.last}, outside 0..{f.shape[0] - 1}"
            if not 0 <= tr.run <= MAX_RUN:
                return f"trial {i}: run {quote(tr.run)} outside 0..{MAX_RUN}"
            if bad := next(filter(None, (name_problem(k, getattr(tr, k)) for k in ("subject", "object", "pose", "action"))), None):
                return f"trial {i}: {bad}"
        return None

    @property
    def n_frames(self) -> int:
        return int(self.frames.shape[0])

    def trial_frames(self, trial: Trial) -> tuple[np.ndarray, np.ndarray]:
        """Frames and timestamps of one trial (views, no copy)."""
        sl = slice(trial.first, trial.last + 1)
        return self.frames[sl], self.timestamps[sl]

    def sample_interval(self) -> float:
        """Median frame interval in seconds (NaN for fewer than two frames)."""
        if self.n_frames < 2:
            return float("nan")
        return float(np.median(np.diff(self.timestamps)))

    def period_s(self) -> float:
        """``sample_interval``, or the controller's nominal period when fewer than two frames cannot
        say one (a rate must still be stated for such a recording)."""
        return self.sample_interval() if self.n_frames > 1 else NOMINAL_PERIOD_S

    # -- building -----------------------------------------------------------------------------
    @classmethod
    def concatenate(
        cls,
        layout: SensorLayout,
        segments: Iterable[tuple[np.ndarray, np.ndarray, dict | None]],
        meta: dict | None = None,
    ) -> Recording:
        """Join ``(frames, timestamps, trial_fields)`` segments; each segment with fields becomes a trial.

        ``trial_fields`` holds Trial's fields except ``first``/``last``, which are filled in.
        Timestamps of later segments must continue after earlier ones.
        """
        frames, stamps, trials, pos = [], [], [], 0
        for seg_frames, seg_t, fields in segments:
            n = len(seg_frames)
            frames.append(np.asarray(seg_frames, dtype=np.uint16))
            stamps.append(np.asarray(seg_t, dtype=np.float64))
            if fields is not None and n:
                trials.append(Trial(first=pos, last=pos + n - 1, **fields))
            pos += n
        if frames:
            all_frames, all_t = np.concatenate(frames), np.concatenate(stamps)
        else:
            all_frames, all_t = np.zeros((0, layout.n_taxels), np.uint16), np.zeros(0)
        return cls(layout, all_frames, all_t, trials, dict(meta or {}))

    # -- files --------------------------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> Path:
        """Write atomically: a temporary file in the same folder, fsync, then rename."""
        path = Path(path)
        problem = self.problem()
        if problem:
            raise RecordingError(f"{path}: not saved: {problem}")
        header = {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "n_frames": self.n_frames,
            "n_taxels": int(self.frames.shape[1]),
            "layout": self.layout.to_dict(),
            "trials": [t.to_dict() for t in self.trials],
            "meta": self.meta,
        }
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)  # remove_stale_temps' pattern
        try:
            os.fchmod(fd, 0o666 & ~_umask())  # mkstemp makes 0600; a recording is shared like any file
            with os.fdopen(fd, "wb") as fh:
                with zipfile.ZipFile(fh, "w", compression=zipfile.ZIP_STORED) as zf:
                    zf.writestr(_member("header.json"), json.dumps(header, indent=1))
                    zf.writestr(_member("frames.npy"), _npy_bytes(self.frames))
                    zf.writestr(_member("timestamps.npy"), _npy_bytes(self.timestamps))
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, path)
            _fsync_dir(path.parent)
        except BaseException:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
            raise
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> Recording:
        """Read and check a recording; any problem raises one RecordingError naming the file.

        Members are read with limits (``MAX_HEADER_BYTES``, ``MAX_FRAME_BYTES``, shapes the header
        declares, JSON nesting): a hostile or damaged file is refused, never read into memory whole."""
        path = Path(path)
        try:
            if problem := _not_a_file(path.stat()):  # before zipfile seeks a FIFO or reads /dev/zero whole
                raise RecordingError(f"{path}: {problem}")
            with zipfile.ZipFile(path, "r") as zf:
                header = _read_header(zf, path)
                n_frames, n_taxels = _declared_size(header, path)
                frames = read_npy(zf, "frames.npy", np.uint16, (n_frames, n_taxels))
                stamps = read_npy(zf, "timestamps.npy", np.float64, (n_frames,))
        except RecordingError:
            raise
        except LimitError as exc:
            raise RecordingError(f"{path}: refused: {exc}") from None
        except FileNotFoundError:
            raise RecordingError(f"{path}: no such file") from None
        except zipfile.BadZipFile as exc:
            raise RecordingError(f"{path}: not a handover recording or truncated ({exc})") from None
        except (OSError, EOFError, ValueError, KeyError, NotImplementedError, RuntimeError) as exc:
            raise RecordingError(f"{path}: damaged recording ({type(exc).__name__}: {first_line(exc)})") from None
        try:
            layout = SensorLayout.from_dict(header["layout"])
            if layout.n_taxels != n_taxels:
                raise RecordingError(f"layout has {layout.n_taxels} taxels, the header says {n_taxels}")
            trials = [Trial.from_dict(t) for t in header.get("trials", [])]
            meta = dict(header.get("meta", {}))
            if why := idle_stretches.codes_problem(meta, n_frames) or arm_marks.problem(meta, n_frames):
                raise RecordingError(why)
            return cls(layout, frames, stamps, trials, meta)
        except Exception as exc:  # any shape of nonsense in a header: one line naming the file
            raise RecordingError(f"{path}: inconsistent recording: {first_line(exc)}") from None


MAX_HEADER_BYTES = 16 << 20
"""header.json: layout, trials and meta; a 900-trial recording's is about 300 kB."""
MAX_FRAME_BYTES = 1 << 30
"""frames.npy: 1 GiB is about 9 hours of 486 taxels at 32 Hz."""
MAX_TAXELS = 1 << 16


def _member(name: str) -> zipfile.ZipInfo:
    """A member with a fixed date: the same recording gives the same bytes whenever it is saved
    (zip stamps have 2 s resolution, so two saves straddling a tick would differ)."""
    info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
    info.external_attr = 0o644 << 16
    return info


def _read_header(zf: zipfile.ZipFile, path: Path) -> dict:
    names = set(zf.namelist())
    if "header.json" not in names:
        raise RecordingError(f"{path}: not a handover recording (no header.json)")
    header = read_json(zf, "header.json", MAX_HEADER_BYTES)
    if not isinstance(header, dict):
        raise RecordingError(f"{path}: not a handover recording (header is a {type(header).__name__})")
    if header.get("format") != FORMAT_NAME:
        raise RecordingError(f"{path}: not a handover recording (format {quote(header.get('format'))})")
    if header.get("version") != FORMAT_VERSION:
        raise RecordingError(
            f"{path}: recording format version {quote(header.get('version'))} is not supported "
            f"(this software reads version {FORMAT_VERSION})"
        )
    missing = {"frames.npy", "timestamps.npy"} - names
    if missing:
        raise RecordingError(f"{path}: damaged recording, missing {', '.join(sorted(missing))}")
    return header


def _declared_size(header: dict, path: Path) -> tuple[int, int]:
    """``(n_frames, n_taxels)`` from the header, within the limits, before any array is read."""
    n_frames, n_taxels = header.get("n_frames"), header.get("n_taxels")
    for key, value in (("n_frames", n_frames), ("n_taxels", n_taxels)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise RecordingError(f"{path}: header {key} is {str(value)[:20]!r}, expected a count")
    if not 1 <= n_taxels <= MAX_TAXELS:
        raise RecordingError(f"{path}: header says {n_taxels} taxels a frame, outside 1..{MAX_TAXELS}")
    if n_frames * n_taxels * 2 > MAX_FRAME_BYTES:
        raise RecordingError(f"{path}: header says {n_frames} frames x {n_taxels} taxels, over the limit of "
                             f"{MAX_FRAME_BYTES >> 20} MiB of frames")
    return n_frames, n_taxels


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _npy_bytes(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=False)
    return buf.getvalue()


def _fsync_dir(folder: Path) -> None:
    """The rename made durable where the file system allows it (some refuse a folder's fsync)."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def remove_stale_temps(path: str | os.PathLike) -> None:
    """Delete the temporary files a killed ``save`` of ``path`` left (kill -9, power loss mid-write): only
    ``save``'s own pattern for that name (mkstemp's 8 characters), only in its folder, only regular files
    this user owns. Call it where no other ``save`` of that file runs (a session resuming its own file)."""
    path = Path(path)
    ours = re.compile(re.escape(f".{path.name}.") + r"[a-z0-9_]{8}\.tmp")
    with contextlib.suppress(OSError), os.scandir(path.parent) as entries:
        for entry in entries:
            if (ours.fullmatch(entry.name) and entry.is_file(follow_symlinks=False)
                    and entry.stat(follow_symlinks=False).st_uid == os.geteuid()):
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(entry.path)


def _not_a_file(st: os.stat_result) -> str | None:
    """Why a path's stat is no recording file, or None."""
    if stat.S_ISDIR(st.st_mode):
        return "is a folder, not a recording"
    if not stat.S_ISREG(st.st_mode):
        return "not a regular file (a device, FIFO or socket), not a recording"
    return "empty file, not a recording (nothing was saved in it)" if st.st_size == 0 else None


def find_recordings(folder: str | os.PathLike) -> list[Path]:
    """All recording files in a folder (sorted); a missing folder raises RecordingError."""
    folder = Path(folder)
    if folder.is_file():
        raise RecordingError(f"{folder}: a file, not a folder; give the folder that holds the recordings "
                             f"({folder.parent})")
    if not folder.is_dir():
        raise RecordingError(f"{folder}: no such folder")
    return sorted(p for p in folder.iterdir() if p.suffix == SUFFIX and not p.name.startswith("."))


def load_all(paths: Sequence[str | os.PathLike]) -> list[Recording]:
    return [Recording.load(p) for p in paths]
