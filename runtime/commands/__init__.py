"""The ``handover`` subcommands of the runtime package (``run``, ``inspect``), one ``*_cli`` module each."""

__all__: list[str] = []
