"""Why the Schur stage sat at 0.04-0.10x of the GEMM rate in the BA bench's roofline (issue 35).

Usage: .venv/bin/python scripts/schur_roofline.py [--repeat N] [--out reports/bench-ba-scale/schur-roofline]
       [--overwrite] PROBLEM [PROBLEM ...]

Per problem (Euclidean form, kernel path, at the initial estimate, 1 BLAS thread), each piece
timed alone in process CPU time (``time.process_time``: a loaded machine's waiting drops out),
minimum over ``--repeat`` calls:

* the entry-pair kernel writing into the dense S (``kernels.schur_dense``, the path before),
* the same products into contiguous camera-pair blocks (``kernels.schur_blocks``, the path
  now), and the scatter of the blocks into the dense S,
* the whole Schur stage as the solver runs it (``SchurStructure.reduced_system``: the point
  blocks' inverse factors, U, the products, the damping) on both paths,
* the dense GEMM rate in the same process, timed the same way (CPU time, best of 5 numpy
  float64 1500x1500 products; ``roofline.gemm_gflops`` times wall, which a loaded machine
  stretches).

Rates are the roofline's analytic flops (roofline.py) over these times. Writes OUT.json (with
provenance and the load average) and OUT.md.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from polarref.ba import kernels  # noqa: E402
from polarref.ba.loaders import load_problem  # noqa: E402
from polarref.ba.options import BAOptions  # noqa: E402
from polarref.ba.parameterization import make_param  # noqa: E402
from polarref.ba.problem import prepare  # noqa: E402
from polarref.ba.roofline import lm_flops  # noqa: E402
from polarref.ba.schur import SchurStructure, _c, chol_inv3  # noqa: E402
from polarref.bench.ba import _resolve  # noqa: E402
from polarref.core.records import to_dict  # noqa: E402
from profile_ba import add_out_arguments, begin, write_doc  # noqa: E402  (scripts/ is sys.path[0])


def _best(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t = time.process_time()
        fn()
        best = min(best, time.process_time() - t)
    return best


def gemm_cpu_gflops(n: int = 1500, repeat: int = 5, seed: int = 0) -> float:
    """numpy's float64 (n x n) @ (n x n) in GFLOP/s of process CPU time (best of ``repeat``)."""
    rng = np.random.default_rng(seed)
    a, b = rng.standard_normal((n, n)), rng.standard_normal((n, n))
    a @ b
    return 2.0 * n**3 / _best(lambda: a @ b, repeat) / 1e9


def measure(spec: str, repeat: int) -> dict:
    base, _ = load_problem(_resolve(spec))
    prepare(base)
    prm = make_param(base, BAOptions(param="euclidean"))
    cv = base.cam_mask.any(1)
    st = SchurStructure(prm.slot_cams, prm.slot_cols, base.obs_pt, cv, base.num_points, 10**6, fast=True)
    st.use_gemm, st.dense_blocks = False, True   # the entry-pair paths, whatever the size rule says
    if not hasattr(st, "pair_blk"):
        st._build_blocks()
    r, Jp, Jc = prm.evaluate(base.R, base.C, prm.init_points(), True, factored=False)
    mask_v = base.cam_mask[st.var_cams].astype(float)
    g_c, W, U = st.apply_mask(mask_v, *st.build(Jc, Jp, r))
    V, g_p = st.point_terms(Jp, r)
    Vd = V + 1e-3 * np.eye(3)
    diag_c = np.ones((st.Nv, 6))
    Li = chol_inv3(Vd)
    q = np.matmul(Li, g_p[:, :, None])[:, :, 0]
    Wc, Nv = _c(W), st.Nv
    none = (np.zeros((1, 6, 4)), np.zeros((1, 3)), np.zeros((1, 3, 3)))

    def dense_kernel():
        kernels.schur_dense(Wc, Li, q, st.entry_bounds, st.entry_pt, st.entry_cam,
                            np.zeros((6 * Nv, 6 * Nv)), np.zeros((Nv, 6)), False, *none,
                            st.slot_entry, st.obs_bounds)

    def block_kernel():
        kernels.schur_blocks(Wc, Li, q, st.entry_bounds, st.entry_pt, st.pair_blk,
                             np.zeros((st.K, 6, 6)), np.zeros((Nv, 6)), st.entry_cam)

    blocks = np.zeros((st.K, 6, 6))

    def scatter():
        S = np.zeros((Nv, 6, Nv, 6))
        S[st.blk_ca, :, st.blk_cb, :] = blocks

    def stage(dense_blocks: bool):
        st.dense_blocks = dense_blocks
        return lambda: st.reduced_system(U, W, Vd, g_c, g_p, diag_c)

    f = lm_flops(base.obs_cam, base.obs_pt, cv, base.num_points, True)
    t = {"dense_kernel_s": _best(dense_kernel, repeat), "block_kernel_s": _best(block_kernel, repeat),
         "scatter_s": _best(scatter, repeat), "point_factors_s": _best(lambda: chol_inv3(Vd), repeat),
         "stage_dense_s": _best(stage(False), repeat), "stage_blocks_s": _best(stage(True), repeat)}
    return {"problem": spec, "num_cameras": base.num_cameras, "variable_cameras": Nv,
            "num_observations": base.num_observations, "entries": st.E, "entry_pairs": st.num_pairs,
            "camera_pair_blocks": st.K, "schur_flops": f.schur, "cpu_s": t,
            "gflops": {k[:-2]: f.schur / v / 1e9 for k, v in t.items() if "kernel" in k or "stage" in k}}


