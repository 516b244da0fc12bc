"""Pressure patches on the pads: where the object touches and how the load spreads.

A patch is separable: a profile across the pad (x) times a profile along it (y). Each profile
is a flat top of half-width ``w`` (the object's contact size) blurred by a Gaussian whose width
adds the object's own edge softness, the rubber's spreading, the tape and the texel's size in
quadrature. A box convolved with a Gaussian has a closed form (erf differences), so no
convolution is needed and thousands of scans render at once.
"""

from __future__ import annotations

import numpy as np

from firmware_io.sim import constants as K

__all__ = ["blur_width", "pad_pressure"]


def erf(x: np.ndarray) -> np.ndarray:
    """Error function (Abramowitz & Stegun 7.1.26, |error| < 1.5e-7): numpy has none."""
    x = np.asarray(x)
    s = np.sign(x)
    a = np.abs(x)
    t = 1.0 / (1.0 + 0.3275911 * a)
    poly = t * (0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429))))
    return s * (1.0 - poly * np.exp(-a * a))


def blur_width(object_soft_mm: float | np.ndarray, taped: bool) -> np.ndarray:
    """Total Gaussian width (mm): object edge, rubber, tape and texel averaging in quadrature."""
    tape = K.TAPE_SPREAD_MM if taped else 0.0
    texel = K.TEXEL_MM / np.sqrt(12.0)  # a taxel averages the pressure over its 3.4 mm square
    return np.sqrt(np.square(object_soft_mm) + K.RUBBER_SPREAD_MM**2 + tape**2 + texel**2)


def axis_profile(centres_mm: np.ndarray, c: np.ndarray, w: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Load density (1/mm, integrates to 1) of a blurred flat top at each taxel centre.

    ``c``, ``w``, ``sigma``: ``[S]`` (centre, half-width, blur) per scan; result ``[S, n]``.
    """
    u = centres_mm[None, :] - c[:, None]
    w = np.maximum(w, 0.05)[:, None]
    k = 1.0 / (np.sqrt(2.0) * sigma[:, None])
    return (erf((u + w) * k) - erf((u - w) * k)) / (4.0 * w)


def tilt_profile(profile: np.ndarray, centres_mm: np.ndarray, c: np.ndarray, w: np.ndarray,
                 tilt: np.ndarray) -> np.ndarray:
    """Apply a torque bias: load grows linearly toward one end of the patch (plank on its edge).

    ``tilt`` = relative extra pressure at distance ``w`` from the centre (+ toward larger y).
    Negative pressure is impossible: the lifted side simply stops touching.
    """
    u = (centres_mm[None, :] - c[:, None]) / np.maximum(w, 1.0)[:, None]
    return profile * np.clip(1.0 + tilt[:, None] * u, 0.0, None)


def taxel_centres(n: int) -> np.ndarray:
    """Centres (mm) of ``n`` taxels along one axis, first taxel at 1.7 mm."""
    return (np.arange(n) + 0.5) * K.TEXEL_MM


def pad_pressure(cells_x: int, cells_y: int, force: np.ndarray, cx: np.ndarray, cy: np.ndarray,
                 wx: np.ndarray, wy: np.ndarray, sigma: np.ndarray, tilt: np.ndarray) -> np.ndarray:
    """Pressure (kPa) on one pad for ``S`` scans: ``[S, cells_y, cells_x]`` (float32).

    ``force`` in newtons, positions and sizes in mm (x across the pad, y along it, row 0 at
    the pad's fingertip end).
    """
    out = np.zeros((len(force), cells_y, cells_x), dtype=np.float32)
    on = np.flatnonzero(np.asarray(force) > 0)  # an unloaded scan is zero: half of an idle stream, not computed
    if len(on) == 0:
        return out
    cx, cy, wx, wy, sigma, tilt = (np.asarray(a)[on] for a in (cx, cy, wx, wy, sigma, tilt))
    xs, ys = taxel_centres(cells_x), taxel_centres(cells_y)
    px = axis_profile(xs, cx, wx, sigma)
    py = tilt_profile(axis_profile(ys, cy, wy, sigma), ys, cy, wy, tilt)
    # N / mm^2 = MPa -> kPa
    scale = (1000.0 * np.asarray(force)[on])[:, None, None]
    out[on] = scale * py[:, :, None] * px[:, None, :]
    return out
