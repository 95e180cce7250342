"""The bundle-adjustment problem: cameras, points, observations, which blocks are fixed, gauge.

Cameras are parameterized by ``(R, C)``: rotation ``cam_from_world`` and centre in world
coordinates (``X_cam = R (X - C)``); steps are ``R <- exp(dtheta) R``, ``C <- C + dC``, so a
camera block is 6 columns ``(dtheta, dC)``. The centre form lets the parallax landmarks, whose
rays depend on anchor-camera centres, share the same camera blocks.
"""

from __future__ import annotations

import copy
import logging
from dataclasses import dataclass, field

import numpy as np

from polarref.ba.priors import BAPriors, fixes_datum
from polarref.core.errors import PolarrefError
from polarref.model.observations import Observations

log = logging.getLogger(__name__)


@dataclass
class BAProblem:
    """A bundle-adjustment problem (updated in place by the solver).

    Attributes:
        cameras: one ``polarref.camera.Camera`` per problem camera (intrinsics, held fixed).
        R: (N, 3, 3) cam_from_world rotations.
        C: (N, 3) camera centres (world).
        X: (P, 3) points (world).
        obs: the M observations (:class:`polarref.model.Observations`): ``obs.image`` is the
            problem-camera index, ``obs.point`` the point index, ``obs.uv`` the pixel (COLMAP
            convention). ``obs_cam`` / ``obs_pt`` / ``obs_uv`` read (and replace) its arrays.
        cam_fixed: (N,) True for cameras held fixed.
        pt_fixed: (P,) True for points held fixed.
        image_ids / point_ids: ids to map results back (default 0..N-1 / 0..P-1).
    """

    cameras: list
    R: np.ndarray
    C: np.ndarray
    X: np.ndarray
    obs: Observations
    cam_fixed: np.ndarray | None = None
    pt_fixed: np.ndarray | None = None
    image_ids: np.ndarray | None = None
    point_ids: np.ndarray | None = None
    # filled by prepare():
    cam_mask: np.ndarray | None = None  # (N, 6) True = free parameter
    gauge: str = ""
    exclusions: dict[str, int] = field(default_factory=dict)   # reason -> count of dropped data
    # (N,) intrinsics group per camera for self-calibration (None: equal cameras share one)
    camera_group: np.ndarray | None = None
    # pose priors and control points (ba/priors.py), cameras indexed as this problem's
    priors: BAPriors | None = None
    control_X: np.ndarray | None = None  # (G, 3) control point estimates (start: their priors)

    # The solver's kernels index these arrays directly: names kept for them.
    @property
    def obs_cam(self) -> np.ndarray:
        return self.obs.image

    @obs_cam.setter
    def obs_cam(self, value) -> None:
        self.obs = Observations(np.asarray(value), self.obs.point, self.obs.uv)

    @property
    def obs_pt(self) -> np.ndarray:
        return self.obs.point

    @obs_pt.setter
    def obs_pt(self, value) -> None:
        self.obs = Observations(self.obs.image, np.asarray(value), self.obs.uv)

    @property
    def obs_uv(self) -> np.ndarray:
        return self.obs.uv

    @obs_uv.setter
    def obs_uv(self, value) -> None:
        self.obs = Observations(self.obs.image, self.obs.point, np.asarray(value))

    @property
    def num_cameras(self) -> int:
        return len(self.R)

    @property
    def num_points(self) -> int:
        return len(self.X)

    @property
    def num_observations(self) -> int:
        return len(self.obs)

    def copy(self) -> "BAProblem":
        return BAProblem(list(self.cameras), self.R.copy(), self.C.copy(), self.X.copy(),
                         self.obs.copy(),
                         None if self.cam_fixed is None else self.cam_fixed.copy(),
                         None if self.pt_fixed is None else self.pt_fixed.copy(),
                         None if self.image_ids is None else self.image_ids.copy(),
                         None if self.point_ids is None else self.point_ids.copy(),
                         None if self.cam_mask is None else self.cam_mask.copy(),
                         self.gauge, copy.deepcopy(self.exclusions),
                         None if self.camera_group is None else self.camera_group.copy(),
                         self.priors,
                         None if self.control_X is None else self.control_X.copy())

    def cam_from_world_t(self) -> np.ndarray:
        """(N, 3) translations t = -R C (matmul: bit-identical to ``-R[i] @ C[i]``)."""
        return -np.matmul(self.R, self.C[:, :, None])[:, :, 0]


