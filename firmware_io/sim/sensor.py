"""DSA 9205 transduction and the DSACON32m firmware: pressure in, 12-bit frames out.

Chain per taxel (each step one function):
1. ``response``: resistive rubber, S-shaped then saturating (Hill curve), per-taxel gain and
   ceiling (manufacturing spread). Applied per scan, before averaging, because it is nonlinear.
2. ``average_scans``: the firmware averages 7 scans (~222 Hz) into one frame (~32 Hz).
3. ``firmware_output``: idle reading + noise, minus the threshold, clipped to 0..4095, whole
   counts, static mask. The threshold is the dead zone: light touches read exactly 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from firmware_io.layout import SensorLayout
from firmware_io.sim import constants as K
from firmware_io.sim.lab import Lab, get_lab

__all__ = ["HandSensor", "average_scans", "firmware_output", "response"]


@dataclass(frozen=True)
class HandSensor:
    """Fixed properties of one physical hand's taxels (the same hand for every subject)."""

    layout: SensorLayout
    gain: np.ndarray  # float32 [C], relative sensitivity, mean 1
    ceiling: np.ndarray  # float32 [C], saturation level before the threshold (counts)
    idle: np.ndarray  # float32 [C], reading with nothing touching (counts)
    mask: np.ndarray  # bool [C], taxel exists and works
    noise_sd: float = K.IDLE_NOISE_SD  # temporal noise of an untouched taxel (counts)

    @classmethod
    def build(cls, layout: SensorLayout, rng: np.random.Generator, lab: Lab | None = None) -> HandSensor:
        """One hand of ``lab`` (default A): its pads' gains, idle level and noise, its dead and hot taxels."""
        lab = get_lab(lab)
        c = layout.n_taxels
        gain = np.clip(rng.normal(1.0, K.GAIN_SPREAD, c), 0.6, 1.4).astype(np.float32)
        ceiling = rng.normal(K.RESPONSE_CEILING, K.RESPONSE_CEILING_SD, c).astype(np.float32)
        idle = np.clip(rng.normal(lab.idle_mean, K.IDLE_READING_SD, c), 0, None).astype(np.float32)
        mask = layout.static_mask()
        if any(g != 1.0 for g in lab.pad_gain):
            for pad in range(layout.n_matrices):
                gain[layout.matrix_slice(pad)] *= np.float32(lab.pad_gain[pad % len(lab.pad_gain)])
        if lab.dead_taxels or lab.hot_taxels:
            odd = rng.choice(np.flatnonzero(mask), lab.dead_taxels + lab.hot_taxels, replace=False)
            mask[odd[:lab.dead_taxels]] = False
            idle[odd[lab.dead_taxels:]] = np.float32(K.THRESHOLD)
        return cls(layout, gain, ceiling, idle, mask, lab.noise_sd)


def response(pressure_kpa: np.ndarray, gain: np.ndarray, ceiling: np.ndarray) -> np.ndarray:
    """Counts above idle for a pressure (kPa); last axis = taxels. Hill curve, see constants."""
    x = (pressure_kpa * (gain / K.RESPONSE_P50_KPA)).astype(np.float32)
    xn = np.zeros_like(x)
    loaded = x != 0  # the power is most of a render's time and most taxels are unloaded (0 ** n = 0)
    xn[loaded] = np.power(x[loaded], np.float32(K.RESPONSE_HILL_N))
    return ceiling * (xn / (1.0 + xn))


def average_scans(scans: np.ndarray, per_frame: int = K.SCANS_PER_FRAME) -> np.ndarray:
    """Mean of each run of ``per_frame`` scans along axis 0 (the firmware's compression)."""
    n = scans.shape[0] // per_frame
    return scans[: n * per_frame].reshape(n, per_frame, *scans.shape[1:]).mean(axis=1)


def firmware_output(signal: np.ndarray, sensor: HandSensor, rng: np.random.Generator) -> np.ndarray:
    """uint16 frames ``[N, C]`` from averaged counts above idle ``[N, C]``.

    Noise: 1.6 counts (the lab's) on an idle taxel plus ~0.9 % of the signal on a loaded one (both
    measured). It is added to the frame, i.e. after averaging, because that is where it was
    measured.
    """
    sd = np.sqrt(np.float32(sensor.noise_sd**2) + np.square(np.float32(K.CONTACT_NOISE_REL) * signal))
    raw = signal + sensor.idle + sd * rng.standard_normal(signal.shape, dtype=np.float32)
    out = np.clip(np.rint(raw - np.float32(K.THRESHOLD)), 0, K.FULL_SCALE)
    out[:, ~sensor.mask] = 0
    return out.astype(np.uint16)
