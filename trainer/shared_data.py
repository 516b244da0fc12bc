"""Where the real SDH-2 recordings are read from: one rule for the commands, benchmarks and tests.

They are other projects' GPL data, so they stay outside the repository: ``$HANDOVER_SHARED_DATA``
when set, else ``../shared/data`` beside the project folder.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["default_data_dir"]

ENV_VAR = "HANDOVER_SHARED_DATA"


def default_data_dir() -> Path:
    """The shared data folder (it holds ``sdh2-dsa/``); it may not exist."""
    env = os.environ.get(ENV_VAR)
    return Path(env) if env else Path(__file__).resolve().parents[2] / "shared" / "data"
