"""LM iterations before / after the radius-growth change (issue 35): every form on every bench
problem, Ceres' growth rule (3) vs ours (``BAOptions.max_radius_growth``), same start.

    .venv/bin/python scripts/lm_growth.py [--out reports/bench-ba-scale/lm-growth] [--overwrite]

Writes ``OUT.json`` (with provenance) and ``OUT.md``. Iteration counts and final objectives are
the figures here (they do not depend on the machine's load); wall times are single runs.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from polarref.ba import BAOptions, prepare  # noqa: E402
from polarref.bench.ba import FULL, _resolve  # noqa: E402
from polarref.ba.entry import solve  # noqa: E402
from polarref.ba.loaders import load_problem  # noqa: E402
from polarref.ba.parameterization import PARAMS  # noqa: E402
from polarref.core.atomic import atomic_write  # noqa: E402
from polarref.core.provenance import collect  # noqa: E402

PROBLEMS = (*FULL, "scale-1e5")
GROWTHS = (3.0, BAOptions().max_radius_growth)


def run() -> list[dict]:
    rows = []
    for spec in PROBLEMS:
        base, _ = load_problem(_resolve(spec))
        prepare(base)
        for form in PARAMS:
            row = {"problem": spec, "form": form}
            for g in GROWTHS:
                s = solve(base.copy(), BAOptions(param=form, max_radius_growth=g), prepared=True)
                row[f"{g:g}"] = {"iterations": s.iterations, "accepted": s.accepted_iterations,
                                 "final_objective": s.final_cost, "final_pixel_cost": s.final_pixel_cost,
                                 "termination": str(s.termination), "wall_s": s.wall_s}
            rows.append(row)
            print(json.dumps(row), flush=True)
    return rows


def markdown(doc: dict) -> str:
    a, b = (f"{g:g}" for g in doc["growths"])
    env = doc["environment"]
    out = [f"LM iterations (accepted + rejected) to the stopping rule, Ceres' radius growth ({a}) vs "
           f"ours ({b}); same start, same tolerances. Commit {env['git_commit'][:10]}"
           f"{' (dirty)' if env['git_dirty'] else ''}. Objective change: (ours - Ceres' rule) / Ceres' rule.", "",
           f"| problem | form | iterations growth {a} | iterations growth {b} | final objective (growth {a}) | "
           "objective change | termination (ours) |", "|---|---|---|---|---|---|---|"]
    tot = {a: 0, b: 0}
    for r in doc["rows"]:
        x, y = r[a], r[b]
        tot[a] += x["iterations"]
        tot[b] += y["iterations"]
        rel = (y["final_objective"] - x["final_objective"]) / x["final_objective"]
        out.append(f"| {r['problem']} | {r['form']} | {x['iterations']} | {y['iterations']} | "
                   f"{x['final_objective']:.9g} | {rel:+.1e} | {y['termination']} |")
    out += ["", f"Total: {tot[a]} iterations at growth {a}, {tot[b]} at growth {b}."]
    return "\n".join(out) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "reports" / "bench-ba-scale" / "lm-growth"))
    ap.add_argument("--overwrite", action="store_true")
    args = ap.parse_args()
    out = Path(args.out)
    if out.with_suffix(".json").exists() and not args.overwrite:
        print(f"{out.with_suffix('.json')} exists (use --overwrite)", file=sys.stderr)
        return 1
    env = collect(threads={"ours_blas": 1})
    load = os.getloadavg()[0]
    doc = {"environment": env, "growths": list(GROWTHS), "load_1min_start": load, "rows": run(),
           "load_1min_end": os.getloadavg()[0]}
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(out.with_suffix(".json"), json.dumps(doc, indent=1, default=float))
    atomic_write(out.with_suffix(".md"), markdown(doc))
    return 0


if __name__ == "__main__":
    sys.exit(main())
