"""Typed readers of one TOML key, each raising :class:`ConfigError` naming the key, and the
closed range of every number of the daemon's config (``runtime.config`` builds the sections from
these; kept apart so each section's reader stays short)."""

from __future__ import annotations

import math
from typing import Any

RANGES: dict[str, tuple[float, float]] = {
    "device.stall_timeout_s": (0.05, 3600.0),
    "device.reconnect_min_s": (0.0, 3600.0),
    "device.reconnect_max_s": (0.0, 3600.0),
    "model.poll_interval_s": (0.01, 3600.0),
    "model.max_bytes": (1024, 1 << 30),
    "model.decision_budget": (0.001, 1.0),
    "trigger.fraction": (0.0, 1.0),
    "trigger.hysteresis": (0.0, 0.99),
    "trigger.refractory_s": (0.0, 3600.0),
    "trigger.rearm_quiet_s": (0.0, 60.0),
    "trigger.baseline_tau_s": (0.01, 86400.0),
    "trigger.pre_frames": (0, 1000),
    "trigger.change": (0.001, 0.99),
    "trigger.track_tau_s": (0.05, 600.0),
    "trigger.settle_s": (0.0, 60.0),
    "continuous.confirm_frames": (1, 1000),
    "continuous.min_margin": (0.0, 1000.0),
    "continuous.rearm_frames": (0, 100000),
    "onnxruntime.intra_op_threads": (1, 64),
    "ros2.depth": (1, 10000),
    "ros2.pad_rate_hz": (0.1, 1000.0),
    "ros2.pad_gain": (1, 16),
    "realtime_priority": (0, 99),
}
"""Every number of the config and its closed range [lo, hi] (the one owner of these limits).
Why bounded above too: an infinite or absurd value (``stall_timeout_s = inf``, a 20-digit
``max_bytes``) turns a safety mechanism off without an error; NaN compares false with
everything, so finiteness is checked first. ``trigger.fraction`` is open at both ends."""


class ConfigError(ValueError):
    """A configuration that cannot be used; the message names the key."""


def no_unknown(section: str, table: dict, known: set[str]) -> None:
    for key in table:
        if key not in known:
            name = f"{section}.{key}" if section else key
            raise ConfigError(f"{name}: unknown key (known: {', '.join(sorted(known))})")


def read_str(key: str, table: dict, default: str) -> str:
    value = table.get(key.rpartition(".")[2], default)
    if not isinstance(value, str) or not value.strip():
        raise ConfigError(f"{key}: must be a non-empty string, got {value!r}")
    return value.strip()


def read_bool(key: str, table: dict, default: bool) -> bool:
    value = table.get(key.rpartition(".")[2], default)
    if not isinstance(value, bool):
        raise ConfigError(f"{key}: must be true or false, got {value!r}")
    return value


def no_nul(value: Any, key: str = "") -> None:
    """No string may hold a NUL character (TOML's "\u0000"): paths with one raise ValueError deep in the daemon."""
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
    for k, v in items:
        no_nul(v, (f"{key}.{k}" if key else str(k)) if isinstance(value, dict) else key)
    if isinstance(value, str) and "\0" in value:
        raise ConfigError(f"{key}: must not contain a NUL character, got {value!r}")


def read_num(key: str, table: dict, default: float) -> float:
    value = table.get(key.rpartition(".")[2], default)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{key}: must be a number, got {value!r}")
    return float(in_range(key, value))


def read_optional_num(key: str, table: dict) -> float | None:
    """A number in ``RANGES[key]``, or None when the key is absent (the model's or the default value applies)."""
    name = key.rpartition(".")[2]
    return None if name not in table else read_num(key, table, 0.0)


def read_int(key: str, table: dict, default: int) -> int:
    value = table.get(key.rpartition(".")[2], default)
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f"{key}: must be an integer, got {value!r}")
    return int(in_range(key, value))


def in_range(key: str, value: float) -> float:
    """``value`` if finite and inside ``RANGES[key]``; else ConfigError with key, value and range."""
    lo, hi = RANGES[key]
    if (isinstance(value, float) and not math.isfinite(value)) or not lo <= value <= hi:
        shown = repr(value) if len(repr(value)) <= 24 else repr(value)[:20] + "..."
        raise ConfigError(f"{key}: must be a finite number in [{_plain(lo)}, {_plain(hi)}], got {shown}")
    return value


def _plain(bound: float) -> str:
    return str(int(bound)) if float(bound).is_integer() else f"{bound:g}"


def read_str_list(key: str, table: dict, default: tuple[str, ...]) -> tuple[str, ...]:
    value = table.get(key.rpartition(".")[2], default)
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list | tuple) or not all(isinstance(v, str) and v.strip() for v in value):
        raise ConfigError(f"{key}: must be a list of strings, got {value!r}")
    return tuple(v.strip() for v in value)

