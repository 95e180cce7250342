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
  stretches), and the memory bandwidth of a one-thread STREAM triad timed the same way;
* the Schur kernel's bytes per LM step in roofline.py's two models (compulsory, per update),
  its arithmetic intensity and the bandwidth roof min(GEMM, intensity x bandwidth);
* three variants of the block kernel, timed interleaved with it on the same inputs, to find
  what bounds it: every pair's update into one block (L1-resident: no memory traffic for
  the blocks; the kernel's in-core bound), the products with fused multiply-adds (numba
  ``fastmath={"contract"}``), and Z held transposed (a block row's six numbers of Z_b
  contiguous instead of at stride 3), and the points visited in order of their first camera
  (consecutive points then update nearby camera-pair blocks: locality in the caches).

Rates are the roofline's analytic flops (roofline.py) over these times. Writes OUT.json (with
provenance and the load average) and OUT.md.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numba
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from polarref.ba import kernels  # noqa: E402
from polarref.ba.loaders import load_problem  # noqa: E402
from polarref.ba.options import BAOptions  # noqa: E402
from polarref.ba.parameterization import make_param  # noqa: E402
from polarref.ba.problem import prepare  # noqa: E402
from polarref.ba.kernels_jit import _longest, _point_factors  # noqa: E402
from polarref.ba.roofline import lm_flops, roof, schur_traffic, triad_gbs  # noqa: E402
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


def _blocks_transposed(W, Li, q, bounds, entry_pt, pair_blk, blocks, b, entry_cam):
    """The block kernel with Z transposed per point (ZT[a] = Z_a^T, 3x6) before the pair products."""
    n = _longest(bounds)
    Z, ZT = np.empty((n, 6, 3)), np.empty((n, 3, 6))
    k = 0
    for g in range(len(bounds) - 1):
        e0, e1 = bounds[g], bounds[g + 1]
        _point_factors(W, Li, q, entry_pt[e0], e0, e1, entry_cam, Z, b)
        for a in range(e1 - e0):
            ZT[a] = Z[a].T
        for a in range(e1 - e0):
            for bb in range(a, e1 - e0):
                blk = blocks[pair_blk[k]]
                k += 1
                for i in range(6):
                    z0, z1, z2 = ZT[a, 0, i], ZT[a, 1, i], ZT[a, 2, i]
                    for j in range(6):
                        blk[i, j] -= z0 * ZT[bb, 0, j] + z1 * ZT[bb, 1, j] + z2 * ZT[bb, 2, j]


# the kernel's own Python source compiled a second time, with fused multiply-adds allowed
_fma = numba.njit(fastmath={"contract"}, error_model="numpy")(kernels.schur_blocks.py_func)
_transposed = numba.njit(error_model="numpy")(_blocks_transposed)


def _by_first_camera(st, W):
    """The kernel's inputs with the points visited in order of their first camera (entries
    sorted by camera within a point), so consecutive points update nearby camera-pair blocks:
    (W, bounds, entry_pt, entry_cam, pair_blk) permuted. The sums into each block come in
    another order (same terms, other rounding)."""
    bounds = st.entry_bounds
    L = np.diff(bounds)
    order = np.argsort(st.entry_cam[bounds[:-1]], kind="stable")
    npairs = L * (L + 1) // 2
    pair_start = np.r_[0, np.cumsum(npairs)]

    def gather(starts, counts):   # the concatenated ranges [starts[g], starts[g] + counts[g]) in `order`
        c = counts[order]
        return np.repeat(starts[order] - np.r_[0, np.cumsum(c)[:-1]], c) + np.arange(c.sum())

    e = gather(bounds[:-1], L)
    return (_c(W[e]), np.r_[0, np.cumsum(L[order])].astype(np.int64), st.entry_pt[e], st.entry_cam[e],
            st.pair_blk[gather(pair_start[:-1], npairs)])


def _interleaved(fns: dict, repeat: int) -> dict:
    """Minimum CPU seconds of each fn, the fns called in turn in every round (load changes hit all)."""
    best = dict.fromkeys(fns, float("inf"))
    for _ in range(repeat):
        for name, fn in fns.items():
            t = time.process_time()
            fn()
            best[name] = min(best[name], time.process_time() - t)
    return best


