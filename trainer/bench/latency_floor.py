"""Two limits of the latency targets that no change to the daemon's own code moves, measured in the
bench's run so the results file says how far each tail is the machine's.

``interference``: a thread that only reads the clock, in the stage tables' scheduling, sees every
moment the machine takes its core away (timer ticks, the hypervisor, other threads). From those
gaps, the p99.9 of a perfectly steady job of a given length follows: the floor under any p99.9.

``per_frame_split``: the issue's per-frame idea measured on the default graph itself. The graph is
cut (``onnx.utils.extract_model``) at its per-pad series, whose rows depend on one frame each: the
part before the cut runs on each frame as it arrives, the part after it on the decision. On the
decision's frame the per-frame part still has to run, so the decision costs both parts; the
bench times them alone, back to back, like the whole graph's ``onnx_p50_us``.
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from trainer.measure import percentiles, time_calls

GAP_S = 5e-6
"""A clock reading later than this after the one before counts as time taken from the thread."""
SPIN_CHUNK_S = 0.02
"""Spin in chunks with as much rest between them: a real-time thread spinning longer than the
kernel's real-time budget (0.95 s a second) would be throttled, which is not the machine's noise;
and short ones keep another thread of that core (a daemon at the same priority) waiting at most
this long, not a quarter of a second."""


@dataclass
class Interference:
    """Where (``at``, seconds into the spinning) and for how long (``taken``) a spinning thread lost
    its core, over ``spun`` seconds of spinning."""

    at: np.ndarray
    taken: np.ndarray
    spun: float

    def summary(self) -> dict:
        return {"spun_s": round(self.spun, 2), "gaps_per_s": len(self.taken) / self.spun,
                "gap_us": percentiles(self.taken * 1e6)}

    def steady_job(self, job_us: float, seed: int = 0, n: int = 200_000) -> dict:
        """p50/p99/p99.9 of the wall time of a job needing ``job_us`` of the core, started at ``n``
        random moments: it is stretched by every gap that begins before it ends."""
        job_s, at, taken = job_us * 1e-6, np.asarray(self.at), np.asarray(self.taken)
        starts = np.random.default_rng(seed).uniform(0.0, max(self.spun - 10 * job_s, job_s), n)
        i = np.searchsorted(at, starts)
        end = starts + job_s
        hit = np.flatnonzero(i < len(at))  # all starts at once, each adding its gaps in order (a loop per start took s)
        while hit.size:
            hit = hit[at[i[hit]] < end[hit]]
            end[hit] += taken[i[hit]]
            i[hit] += 1
            hit = hit[i[hit] < len(at)]
        return percentiles((end - starts) * 1e6)


def interference(seconds: float) -> Interference:
    """Time taken from a thread that only reads the clock, over ``seconds`` of spinning."""
    clock = time.perf_counter
    starts: list[float] = []
    lengths: list[float] = []
    spun = 0.0
    while spun < seconds:
        t0 = last = clock()
        end = t0 + SPIN_CHUNK_S
        while last < end:
            now = clock()
            if now - last > GAP_S:
                starts.append(last - t0 + spun)
                lengths.append(now - last)
            last = now
        spun += last - t0
        time.sleep(SPIN_CHUNK_S)
    return Interference(np.asarray(starts), np.asarray(lengths), spun)


def _cut_names(graph) -> tuple[str, str] | None:
    """The per-pad series tensor (the Concat the series pipeline names ``series_*``) and the model's
    input, or None when the graph has no such series (a BoW or flat graph)."""
    for node in graph.node:
        if node.op_type == "Concat" and node.output[0].startswith("series_"):
            return graph.input[0].name, node.output[0]
    return None


def per_frame_split(model_path: Path, windows: np.ndarray, rounds: int) -> dict | None:
    """Whole graph, per-frame part on one frame, decision part (window + series), each alone back to
    back; and how far the split's scores are from the whole graph's on ``windows``."""
    import onnx
    import onnx.utils

    from runtime.model import session_options

    model = onnx.load(str(model_path))
    names = _cut_names(model.graph)
    if names is None:
        return None
    frames, series = names
    import onnxruntime as ort

    with tempfile.TemporaryDirectory(prefix="handover-split-") as tmp:
        per_frame, decision = Path(tmp) / "per_frame.onnx", Path(tmp) / "decision.onnx"
        onnx.utils.extract_model(str(model_path), str(per_frame), [frames], [series])
        onnx.utils.extract_model(str(model_path), str(decision), [frames, series], ["label", "scores"])
        part = onnx.load(str(per_frame))
        part.graph.input[0].type.tensor_type.shape.dim[1].dim_param = "T"  # any number of frames
        del part.graph.value_info[:]
        part.graph.output[0].type.tensor_type.shape.Clear()
        opts = session_options()
        whole_s = ort.InferenceSession(str(model_path), opts, providers=["CPUExecutionProvider"])
        part_s = ort.InferenceSession(part.SerializeToString(), opts, providers=["CPUExecutionProvider"])
        decide_s = ort.InferenceSession(str(decision), opts, providers=["CPUExecutionProvider"])
        nodes = {"whole": len(model.graph.node), "per_frame_part": len(part.graph.node),
                 "decision_part": len(onnx.load(str(decision)).graph.node)}

    def rows(window: np.ndarray) -> np.ndarray:  # the series built frame by frame, as frames arrive
        each = [part_s.run(None, {frames: window[:, t : t + 1]})[0] for t in range(window.shape[1])]
        return np.concatenate(each, axis=-1)

    worst = 0.0
    for w in windows[:50]:
        w = w[None]
        whole = whole_s.run(["scores"], {frames: w})[0]
        split = decide_s.run(["scores"], {frames: w, series: rows(w)})[0]
        worst = max(worst, float(np.max(np.abs(whole - split))))
    w = np.ascontiguousarray(windows[:1])
    last = np.ascontiguousarray(w[:, -1:])
    feed = {frames: w, series: rows(w)}
    out = {"whole": percentiles(time_calls(lambda: whole_s.run(None, {frames: w}), rounds)),
           "per_frame_part": percentiles(time_calls(lambda: part_s.run(None, {frames: last}), rounds)),
           "decision_part": percentiles(time_calls(lambda: decide_s.run(None, feed), rounds)),
           "max_score_difference": worst, "nodes": nodes}
    out["decision_with_its_frame_p50_us"] = out["per_frame_part"]["p50"] + out["decision_part"]["p50"]
    return out
