"""Pose priors inside the incremental mapper (issue 33): the model is built in the priors' frame.

The mapper starts in its own frame (first camera at the origin, unit baseline). As soon as the
registered images' priors can fix a similarity, :meth:`PriorHook.place` moves the map into
the priors' frame; from then on every local and global BA carries the priors of its variable
cameras as residual blocks and the global BA holds no camera for the gauge (the priors fix the
datum). The output model is georeferenced without a Sim3 to anything.

Placing: with attitude priors the rotation is their chordal mean (two cameras suffice), scale and
translation the least squares of the centres given that rotation; without them the
similarity of >= 3 non-collinear prior centres (Umeyama).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from polarref.ba.priors import AttitudePriors, BAPriors, CentrePriors, restrict
from polarref.ba.parameterization import PARAMS
from polarref.core.errors import PolarrefError
from polarref.core.geometry import Rigid3, Sim3, umeyama
from polarref.georef.datum import DatumPriors, weighted_similarity
from polarref.georef.formats import PosePrior

log = logging.getLogger(__name__)

# centres spanning less than this fraction of their extent across the strip count as collinear
MIN_SPREAD = 0.05


@dataclass(frozen=True)
class MapperPriors:
    """Pose priors by image index of the map: ``centre`` (N, 3) (NaN: none), ``sigma`` (N, 3),
    ``R`` (N, 3, 3) prior cam_from_world and ``sigma_rad`` (N,) (NaN: no attitude prior)."""

    centre: np.ndarray
    sigma: np.ndarray
    R: np.ndarray
    sigma_rad: np.ndarray
    image_sigma_px: float

    @classmethod
    def from_priors(cls, priors: tuple[PosePrior, ...], names: list[str], image_sigma_px: float):
        n = len(names)
        idx = {m: k for k, m in enumerate(names)}
        centre, sigma = np.full((n, 3), np.nan), np.ones((n, 3))
        R, sig_r = np.tile(np.eye(3), (n, 1, 1)), np.full(n, np.nan)
        for p in priors:
            k = idx[p.name]
            centre[k], sigma[k] = p.centre, p.sigma
            if p.R is not None:
                R[k], sig_r[k] = p.R, np.radians(p.sigma_angle_deg)
        return cls(centre, sigma, R, sig_r, image_sigma_px)

    def whitening(self, idx: np.ndarray) -> np.ndarray:
        """(len(idx), 3, 3) diag(1 / sigma) of the centre priors of images ``idx``."""
        return np.array([np.diag(1.0 / s) for s in self.sigma[idx]]).reshape(-1, 3, 3)

    def ba_priors(self) -> BAPriors:
        """Every prior, cameras numbered by image index."""
        c = np.flatnonzero(np.isfinite(self.centre).all(1))
        a = np.flatnonzero(np.isfinite(self.sigma_rad))
        centres = CentrePriors(c, self.centre[c], self.whitening(c)) if len(c) else None
        att = AttitudePriors(a, self.R[a], self.sigma_rad[a]) if len(a) else None
        return BAPriors(centres, att, None, self.image_sigma_px)


@dataclass
class PriorHook:
    """The mapper's priors: placed once, then added to every BA."""

    priors: MapperPriors
    placed: bool = False
    _all: BAPriors | None = field(default=None, repr=False)

    def place(self, state) -> bool:
        """Move the map into the priors' frame once the registered images allow it; True when
        the map is (now or already) in that frame."""
        if self.placed:
            return True
        sim = _similarity(state, self.priors)
        if sim is None:
            return False
        _move(state, sim)
        self.placed, self._all = True, self.priors.ba_priors()
        log.info("mapper: map placed in the priors' frame at %d registered images (scale %.4g)",
                 int(state.registered.sum()), sim.s)
        return True

    def realign(self, state) -> None:
        """Before a global BA: the datum again, by the similarity that fits the priors as the BA
        weights them (georef.datum; the closed form where they cannot fix it yet). The priors
        are weak against the tie points, so LM's damping creeps along the 7 datum directions (50
        iterations without converging, measured on the small UAV) or stops where it started
        (the function tolerance on a large block, issue 33's sub-block: 0.78 m off); the
        similarity takes that step at once and the BA refines the rest."""
        if self.placed:
            sim = _weighted(state, self.priors) or _similarity(state, self.priors)
            if sim is not None:
                _move(state, sim)


    def gauge(self, default: list[int]) -> list[int]:
        """Cameras held for the gauge: none once the priors fix the datum."""
        return [] if self.placed else default

    def for_problem(self, problem) -> BAPriors | None:
        """The priors of the problem's variable cameras (None before placing)."""
        if not self.placed:
            return None
        index = np.asarray(problem.image_ids, np.int64) - 1
        index = np.where(np.asarray(problem.cam_fixed, bool), -1, index)  # fixed: no prior block
        out = restrict(self._all, index)
        return None if out.centres is None and out.attitudes is None else out


