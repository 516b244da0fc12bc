"""The ``handover`` subcommands of this package (``dump``, ``emulate``, ``import``, ``record``,
``simulate``), one ``*_cli`` module each, and ``errors``: how every command reports a user error."""
