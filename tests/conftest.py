"""Shared fixtures. Real recordings are read from ../shared/data and never copied."""

from __future__ import annotations

import contextlib
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


SCRIPTED_IDLE_MINUTES = 3
SCRIPTED_SUBJECT_ARGS = ["--poses", "down", "--objects", "ball", "--auto", "--retries", "0", "--gap", "0", "--quiet",
                         "--no-look", "--runs", "2", "--idle-minutes", str(SCRIPTED_IDLE_MINUTES)]
"""One pose, one object, 4 actions x 2 runs and three minutes of idle: the scripted subjects that
tests/test_prior.py, tests/test_data_warnings.py and tests/test_own_data_model.py train on."""


def scripted_subjects(tmp_path_factory: pytest.TempPathFactory, out: Path, seeds: dict[str, int]) -> Path:
    """``out`` with ``subject_NAME.hrec`` for each name: seed (``SCRIPTED_SUBJECT_ARGS``), each recorded once
    per run and copied. The recording is deterministic and takes seconds a subject (its idle is simulated),
    so modules that need the same subjects share it, across xdist workers too (a lock in the run's folder)."""
    from runtime.cli import main as handover

    base = tmp_path_factory.getbasetemp()
    store = (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "scripted-subjects"
    store.mkdir(exist_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    for name, seed in seeds.items():
        kept = store / f"seed{seed}" / f"subject_{name}.hrec"
        with _locked(store / f"seed{seed}-{name}.lock"):
            if not kept.is_file():
                fresh = store / f"seed{seed}-{name}.partial"
                shutil.rmtree(fresh, ignore_errors=True)
                assert handover(["record", "--device", f"subject://?seed={seed}&speed=max", "--subject", name,
                                 "--out", str(fresh), *SCRIPTED_SUBJECT_ARGS]) == 0
                kept.parent.mkdir(exist_ok=True)
                os.replace(fresh / f"subject_{name}.hrec", kept)
        shutil.copyfile(kept, out / kept.name)
    return out


@contextlib.contextmanager
def _locked(path: Path):
    """An exclusive lock on ``path`` (another worker waits for the recording it holds)."""
    import fcntl

    with open(path, "w") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


LONGEST_FIRST = ("tests/test_demo.py",)
"""Modules that take minutes (the demo trains a model): started first, so that with two workers
(./dev test) the rest of the suite runs beside them instead of after them."""


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    items.sort(key=lambda item: not item.nodeid.startswith(LONGEST_FIRST))
