"""The emulated DSACON32m: ``device`` (host bytes in, device bytes out, with faults), ``server``
(served over loopback TCP or a pseudo-terminal), ``links`` (behind a pyusb backend or a hidapi
device) and ``frame_source`` (the frames it sends: the simulated hand or a recording file).
Its in-process transports (``sim://``, ``replay://``, ``subject://``) sit with every other
transport in :mod:`firmware_io.transports`."""

__all__: list[str] = []
