"""The CSV formats of pose priors, ground control points and their image marks; strict readers.

* ``--priors``: ``name,x,y,z,sigma_x,sigma_y,sigma_z`` (metres), optional
  ``omega,phi,kappa,sigma_angle_deg`` (degrees): ``cam_from_world = Rx(omega) Ry(phi) Rz(kappa)``
  in COLMAP's camera frame (x right, y down, z forward), so a nadir camera with its x along
  world x is omega = 180, phi = kappa = 0.
* ``--gcps``: ``id,x,y,z,sigma_x,sigma_y,sigma_z,role`` with role ``control`` or ``check``.
* ``--gcp-observations``: ``id,image,u,v``: pixel (COLMAP convention: the centre of the top-left
  pixel is (0.5, 0.5)) of point ``id`` in the image named ``image`` (file name).

Every reader raises :class:`PolarrefError` naming the file, line and problem.
"""

from __future__ import annotations

import csv
import enum
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from polarref.core.atomic import atomic_write
from polarref.core.errors import PolarrefError
from polarref.core.geometry import axis_rotation

PRIOR_COLUMNS = ("name", "x", "y", "z", "sigma_x", "sigma_y", "sigma_z")
ATTITUDE_COLUMNS = ("omega", "phi", "kappa", "sigma_angle_deg")
GCP_COLUMNS = ("id", "x", "y", "z", "sigma_x", "sigma_y", "sigma_z", "role")
MARK_COLUMNS = ("id", "image", "u", "v")
MIN_CONTROL_POINTS = 3


class Role(enum.StrEnum):
    CONTROL = "control"  # enters the adjustment with its 3D prior
    CHECK = "check"      # never enters it: triangulated in the final model, reported apart


@dataclass(frozen=True)
class PosePrior:
    """One image's prior: centre (3,) and its 1-sigma (3,), metres; attitude ``R`` (3, 3)
    cam_from_world with ``sigma_angle_deg``, or None."""

    name: str
    centre: np.ndarray
    sigma: np.ndarray
    R: np.ndarray | None = None
    sigma_angle_deg: float | None = None


@dataclass(frozen=True)
class GroundPoint:
    id: str
    xyz: np.ndarray    # (3,) metres
    sigma: np.ndarray  # (3,) 1-sigma, metres
    role: Role


@dataclass(frozen=True)
class Mark:
    """Pixel ``uv`` (2,) of ground point ``id`` in image ``image``."""

    id: str
    image: str
    uv: np.ndarray


@dataclass(frozen=True)
class Georef:
    """What one block is georeferenced with (any part may be empty)."""

    priors: tuple[PosePrior, ...] = ()
    points: tuple[GroundPoint, ...] = ()
    marks: tuple[Mark, ...] = ()

    def of_role(self, role: Role) -> tuple[GroundPoint, ...]:
        return tuple(p for p in self.points if p.role == role)

    def marks_of(self, ids) -> tuple[Mark, ...]:
        ids = set(ids)
        return tuple(m for m in self.marks if m.id in ids)


def omega_phi_kappa_matrix(omega: float, phi: float, kappa: float) -> np.ndarray:
    """cam_from_world ``Rx(omega) Ry(phi) Rz(kappa)`` (angles in degrees)."""
    r = np.radians([omega, phi, kappa])
    return axis_rotation(0, r[0]) @ axis_rotation(1, r[1]) @ axis_rotation(2, r[2])


def _rows(path: Path, required: tuple[str, ...], optional: tuple[str, ...] = ()):
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise PolarrefError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    reader = csv.reader(line for line in text.splitlines() if line.strip() and not line.startswith("#"))
    header = next(reader, None)
    if header is None:
        raise PolarrefError(f"{path}: empty file (expected a header {','.join(required)})")
    header = [h.strip() for h in header]
    missing = [c for c in required if c not in header]
    if missing:
        raise PolarrefError(f"{path}: header lacks {', '.join(missing)} "
                            f"(expected {','.join(required + optional)})")
    unknown = [h for h in header if h not in required + optional]
    if unknown:
        raise PolarrefError(f"{path}: unknown column(s) {', '.join(unknown)}")
    rows = []
    for k, row in enumerate(reader, start=2):
        if len(row) != len(header):
            raise PolarrefError(f"{path}: line {k}: {len(row)} fields, header has {len(header)}")
        rows.append((k, dict(zip(header, (v.strip() for v in row)))))
    if not rows:
        raise PolarrefError(f"{path}: no rows after the header")
    return header, rows


def _num(path, line, row, key, positive=False) -> float:
    try:
        v = float(row[key])
    except ValueError:
        raise PolarrefError(f"{path}: line {line}: {key} = {row[key]!r} is not a number") from None
    if not math.isfinite(v):
        raise PolarrefError(f"{path}: line {line}: {key} = {row[key]} is not finite")
    if positive and v <= 0:
        raise PolarrefError(f"{path}: line {line}: {key} = {row[key]} must be > 0")
    return v


def _unique(path, line, key, seen: set) -> None:
    if key in seen:
        raise PolarrefError(f"{path}: line {line}: {key!r} appears twice")
    seen.add(key)


