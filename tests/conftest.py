"""Shared fixtures. Real recordings are read from ../shared/data and never copied."""

from __future__ import annotations

from pathlib import Path

import pytest

from trainer.shared_data import default_data_dir

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = default_data_dir()
SDH2_DATA = SHARED_DATA / "sdh2-dsa"


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
