"""A BA problem exported from our SfM, in one lossless file (``.npz``, format tag + version).

Why not BAL: BAL holds one RADIAL camera per image and text decimals, so our camera models,
which cameras are held, the intrinsics groups and the bits of every float would be lost or
rounded; a COLMAP text model loses the bits too. ``.npz`` stores every array as it is in
memory (float64 bit for bit), reads without pickle, and is one file a loader recognises by its
``format`` entry. Held inside:

* the problem as it entered the solver (before ``prepare``): cameras (a table of distinct
  :class:`polarref.camera.Camera` + one index per problem camera), rotations, centres, points,
  observations, held cameras / points, image and point ids, intrinsics groups;
* how the mapper solved it (:class:`ExportedOptions`: form, loss, iteration cap, tolerance,
  refined intrinsics groups);
* the mapper's own result (:class:`MapperResult`), so that a re-solve can be checked against it;
* the ground-truth pose of each problem camera (NaN where the ground truth lacks the image).
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from polarref.ba.options import BAOptions
from polarref.ba.problem import BAProblem
from polarref.camera import Camera
from polarref.core.atomic import atomic_open
from polarref.core.errors import PolarrefError
from polarref.core.geometry import Rigid3
from polarref.model.observations import Observations
from polarref.model.reconstruction import Image, Reconstruction

FORMAT = "polarref-ba-problem"
VERSION = 1


@dataclass(frozen=True)
class ExportedOptions:
    """The options the mapper's BA ran with (the rest: BAOptions' defaults)."""

    param: str
    loss: str
    max_iterations: int
    function_tolerance: float
    refine: tuple[str, ...]

    def ba_options(self) -> BAOptions:
        return BAOptions(param=self.param, loss=self.loss, max_iterations=self.max_iterations,
                         function_tolerance=self.function_tolerance, refine=self.refine)


@dataclass(frozen=True)
class MapperResult:
    """What the mapper's solve of this problem ended with (ids index the prepared problem)."""

    initial_cost: float
    final_cost: float
    iterations: int
    image_ids: np.ndarray   # (N',) ids of the result's cameras
    R: np.ndarray           # (N', 3, 3)
    C: np.ndarray           # (N', 3)
    point_ids: np.ndarray   # (P',)
    X: np.ndarray           # (P', 3)


@dataclass(frozen=True)
class ProblemFile:
    """One exported problem. ``problem`` is a fresh unprepared copy on every read."""

    problem: BAProblem
    options: ExportedOptions
    result: MapperResult | None
    image_names: tuple[str, ...]   # (N,) name of each problem camera's image
    truth_R: np.ndarray            # (N, 3, 3) ground-truth cam_from_world; NaN: no ground truth
    truth_C: np.ndarray            # (N, 3) ground-truth centres; NaN: no ground truth
    source: str                    # what it was exported from (free text)


def _camera_table(cameras: list) -> tuple[list[Camera], np.ndarray]:
    table: list[Camera] = []
    index = np.empty(len(cameras), np.int64)
    where: dict[Camera, int] = {}
    for k, cam in enumerate(cameras):
        if cam not in where:
            where[cam] = len(table)
            table.append(cam)
        index[k] = where[cam]
    return table, index


def _optional(arrays: dict[str, np.ndarray], name: str, value) -> None:
    if value is not None:
        arrays[name] = np.asarray(value)


def write_problem_file(path: Path, pf: ProblemFile) -> None:
    """Write ``pf`` to ``path`` (atomically; ``.npz``, uncompressed: the floats' bits as they are)."""
    p = pf.problem
    if p.priors is not None:
        raise PolarrefError("exporting a BA problem with pose priors or control points is not supported "
                            f"(format {FORMAT} version {VERSION})")
    table, cam_index = _camera_table(p.cameras)
    width = max(len(c.params) for c in table)
    params = np.full((len(table), width), np.nan)
    for k, c in enumerate(table):
        params[k, :len(c.params)] = c.params
    o = pf.options
    arrays = {
        "format": np.array(FORMAT), "version": np.array(VERSION), "source": np.array(pf.source),
        "camera_model": np.array([c.model for c in table]), "camera_size": np.array(
            [[c.width, c.height] for c in table], np.int64).reshape(-1, 2),
        "camera_params": params, "camera_nparams": np.array([len(c.params) for c in table], np.int64),
        "camera_index": cam_index, "R": p.R, "C": p.C, "X": p.X,
        "obs_image": p.obs.image, "obs_point": p.obs.point, "obs_uv": p.obs.uv,
        "image_names": np.array(pf.image_names, dtype=str), "truth_R": pf.truth_R, "truth_C": pf.truth_C,
        "opt_param": np.array(o.param), "opt_loss": np.array(o.loss),
        "opt_max_iterations": np.array(o.max_iterations), "opt_function_tolerance": np.array(o.function_tolerance),
        "opt_refine": np.array(list(o.refine), dtype=str),
    }
    for name in ("cam_fixed", "pt_fixed", "image_ids", "point_ids", "camera_group"):
        _optional(arrays, name, getattr(p, name))
    if pf.result is not None:
        r = pf.result
        arrays.update(result_costs=np.array([r.initial_cost, r.final_cost]), result_iterations=np.array(r.iterations),
                      result_image_ids=r.image_ids, result_R=r.R, result_C=r.C, result_point_ids=r.point_ids,
                      result_X=r.X)
    with atomic_open(Path(path)) as fh:
        np.savez(fh, **arrays)