def read_priors(path: Path, image_names) -> tuple[PosePrior, ...]:
    """Pose priors of images in ``image_names`` (a prior of any other image is an error)."""
    header, rows = _rows(path, PRIOR_COLUMNS, ATTITUDE_COLUMNS)
    att = [c for c in ATTITUDE_COLUMNS if c in header]
    if att and len(att) != len(ATTITUDE_COLUMNS):
        raise PolarrefError(f"{path}: attitude priors need all of {','.join(ATTITUDE_COLUMNS)}")
    names, seen, out = set(image_names), set(), []
    for line, row in rows:
        name = row["name"]
        if name not in names:
            raise PolarrefError(f"{path}: line {line}: prior for image {name!r}, which is not in "
                                "the image folder")
        _unique(path, line, name, seen)
        c = np.array([_num(path, line, row, k) for k in "xyz"])
        s = np.array([_num(path, line, row, f"sigma_{k}", positive=True) for k in "xyz"])
        R = sa = None
        if att:
            R = omega_phi_kappa_matrix(*(_num(path, line, row, k) for k in ("omega", "phi", "kappa")))
            sa = _num(path, line, row, "sigma_angle_deg", positive=True)
        out.append(PosePrior(name, c, s, R, sa))
    return tuple(out)


def read_gcps(path: Path) -> tuple[GroundPoint, ...]:
    _, rows = _rows(path, GCP_COLUMNS)
    seen, out = set(), []
    for line, row in rows:
        gid = row["id"]
        if not gid:
            raise PolarrefError(f"{path}: line {line}: empty id")
        _unique(path, line, gid, seen)
        try:
            role = Role(row["role"].lower())
        except ValueError:
            raise PolarrefError(f"{path}: line {line}: role {row['role']!r} (use control or check)") from None
        out.append(GroundPoint(gid, np.array([_num(path, line, row, k) for k in "xyz"]),
                               np.array([_num(path, line, row, f"sigma_{k}", positive=True)
                                         for k in "xyz"]), role))
    return tuple(out)


def read_marks(path: Path, points: tuple[GroundPoint, ...], image_names) -> tuple[Mark, ...]:
    """Marks of known points in known images; every point needs at least one mark."""
    _, rows = _rows(path, MARK_COLUMNS)
    ids, names = {p.id for p in points}, set(image_names)
    seen, out = set(), []
    for line, row in rows:
        if row["id"] not in ids:
            raise PolarrefError(f"{path}: line {line}: unknown ground point id {row['id']!r}")
        if row["image"] not in names:
            raise PolarrefError(f"{path}: line {line}: unknown image {row['image']!r}")
        _unique(path, line, (row["id"], row["image"]), seen)
        out.append(Mark(row["id"], row["image"],
                        np.array([_num(path, line, row, "u"), _num(path, line, row, "v")])))
    marked = {m.id for m in out}
    lacking = [p.id for p in points if p.id not in marked]
    if lacking:
        raise PolarrefError(f"{path}: ground point {lacking[0]!r} has no observations"
                            + (f" (and {len(lacking) - 1} more)" if len(lacking) > 1 else ""))
    return tuple(out)


def load_georef(image_names, priors: Path | None = None, gcps: Path | None = None,
                marks: Path | None = None, extra_priors: tuple[PosePrior, ...] = ()) -> Georef:
    """Read and cross-check the files: GCPs and their marks come together, and without pose
    priors at least 3 control points must fix the datum."""
    if (gcps is None) != (marks is None):
        raise PolarrefError("ground control points need both the point file and the "
                            "observation file", option="gcps")
    pri = read_priors(priors, image_names) if priors is not None else extra_priors
    pts = read_gcps(gcps) if gcps is not None else ()
    mk = read_marks(marks, pts, image_names) if marks is not None else ()
    n_ctl = sum(p.role == Role.CONTROL for p in pts)
    if pts and not pri and n_ctl < MIN_CONTROL_POINTS:
        raise PolarrefError(f"{gcps}: {n_ctl} control point(s) and no pose priors: at least "
                            f"{MIN_CONTROL_POINTS} control points are needed to fix the datum")
    return Georef(tuple(pri), pts, mk)


def write_gcps(path: Path, points) -> None:
    """The ``--gcps`` CSV of ``points`` (GroundPoint)."""
    lines = [",".join(GCP_COLUMNS)]
    lines += [f"{p.id},{p.xyz[0]:.4f},{p.xyz[1]:.4f},{p.xyz[2]:.4f},{p.sigma[0]:g},{p.sigma[1]:g},"
              f"{p.sigma[2]:g},{p.role}" for p in points]
    _write(path, lines)


def write_marks(path: Path, marks) -> None:
    lines = [",".join(MARK_COLUMNS)] + [f"{m.id},{m.image},{m.uv[0]:.3f},{m.uv[1]:.3f}" for m in marks]
    _write(path, lines)


def write_priors(path: Path, priors) -> None:
    lines = [",".join(PRIOR_COLUMNS)]
    lines += [f"{p.name},{p.centre[0]:.4f},{p.centre[1]:.4f},{p.centre[2]:.4f},"
              f"{p.sigma[0]:g},{p.sigma[1]:g},{p.sigma[2]:g}" for p in priors]
    _write(path, lines)


def _write(path: Path, lines) -> None:
    atomic_write(Path(path), "\n".join(lines) + "\n")
