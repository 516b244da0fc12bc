"""Where the real SDH-2 recordings are read from: one rule for the commands, benchmarks and tests.

They are other projects' GPL data, so they stay outside the repository: ``$HANDOVER_SHARED_DATA``
when set, else ``../shared/data`` beside the project folder.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["default_data_dir", "real_files"]

ENV_VAR = "HANDOVER_SHARED_DATA"


def default_data_dir() -> Path:
    """The shared data folder (it holds ``sdh2-dsa/``); it may not exist."""
    env = os.environ.get(ENV_VAR)
    return Path(env) if env else Path(__file__).resolve().parents[2] / "shared" / "data"


def real_files(root: Path) -> list[tuple[Path, str, str]]:
    """(file, category, why it holds no human handover) for every recording under ``root``."""
    from firmware_io.recordings.importers import find_sources

    reasons = {
        "calibration": "calibration: noise, sensitivity, weights at three temperatures put on the pads; no hand-over",
        "grasps": "the hand grasping objects on its own; nobody takes them",
        "slip": "slip experiments: objects slipping in (or pulled through) the grasp; no hand-over",
        "objects": "the hand grasping test objects for classification; nobody takes them",
        "misc": "sensor tests (ghosting, masked matrices, reactive grasping, sensitivity)",
        "fast": "recorded at ~70 Hz for frequency analysis (slip and roughness tests); the daemon decimates them to "
                "the model's 32 Hz (runtime/frame_rate.py), so 15-frame windows span 0.47 s as in training",
    }
    out = []
    for path in sorted(find_sources(root)):
        text = str(path).lower()
        cat = ("fast" if "frequency_analysis" in text else "calibration" if "calibration" in text
               else "grasps" if "grasps" in text or "/bin/" in text else "slip" if "slip" in text else
               "objects" if "classification" in text or "/video/" in text else "misc")
        out.append((path, cat, reasons[cat]))
    return out
