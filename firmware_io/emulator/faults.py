"""The emulator's fault plan: what ``--fault`` asks for, and how a frame packet is damaged by it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from firmware_io.errors import HandoverError

__all__ = ["FaultPlan", "FaultSpecError", "inject"]


class FaultSpecError(HandoverError, ValueError):
    """A fault description that cannot be read."""


@dataclass
class FaultPlan:
    """Which faults to inject and how often. Probabilities are per frame packet sent.

    Text form (``--fault``): ``crc=0.01,garbage=0.01,drop=0.01,stall=0.005:0.5,disconnect=300,boot``
    (``stall=P:SECONDS``; ``disconnect=N`` drops the link after N frames of each connection, which on
    a pseudo-terminal and over TCP is a power cycle (``DeviceEmulator.power_cycle``);
    ``boot`` sends the power-up terminal query ESC[5n three times when a host connects).
    """

    crc: float = 0.0
    garbage: float = 0.0
    drop: float = 0.0
    stall: float = 0.0
    stall_seconds: float = 0.5
    disconnect_after: int | None = None
    boot_query: bool = False

    @classmethod
    def parse(cls, text: str | None) -> FaultPlan:
        plan = cls()
        if not text:
            return plan
        for item in text.split(","):
            item = item.strip()
            if not item:
                continue
            key, _, value = item.partition("=")
            key = key.strip().lower()
            try:
                if key == "boot":
                    switch = value.strip().lower()
                    if switch not in _SWITCHES:
                        raise ValueError
                    plan.boot_query = _SWITCHES[switch]
                elif key == "disconnect":
                    plan.disconnect_after = int(value)
                    if plan.disconnect_after < 1:
                        raise ValueError
                elif key == "stall":
                    p, _, secs = value.partition(":")
                    plan.stall = _probability(p)
                    if secs:
                        plan.stall_seconds = float(secs)
                        if not 0 < plan.stall_seconds <= 60:
                            raise ValueError
                elif key in ("crc", "garbage", "drop"):
                    setattr(plan, key, _probability(value))
                else:
                    raise FaultSpecError(
                        f"unknown fault {key!r} (known: crc, garbage, drop, stall=P:SECONDS, disconnect=N, boot)"
                    )
            except ValueError as exc:
                if isinstance(exc, FaultSpecError):
                    raise
                raise FaultSpecError(f"{item!r}: bad value ({_FAULT_VALUES.get(key, 'see --help')})") from None
        return plan

    @property
    def any(self) -> bool:
        return bool(self.crc or self.garbage or self.drop or self.stall or self.disconnect_after or self.boot_query)


_SWITCHES = {"": True, "1": True, "true": True, "yes": True, "on": True,
             "0": False, "false": False, "no": False, "off": False}
"""What ``boot`` may be set to (nothing: on)."""

_FAULT_VALUES = {"boot": "nothing (on), or on/off", "crc": "a probability from 0 to 1, e.g. crc=0.02", "garbage": "a probability from 0 to 1",
                 "drop": "a probability from 0 to 1", "disconnect": "a whole number of frames, at least 1",
                 "stall": "P:SECONDS, a probability from 0 to 1 and 0 < SECONDS <= 60, e.g. stall=0.01:2"}
"""What each fault's value must be, for the line that refuses a bad one."""


def _probability(text: str) -> float:
    p = float(text)
    if not 0.0 <= p <= 1.0:
        raise ValueError(text)
    return p


def inject(plan: FaultPlan, rng: np.random.Generator, stats, packet: bytearray, out: bytearray) -> bool:
    """Append ``packet`` to ``out`` with the plan's damage (garbage before it, a flipped CRC bit,
    bytes cut out), counted in ``stats``; True when a stall starts after it."""
    if plan.garbage and rng.random() < plan.garbage:
        junk = rng.integers(0, 256, size=int(rng.integers(1, 33)), dtype=np.uint8).tobytes()
        out += junk
        stats.garbage_inserted += 1
        stats.garbage_bytes += len(junk)
    if plan.crc and rng.random() < plan.crc:
        packet[-1] ^= 1 << int(rng.integers(0, 8))
        stats.crc_corrupted += 1
    if plan.drop and rng.random() < plan.drop:
        k = int(rng.integers(1, 9))
        at = int(rng.integers(0, max(1, len(packet) - k)))
        del packet[at : at + k]
        stats.packets_truncated += 1
        stats.bytes_dropped += k
    out += packet
    if plan.stall and rng.random() < plan.stall:
        stats.stalls += 1
        return True
    return False