def is_problem_file(path: Path) -> bool:
    """Whether ``path`` names a file this module reads (by its suffix; the content is checked on read)."""
    return Path(path).suffix.lower() == ".npz" and Path(path).is_file()


def read_problem_file(path: Path) -> ProblemFile:
    """Read a file of :func:`write_problem_file`.

    Raises:
        PolarrefError: not such a file, another version, or truncated/corrupt (one line naming it).
    """
    try:
        with np.load(Path(path), allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError) as exc:
        raise PolarrefError(f"{path}: not a readable BA problem file ({type(exc).__name__}: {exc})") from exc
    return _decode(path, data)


def _cameras(models, sizes, params, nparams, index) -> list[Camera]:
    table = [Camera(str(m), int(wh[0]), int(wh[1]), prm[:n]) for m, wh, prm, n in zip(models, sizes, params, nparams)]
    return [table[k] for k in index]


def _decode(path: Path, d: dict[str, np.ndarray]) -> ProblemFile:
    """The arrays of one file as a ProblemFile (PolarrefError naming ``path`` when they are not one)."""
    if str(d.get("format", "")) != FORMAT:
        raise PolarrefError(f"{path}: not a {FORMAT} file (no format tag)")
    if int(d["version"]) != VERSION:
        raise PolarrefError(f"{path}: {FORMAT} version {int(d['version'])}; this reader knows version {VERSION}")
    try:
        problem = BAProblem(cameras=_cameras(d["camera_model"], d["camera_size"], d["camera_params"],
                                             d["camera_nparams"], d["camera_index"]), R=d["R"], C=d["C"], X=d["X"],
                            obs=Observations.from_arrays(d["obs_image"], d["obs_point"], d["obs_uv"]),
                            cam_fixed=d.get("cam_fixed"), pt_fixed=d.get("pt_fixed"), image_ids=d.get("image_ids"),
                            point_ids=d.get("point_ids"))
        problem.camera_group = d.get("camera_group")
        options = ExportedOptions(str(d["opt_param"]), str(d["opt_loss"]), int(d["opt_max_iterations"]),
                                  float(d["opt_function_tolerance"]), tuple(str(g) for g in d["opt_refine"]))
        result = None
        if "result_costs" in d:
            c = d["result_costs"]
            result = MapperResult(float(c[0]), float(c[1]), int(d["result_iterations"]), d["result_image_ids"],
                                  d["result_R"], d["result_C"], d["result_point_ids"], d["result_X"])
        return ProblemFile(problem, options, result, tuple(str(n) for n in d["image_names"]), d["truth_R"],
                           d["truth_C"], str(d["source"]))
    except (KeyError, ValueError, IndexError) as exc:
        raise PolarrefError(f"{path}: incomplete or inconsistent BA problem file ({type(exc).__name__}: {exc})") from exc


def truth_reconstruction(pf: ProblemFile) -> Reconstruction | None:
    """The ground-truth poses as a Reconstruction (images only, ids as the problem's); None
    when the file holds none."""
    have = np.isfinite(pf.truth_C).all(1) & np.isfinite(pf.truth_R).all((1, 2))
    if not have.any():
        return None
    p = pf.problem
    ids = np.arange(1, p.num_cameras + 1) if p.image_ids is None else np.asarray(p.image_ids)
    rec = Reconstruction()
    table, index = _camera_table(p.cameras)
    rec.cameras = {k + 1: cam for k, cam in enumerate(table)}
    for k in np.flatnonzero(have):
        R = pf.truth_R[k]
        rec.images[int(ids[k])] = Image(int(ids[k]), pf.image_names[k], int(index[k]) + 1,
                                        Rigid3(R, -R @ pf.truth_C[k]))
    return rec
