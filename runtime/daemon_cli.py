"""``handover run --config FILE [--check]``: the detection daemon (systemd service).

``--check`` validates the config and the model folder (newest valid model against the scene)
and exits: 0 when a model would serve, 1 when none would, 2 for a config error.
"""

from __future__ import annotations

import argparse
import logging
import sys

PROG = "handover run"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, metavar="FILE", help="TOML configuration (see deploy/handover.toml)")
    parser.add_argument("--check", action="store_true", help="validate the config and the model folder, then exit")


def main(args: argparse.Namespace) -> int:
    from runtime.config import ConfigError, load_config

    try:
        cfg = load_config(args.config)
    except ConfigError as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 2
    logging.basicConfig(stream=sys.stderr, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("handover").setLevel(cfg.log_level.upper())
    if args.check:
        return _check(cfg)
    from runtime.daemon import Daemon

    daemon = Daemon(cfg)
    daemon.install_signal_handlers()
    return daemon.run()


def _check(cfg) -> int:
    """Report what the daemon would serve, without opening the device."""
    from runtime.daemon import Daemon, scene_problem
    from runtime.model_watch import ModelWatcher

    daemon = Daemon(cfg)
    watcher = ModelWatcher(cfg.model.folder, loader=daemon._load, check=lambda m: scene_problem(m, cfg, None))
    model = watcher.poll(require_stable=False)
    if model is None:
        reasons = "; ".join(f"{r.path.name}: {r.reason}" for r in watcher.rejections) or "no .onnx file"
        print(f"{PROG}: config {cfg.source} is valid, but no model in {cfg.model.folder} would serve ({reasons})",
              file=sys.stderr)
        return 1
    print(f"config {cfg.source} is valid; would serve model {model.model_id} ({model.path.name})")
    return 0
