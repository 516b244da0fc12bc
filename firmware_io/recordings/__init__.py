"""Recordings of the pads: ``recording`` (the ``.hrec`` file and its trials), ``bounded_zip``
(reading its members with limits), ``importers`` (.dsa files and ROS bags), ``record_session``
(recording a subject the paper's way) and ``terminal_view`` (a quick look at a trial)."""

__all__: list[str] = []