def measure(spec: str, repeat: int) -> dict:
    base, _ = load_problem(_resolve(spec))
    prepare(base)
    prm = make_param(base, BAOptions(param="euclidean"))
    cv = base.cam_mask.any(1)
    st = SchurStructure(prm.slot_cams, prm.slot_cols, base.obs_pt, cv, base.num_points, 10**6, fast=True)
    st.use_gemm, st.dense_blocks = False, True   # the entry-pair paths, whatever the size rule says
    if st.pair_blk is None:
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

    def block(fn, pair_blk):
        return lambda: fn(Wc, Li, q, st.entry_bounds, st.entry_pt, pair_blk, np.zeros((st.K, 6, 6)),
                          np.zeros((Nv, 6)), st.entry_cam)

    block_kernel = block(kernels.schur_blocks, st.pair_blk)
    Wo, bo, po, co, ko = _by_first_camera(st, W)
    variants = {"block_kernel": block_kernel, "one_block": block(kernels.schur_blocks, np.zeros_like(st.pair_blk)),
                "fma": block(_fma, st.pair_blk), "transposed": block(_transposed, st.pair_blk),
                "by_first_camera": lambda: kernels.schur_blocks(Wo, Li, q, bo, po, ko, np.zeros((st.K, 6, 6)),
                                                                np.zeros((Nv, 6)), co)}
    for fn in variants.values():
        fn()    # compile

    blocks = np.zeros((st.K, 6, 6))

    def scatter():
        S = np.zeros((Nv, 6, Nv, 6))
        S[st.blk_ca, :, st.blk_cb, :] = blocks

    def stage(dense_blocks: bool):
        st.dense_blocks = dense_blocks
        return lambda: st.reduced_system(U, W, Vd, g_c, g_p, diag_c)

    f = lm_flops(base.obs_cam, base.obs_pt, cv, base.num_points, True)
    tr = schur_traffic(base.obs_cam, base.obs_pt, cv)
    var = _interleaved(variants, repeat)
    t = {"dense_kernel_s": _best(dense_kernel, repeat), "block_kernel_s": var.pop("block_kernel"),
         "scatter_s": _best(scatter, repeat), "point_factors_s": _best(lambda: chol_inv3(Vd), repeat),
         "stage_dense_s": _best(stage(False), repeat), "stage_blocks_s": _best(stage(True), repeat)}
    return {"problem": spec, "num_cameras": base.num_cameras, "variable_cameras": Nv,
            "num_observations": base.num_observations, "entries": st.E, "entry_pairs": st.num_pairs,
            "camera_pair_blocks": st.K, "schur_flops": f.schur, "cpu_s": t,
            "gflops": {k[:-2]: f.schur / v / 1e9 for k, v in t.items() if "kernel" in k or "stage" in k},
            "bytes": {"compulsory": tr.compulsory_bytes, "per_update": tr.per_update_bytes},
            "variants_cpu_s": var, "variants_gflops": {k: f.schur / v / 1e9 for k, v in var.items()}}


def _roof_lines(doc: dict) -> list[str]:
    """Per problem: bytes, intensity, both roofs and where the block kernel and its variants sit."""
    g1, bw = doc["gemm_gflops_1t"], doc["triad_gbs_1t"]
    out = ["", f"Bandwidth roof: STREAM triad {bw:.2f} GB/s (1 thread, CPU time, same run); roof = min(GEMM, "
           "flop/B x bandwidth) for the compulsory bytes (every array once) and the per-update bytes (each "
           "entry pair's block read and written from memory), roofline.py. Variants of the block kernel, "
           "interleaved with it: all pairs into one block (L1-resident blocks: its in-core bound), fused "
           "multiply-adds, Z transposed, points in order of their first camera.", "",
           "| problem | MB compulsory / per update | flop/B | roof GFLOP/s | block kernel GFLOP/s (x roof, x GEMM) "
           "| one block | FMA | Z transposed | by first camera |", "|---|---|---|---|---|---|---|---|---|"]
    for r in doc["problems"]:
        by, fl, k = r["bytes"], r["schur_flops"], r["gflops"]["block_kernel"]
        ai = [fl / by["compulsory"], fl / by["per_update"]]
        rf = [roof(a, bw, g1) for a in ai]
        v = r["variants_gflops"]
        out.append(f"| {r['problem']} | {by['compulsory'] / 1e6:.1f} / {by['per_update'] / 1e6:.1f} | "
                   f"{ai[0]:.3f} / {ai[1]:.3f} | {rf[0]:.2f} / {rf[1]:.2f} | {k:.2f} ({k / rf[0]:.2f} / "
                   f"{k / rf[1]:.2f}, {k / g1:.2f}x) | "
                   + " | ".join(f"{v[n]:.2f} ({v[n] / k:.2f}x)" for n in ("one_block", "fma", "transposed", "by_first_camera")) + " |")
    return out


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
    return "\n".join(out + _roof_lines(doc)) + "\n"


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
    triad = triad_gbs(clock=time.process_time)
    doc = {"command": "python scripts/schur_roofline.py " + " ".join(sys.argv[1:]), "repeat": args.repeat,
           "clock": "process CPU time (time.process_time)", "gemm_gflops_1t": gemm, "triad_gbs_1t": triad,
           "load_1min": [load0, os.getloadavg()[0]], "problems": problems, "environment": to_dict(env)}
    write_doc(out, doc, markdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
