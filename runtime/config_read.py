"""Typed readers of one TOML key, each raising :class:`ConfigError` naming the key and, for a number,
its closed range from ``runtime.config_keys`` (kept apart from the parser so each reader stays short)."""

from __future__ import annotations

import math
from typing import Any

from firmware_io.errors import HandoverError
from runtime.config_keys import RANGES, Key

__all__ = ["ConfigError", "no_control_chars", "no_unknown", "read_key", "read_str", "read_str_list"]


class ConfigError(HandoverError, ValueError):
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


def no_control_chars(value: Any, key: str = "") -> None:
    """No string may hold a control character (TOML's "\u0000", "\n", "\u001b"): a path with NUL raised
    ValueError deep in the daemon, and a newline or escape in a path or name broke every line naming it."""
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
    for k, v in items:
        no_control_chars(v, (f"{key}.{k}" if key else str(k)) if isinstance(value, dict) else key)
    if isinstance(value, str) and not value.isprintable():
        bad = next(c for c in value if not c.isprintable())
        raise ConfigError(f"{key}: must not contain a control character ({bad!r}), got {value!r}")


def read_num(key: str, table: dict, default: float) -> float:
    value = table.get(key.rpartition(".")[2], default)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{key}: must be a number, got {value!r}")
    return float(in_range(key, value))


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


def read_key(k: Key, table: dict) -> Any:
    """``k``'s value from its section's table, read by its declared type (and choices); an absent
    key gives ``k.config_default``."""
    if k.short not in table:
        return k.config_default
    if k.type is bool:
        return read_bool(k.name, table, False)
    if k.type is int:
        return int(read_int(k.name, table, 0))
    if k.type is float:
        return read_num(k.name, table, 0.0)
    if k.type is tuple:
        return read_str_list(k.name, table, ())
    value = read_str(k.name, table, "")
    if k.choices and value not in k.choices:
        raise ConfigError(f"{k.name}: must be one of {', '.join(k.choices)}, got {table[k.short]!r}")
    return value
