"""The paper's trigger level, the one number the recorder, the runtime and the trainer share.

It lives here, at the bottom of ``trainer -> runtime -> firmware_io``, so that the recorder can
check a trial reaches it; ``runtime.trigger_settings`` takes it as the threshold trigger's level.
"""

__all__ = ["PAPER_FRACTION", "is_trigger_level"]

PAPER_FRACTION = 0.15
"""The paper's trigger level: any taxel at 15 % of full scale."""


def is_trigger_level(fraction: object) -> bool:
    """A usable trigger level: a number strictly between 0 and 1 of full scale (the open range:
    0 would fire on every frame, 1 never; NaN is no level)."""
    return isinstance(fraction, int | float) and not isinstance(fraction, bool) and 0.0 < float(fraction) < 1.0
