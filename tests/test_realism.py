"""Synthetic frames against the real SDH-2 recordings (skips where the data folder is absent).

Tolerances are stated here, not tuned: the real files are firm grasps and calibration
weights, the simulator makes light handover grasps, so value ranges may differ in level but
must share floor, noise, ceiling and timing.
"""

from __future__ import annotations

import numpy as np
import pytest

from firmware_io.sim import realism, simulate_protocol
from tests.conftest import real_data_dir


@pytest.fixture(scope="module")
def real() -> dict:
    folder = real_data_dir()
    files = realism.real_dsa_files(folder, ("grasps", "room temperature"))
    if not files:
        pytest.skip(f"no real .dsa files under {folder}")
    from firmware_io.recordings.importers.dsa import read_dsa

    return realism.summarise([read_dsa(p) for p in files])


@pytest.fixture(scope="module")
def sim() -> dict:
    return realism.summarise(simulate_protocol(seed=0, n_subjects=2, runs=2))


def test_untouched_taxels_read_zero_like_real(real, sim):
    # real: ~2e-4 of far-from-contact readings are non-zero; both must stay below 0.1 %
    assert real["noise"]["untouched_nonzero_fraction"] < 1e-3
    assert sim["noise"]["untouched_nonzero_fraction"] < 1e-3


def test_frame_interval_statistics_match_real(real, sim):
    r, s = real["intervals"], sim["intervals"]
    assert abs(r["mean_ms"] - s["mean_ms"]) < 0.3
    assert 0.7 < s["std_ms"] / r["std_ms"] < 1.4
    assert abs(r["p1_ms"] - s["p1_ms"]) <= 2 and abs(r["p99_ms"] - s["p99_ms"]) <= 2
    assert s["lag1_corr"] < -0.2 and r["lag1_corr"] < -0.2  # late reads, not a drifting clock
    assert abs(r["outside_31_32_fraction"] - s["outside_31_32_fraction"]) < 0.08


def test_contact_values_within_real_range(real, sim):
    r, s = real["values"], sim["values"]
    assert s["max"] <= 4095 and s["max"] <= r["max"] + 100  # the rubber saturates ~3550, not at 4095
    assert s["nonzero_p5"] >= 1
    # light handover grasps sit lower than the real firm grasps, but within a factor 4
    for q in ("nonzero_p25", "nonzero_p50", "nonzero_p75", "nonzero_p95"):
        assert r[q] / 4 < s[q] < r[q] * 1.5, q
    # contact noise of loaded taxels: about 1 % of the value per frame in both
    assert 0.5 < s["loaded_rel_change_median"] / r["loaded_rel_change_median"] < 2.5


def test_contact_area_like_real(real, sim):
    r, s = real["area"], sim["area"]
    assert 0.5 < s["area_median"] / r["area_median"] < 2.0


def test_statistics_on_a_known_input():
    from firmware_io.layout import SensorLayout

    layout = SensorLayout.sdh2()
    frames = np.zeros((4, layout.n_taxels), dtype=np.uint16)
    frames[:, 0] = 7  # an isolated reading on proximal pad 0, far from anything
    frames[:, 100:103] = 500
    st = realism.noise_floor(frames, layout)
    assert st["untouched_nonzero_median"] == 7 and st["untouched_nonzero_fraction"] > 0
    iv = realism.frame_intervals(np.array([0.0, 0.031, 0.063, 0.094, 5.0, 5.032]))
    assert iv["n"] == 4 and abs(iv["mean_ms"] - 31.5) < 0.01
    area = realism.contact_area(frames, layout)
    assert area["area_median"] == 3
    level = realism.contact_level(frames, layout)
    assert level["peak_median"] == 500 and level["pad_frames_in_contact"] == 4
    a = {"noise": {"untouched_nonzero_fraction": 1e-4}, "level": {"peak_median": 400.0}}
    b = {"noise": {"untouched_nonzero_fraction": 2e-4}, "level": {"peak_median": 100.0}}
    s = realism.shift(a, b)
    assert s["noise_floor_factor"] == 2.0 and s["contact_level_ratio"] == 0.25 and s["contact_level_factor"] == 4.0


@pytest.mark.slow
def test_lab_b_sits_at_least_as_far_from_lab_a_as_the_real_sources_from_each_other():
    """docs/SIMULATOR.md's rule for lab B, on the real recordings (both sources) and seed 0."""
    from benchmarks.studies.lab_shift import measure

    result = measure(0, real_data_dir())
    if "real_shift" not in result:
        pytest.skip("one of the two real sources is absent")
    assert result["lab_b_at_least_real"], (result["lab_shift"], result["real_shift"])