def prepare(problem: BAProblem, min_track: int = 2) -> BAProblem:
    """Validate, drop unusable data (counted in ``exclusions``), sort, and fix the gauge.

    Excluded and counted: observations with non-finite pixels or of unknown cameras/points,
    points with fewer than ``min_track`` observations, cameras without observations (held
    fixed). Raises PolarrefError for an empty problem or non-finite poses/points.
    """
    p = problem
    N, P = len(p.R), len(p.X)
    if N == 0 or P == 0 or len(p.obs) == 0:
        raise PolarrefError(f"empty bundle-adjustment problem: {N} cameras, {P} points, "
                            f"{len(p.obs)} observations")
    if not (np.isfinite(p.R).all() and np.isfinite(p.C).all()):
        raise PolarrefError("bundle adjustment: non-finite camera pose in the input")
    if not np.isfinite(p.X).all():
        raise PolarrefError("bundle adjustment: non-finite 3D point in the input")
    if len(p.cameras) != N:
        raise PolarrefError(f"bundle adjustment: {len(p.cameras)} intrinsics for {N} cameras")
    p.cam_fixed = np.zeros(N, bool) if p.cam_fixed is None else np.asarray(p.cam_fixed, bool).copy()
    p.pt_fixed = np.zeros(P, bool) if p.pt_fixed is None else np.asarray(p.pt_fixed, bool).copy()
    p.image_ids = np.arange(N) if p.image_ids is None else np.asarray(p.image_ids)
    p.point_ids = np.arange(P) if p.point_ids is None else np.asarray(p.point_ids)
    o = Observations.from_arrays(p.obs.image, p.obs.point, p.obs.uv)  # shapes; values are counted below
    cam, pt, uv = o.image, o.point, o.uv
    good = np.isfinite(uv).all(1)
    inrange = (cam >= 0) & (cam < N) & (pt >= 0) & (pt < P)
    keep = good & inrange
    # Points seen fewer than min_track times are unconstrained (drop them with their observations).
    counts = np.bincount(pt[keep], minlength=P)
    short = counts < min_track
    dropped = short[np.clip(pt, 0, P - 1)]
    ex = _add_counts(p.exclusions, observations_nonfinite=int((~good).sum()),
                     observations_bad_index=int((good & ~inrange).sum()),
                     points_short_track=int((short & (counts > 0)).sum()),
                     points_unobserved=int((counts == 0).sum()))
    ex.update(observations_of_dropped_points=int((dropped & good & inrange).sum()))
    keep &= ~dropped
    cam, pt, uv = cam[keep], pt[keep], uv[keep]
    if len(cam) == 0:
        raise PolarrefError("bundle adjustment: no usable observations left "
                            f"(exclusions: {_nonzero(ex)})")
    # Re-index points densely, sort observations by point (the solver's reductions need it).
    pts_used = np.flatnonzero(counts >= min_track)
    remap = -np.ones(P, np.int64)
    remap[pts_used] = np.arange(len(pts_used))
    pt = remap[pt]
    order = np.lexsort((cam, pt))
    p.obs = Observations(cam[order], pt[order], uv[order])
    p.X = np.asarray(p.X, np.float64)[pts_used].copy()
    p.pt_fixed = p.pt_fixed[pts_used]
    p.point_ids = p.point_ids[pts_used]
    cam_counts = np.bincount(p.obs_cam, minlength=N)
    idle = int(((cam_counts == 0) & ~p.cam_fixed).sum())
    p.cam_fixed = p.cam_fixed | (cam_counts == 0)
    p.exclusions = {**ex, "cameras_without_observations": idle}
    if idle:
        log.warning("bundle adjustment: %d cameras without observations are held fixed", idle)
    p.R = np.asarray(p.R, np.float64).copy()
    p.C = np.asarray(p.C, np.float64).copy()
    if p.priors is not None:
        check_priors(p)
    if fixes_datum(p.priors):
        hold_datum_by_priors(p)
    else:
        fix_gauge(p)
    return p


