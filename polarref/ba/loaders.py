"""Read a BA problem from BAL, ParallaxBA, a COLMAP model folder, or a synthetic spec."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from polarref.ba.problem import BAProblem
from polarref.core.errors import PolarrefError
from polarref.model.colmap import read_model


def load_problem(spec: str, *, seed: int = 0) -> tuple[BAProblem, object | None]:
    """See :func:`_load`; numeric failures of a parsed but degenerate problem (singular
    triangulation, a value that breaks a conversion) become a PolarrefError naming it."""
    try:
        problem, truth = _load(spec, seed=seed)
    except PolarrefError:
        raise
    except (ValueError, ArithmeticError, np.linalg.LinAlgError, UnicodeError) as exc:
        raise PolarrefError(f"{spec}: not a usable BA problem ({type(exc).__name__}: {exc})") from exc
    _check_in_front(spec, problem)
    return problem, truth


def _check_in_front(spec: str, problem: BAProblem) -> None:
    """PolarrefError when no observed point lies in front of its camera: such a problem is
    physically impossible (a sign or axis convention error), and LM would "solve" it silently."""
    cam, pt = problem.obs.image, problem.obs.point
    if len(cam) == 0:
        return
    depth = np.einsum("mj,mj->m", problem.R[cam][:, 2, :], problem.X[pt] - problem.C[cam])
    if not (depth > 0).any():
        raise PolarrefError(f"{spec}: every point is behind every camera that observes it ({len(cam)} "
                            "observations, none at positive depth); check the file's camera convention "
                            "(BAL cameras look down -z)")


def _load(spec: str, *, seed: int = 0) -> tuple[BAProblem, object | None]:
    """(problem, truth Reconstruction or None) for a path or ``synth-20``/``synth-60``/``synth-200``.

    BAL: a ``.txt`` file (RADIAL cameras via ``polarref.io.bal``); ParallaxBA: a folder with
    ``Cam.txt`` + ``Feature.pmba`` or ``Cam<N>.txt`` + ``Feature<N>.txt`` + ``cal<N>.txt`` (points
    from ``XYZ.txt`` if present, else by DLT triangulation; PINHOLE); PVL-BA: a folder with
    ``cal.txt`` + ``XYZ.txt`` + ``Feature.txt``, or a ContextCapture BlocksExchange ``.xml``
    (observations undistorted by ``polarref.io.pvlba``); COLMAP: a model folder; an exported SfM
    problem: a ``.npz`` of ``polarref.ba.export_problem`` (truth: its ground-truth poses).
    """
    from polarref.ba.adapter import problem_from_reconstruction

    if spec.startswith("synth-"):
        from polarref.ba.synthetic import SIZES, SPARSE_SIZES, SPARSE_TRACK, synthetic_reconstruction
        sizes = {**SIZES, **SPARSE_SIZES}
        if spec not in sizes:
            raise PolarrefError(f"unknown synthetic problem {spec!r}; known: {', '.join(sizes)}")
        init, truth = synthetic_reconstruction(*sizes[spec], seed=seed, rot_deg=0.3,
                                               point_sigma=0.05, center_sigma=0.05,
                                               track_length=SPARSE_TRACK if spec in SPARSE_SIZES else -1)
        return problem_from_reconstruction(init), truth
    if spec.startswith("scale-"):  # generated in memory, the same problem as its BAL file
        from polarref.ba.scale_synth import generate, parse_spec
        from polarref.io.bal import bal_to_reconstruction
        try:
            scale_spec, scale_seed = parse_spec(spec)
        except ValueError as exc:
            raise PolarrefError(str(exc)) from exc
        gen = generate(scale_spec, scale_seed)
        return (problem_from_reconstruction(bal_to_reconstruction(gen.initial)),
                bal_to_reconstruction(gen.truth))
    path = Path(spec)
    if not path.exists():
        raise PolarrefError(f"BA problem not found: {path}")
    from polarref.ba.export_problem import is_problem_file, read_problem_file, truth_reconstruction
    if is_problem_file(path):
        pf = read_problem_file(path)
        return pf.problem, truth_reconstruction(pf)
    from polarref.io.parallaxba import find_parallaxba_files
    if find_parallaxba_files(path) is not None:
        from polarref.io.parallaxba import read_parallaxba, triangulate_dlt
        pb = read_parallaxba(path)
        X = triangulate_dlt(pb) if pb.points is None else pb.points.copy()
        cam = pb.camera()
        N = pb.num_cameras
        return BAProblem(cameras=[cam] * N, R=pb.R.copy(), C=pb.centers.copy(), X=X,
                         obs=pb.obs.copy()), None
    if (path.is_dir() and (path / "cal.txt").exists()) or path.suffix.lower() == ".xml":
        from polarref.io.pvlba import read_blocks_exchange, read_pvlba
        pvl = read_pvlba(path) if path.is_dir() else read_blocks_exchange(path)
        return problem_from_reconstruction(pvl.to_reconstruction()), None
    if path.is_dir():
        from polarref.model import Reconstruction
        return problem_from_reconstruction(read_model(path)), None
    from polarref.io.bal import bal_to_reconstruction, read_bal
    try:
        bal = read_bal(path)
    except OSError as exc:
        raise PolarrefError(f"cannot read BAL problem {path}: {exc.strerror or exc}") from exc
    return problem_from_reconstruction(bal_to_reconstruction(bal)), None

