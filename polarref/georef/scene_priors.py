"""Pose priors from a rendered scene's ``scene.json`` (section ``priors``, written by synth/priors.py).

The twins draw their priors as AR(1) drift along the image order (``params.correlation``); the
adjustment weights them as independent with their stated sigmas, as a user with GPS/INS logs
would. The correlation is kept in :class:`ScenePriorParams` so that predictions can use it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from polarref.core.errors import PolarrefError
from polarref.core.geometry import Rigid3
from polarref.georef.formats import PosePrior

PRIORS_FORMAT = "polarref-pose-priors/1"
SCENE_KEYWORD = "scene"  # `--priors scene`: the priors of DIR/scene.json


@dataclass(frozen=True)
class ScenePriorParams:
    """How the scene's priors were drawn (1-sigma, metres / degrees; lag-one correlation)."""

    position_sigma_m: float
    vertical_sigma_m: float
    rotation_sigma_deg: float
    correlation: float
    position_sigma_rel: float = 0.0  # plus this share of the range to the scene centre (comet)


@dataclass(frozen=True)
class ViewPrior:
    """One view's drawn prior as scene.json states it: centre (3,) and its 1-sigma (3,), metres;
    cam_from_world ``qvec`` (4,) w, x, y, z and ``tvec`` (3,); attitude 1-sigma, degrees."""

    centre: np.ndarray
    sigma: np.ndarray
    qvec: np.ndarray
    tvec: np.ndarray
    rotation_sigma_deg: float


@dataclass(frozen=True)
class ScenePriors:
    """A scene.json's priors: the views' names (N), their priors (N), how they were drawn, and
    each view's index in the flight they drifted along (N,) (``priors.sequence`` of a twin's
    sub-block, synth.subblock; else 0..N-1)."""

    view_names: tuple[str, ...]
    views: tuple[ViewPrior, ...]
    params: ScenePriorParams
    sequence: np.ndarray


def views_from_json(pri: list) -> tuple[ViewPrior, ...]:
    """The ``priors.views`` list of scene.json (synth.priors.draw_priors) as records."""
    return tuple(ViewPrior(np.asarray(p["center"], float), np.asarray(p["center_sigma_m"], float),
                           np.asarray(p["qvec"], float), np.asarray(p["tvec"], float),
                           float(p["rotation_sigma_deg"])) for p in pri)


def _scene_priors_from_json(data: dict) -> ScenePriors:
    pri, p = data["priors"], data["priors"]["params"]
    names = tuple(v["name"] for v in data.get("views") or [])
    vert = p.get("vertical_sigma_m") or p["position_sigma_m"]
    params = ScenePriorParams(float(p["position_sigma_m"]), float(vert), float(p["rotation_sigma_deg"]),
                              float(p["correlation"]), float(p.get("position_sigma_rel", 0.0)))
    seq = np.asarray(pri.get("sequence", range(len(names))), np.int64)
    return ScenePriors(names, views_from_json(pri["views"]), params, seq)


def _load(path: Path) -> ScenePriors:
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise PolarrefError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    except json.JSONDecodeError as exc:
        raise PolarrefError(f"{path}: not JSON ({exc.msg}, line {exc.lineno})") from exc
    pri = data.get("priors") if isinstance(data, dict) else None
    if not pri:
        raise PolarrefError(f"{path}: no pose priors in this scene (its 'priors' section is empty; "
                            "render a twin, or pass --priors FILE)")
    if pri.get("format") != PRIORS_FORMAT:
        raise PolarrefError(f"{path}: priors format {pri.get('format')!r}, expected {PRIORS_FORMAT!r}")
    try:
        return _scene_priors_from_json(data)
    except (KeyError, TypeError, ValueError) as exc:
        raise PolarrefError(f"{path}: malformed priors section ({type(exc).__name__}: {exc})") from exc


def scene_prior_params(path: Path) -> ScenePriorParams:
    return _load(path).params


def prior_sequence(path: Path, image_names) -> np.ndarray:
    """(N,) flight index of each image of ``image_names`` along which the priors drifted: the
    ``priors.sequence`` of a twin's sub-block (synth.subblock), else the views' order."""
    sp = _load(path)
    where = dict(zip(sp.view_names, sp.sequence.tolist()))
    missing = [n for n in image_names if n not in where]
    if missing:
        raise PolarrefError(f"{path}: no prior for image {missing[0]!r}")
    return np.array([where[n] for n in image_names], np.int64)


def read_scene_priors(path: Path, image_names) -> tuple[PosePrior, ...]:
    """Centre and attitude priors of ``scene.json`` at ``path`` for the views named in it.

    Views are matched to images by the ``views[k].name`` of the same index; a prior of an image
    not in ``image_names`` is an error, as for ``--priors FILE``.
    """
    sp = _load(path)
    return pose_priors(sp.views, list(sp.view_names), image_names, str(path))


def pose_priors(pri: tuple[ViewPrior, ...], view_names: list[str], image_names, where: str) -> tuple[PosePrior, ...]:
    """PosePriors of drawn view priors (:func:`views_from_json`) for views ``view_names``."""
    path = where
    if len(view_names) != len(pri):
        raise PolarrefError(f"{path}: {len(pri)} priors for {len(view_names)} views")
    names, out = set(image_names), []
    for name, p in zip(view_names, pri):
        if name not in names:
            raise PolarrefError(f"{path}: prior for image {name!r}, which is not in the image folder")
        if not np.all(p.sigma > 0):
            raise PolarrefError(f"{path}: centre prior of {name!r} has a sigma <= 0")
        R = None
        if p.rotation_sigma_deg > 0:  # a twin drawn without attitude noise states no attitude prior
            R = Rigid3.from_quat(p.qvec, p.tvec).R
        out.append(PosePrior(name, p.centre, p.sigma, R, p.rotation_sigma_deg if R is not None else None))
    return tuple(out)
