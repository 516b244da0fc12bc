"""How far simulated lab B sits from lab A, against how far the two real SDH-2 sources sit apart.

    ./dev bench lab_shift [--seed 0] [--out results]

The rule (docs/SIMULATOR.md, "A second lab"): lab B's noise floor and contact level must differ
from lab A's at least by the factor the real sources (Kiechle's ~31 Hz .dsa files, mas-group's slip
bags) differ by. Synthetic: each lab's protocol, 2 subjects x 2 runs, seed 0 (as the realism table).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

QUANTITIES = (("noise", "untouched_nonzero_fraction", "untouched taxels read non-zero", "{:.2e}"),
              ("level", "peak_median", "pad peak in contact, median (counts)", "{:.0f}"),
              ("level", "peak_p75", "pad peak in contact, p75 (counts)", "{:.0f}"),
              ("values", "nonzero_p50", "non-zero reading, median (counts)", "{:.0f}"),
              ("area", "area_median", "contact area, median (taxels/pad)", "{:.0f}"))


def measure(seed: int, sdh2_dsa: Path) -> dict:
    """Summaries of the real sources (those present) and of labs A and B, and the shifts between them."""
    from firmware_io.sim import realism, simulate_protocol

    real = {name: realism.summarise(recs) for name, recs in realism.load_sources(sdh2_dsa).items() if recs}
    sim = {f"lab {lab} (synthetic)": realism.summarise(simulate_protocol(seed=seed, n_subjects=2, runs=2, lab=lab))
           for lab in ("A", "B")}
    out = {"summaries": {**real, **sim}, "lab_shift": realism.shift(*sim.values())}
    if len(real) == 2:
        out["real_shift"] = realism.shift(real["kiechle"], real["mas-group"])
        out["lab_b_at_least_real"] = all(out["lab_shift"][k] >= out["real_shift"][k]
                                         for k in ("noise_floor_factor", "contact_level_factor"))
    return out


def markdown(result: dict) -> list[str]:
    names = list(result["summaries"])
    rows = ["| quantity | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    for part, key, label, fmt in QUANTITIES:
        cells = [fmt.format(s[part][key]) if key in s.get(part, {}) else "-" for s in result["summaries"].values()]
        rows.append(f"| {label} | " + " | ".join(cells) + " |")
    shifts = [f"| {what} | " + " | ".join(f"{result[k][f'{q}_ratio']:.2f} (x{result[k][f'{q}_factor']:.2f})"
                                          for q in ("noise_floor", "contact_level")) + " |"
              for what, k in (("mas-group / Kiechle (real)", "real_shift"), ("lab B / lab A (synthetic)", "lab_shift"))
              if k in result]
    verdict = ("Lab B's shift is at least the real sources' on both: "
               + ("yes" if result.get("lab_b_at_least_real") else "NO")) if "real_shift" in result else \
        "The real recordings were absent: no comparison."
    return ["# Lab B against lab A, sized by the two real sources", "",
            __doc__.split("\n\n", 2)[2].strip(), "", *rows, "",
            "| ratio (factor) | noise floor | contact level |", "|---|---|---|", *shifts, "", verdict]


def main(argv: list[str] | None = None) -> int:
    from trainer.measure import load_average, machine_info, write_results
    from trainer.shared_data import default_data_dir

    ap = argparse.ArgumentParser(prog="./dev bench lab_shift", description=__doc__.split("\n", 1)[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("results"))
    args = ap.parse_args(argv)
    t0, load_before = time.perf_counter(), load_average()
    result = measure(args.seed, default_data_dir() / "sdh2-dsa")
    result.update(command=f"./dev bench lab_shift --seed {args.seed}", machine=machine_info(),
                  seconds=round(time.perf_counter() - t0, 1), load_before=load_before, load_after=load_average())
    write_results(args.out, "lab_shift", result, markdown(result))
    print("\n".join(markdown(result)[-6:]))
    return 0 if result.get("lab_b_at_least_real", True) else 1
