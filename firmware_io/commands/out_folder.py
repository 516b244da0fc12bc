"""The folder a command writes into: created up front, or one line saying which and what to do.

Checked before any work, so a typo in ``--out`` costs nothing and never ends in a traceback after
minutes of simulating or recording.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

__all__ = ["out_folder_problem"]


def out_folder_problem(folder: str | Path, option: str = "--out") -> str | None:
    """Create ``folder`` (and its parents) and check it takes files; None, or the line to print."""
    if not str(folder).strip():  # Path("") is the current folder: an empty option is a slip, not a choice
        return f"{option} is empty; give a folder (it is created if missing), e.g. {option} ./out"
    path = Path(folder)
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path, prefix=".write-test-"):
            pass
    except FileExistsError:
        return f"{option} {path}: is a file, not a folder; choose a folder (it is created if missing)"
    except OSError as exc:
        reason = exc.strerror or str(exc)
        return (f"{option} {path}: cannot create or write this folder ({reason}); choose a folder you can "
                f"write (it is created if missing), e.g. {option} ./out")
    return None
