"""``polarref compare --dense`` in the report: the dense section's blocks and the side-by-side
figure (clouds on top, meshes below, all in the GT frame, one shared viewpoint) drawn from
``OUT/dense/<name>/{fused,mesh}_gt.ply``. The stage itself runs in :mod:`polarref.compare.run.dense`;
its record (``DenseSection``) is part of metrics.json (:mod:`polarref.compare.schema`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from polarref.compare.report.render import DrawnFigure
from polarref.core.status import RunStatus

FIGURE_KEY = "dense_side_by_side"


def _f(v, nd=3) -> str:
    return "–" if v is None else f"{v:.{nd}f}"


def dense_blocks(metrics, figure_keys: set[str]) -> list:
    """Report blocks for ``metrics.dense`` (empty when the dense stage did not run)."""
    from polarref.compare.report.render import Fig, Heading, Para, Table

    sec = getattr(metrics, "dense", None)
    if sec is None or not sec.runs:
        return []
    tau = next((r for r in sec.runs if r.tau is not None), None)
    rows = [[r.name, r.status, _f(r.cloud_fscore), _f(r.cloud_precision), _f(r.cloud_recall),
             _f(r.accuracy_median, 2), _f(r.completeness_median, 2), _f(r.mesh_fscore),
             _f(r.depth_median_abs, 2), str(r.fused_points), _f(r.dense_runtime_s, 1)] for r in sec.runs]
    blocks = [Heading(2, "Dense reconstruction (downstream effect of the poses)"),
              Para("Plane-sweep stereo, consistency filter, fused cloud and Poisson mesh (`polarref dense`) "
                   "from each source's poses; scored in the GT frame against the GT mesh"
                   + (f" at tau = {tau.tau:.4g} ({100 * tau.tau_rel:g}% of the scene diameter)" if tau else "")
                   + ". Accuracy/completeness: median distances (GT units)."),
              Table(["poses", "status", "F (cloud)", "precision", "recall", "accuracy", "completeness",
                     "F (mesh)", "depth error", "points", "dense s"], rows)]
    if FIGURE_KEY in figure_keys:
        blocks.append(Fig(FIGURE_KEY, "Fused clouds (top) and meshes (bottom) from GT, ours-euclidean and "
                                      "ours-polar poses, GT frame, same viewpoint"))
    return blocks


def draw_dense_figure(metrics, out_dir: Path, fig_dir: Path) -> DrawnFigure | None:
    """Side-by-side snapshot (matplotlib, headless) of the dense runs that left GT-frame outputs."""
    sec = getattr(metrics, "dense", None)
    runs = [r for r in (sec.runs if sec else []) if r.status == RunStatus.OK
            and (out_dir / r.out_dir / "fused_gt.ply").is_file()]
    if not runs:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from polarref.dense.fusion import read_point_cloud
    from synth.meshes import read_mesh

    rng = np.random.default_rng(0)
    fig = plt.figure(figsize=(4.2 * len(runs), 8.0))
    view = None
    for k, r in enumerate(runs):
        cloud = read_point_cloud(out_dir / r.out_dir / "fused_gt.ply")
        sel = rng.choice(len(cloud), min(len(cloud), 30000), replace=False)
        P = cloud.points[sel]
        if view is None:  # one viewpoint for all panels: the first cloud's centre, extent, mean normal
            n = cloud.normals[sel].mean(0)
            n = n / max(np.linalg.norm(n), 1e-12)
            view = (np.median(P, 0), np.percentile(np.abs(P - np.median(P, 0)), 98),
                    float(np.degrees(np.arcsin(np.clip(n[2], -1, 1)))), float(np.degrees(np.arctan2(n[1], n[0]))))
        ax = fig.add_subplot(2, len(runs), k + 1, projection="3d")
        ax.scatter(P[:, 0], P[:, 1], P[:, 2], c=cloud.colors[sel] / 255.0, s=0.3, linewidths=0)
        ax.set_title(f"{r.name}: cloud F = {_f(r.cloud_fscore)}", fontsize=9)
        mesh_path = out_dir / r.out_dir / "mesh_gt.ply"
        ax2 = fig.add_subplot(2, len(runs), len(runs) + k + 1, projection="3d")
        if mesh_path.is_file():
            V, F = read_mesh(mesh_path)
            F = F[rng.choice(len(F), min(len(F), 40000), replace=False)] if len(F) else F
            if len(F):
                ax2.plot_trisurf(V[:, 0], V[:, 1], V[:, 2], triangles=F, color="0.7", linewidth=0,
                                 antialiased=False, shade=True)
        ax2.set_title(f"{r.name}: mesh F = {_f(r.mesh_fscore)}", fontsize=9)
        for a in (ax, ax2):
            c, e, elev, azim = view
            a.set_xlim(c[0] - e.max(), c[0] + e.max())
            a.set_ylim(c[1] - e.max(), c[1] + e.max())
            a.set_zlim(c[2] - e.max(), c[2] + e.max())
            a.set_axis_off()
            a.view_init(elev=elev, azim=azim)  # looking along -mean normal: the side the cameras saw
    fig.tight_layout()
    fig_dir.mkdir(parents=True, exist_ok=True)
    path = fig_dir / f"{FIGURE_KEY}.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return DrawnFigure(FIGURE_KEY, path)
