"""Who the emulated controller says it is: the 0x01 controller info and the 0x02 sensor info.

Fields follow SDHLibrary ``dsa.h`` (``sControllerInfo``, ``sSensorInfo``); the values come from the
recording where it holds them (DSA-Konqueror's ``.dsa`` header, a ``handover record`` session's
controller). ``hw_version`` is BCD (SDHLibrary-Python's ``dsa.py``: 0x10 is 1.0); the status and
feature flags, sensor-controller type and interface stay 0: their meaning is not published and no
client reads them (docs/EMULATOR.md).
"""

from __future__ import annotations

from firmware_io.wire import replies

__all__ = ["recorded_controller", "recorded_sensor"]

NEW_FIRMWARE = 0x2900  # 2.9.0.0: single frames work
OLD_FIRMWARE = 288  # R288: a single-frame request starts push mode
HW_VERSION_BCD = 0x10
DEFAULT_SERIAL = 12345
"""The serial number when neither the caller nor the recording gives one."""


def _last_session_controller(meta: dict) -> dict:
    sessions = meta.get("sessions") or []
    last = sessions[-1] if sessions else None
    return (last.get("controller") or {}) if isinstance(last, dict) else {}


def recorded_controller(meta: dict, serial_no: int | None, old_firmware: bool) -> replies.ControllerInfo:
    """The controller a ``handover record`` session was made with (its serial number), else ``serial_no``;
    the firmware is the emulator's (2.9.0.0, or R288 in old-firmware mode) since that decides its behaviour."""
    recorded = _last_session_controller(meta).get("serial_no")
    if serial_no is None:
        serial_no = recorded if isinstance(recorded, int) and 0 <= recorded <= 0xFFFFFFFF else DEFAULT_SERIAL
    return replies.ControllerInfo(serial_no=serial_no, hw_version=HW_VERSION_BCD,
                                  sw_version=OLD_FIRMWARE if old_firmware else NEW_FIRMWARE)


def recorded_sensor(meta: dict, n_matrices: int, default_serial: int) -> replies.SensorInfo:
    """The sensor a recording was made with (serial number, generator, hardware revision), as
    DSA-Konqueror files (serial in hex) and ``handover record`` sessions (an int) store them;
    defaults where absent."""
    fields = {"serial_no": default_serial, "generated_by": replies.SensorInfo.generated_by, "hw_revision": replies.SensorInfo.hw_revision}
    controller = _last_session_controller(meta)
    candidates = {"serial_no": ((meta.get("dsa_serial_nr"), 16), (meta.get("sensor_serial_no"), 0),
                                (controller.get("sensor_serial_no"), 0)),
                  "generated_by": ((meta.get("dsa_generated_by"), 0),), "hw_revision": ((meta.get("dsa_hw_revision"), 0),)}
    limits = {"serial_no": 0xFFFFFFFF, "generated_by": 0xFFFF, "hw_revision": 0xFF}
    for key, values in candidates.items():
        for value, base in values:
            try:  # DSA-Konqueror writes <serial_nr> in hex without 0x (1D9B0057); the rest in decimal
                number = value if isinstance(value, int) else int(str(value).strip(), base)
            except (TypeError, ValueError):
                continue
            if 0 <= number <= limits[key]:
                fields[key] = number
                break
    return replies.SensorInfo(nb_matrices=n_matrices, **fields)
