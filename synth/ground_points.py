"""Seeded surveyed points on a rendered surface with their image marks (issue 33): ground
control / check points for the UAV scenes, surface landmarks for the comet.

A point is a mesh vertex seen in >= ``min_views`` GT views: inside the image (a margin from the
border) and not occluded (its GT depth matches the view's depth map within 1 %). Its marks are
the GT projections plus N(0, mark_sigma_px^2) per coordinate. The first ``n_control`` points in
draw order are control points, the rest check points.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from polarref.georef.formats import GroundPoint, Mark, Role

MIN_VIEWS = 3      # a point is laid out only where >= 3 GT views see it
BORDER_PX = 8      # marks stay this far inside the image


def lay_out(root: Path, n_control: int, n_check: int, mark_sigma_px: float, target_sigma_m: float,
            rng: np.random.Generator, prefix: str = "GCP"):
    """(points, marks, gt images sorted by id) for the rendered scene folder ``root``."""
    from polarref.model.colmap import read_model
    from synth.scene import load_scene

    scene = load_scene(root)
    gt = read_model(root / "gt")
    cam = scene.polarref_camera()
    imgs = [gt.images[i] for i in sorted(gt.images)]
    depths = [scene.depth(k) for k in range(len(imgs))]
    V, _ = scene.mesh()
    points, marks = [], []
    for v in rng.permutation(len(V)):
        seen = _seen(V[v], imgs, cam, depths)
        if len(seen) < MIN_VIEWS:
            continue
        gid = f"{prefix}{len(points) + 1:02d}"
        role = Role.CONTROL if len(points) < n_control else Role.CHECK
        points.append(GroundPoint(gid, V[v].copy(), np.full(3, target_sigma_m), role))
        marks += [Mark(gid, name, uv + rng.normal(0, mark_sigma_px, 2)) for name, uv in seen]
        if len(points) == n_control + n_check:
            break
    return points, marks, imgs


def _seen(X: np.ndarray, imgs, cam, depths) -> list[tuple[str, np.ndarray]]:
    seen = []
    for k, im in enumerate(imgs):
        Xc = im.cam_from_world.apply(X[None])[0]
        if Xc[2] <= 0:
            continue
        uv = np.asarray(cam.project(Xc[None]))[0]
        if not (BORDER_PX <= uv[0] < cam.width - BORDER_PX and BORDER_PX <= uv[1] < cam.height - BORDER_PX):
            continue
        d = float(depths[k][int(uv[1]), int(uv[0])])
        if d > 0 and abs(d - Xc[2]) < 0.01 * Xc[2]:
            seen.append((im.name, uv))
    return seen
