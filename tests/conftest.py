"""Shared fixtures. Real recordings are read from ../shared/data and never copied."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import pytest

from trainer.shared_data import default_data_dir

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = default_data_dir()
SDH2_DATA = SHARED_DATA / "sdh2-dsa"


@pytest.fixture(scope="session", autouse=True)
def own_lock_folder():
    """The suite's daemons take their instance locks in a folder of their own: a daemon the user (or
    another run of the suite) has on the same machine holds its device's lock in the shared folder,
    and the suite's daemons on the README's ports would be refused as second daemons."""
    saved = {k: os.environ.get(k) for k in ("RUNTIME_DIRECTORY", "XDG_RUNTIME_DIR")}
    folder = tempfile.mkdtemp(prefix="handover-tests-")
    os.environ.pop("RUNTIME_DIRECTORY", None)
    os.environ["XDG_RUNTIME_DIR"] = folder
    yield Path(folder)
    for key, value in saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value
    shutil.rmtree(folder, ignore_errors=True)


def real_data_dir() -> Path:
    """The real SDH-2 recordings folder, or skip the test with the reason."""
    if not SDH2_DATA.is_dir():
        pytest.skip(f"real SDH-2 recordings not found at {SDH2_DATA} (set HANDOVER_SHARED_DATA to the shared/data folder)")
    return SDH2_DATA


@pytest.fixture
def sdh2_data() -> Path:
    return real_data_dir()


def dsa_files() -> list[Path]:
    return sorted(SDH2_DATA.rglob("*.dsa")) if SDH2_DATA.is_dir() else []


def bag_files() -> list[Path]:
    return sorted(SDH2_DATA.rglob("*.bag")) if SDH2_DATA.is_dir() else []


LONGEST_FIRST = ("tests/test_demo.py",)
"""Modules that take minutes (the demo trains a model): started first, so that with two workers
(./dev test) the rest of the suite runs beside them instead of after them."""


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    items.sort(key=lambda item: not item.nodeid.startswith(LONGEST_FIRST))
