"""The DSACON32m wire protocol: bytes on the link <-> packets, replies and frames."""

__all__: list[str] = []
