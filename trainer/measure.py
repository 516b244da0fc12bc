"""What ``handover bench`` and the checkout's benchmarks/ share (one owner, so both measure and
report alike): machine info, percentiles, timing loops, the deadline, the simulated data and a
model trained on it, and writing ``results/<name>.{json,md,png}`` with the reproducing command.

Everything trained here is trained on the simulated hand (synthetic data) and says so.
"""

from __future__ import annotations

import contextlib
import json
import os
import platform
import shlex
import tempfile
import time
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path

import numpy as np

from firmware_io.frame_timing import NOMINAL_PERIOD_S, NOMINAL_RATE_HZ
from trainer.defaults import DEFAULT_MODEL

__all__ = [
    "DEADLINE_US", "PRODUCT_BENCHES", "command_line", "cycling", "deadline_ratio", "default_out", "export_metadata",
    "fmt_us", "load_average", "load_note", "machine_info", "out_option", "percentiles",
    "run_facts", "simulated_protocol", "tap_gap", "tap_stream", "time_calls", "train_default_model", "with_metadata",
    "write_results",
]

DEADLINE_US = 1e6 * NOMINAL_PERIOD_S
"""One sample period at the controller's nominal rate: the hard deadline of a decision."""


def machine_info() -> dict:
    """CPU, cores, versions and the load average at the time of the call."""
    import onnxruntime

    cpu = "unknown"
    with contextlib.suppress(OSError, StopIteration):
        lines = Path("/proc/cpuinfo").read_text().splitlines()
        cpu = next(line.split(":", 1)[1].strip() for line in lines if line.startswith("model name"))
    info = {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(),
            "platform": platform.platform(), "numpy": np.__version__, "onnxruntime": onnxruntime.__version__,
            "load_average": [round(v, 2) for v in os.getloadavg()]}
    with contextlib.suppress(ImportError):
        import sklearn

        info["scikit-learn"] = sklearn.__version__
    return info


def load_average() -> list[float]:
    """The 1, 5 and 15 minute load averages (other work on the shared machine)."""
    return [round(float(v), 2) for v in os.getloadavg()]


def percentiles(values_us) -> dict:
    """median, p99, p99.9, max, mean and count of a sample in microseconds (None when empty)."""
    v = np.asarray(values_us, dtype=np.float64)
    if v.size == 0:
        return {"n": 0, "p50": None, "p99": None, "p999": None, "max": None, "mean": None}
    return {"n": int(v.size), "p50": float(np.percentile(v, 50)), "p99": float(np.percentile(v, 99)),
            "p999": float(np.percentile(v, 99.9)), "max": float(v.max()), "mean": float(v.mean())}


def deadline_ratio(stats: dict) -> dict:
    """How many times each figure fits into one sample period (``DEADLINE_US``)."""
    return {k: (DEADLINE_US / stats[k] if stats.get(k) else None) for k in ("p50", "p99", "p999", "max")}


def cycling(fn: Callable, cases) -> Callable[[], object]:
    """A no-argument call that runs ``fn`` on the next case, round robin (for ``time_calls``)."""
    state = {"i": 0}

    def call():
        state["i"] += 1
        return fn(cases[state["i"] % len(cases)])

    return call


def time_calls(fn: Callable[[], object], repeats: int, warmup: int = 20, period_s: float | None = None,
               cpu: bool = False) -> np.ndarray:
    """Durations (us) of ``repeats`` calls; with ``period_s`` the calls are paced (sleep in between).

    ``cpu=True`` counts the calling thread's CPU time instead of wall time: what the work itself
    costs, without the time the scheduler gave other processes (onnxruntime with one intra-op
    thread computes on the calling thread), so a busy shared machine cannot decide a comparison.
    """
    for _ in range(warmup):
        fn()
    out = np.empty(repeats)
    clock = time.thread_time_ns if cpu else time.perf_counter_ns
    next_t = time.perf_counter()
    for i in range(repeats):
        if period_s:
            next_t += period_s
            pause = next_t - time.perf_counter()
            if pause > 0:
                time.sleep(pause)
        t0 = clock()
        fn()
        out[i] = clock() - t0
    return out / 1000.0


def default_out(quick: bool) -> str:
    """Where a benchmark writes: the committed ``results`` folder for a measurement; a smoke test
    (``--quick``) under the system's temp folder, so it never overwrites the committed figures; one
    folder per user, so another user's smoke test on a shared machine does not stand in the way."""
    if not quick:
        return "results"
    return str(Path(tempfile.gettempdir()) / f"handover-bench-quick-{_user()}")


def _user() -> str:
    """The user's name for a folder name (the uid where the name cannot be found)."""
    import getpass

    try:
        name = getpass.getuser()
    except (KeyError, OSError):
        name = ""
    safe = "".join(c for c in name if c.isalnum() or c in "-_.")
    return safe or str(os.getuid())