def markdown(doc: dict) -> str:
    g1 = doc["gemm_gflops_1t"]
    out = [f"Schur stage vs GEMM (issue 35), commit {doc['environment']['git_commit'][:7]}"
           f"{' (dirty)' if doc['environment']['git_dirty'] else ''}, process CPU time, 1 thread, min of "
           f"{doc['repeat']}; load {doc['load_1min'][0]:.1f}-{doc['load_1min'][1]:.1f} on "
           f"{doc['environment']['cpu_count']} cores (indicative). GEMM {g1:.2f} GFLOP/s (1 thread, CPU time, same run). "
           "Rates: the roofline's Schur flops / time (x GEMM).", "",
           "| problem | cams | entry pairs | blocks | kernel, dense S ms | kernel, blocks ms | scatter ms "
           "| point factors ms | stage before ms | stage now ms | kernel GFLOP/s before / now | "
           "stage GFLOP/s before / now |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in doc["problems"]:
        t, g = r["cpu_s"], r["gflops"]
        out.append(f"| {r['problem']} | {r['variable_cameras']} | {r['entry_pairs']} | {r['camera_pair_blocks']} | "
                   f"{1e3 * t['dense_kernel_s']:.1f} | {1e3 * t['block_kernel_s']:.1f} | {1e3 * t['scatter_s']:.1f} | "
                   f"{1e3 * t['point_factors_s']:.1f} | {1e3 * t['stage_dense_s']:.1f} | {1e3 * t['stage_blocks_s']:.1f} | "
                   f"{g['dense_kernel']:.2f} ({g['dense_kernel'] / g1:.2f}x) / {g['block_kernel']:.2f} "
                   f"({g['block_kernel'] / g1:.2f}x) | {g['stage_dense']:.2f} ({g['stage_dense'] / g1:.2f}x) / "
                   f"{g['stage_blocks']:.2f} ({g['stage_blocks'] / g1:.2f}x) |")
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("problems", nargs="+")
    ap.add_argument("--repeat", type=int, default=5)
    add_out_arguments(ap, ROOT / "reports" / "bench-ba-scale" / "schur-roofline")
    args = ap.parse_args(argv)
    out = Path(args.out)
    started = begin(out, args.overwrite)
    if started is None:
        return 2
    env, load0 = started
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        problems = [measure(p, args.repeat) for p in args.problems]
        gemm = gemm_cpu_gflops()
    doc = {"command": "python scripts/schur_roofline.py " + " ".join(sys.argv[1:]), "repeat": args.repeat,
           "clock": "process CPU time (time.process_time)", "gemm_gflops_1t": gemm,
           "load_1min": [load0, os.getloadavg()[0]], "problems": problems, "environment": to_dict(env)}
    write_doc(out, doc, markdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
