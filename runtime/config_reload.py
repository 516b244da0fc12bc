"""SIGHUP's words: what changed between two configs, and the log level (``Daemon.reload`` applies
a reloaded config: only what changed is rebuilt, sinks always)."""

from __future__ import annotations

import dataclasses
import logging

from runtime.config import Config

__all__ = ["changed_sections", "set_log_level"]


def changed_sections(old: Config, new: Config) -> str:
    """``changed: sinks, trigger`` (the config's tables and top-level keys that differ), or
    ``nothing changed``: what an operator wants to read after a SIGHUP."""
    names = [f.name for f in dataclasses.fields(new)
             if f.name not in ("source", "warnings") and getattr(new, f.name) != getattr(old, f.name)]
    return "changed: " + ", ".join(names) if names else "nothing changed"


def set_log_level(level: str) -> None:
    logging.getLogger("handover").setLevel(level.upper())