PRODUCT_BENCHES = ("latency", "throughput", "inference")
"""What ``handover bench`` runs (trainer/bench/); the rest are the checkout's benchmarks/."""


def command_line(name: str, args) -> str:
    """The command that reproduces a result (``args``: the bench options; a benchmark called from
    Python may pass a namespace with only some of them): the product's ``handover bench`` for what
    it has, else the checkout's ``./dev bench``."""
    parts = ["handover" if name in PRODUCT_BENCHES else "./dev", "bench", name]
    if getattr(args, "quick", False):
        parts.append("--quick")
    if name == "latency" and getattr(args, "load", False):
        parts.append("--load")
    per_benchmark = {"latency": ("duration",), "decode": ("frames", "repeats"), "inference": ("repeats", "model"),
                     "ros2": ("seconds", "speed", "pad_rate")}
    for option in per_benchmark.get(name, ()):
        if getattr(args, option, None) is not None:
            parts += ["--" + option.replace("_", "-"), str(getattr(args, option))]
    if name == "decode" and getattr(args, "synthetic", False):
        parts.append("--synthetic")
    if getattr(args, "seed", None) is not None:
        parts += ["--seed", str(args.seed)]
    parts += out_option(getattr(args, "out", None), getattr(args, "quick", False))
    return shlex.join(parts)


def out_option(out: str | None, quick: bool) -> list[str]:
    """``--out`` for a Reproduce line: nothing for the default folder (a temp one on ``--quick``, a
    path of one machine), else the folder given."""
    return [] if out in (None, default_out(quick)) else ["--out", str(out)]


def with_metadata(model_path: Path, out: Path, change: Callable[[dict], None]) -> Path:
    """A copy of ``model_path`` at ``out`` whose model metadata ``change`` edited in place (the same
    graph; a different file, so a different model id)."""
    import onnx

    from runtime.model import METADATA_KEY

    graph = onnx.load(str(model_path))
    for prop in graph.metadata_props:
        if prop.key == METADATA_KEY:
            meta = json.loads(prop.value)
            change(meta)
            prop.value = json.dumps(meta, sort_keys=True)
    onnx.save(graph, str(out))
    return out


def write_results(out: str | Path, name: str, result: dict, markdown: list[str]) -> Path:
    """results/<name>.json (machine + command included) and results/<name>.md; returns the json path."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}.json"
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(result, indent=2, default=_json_default) + "\n")
    os.replace(tmp, path)
    m = result["machine"]
    quick = ["", "**A quick run (`--quick`): tiny sizes and short runs, a smoke test, not a measurement.**"] \
        if " --quick" in result.get("command", "") else []
    md = [
        markdown[0], *quick, *markdown[1:],
        "",
        f"Machine: {m['cpu']}, {m['cores']} cores, Python {m['python']}, numpy {m['numpy']}, "
        f"onnxruntime {m['onnxruntime']}" + (f", scikit-learn {m['scikit-learn']}" if "scikit-learn" in m else "")
        + f". Load average at the start {result.get('load_before', m['load_average'])}, "
        f"at the end {result.get('load_after', '?')}. " + _load_sentence(result, m),
        "",
        f"Reproduce: `{result['command']}`",
        "",
    ]
    (out / f"{name}.md").write_text("\n".join(md))
    return path


def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def fmt_us(v: float | None) -> str:
    return "-" if v is None else (f"{v:.1f}" if v < 100 else f"{v:.0f}")


def _load_sentence(result: dict, machine: dict) -> str:
    """``load_note`` for a results file that recorded its load averages, else what is known."""
    before, after = result.get("load_before"), result.get("load_after")
    if isinstance(before, list) and isinstance(after, list) and before and after:
        return load_note(before, after, machine.get("cores"))
    return "The machine is shared: tails (p99, p99.9, max) may include other work."


def run_facts(name: str, args, load_before: list[float], t_start: float) -> dict:
    """What a results file records about its run: how long, on what, under what load, by which command."""
    seconds, machine, load_after = round(time.perf_counter() - t_start, 1), machine_info(), load_average()
    return {"seconds": seconds, "machine": machine, "load_before": load_before, "load_after": load_after,
            "command": command_line(name, args), "note": load_note(load_before, load_after, machine["cores"])}


def load_note(before: list[float], after: list[float], cores: int | None) -> str:
    """An honest line about other work on the machine during the run."""
    worst = max(before[0], after[0])
    n = cores or 1
    if worst < 0.5:
        return "The machine was quiet during the run (1-minute load average below 0.5)."
    return (f"The machine was shared with other work: 1-minute load average {before[0]:.2f} at the start and "
            f"{after[0]:.2f} at the end on {n} cores; tails (p99, p99.9, max) include that interference.")


# -- data and models (synthetic) -----------------------------------------------------------------
@lru_cache(maxsize=4)
def simulated_protocol(seed: int = 0, quick: bool = False) -> tuple:
    """The paper's protocol from the simulated hand, simulated once per process (synthetic data)."""
    from firmware_io.sim import simulate_protocol

    if quick:
        return tuple(simulate_protocol(seed=seed, n_subjects=2, runs=1))
    return tuple(simulate_protocol(seed=seed))


