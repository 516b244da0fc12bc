"""The ``handover`` subcommands of this package (``dump``, ``emulate``, ``import``,
``simulate``), one ``*_cli`` module each; ``options``: the options and checks every command shares;
``playback``: the --speed and --fault options of commands that play frames through an emulator."""

__all__: list[str] = []
