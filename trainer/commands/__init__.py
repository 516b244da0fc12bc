"""The ``handover`` subcommands of the trainer package (``train``, ``record``, ``demo``, ...), one ``*_cli`` module each."""

__all__: list[str] = []