def check_priors(p: BAProblem) -> None:
    """Priors' indices in range and weights finite and positive (PolarrefError otherwise);
    the control point estimates start at their priors unless given."""
    N = len(p.R)
    pr = p.priors
    for name, cams in (("centre prior", None if pr.centres is None else pr.centres.cam),
                       ("attitude prior", None if pr.attitudes is None else pr.attitudes.cam),
                       ("control observation", None if pr.control is None else pr.control.obs_cam)):
        if cams is not None and len(cams) and (cams.min() < 0 or cams.max() >= N):
            raise PolarrefError(f"bundle adjustment: {name} of an unknown camera")
    if pr.attitudes is not None and not (pr.attitudes.sigma_rad > 0).all():
        raise PolarrefError("bundle adjustment: attitude prior sigma must be > 0")
    if pr.control is not None:
        g = pr.control
        if len(g.obs_gcp) and (g.obs_gcp.min() < 0 or g.obs_gcp.max() >= len(g.X0)):
            raise PolarrefError("bundle adjustment: observation of an unknown control point")
        if not g.mark_sigma_px > 0:
            raise PolarrefError("bundle adjustment: marking sigma must be > 0")
        if p.control_X is None or p.control_X.shape != g.X0.shape:
            p.control_X = np.array(g.X0, np.float64)


def hold_datum_by_priors(p: BAProblem) -> None:
    """The priors fix all 7 similarity DoF: no camera coordinate is held for the gauge."""
    mask = np.ones((len(p.R), 6), bool)
    mask[p.cam_fixed] = False
    p.cam_mask = mask
    n_c = 0 if p.priors.centres is None else len(p.priors.centres.cam)
    n_g = 0 if p.priors.control is None else len(p.priors.control.X0)
    p.gauge = (f"datum fixed by the priors ({n_c} camera centres, {n_g} control points): "
               "no gauge DoF held")


def fix_gauge(p: BAProblem) -> None:
    """Fix the 7 similarity DoF (rotation 3, translation 3, scale 1) explicitly.

    * No fixed camera: camera 0 (the first variable camera) is held fixed (rotation and centre:
      6 DoF) and the scale by the centre coordinate of the next variable camera along which it
      is farthest from camera 0 (1 DoF).
    * One fixed camera (with observations): it fixes 6 DoF; the scale is fixed as above with
      the first variable camera.
    * Two or more fixed cameras with distinct centres: they fix all 7 DoF.
    Fixed points are not counted toward the gauge (conservative).
    """
    N = len(p.R)
    mask = np.ones((N, 6), bool)
    mask[p.cam_fixed] = False
    observed = np.bincount(p.obs_cam, minlength=N) > 0
    fixed_obs = np.flatnonzero(p.cam_fixed & observed)
    variable = np.flatnonzero(~p.cam_fixed)
    gauge = ""
    if len(fixed_obs) >= 2 and np.ptp(p.C[fixed_obs], axis=0).max() > 0:
        gauge = f"{len(fixed_obs)} fixed cameras fix rotation, translation and scale"
    elif len(variable):
        if len(fixed_obs) == 0:
            first = variable[0]
            mask[first] = False
            variable = variable[1:]
            anchor, what = first, f"camera {int(p.image_ids[first])} pose fixed (6 DoF)"
        else:
            anchor = fixed_obs[0]
            what = f"fixed camera {int(p.image_ids[anchor])} fixes 6 DoF"
        if len(variable):
            dist = np.linalg.norm(p.C[variable] - p.C[anchor], axis=1)
            second = variable[int(np.argmax(dist > 1e-9 * max(dist.max(), 1e-300)))]
            k = int(np.argmax(np.abs(p.C[second] - p.C[anchor])))
            mask[second, 3 + k] = False
            gauge = (f"{what}; scale by centre coordinate {'xyz'[k]} of camera "
                     f"{int(p.image_ids[second])} (1 DoF)")
        else:
            gauge = what
    else:
        gauge = "all cameras fixed"
    p.cam_mask = mask
    p.gauge = gauge


def _add_counts(counts: dict[str, int], **more: int) -> dict[str, int]:
    """``counts`` with ``more`` added to its entries (a problem may come with counts of its own)."""
    return {**counts, **{k: counts.get(k, 0) + v for k, v in more.items()}}


def _nonzero(counts: dict[str, int]) -> dict[str, int]:
    return {k: v for k, v in counts.items() if v}
