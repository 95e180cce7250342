"""Report figures, drawn from ``metrics.json`` data only (so ``polarref report`` can redraw them).

Uses matplotlib's object API with the Agg canvas directly: no pyplot state, no global backend
switch. PNG metadata carries no software version or date, so the same data and matplotlib
version give the same bytes.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from polarref.core.atomic import atomic_open
from polarref.compare.report.render import DrawnFigure
from polarref.compare.schema import Histogram, MetricsFile
from polarref.core.status import RunStatus

log = logging.getLogger(__name__)

DPI = 90
_PNG_META = {"Software": None}
COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf")


def method_color(metrics: MetricsFile, name: str) -> str:
    """A method's colour: fixed by its position in metrics.methods (the 3D view uses the same)."""
    k = next((i for i, m in enumerate(metrics.methods) if m.name == name), 0)
    return COLORS[k % len(COLORS)]


def _figure(width: float, height: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=DPI)
    FigureCanvasAgg(fig)
    return fig


def _save(fig, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_open(path) as fh:
        fig.savefig(fh, format="png", dpi=DPI, metadata=_PNG_META)
    return path


def _ok_with_plot(metrics: MetricsFile):
    return [m for m in metrics.methods if m.status == RunStatus.OK and m.plot is not None]


def trajectory(metrics: MetricsFile, path: Path) -> Path | None:
    """GT camera centres vs Sim3-aligned estimates (the paper's Fig. 6b 'photographic orbit')."""
    methods = [m for m in _ok_with_plot(metrics) if m.plot.centers_est_aligned]
    gt = next((np.asarray(m.plot.centers_gt) for m in methods if m.plot.centers_gt), None)
    if gt is None:
        return None
    fig = _figure(11, 4.6)
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    ax2 = fig.add_subplot(1, 2, 2)
    ax3.plot(*gt.T, "k-", lw=1.0, alpha=0.5)
    ax3.scatter(*gt.T, c="k", s=22, marker="o", label="ground truth")
    ax2.plot(gt[:, 0], gt[:, 1], "k-", lw=1.0, alpha=0.5)
    ax2.scatter(gt[:, 0], gt[:, 1], c="k", s=22, label="ground truth")
    for k, m in enumerate(methods):
        est = np.asarray(m.plot.centers_est_aligned)
        c = method_color(metrics, m.name)
        ax3.scatter(*est.T, s=10, marker="x", color=c, label=m.label)
        ax2.scatter(est[:, 0], est[:, 1], s=12, marker="x", color=c, label=m.label)
    ax3.set_title("photographic orbit (3D, GT frame)")
    ax3.set_xlabel("x"), ax3.set_ylabel("y"), ax3.set_zlabel("z")
    ax2.set_title("top view (x-y), estimates Sim3-aligned to GT")
    ax2.set_aspect("equal", adjustable="datalim")
    ax2.set_xlabel("x"), ax2.set_ylabel("y")
    ax2.legend(fontsize=7, loc="best")
    fig.tight_layout()
    return _save(fig, path)


def point_clouds(metrics: MetricsFile, path: Path) -> Path | None:
    """Sparse points of each method, two orthographic views (x-y and x-z), GT frame.

    Axis limits come from the 1st-99th percentiles of all methods' points, so a few wild points
    do not shrink the cloud to a dot (they are counted in the panel title).
    """
    methods = [m for m in _ok_with_plot(metrics) if m.plot.points_sample]
    if not methods:
        return None
    allpts = np.concatenate([np.asarray(m.plot.points_sample) for m in methods])
    lo, hi = np.percentile(allpts, 1, axis=0), np.percentile(allpts, 99, axis=0)
    pad = 0.08 * (hi - lo).max()
    lo, hi = lo - pad, hi + pad
    ncols = min(4, len(methods))
    groups = -(-len(methods) // ncols)
    span = np.maximum(hi - lo, 1e-12)
    ratios = [span[1] / span[0], span[2] / span[0]] * groups
    fig = _figure(2.7 * ncols, sum(2.7 * r + 0.55 for r in ratios))
    grid = fig.add_gridspec(2 * groups, ncols, height_ratios=ratios)
    for k, m in enumerate(methods):
        pts = np.asarray(m.plot.points_sample)
        outside = int((~((pts >= lo) & (pts <= hi)).all(1)).sum())
        g, c = divmod(k, ncols)
        for row, (a, b, name) in enumerate(((0, 1, "x-y"), (0, 2, "x-z"))):
            ax = fig.add_subplot(grid[2 * g + row, c])
            ax.scatter(pts[:, a], pts[:, b], s=0.8, c=pts[:, 3 - a - b], cmap="viridis", linewidths=0)
            ax.set_xlim(lo[a], hi[a])
            ax.set_ylim(lo[b], hi[b])
            ax.set_aspect("equal", adjustable="box")
            ax.tick_params(labelsize=6)
            title = f"{m.label}: {name}"
            if row == 0:
                title += f"\n{m.metric('tie_points') or 0:,} points ({len(pts):,} drawn, {outside} off-axes)"
            ax.set_title(title, fontsize=7)
    fig.tight_layout()
    return _save(fig, path)


def convergence(metrics: MetricsFile, path: Path) -> Path | None:
    """BA cost vs wall time and vs iteration, one row per problem, one line per parameterization."""
    traces = [t for t in metrics.ba_traces if t.points]
    if not traces:
        return None
    problems = list(dict.fromkeys(t.problem for t in traces))
    fig = _figure(11, 3.9 * len(problems))
    for row, problem in enumerate(problems):
        ax_t = fig.add_subplot(len(problems), 2, 2 * row + 1)
        ax_i = fig.add_subplot(len(problems), 2, 2 * row + 2)
        for k, tr in enumerate(t for t in traces if t.problem == problem):
            own = metrics.method(f"ours-{tr.label}")  # our parameterizations keep their method colour
            c = method_color(metrics, own.name) if own else COLORS[k % len(COLORS)]
            cost = [max(p.cost, 1e-300) for p in tr.points]
            ax_t.plot([p.time_s for p in tr.points], cost, "-o", ms=2.5, color=c, label=tr.label)
            ax_i.plot([p.iteration for p in tr.points], cost, "-o", ms=2.5, color=c, label=tr.label)
        for ax, xl in ((ax_t, "wall time (s)"), (ax_i, "iteration")):
            ax.set_yscale("log")
            ax.set_xlabel(xl)
            ax.set_ylabel("cost (own objective)", fontsize=8)
            ax.grid(alpha=0.3)
        ax_t.set_title(f"{problem}: cost vs time", fontsize=8)
        ax_i.set_title("cost vs iteration (accepted steps)", fontsize=8)
        ax_i.legend(fontsize=7)
    fig.tight_layout()
    return _save(fig, path)


def _hist_line(ax, h: Histogram, label: str, color: str) -> None:
    edges = np.asarray(h.edges)
    counts = np.asarray(h.counts, dtype=float)
    total = counts.sum()
    if total <= 0:
        return
    # Cumulative: comparable across methods even though each method's bins differ.
    ax.step(np.concatenate([[edges[0]], edges[1:]]), np.concatenate([[0.0], np.cumsum(counts) / total]),
            where="post", color=color, label=label)


def error_histograms(metrics: MetricsFile, path: Path) -> Path | None:
    """Cumulative distributions of reprojection, rotation and point-to-surface errors per method."""
    methods = _ok_with_plot(metrics)
    panels = (("reproj_hist", "reprojection error (px)"), ("rotation_err_hist", "rotation error (deg)"),
              ("surface_err_hist", "point-to-surface distance / scene size"))
    used = [(attr, title) for attr, title in panels
            if any(getattr(m.plot, attr) is not None for m in methods)]
    if not used:
        return None
    fig = _figure(4.0 * len(used), 3.6)
    for j, (attr, title) in enumerate(used):
        ax = fig.add_subplot(1, len(used), j + 1)
        for k, m in enumerate(methods):
            h = getattr(m.plot, attr)
            if h is not None:
                _hist_line(ax, h, m.label, method_color(metrics, m.name))
        ax.set_xlabel(title, fontsize=8)
        ax.set_ylabel("fraction <= x", fontsize=8)
        ax.set_ylim(0.0, 1.02)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    fig.axes[0].legend(fontsize=6)
    fig.tight_layout()
    return _save(fig, path)


def runtimes(metrics: MetricsFile, path: Path) -> Path | None:
    """Stacked stage runtimes per method."""
    methods = [m for m in metrics.methods if m.status == RunStatus.OK and m.runtime_s is not None]
    if not methods:
        return None
    stages: list[str] = []
    for m in methods:
        stages += [s for s in m.stage_runtime_s if s not in stages]
    fig = _figure(8, 0.45 * len(methods) + 2.0)
    ax = fig.add_subplot(1, 1, 1)
    y = np.arange(len(methods))
    left = np.zeros(len(methods))
    for k, s in enumerate(stages):
        w = np.array([m.stage_runtime_s.get(s, 0.0) for m in methods])
        ax.barh(y, w, left=left, color=COLORS[k % len(COLORS)], label=s)
        left += w
    ax.set_yticks(y, [m.label for m in methods], fontsize=7)
    ax.invert_yaxis()
    ax.set_xlabel("wall time (s)")
    ax.legend(fontsize=7, ncols=min(5, len(stages)), loc="upper center", bbox_to_anchor=(0.5, -0.2))
    fig.tight_layout()
    return _save(fig, path)


def per_image_errors(metrics: MetricsFile, path: Path) -> Path | None:
    """Rotation and centre error of every image along the trajectory (images in name order)."""
    methods = [m for m in _ok_with_plot(metrics) if m.plot.image_names and m.plot.centers_gt]
    if not methods:
        return None
    names = sorted({n for m in methods for n in m.plot.image_names})
    pos = {n: i for i, n in enumerate(names)}
    extent = metrics.scene.scene_extent or 1.0
    with_rot = any(m.plot.rotation_err_deg for m in methods)
    fig = _figure(11, 5.6 if with_rot else 3.2)
    axes = [fig.add_subplot(2 if with_rot else 1, 1, k + 1) for k in range(2 if with_rot else 1)]
    for m in methods:
        x = np.array([pos[n] for n in m.plot.image_names])
        c = method_color(metrics, m.name)
        cen = np.linalg.norm(np.asarray(m.plot.centers_est_aligned) - np.asarray(m.plot.centers_gt), axis=1)
        axes[-1].plot(x, 100 * cen / extent, "-o", ms=2.5, lw=1, color=c, label=m.label)
        if with_rot and len(m.plot.rotation_err_deg) == len(x):
            axes[0].plot(x, m.plot.rotation_err_deg, "-o", ms=2.5, lw=1, color=c, label=m.label)
    if with_rot:
        axes[0].set_ylabel("rotation error (deg)", fontsize=8)
        axes[0].legend(fontsize=6, ncols=2)
    axes[-1].set_ylabel("centre error (% of scene size)", fontsize=8)
    axes[-1].set_xlabel("image (name order = capture order along the trajectory)", fontsize=8)
    for ax in axes:
        ys = np.concatenate([ln.get_ydata() for ln in ax.get_lines()] or [np.zeros(0)])
        if ys.size and (ys > 0).all():  # errors span decades; exact zeros (a perfect model) stay linear
            ax.set_yscale("log")
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
    if not with_rot:
        axes[0].legend(fontsize=6, ncols=2)
    fig.tight_layout()
    return _save(fig, path)


def track_and_reprojection_histograms(metrics: MetricsFile, path: Path) -> Path | None:
    """Track length (observations per 3D point) and reprojection error, fraction of points/observations."""
    methods = [m for m in _ok_with_plot(metrics) if m.plot.track_length_hist or m.plot.reproj_hist]
    if not methods:
        return None
    fig = _figure(11, 3.6)
    ax_t, ax_r = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    for m in methods:
        c = method_color(metrics, m.name)
        for ax, h in ((ax_t, m.plot.track_length_hist), (ax_r, m.plot.reproj_hist)):
            if h is None or sum(h.counts) == 0:
                continue
            frac = np.asarray(h.counts, float) / sum(h.counts)
            ax.stairs(frac, np.asarray(h.edges), color=c, label=m.label, lw=1.2)
    ax_t.set_xlabel("track length (images per 3D point; last bin: that many or more)", fontsize=8)
    ax_t.set_ylabel("fraction of 3D points", fontsize=8)
    ax_r.set_xlabel("reprojection error (px; last bin: everything above the 99th percentile)", fontsize=8)
    ax_r.set_ylabel("fraction of observations", fontsize=8)
    for ax in (ax_t, ax_r):
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
    for ax in (ax_t, ax_r):
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=6)
            break
    fig.tight_layout()
    return _save(fig, path)


FIGURES = (
    ("trajectory", "Camera trajectory: ground truth vs estimated (the paper's Fig. 6b)", trajectory),
    ("per_image", "Error of every image along the trajectory, after the Sim3 alignment",
     per_image_errors),
    ("points", "Sparse point clouds (GT frame after Sim3 alignment)", point_clouds),
    ("histograms", "Track lengths and reprojection errors per method", track_and_reprojection_histograms),
    ("convergence", "Bundle adjustment convergence per parameterization (each form's own objective: the "
                    "polar form adds view-angle residuals, so its cost is not on the same scale)", convergence),
    ("errors", "Error distributions (cumulative; the last bin holds everything above the 99th percentile)",
     error_histograms),
    ("runtime", "Runtime per stage", runtimes),
)


def draw_all(metrics: MetricsFile, fig_dir: Path) -> list[DrawnFigure]:
    """Draw every figure the data allows, in FIGURES order. A failing figure is logged, not fatal."""
    out: list[DrawnFigure] = []
    for key, _, fn in FIGURES:
        try:
            p = fn(metrics, fig_dir / f"{key}.png")
        except Exception as exc:  # a broken plot must not lose the tables
            log.warning("figure %s failed: %s: %s", key, type(exc).__name__, exc)
            continue
        if p is not None:
            out.append(DrawnFigure(key, p))
    return out
