"""The paper's trigger level, the one number the recorder, the runtime and the trainer share.

It lives here, at the bottom of ``trainer -> runtime -> firmware_io``, so that the recorder can
check a trial reaches it; ``runtime.trigger_settings`` takes it as the threshold trigger's level.
"""

PAPER_FRACTION = 0.15
"""The paper's trigger level: any taxel at 15 % of full scale."""