def export_metadata(ds, model, evaluation: dict | None = None, seed: int = 0) -> dict:
    """The metadata ``handover train`` writes (``trainer.model_meta``), for a model trained on the
    simulated protocol."""
    from trainer.model_meta import dataset_metadata

    return dataset_metadata(ds, training={"data": "simulated protocol (synthetic)", "synthetic": True, "seed": seed,
                                          "C": model.best_params_.get("C"), "gamma": model.best_params_.get("gamma")},
                            evaluation={"synthetic": True, **(evaluation or {})})


def train_default_model(folder: str | Path, seed: int = 0, quick: bool = False, name: str = "bench.onnx",
                        pads: str = DEFAULT_MODEL["pads"]) -> Path:
    """Train the product default (``trainer.defaults``, what ``handover train`` exports without
    options) on the simulated protocol and export it (the fitted estimator beside it as ``.joblib``);
    ``pads`` another selection of pads.

    Its windows are cut by the paper's threshold (recorded in the model, so the daemon serves it
    with the threshold): the latency and throughput benchmarks feed the tap stream, whose
    back-to-back windows fire a threshold every time but give the onset trigger no settled grasp.
    The features, and so the cost of a decision, are the default model's."""
    import joblib

    from runtime.trigger_settings import PAPER_FRACTION
    from trainer.dataset import build_dataset
    from trainer.defaults import default_classifier
    from trainer.onnx_export import export_onnx

    ds = build_dataset(list(simulated_protocol(seed, quick)), T=DEFAULT_MODEL["T"], pads=pads, fraction=PAPER_FRACTION)
    shapes = [(ds.layout.matrices[p].cells_y, ds.layout.matrices[p].cells_x) for p in ds.pads]
    model = default_classifier(ds.pad_sizes, pad_shapes=shapes, random_state=seed, fullscale=ds.fullscale)
    model.fit(ds.X, ds.y)
    path = export_onnx(model, Path(folder) / name, export_metadata(ds, model, seed=seed))
    joblib.dump(model, path.with_suffix(".joblib"))  # the fitted estimator beside its graph, as handover train leaves it
    return path


def tap_gap(T: int = 15) -> int:
    """Untouched frames after each window of the tap stream: enough for the daemon's default
    trigger to re-arm (quiet time below the off level, when the runtime has one) and for its
    refractory time to pass, so that every window is classified once."""
    import math

    from runtime.config import TriggerConfig

    cfg = TriggerConfig()
    quiet = math.ceil(float(getattr(cfg, "rearm_quiet_s", 0.0) or 0.0) * NOMINAL_RATE_HZ) + 2
    refractory = math.ceil(float(cfg.refractory_s) * NOMINAL_RATE_HZ) + 1 - T
    return max(5, quiet, refractory)


def tap_stream(seed: int = 0, quick: bool = False, n_windows: int | None = None, T: int = 15, gap: int = 5):
    """A dense synthetic stream: the T frames from each simulated trial's trigger, back to back,
    each followed by ``gap`` untouched frames (so the trigger re-arms). One window every T + gap
    frames: the most inference work a threshold-triggered daemon can get at 32 Hz.
    """
    from firmware_io.recordings.recording import Recording, Trial
    from runtime.trigger_settings import PAPER_FRACTION
    from trainer.dataset import build_dataset

    recs = list(simulated_protocol(seed, quick))
    ds = build_dataset(recs, T=T, pads="all", fraction=PAPER_FRACTION)
    layout = recs[0].layout
    cols = layout.columns("all")
    cases = ds.X if n_windows is None else ds.X[np.resize(np.arange(len(ds.X)), n_windows)]
    period = T + gap
    frames = np.zeros((len(cases) * period + gap, layout.n_taxels), dtype=np.uint16)
    trials = []
    for i, case in enumerate(cases):
        start = gap + i * period
        frames[start : start + T, cols] = case.T.astype(np.uint16)
        trials.append(Trial("tap", "stream", "-", str(ds.y[i % len(ds.y)]), i, start, start + T - 1))
    timestamps = np.arange(len(frames)) * NOMINAL_PERIOD_S
    meta = {"synthetic": True, "source": "handover bench: simulated trial windows back to back"}
    return Recording(layout, frames, timestamps, trials, meta)


