"""The DSACON32m wire protocol: bytes on the link <-> packets, replies and frames."""
