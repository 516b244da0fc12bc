"""The ``handover`` subcommands of this package (``dump``, ``emulate``, ``import``, ``record``,
``simulate``), one ``*_cli`` module each; ``errors``: how every command reports a user error;
``playback``: the --speed and --fault options of commands that play frames through an emulator."""

__all__: list[str] = []
