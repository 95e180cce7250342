"""Does the model belong to the scene? Checked before any dense work.

A model of another scene whose images have the same names and sizes loads without complaint and
gives a meaningless score (issue 31: F = 0.009, exit 0). Two checks need nothing but the model's
own points and observations:

* against the scene's images: a 3D point's keypoints in two images show the same surface, so
  small grey patches around them correlate (median NCC well above 0); at another scene's
  keypoint positions the patches are unrelated (median NCC near 0);
* against the scene's ground truth (when it has one): after the similarity that best maps the
  model's cameras onto the GT cameras, the model's points reproject with the GT cameras close to
  the model's own keypoints (a few px); another scene's points land anywhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from polarref.dense.views import DenseView
from polarref.model.reconstruction import Image, Point3D, Reconstruction

PATCH_RADIUS = 5             # 11 x 11 px patches, at the working resolution
MAX_PAIRS = 2000             # observation pairs sampled for the patch test
MIN_PATCH_NCC = 0.25         # median below this: the keypoints do not show one surface
MAX_GT_REPROJ_REL = 0.02     # median GT reprojection error / image diagonal above this: wrong model
MIN_SAMPLES = 20             # fewer usable samples: the check is not made (and says so)


@dataclass(frozen=True)
class ModelCheck:
    """The checks' figures (None: not made, with the reason in ``notes``) and what failed."""

    patch_ncc_median: float | None
    patch_pairs: int
    gt_reprojection_px_median: float | None
    gt_observations: int
    problems: tuple[str, ...]
    notes: tuple[str, ...]


def verdict(check: ModelCheck) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(reasons to refuse, warnings to flag): refused when every check made failed; when one of
    two failed the result is kept and flagged (a poor but genuine model can miss one bound)."""
    made = (check.patch_ncc_median is not None) + (check.gt_reprojection_px_median is not None)
    if check.problems and len(check.problems) >= made:
        return check.problems, ()
    return (), check.problems


def check_model(rec: Reconstruction, views: list[DenseView], gt: Reconstruction | None,
                sim=None, seed: int = 0) -> ModelCheck:
    """Both checks, on the views' working-resolution grey images; ``sim``: the model-to-GT
    similarity (None: no GT alignment available)."""
    problems, notes = [], []
    ncc, pairs = patch_ncc(rec, views, seed)
    if ncc is None:
        notes.append(f"patch check not made: {pairs} observation pairs (need {MIN_SAMPLES})")
    elif ncc < MIN_PATCH_NCC:
        problems.append(f"the patches around a point's keypoints do not match in the scene's images "
                        f"(median NCC {ncc:.2f} over {pairs} pairs, expected >= {MIN_PATCH_NCC})")
    reproj, count = None, 0
    if gt is not None and sim is not None:
        reproj, count, diag = gt_reprojection(rec, gt, sim)
        if reproj is None:
            notes.append(f"GT reprojection check not made: {count} usable observations")
        elif reproj > MAX_GT_REPROJ_REL * diag:
            problems.append(f"its points reproject {reproj:.1f} px (median) from its keypoints in the "
                            f"scene's GT cameras (expected <= {MAX_GT_REPROJ_REL * diag:.1f} px)")
    return ModelCheck(ncc, pairs, reproj, count, tuple(problems), tuple(notes))


def _pairs(rec: Reconstruction, seed: int) -> list[tuple[int, int, int, int]]:
    """(image a, keypoint a, image b, keypoint b) of consecutive track elements, seeded sample."""
    out = []
    for p in rec.points3D.values():
        t = np.asarray(p.track, np.int64).reshape(-1, 2)
        out.extend((int(t[k, 0]), int(t[k, 1]), int(t[k + 1, 0]), int(t[k + 1, 1])) for k in range(len(t) - 1))
    if len(out) > MAX_PAIRS:
        pick = np.random.default_rng(seed).choice(len(out), MAX_PAIRS, replace=False)
        out = [out[i] for i in sorted(pick)]
    return out


def _patch(img: np.ndarray, uv: np.ndarray) -> np.ndarray | None:
    # COLMAP pixel centres sit at +0.5
    x, y = int(np.floor(uv[0])), int(np.floor(uv[1]))
    r = PATCH_RADIUS
    if not (r <= x < img.shape[1] - r and r <= y < img.shape[0] - r):
        return None
    return img[y - r:y + r + 1, x - r:x + r + 1].ravel()


def patch_ncc(rec: Reconstruction, views: list[DenseView], seed: int = 0) -> tuple[float | None, int]:
    """(median NCC of the patch pairs, number of pairs) over a seeded sample of track pairs."""
    images = {v.name: (v.image, v.scale) for v in views}
    values = []
    for ia, ka, ib, kb in _pairs(rec, seed):
        a_im, b_im = rec.images.get(ia), rec.images.get(ib)
        if a_im is None or b_im is None or ka >= len(a_im.keypoints) or kb >= len(b_im.keypoints):
            continue
        if a_im.name not in images or b_im.name not in images:
            continue
        (ga, sa), (gb, sb) = images[a_im.name], images[b_im.name]
        a = _patch(ga, sa * np.asarray(a_im.keypoints[ka]))  # corner pixel origin: uv scales exactly
        b = _patch(gb, sb * np.asarray(b_im.keypoints[kb]))
        if a is None or b is None:
            continue
        a, b = a - a.mean(), b - b.mean()
        den = float(np.sqrt((a * a).sum() * (b * b).sum()))
        if den > 1e-9:  # flat patches say nothing
            values.append(float((a * b).sum()) / den)
    if len(values) < MIN_SAMPLES:
        return None, len(values)
    return float(np.median(values)), len(values)


def gt_reprojection(rec: Reconstruction, gt: Reconstruction, sim) -> tuple[float | None, int, float]:
    """(median px, observations used, image diagonal px): the model's points mapped by ``sim``
    into the GT frame, projected with the GT camera of each image (matched by name)."""
    gt_by_name = {im.name: im for im in gt.images.values()}
    moved = Reconstruction(cameras=dict(gt.cameras))
    for image_id, im in rec.images.items():
        g = gt_by_name.get(im.name)
        if g is not None:
            moved.images[image_id] = Image(image_id, im.name, g.camera_id, g.cam_from_world,
                                           im.keypoints, im.point3D_ids)
    for pid, p in rec.points3D.items():
        track = np.asarray(p.track, np.int64).reshape(-1, 2)
        track = track[np.isin(track[:, 0], list(moved.images))]
        if len(track):
            moved.points3D[pid] = Point3D(sim.apply(np.asarray(p.xyz, np.float64)), track)
    # a point behind its GT camera counts (inf), so a mirrored model cannot pass on the rest
    errs = moved.observation_errors()[0]
    cams = list(gt.cameras.values())
    diag = float(np.median([np.hypot(c.width, c.height) for c in cams])) if cams else 1.0
    if len(errs) < MIN_SAMPLES:
        return None, len(errs), diag
    return float(np.median(errs)), len(errs), diag
