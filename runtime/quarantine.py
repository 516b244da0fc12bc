"""Models taken out of service at run time, remembered by file identity across restarts.

Why: a model that broke the output contract on real frames must not come back on the next poll or
after a restart. A file is named by path, size, mtime and inode, so a new copy is a candidate again.
The list is a small JSON file in the state folder, written atomically (in memory only without one).
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

from runtime.health import write_json_atomically

__all__ = ["QuarantineStore", "file_key", "log", "store_path"]

log = logging.getLogger("handover.models")

FILE_NAME = "quarantined-models.json"
MAX_ENTRIES = 256
"""Oldest entries are forgotten beyond this (a folder churned by a script must not grow it forever)."""


def file_key(path: str | Path, size: int, mtime_ns: int, inode: int) -> str:
    """The identity of one version of a file."""
    return f"{Path(path)}|{int(size)}|{int(mtime_ns)}|{int(inode)}"


def store_path(quarantine_file: str | None, health_file: str | None) -> Path | None:
    """``model.quarantine_file``, else beside the health file (the service's state folder), else
    None (kept in memory only)."""
    if quarantine_file:
        return Path(quarantine_file)
    if health_file:
        return Path(health_file).expanduser().parent / FILE_NAME
    return None


class QuarantineStore:
    """``reason(key)`` of a quarantined file version, ``add(key, reason)``; persisted when ``path`` is set."""

    def __init__(self, path: str | Path | None = None) -> None:
        self.path = Path(path) if path else None
        self._entries: dict[str, str] = {}
        self._write_failed = False
        if self.path is not None:
            self._entries = self._read()

    def _read(self) -> dict[str, str]:
        assert self.path is not None
        try:
            data = json.loads(self.path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            return {}
        except (OSError, ValueError, RecursionError) as exc:
            log.warning("quarantine list %s unreadable (%s); starting an empty one", self.path, exc)
            return {}
        entries = data.get("quarantined") if isinstance(data, dict) else None
        if not isinstance(entries, dict):
            return {}
        return {str(k): str(v) for k, v in entries.items()}

    def reason(self, key: str) -> str | None:
        return self._entries.get(key)

    def add(self, key: str, reason: str) -> None:
        self._entries[key] = reason
        while len(self._entries) > MAX_ENTRIES:
            del self._entries[next(iter(self._entries))]
        self._write()

    def quarantine_file(self, path: str | Path, reason: str) -> None:
        """Quarantine the file at ``path`` as it is now (a vanished file is nothing to remember)."""
        try:
            st = os.stat(path, follow_symlinks=False)
        except OSError:
            return
        self.add(file_key(path, st.st_size, st.st_mtime_ns, st.st_ino), reason)

    def __len__(self) -> int:
        return len(self._entries)

    def _write(self) -> None:
        if self.path is None:
            return
        try:
            write_json_atomically(self.path, {"quarantined": self._entries})
            self._write_failed = False
        except OSError as exc:
            if not self._write_failed:  # one line, not one per quarantined model
                log.error("quarantine list %s: cannot write (%s); it is kept in memory until a restart",
                          self.path, exc.strerror or exc)
            self._write_failed = True
