"""``polarref compare --dense``: the dense stage (``polarref.dense``) from the GT poses and from
ours-euclidean's and ours-polar's, each scored in the GT frame into the ``DenseSection`` record of
metrics.json (:mod:`polarref.compare.schema`); the report draws it (:mod:`polarref.compare.report.dense_section`).
"""

from __future__ import annotations

import logging
from pathlib import Path

from polarref.compare.schema import DenseRun, DenseSection
from polarref.core.errors import PolarrefError
from polarref.core.status import RunStatus

log = logging.getLogger(__name__)

DENSE_SOURCES = ("gt", "ours-euclidean", "ours-polar")


def run_dense_stage(scene_root: Path, model_dirs: dict[str, str | None], out: Path) -> DenseSection:
    """Dense stage per source in :data:`DENSE_SOURCES`; ``model_dirs``: method name -> model folder."""
    from polarref.dense.pipeline import DenseConfig, run_dense  # open3d: only when --dense asks for it

    section = DenseSection()
    for name in DENSE_SOURCES:
        model = "gt" if name == "gt" else model_dirs.get(name)
        run = DenseRun(name, RunStatus.SKIPPED, out_dir=f"dense/{name}")
        section.runs.append(run)
        if model is None:
            run.message = "method did not run or produced no model"
            continue
        log.info("dense stage from %s poses", name)
        try:
            m = run_dense(scene_root, model, out / "dense" / name, DenseConfig(), overwrite=True)
        except PolarrefError as exc:
            run.status, run.message = RunStatus.FAILED, str(exc)
            continue
        run.status = RunStatus.OK
        run.fused_points = m.num_fused_points
        run.dense_runtime_s = m.runtime_s.get("dense_total")
        if m.gt is not None and m.gt.cloud is not None:
            run.tau, run.tau_rel = m.gt.tau, m.gt.tau_rel
            c = m.gt.cloud
            run.cloud_fscore, run.cloud_precision, run.cloud_recall = c.fscore, c.precision, c.recall
            run.accuracy_median, run.completeness_median = c.accuracy_median, c.completeness_median
            run.mesh_fscore = m.gt.mesh.fscore if m.gt.mesh is not None else None
            run.depth_median_abs = m.gt.depth_median_abs
    return section
