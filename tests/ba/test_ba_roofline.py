"""The Schur stage's bytes, intensity and bandwidth roof (roofline.py) against hand counts and
against the Schur structure the solver builds; bench.md's bandwidth table from bench.json alone."""

import numpy as np
import pytest

from polarref.ba import roofline
from polarref.ba.roofline import roof, schur_traffic, triad_gbs


def test_schur_traffic_by_hand():
    # cameras 0, 1, 2 variable, 3 fixed; point 0 in cameras 0, 1 (and 0 again, one entry);
    # point 1 in 0, 1, 2 and the fixed 3 (not an entry); point 2 only in the fixed camera
    obs_cam = np.array([0, 1, 0, 2, 1, 0, 3, 3])
    obs_pt = np.array([0, 0, 0, 1, 1, 1, 1, 2])
    t = schur_traffic(obs_cam, obs_pt, np.array([True, True, True, False]))
    # entries 2 + 3 = 5; pairs 3 + 6 = 9; blocks (0,0) (0,1) (1,1) (0,2) (1,2) (2,2) = 6
    assert (t.entries, t.points, t.pairs, t.blocks, t.cameras) == (5, 2, 9, 6, 3)
    assert t.flops == 144 * 5 + 216 * 9 == 2664
    shared = 152 * 5 + 112 * 2 + 8 * 9                      # W + camera, point factors + range, block index
    assert t.compulsory_bytes == shared + 576 * 6 + 96 * 3 == 4800
    assert t.per_update_bytes == shared + 576 * 9 + 96 * 5 == 6720
    assert t.intensity(False) == pytest.approx(2664 / 4800) and t.intensity(True) == pytest.approx(2664 / 6720)


def test_schur_traffic_matches_the_solvers_block_structure():
    """Entries, entry pairs and camera-pair blocks as SchurStructure lays them out (its own code),
    and the flops as lm_flops counts them."""
    from polarref.ba.loaders import load_problem
    from polarref.ba.options import BAOptions
    from polarref.ba.parameterization import make_param
    from polarref.ba.problem import prepare
    from polarref.ba.schur import SchurStructure

    base, _ = load_problem("synth-60-sparse")
    prepare(base)
    cv = base.cam_mask.any(1)
    prm = make_param(base, BAOptions(param="euclidean"))
    st = SchurStructure(prm.slot_cams, prm.slot_cols, base.obs_pt, cv, base.num_points, 10**6, fast=True)
    if st.pair_blk is None:
        st._build_blocks()
    t = schur_traffic(base.obs_cam, base.obs_pt, cv)
    assert (t.entries, t.pairs, t.blocks) == (st.E, st.num_pairs, st.K)
    assert t.flops == roofline.lm_flops(base.obs_cam, base.obs_pt, cv, base.num_points, True).schur


def test_roof_is_the_lower_of_peak_and_intensity_times_bandwidth():
    assert roof(0.5, 10.0, 20.0) == 5.0
    assert roof(3.0, 10.0, 20.0) == 20.0


def test_triad_counts_24_bytes_per_element():
    ticks = iter(np.arange(0.0, 100.0, 0.5))         # every timed call takes 0.5 s by this clock
    pytest.importorskip("numba")
    assert triad_gbs(n=1000, repeats=3, clock=lambda: next(ticks)) == pytest.approx(24 * 1000 / 0.5 / 1e9)
    assert triad_gbs(n=1 << 20, repeats=2) > 0.1     # a real machine moves more than 0.1 GB/s


def test_bandwidth_table_from_json_alone():
    from _ba_bench_docs import doc as make_doc
    from polarref.bench.ba_report import markdown

    st = {"median": 5.0, "min": 5.0, "max": 5.0, "n": 1}
    res = {"problem": "p", "num_cameras": 2, "num_points": 3, "num_observations": 4, "target_cost": 1.0, "rows": [],
           "roofline": {"form": "euclidean", "linear_solver": "Schur (x) + sparse LU; numba", "num_unknowns": 6,
                        "flops_per_iteration": {"build": 2e9, "schur": 3e9, "factorisation": None},
                        "gflops": {"build": st, "schur": st, "factorisation": None}, "time_in_s": {},
                        "schur_bytes": {"compulsory": 1e9, "per_update": 6e9, "entry_pairs": 100, "pair_blocks": 10}}}
    md = markdown(make_doc([res], machine={"gemm_gflops": {"1": 20.0}, "gemm": "g", "triad_gbs": 10.0,
                                           "load_1min_at_triad": 1.0}))
    # intensity 3e9 / 1e9 = 3 and 3e9 / 6e9 = 0.5; roofs min(20, 30) = 20 and min(20, 5) = 5
    assert "| p | 100 | 10 | 1000.0 / 6000.0 | 3.000 / 0.500 | 20.00 / 5.00 | 5.00 | 0.25 / 1.00 | 0.25 |" in md
    assert "10.0 GB/s on 1 thread (load 1.0)" in md
    older = markdown(make_doc([res], machine={"gemm_gflops": {"1": 20.0}, "gemm": "g"}))
    assert "bandwidth roof" not in older          # benches without a triad keep their bench.md


def test_ceres_scope_says_so_when_no_setting_reaches_the_target_within_its_cap():
    """No ratio where every Ceres setting stopped at its time cap or stopped early above the
    common target; nothing said where one reached it."""
    import dataclasses

    from polarref.ba.options import BAOptions
    from polarref.bench.ba import _ceres_scope
    from polarref.bench.ba_records import SolverKind, SolverRow, SolveRun

    def row(name, term, its, cost=7e6, reached=False):
        return SolverRow(name, SolverKind.CERES, reached_target=reached,
                         full_runs=(SolveRun.measured(wall_s=650.0, final_cost=cost, iterations=its, termination=term),))

    ours = SolverRow("euclidean", SolverKind.OURS, reached_target=True,
                     full_runs=(SolveRun.measured(wall_s=50.0, final_cost=1.0, iterations=100,
                                                        termination="max_iterations"),))
    rows = [ours, row("ceres-dense-schur-1t", "NO_CONVERGENCE", 11),
            row("ceres-iterative-schur-2t", "CONVERGENCE", 65, 1.1e7)]
    said = _ceres_scope(rows, 600.0, BAOptions(max_iterations=100))
    assert said.startswith("Ceres did not finish in 600 s")
    assert "ceres-dense-schur-1t stopped at the 600 s cap after 11 iterations at cost 7e+06" in said
    assert "ceres-iterative-schur-2t stopped (CONVERGENCE) above the target after 65 iterations at cost 1.1e+07" in said
    reached = rows[:2] + [dataclasses.replace(rows[2], reached_target=True)]
    assert _ceres_scope(reached, 600.0, BAOptions(max_iterations=100)) is None
    assert _ceres_scope([ours], 600.0, BAOptions()) is None
