"""Figures the simulator is built on, with where each one comes from.

"measured" means computed by us from the real recordings in ``../shared/data/sdh2-dsa``
(Kiechle 2015, DSA-Konqueror files; see docs/SIMULATOR.md for the scripts' method);
"assumed" means a physically motivated choice that the real data cannot pin down.
"""

from __future__ import annotations

__all__ = [
    "CONTACT_NOISE_REL", "FRAME_PERIOD_S", "FRICTION_BARE", "FULL_SCALE", "GAIN_SPREAD", "GRAVITY",
    "IDLE_NOISE_SD", "IDLE_READING_MEAN", "IDLE_READING_SD", "RESPONSE_CEILING", "RESPONSE_CEILING_SD",
    "RESPONSE_HILL_N", "RESPONSE_P50_KPA", "RUBBER_SPREAD_MM", "SCANS_PER_FRAME", "STAMP_BASE_JITTER_S",
    "STAMP_LATE_MEAN_S", "STAMP_LATE_PROB", "STAMP_RESOLUTION_S", "STAMP_VERY_LATE_MEAN_S",
    "STAMP_VERY_LATE_PROB", "TAPE_FRICTION_FACTOR", "TAPE_SPREAD_MM", "TEXEL_MM", "THRESHOLD"
]

# -- timing -------------------------------------------------------------------------------------
FRAME_PERIOD_S = 0.03156
"""measured: mean PC time-stamp interval over all ~31 Hz .dsa files (170 903 intervals, gaps
over 100 ms excluded): 31.56 ms, median 32 ms, std 1.40 ms, p1 28 ms, p99 36 ms. The simulator
writes its recordings at it; the controller's configured rate is another quantity
(``firmware_io.frame_timing``)."""

SCANS_PER_FRAME = 7
"""paper (Sec. III): taxels are scanned at about 230 Hz and the firmware averages seven scans
into one frame; 7 / 31.56 ms = 222 Hz scan rate."""

STAMP_RESOLUTION_S = 0.001
"""measured: .dsa time stamps are whole milliseconds of the PC clock."""

# timestamp jitter: t_k = k * period + delay_k, delay >= 0 (the PC reads a frame late, the
# next one arrives on time again). Chosen so that the interval histogram matches the real one
# (lag-1 autocorrelation of intervals measured -0.42: late frames, not a drifting clock).
STAMP_BASE_JITTER_S = 0.0004
"""measured/fitted: small Gaussian jitter of the PC read time (gives the 31/32 ms mix)."""
STAMP_LATE_PROB = 0.11
STAMP_LATE_MEAN_S = 0.0018
STAMP_VERY_LATE_PROB = 0.008
STAMP_VERY_LATE_MEAN_S = 0.005
"""fitted to the real interval histogram: ~10 % of intervals lie outside 31-32 ms, tail to ~44 ms."""

# -- sensor (DSA 9205 + DSACON32m) ---------------------------------------------------------------
FULL_SCALE = 4095
"""12-bit converter."""

IDLE_READING_MEAN = 43.0
IDLE_READING_SD = 4.5
"""measured: calibration_noise/temperature-noise.dsa (threshold off): per-taxel idle reading,
median 42, 5th-95th percentile 39-49.5 counts."""

IDLE_NOISE_SD = 1.6
"""measured: same file, temporal std of an untouched taxel in one frame: median 1.62 counts."""

CONTACT_NOISE_REL = 0.009
"""measured: static weights (room temperature C.dsa, F.dsa): median |frame-to-frame change|
of loaded taxels is 0.7-1.3 % of the value."""

THRESHOLD = 100.0
"""measured_record of the calibration sets: 'Threshold: 100'. The controller subtracts it and
clips at zero, which is why untouched taxels read exactly 0 (idle ~43 + noise << 100) and why
real contact values start at 1 count (the smallest non-zero value in every file)."""

RESPONSE_CEILING = 3650.0
RESPONSE_CEILING_SD = 25.0
"""measured: taxels driven into saturation top out at 3505-3567 counts after the threshold
(median 3553), i.e. ~3650 before it: the conductive rubber saturates below the 12-bit limit."""

RESPONSE_P50_KPA = 50.0
RESPONSE_HILL_N = 1.7
"""fitted: calibration weights 200-900 g on a 1.1 cm^2 stamp (17.8-80.1 kPa), median frame peak
482, 595, 866, 1368, 1834, 2229, 2258, 2510 counts; a Hill curve C * x^n / (1 + x^n), x = p / p50,
matches within ~15 % (resistive sensor: percolation makes it S-shaped, then it saturates)."""

GAIN_SPREAD = 0.08
"""assumed: per-taxel sensitivity spread (manufacturing), 8 % standard deviation."""

RUBBER_SPREAD_MM = 1.8
"""measured (roughly): a 10.5 mm square stamp lights 16-26 taxels (3.4 mm texels), i.e. the
rubber spreads load over neighbours with about this Gaussian width."""

TEXEL_MM = 3.4

# -- tape (paper Sec. III: pads covered with tape) -----------------------------------------------
TAPE_SPREAD_MM = 1.2
"""assumed: an extra layer spreads the load further (adds in quadrature)."""
TAPE_FRICTION_FACTOR = 0.6
"""assumed: tape on rubber: friction coefficient about 0.6 of bare silicone (easier slip)."""
FRICTION_BARE = 0.9

GRAVITY = 9.81