def _move(state, sim: Sim3) -> None:
    for i in np.flatnonzero(state.registered):
        state.set_pose(int(i), sim.transform_pose(Rigid3(state.R[i], state.t[i])))
    state.X[state.has_point] = sim.apply(state.X[state.has_point])


def prior_hook(priors: tuple[PosePrior, ...], names: list[str], image_sigma_px: float,
               mapper_cfg) -> PriorHook | None:
    """The mapper's hook for ``priors`` (None without priors); refused with intrinsics refinement
    (their trade-off against the datum is not modelled) and with pycolmap's adjuster."""
    if not priors:
        return None
    if mapper_cfg.refine:
        raise PolarrefError("pose priors in the mapper need fixed intrinsics (no --refine)")
    if mapper_cfg.ba not in PARAMS:
        raise PolarrefError(f"pose priors in the mapper need one of our BA forms ({', '.join(PARAMS)})")
    return PriorHook(MapperPriors.from_priors(priors, names, image_sigma_px))


def _similarity(state, pri: MapperPriors) -> Sim3 | None:
    reg = np.flatnonzero(state.registered & np.isfinite(pri.centre).all(1))
    if len(reg) < 2:
        return None
    src, dst = state.centers()[reg], pri.centre[reg]
    att = reg[np.isfinite(pri.sigma_rad[reg])]
    if len(att):
        # world_from_model = R_prior^T R_est per camera; their chordal mean
        M = np.einsum("nji,njk->ik", pri.R[att], state.R[att])
        U, _, Vt = np.linalg.svd(M)
        R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
        a, b = src - src.mean(0), dst - dst.mean(0)
        s = float(np.sum(b * (a @ R.T)) / np.sum(a * a))
        if not s > 0:
            return None
        return Sim3(s, R, dst.mean(0) - s * R @ src.mean(0))
    if len(reg) < 3 or not _spread(dst):
        return None
    return umeyama(src, dst)


def _weighted(state, pri: MapperPriors) -> Sim3 | None:
    """The weighted similarity of >= 3 non-collinear registered prior centres (and the attitude
    priors); None where the centres cannot fix it."""
    reg = np.flatnonzero(state.registered & np.isfinite(pri.centre).all(1))
    dst = pri.centre[reg]
    if len(reg) < 3 or not _spread(dst):
        return None
    att = reg[np.isfinite(pri.sigma_rad[reg])]
    return weighted_similarity(DatumPriors(state.centers()[reg], dst, pri.whitening(reg), state.R[att],
                                           pri.R[att], pri.sigma_rad[att]))


def _spread(centres: np.ndarray) -> bool:
    """Whether prior centres (P, 3) are spread enough across the strip to fix a similarity."""
    sv = np.linalg.svd(centres - centres.mean(0), compute_uv=False)
    return bool(sv[1] >= MIN_SPREAD * sv[0])
