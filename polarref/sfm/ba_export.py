"""``run_sfm(export_final_ba=PATH)``: the mapper's last global BA, with the ground-truth poses,
written as a :mod:`polarref.ba.export_problem` file (a bench problem of realistic structure)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from polarref.ba.export_problem import ProblemFile, write_problem_file
from polarref.core.errors import PolarrefError
from polarref.model import Reconstruction
from polarref.sfm.ba_runs import ExportedBA


def truth_poses(names: list[str], gt: Reconstruction | None) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3, 3) cam_from_world and (N, 3) centres of the images ``names`` in ``gt``; NaN for an
    image the ground truth lacks (or all, without one)."""
    R = np.full((len(names), 3, 3), np.nan)
    C = np.full((len(names), 3), np.nan)
    by_name = {} if gt is None else {im.name: im.cam_from_world for im in gt.images.values()}
    for k, name in enumerate(names):
        pose = by_name.get(name)
        if pose is not None:
            R[k] = pose.R
            C[k] = pose.center
    return R, C


def write_final_ba(path: Path, exported: ExportedBA | None, names: list[str], gt: Reconstruction | None,
                   source: str) -> None:
    """Write the mapper's last global BA (``names``: every image's name, indexed as the map's).

    Raises:
        PolarrefError: the mapper kept none (pycolmap's adjuster, or no global BA ran).
    """
    if exported is None:
        raise PolarrefError("no global bundle adjustment of ours to export (the export needs one of "
                            "our forms, not ba=colmap)")
    p = exported.problem
    img_names = [names[int(i) - 1] for i in p.image_ids]  # image id = map index + 1 (sfm.bundle)
    truth_R, truth_C = truth_poses(img_names, gt)
    write_problem_file(Path(path), ProblemFile(p, exported.options, exported.result, tuple(img_names),
                                               truth_R, truth_C, source))
