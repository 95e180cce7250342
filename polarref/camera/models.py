"""Camera model table: names, parameter orders and radial maps.

Names and parameter orders follow COLMAP wherever COLMAP has the model. The five classical
projection families of the Polar-vision paper (section 1.2.1) are added with one focal length:

============== ======================================= =============================== =========
model          params                                  normalized radius rd(theta)     theta_max
============== ======================================= =============================== =========
SIMPLE_PINHOLE f, cx, cy                               tan(theta)                      pi/2
PINHOLE        fx, fy, cx, cy                          tan(theta)                      pi/2
SIMPLE_RADIAL  f, cx, cy, k                            D(tan theta), D(r)=r(1+k r^2)   mono.
RADIAL         f, cx, cy, k1, k2                       D(r) = r(1 + k1 r^2 + k2 r^4)   mono.
OPENCV         fx, fy, cx, cy, k1, k2, p1, p2          not radial: see camera/opencv.py  det > 0
OPENCV_FISHEYE fx, fy, cx, cy, k1, k2, k3, k4          theta(1+k1 t^2+..+k4 t^8)       mono., pi
SIMPLE_FISHEYE f, cx, cy                               theta (equidistant, COLMAP)     pi
FISHEYE        fx, fy, cx, cy                          theta (equidistant, COLMAP)     pi
PERSPECTIVE    f, cx, cy                               tan(theta)   (= SIMPLE_PINHOLE) pi/2
EQUIDISTANT    f, cx, cy                               theta        (= SIMPLE_FISHEYE) pi
STEREOGRAPHIC  f, cx, cy                               2 tan(theta/2)                  pi
EQUISOLID      f, cx, cy                               2 sin(theta/2)                  pi
ORTHOGRAPHIC   f, cx, cy                               sin(theta)                      pi/2
============== ======================================= =============================== =========

"mono." = the first angle where the radial map stops increasing (if any). Differences from
COLMAP: COLMAP rejects every point with z <= 0, polarref accepts the angle-kind models up to
their theta_max (beyond 90 degrees for fisheye lenses); COLMAP projects distorted models past the
fold of the distortion polynomial, polarref masks those points (NaN).
"""

from __future__ import annotations

from dataclasses import dataclass

from polarref.camera.radial import RadialMap


@dataclass(frozen=True)
class ModelSpec:
    """Layout of one model's parameter vector.

    Attributes:
        names: parameter names in order.
        fx, fy, cx, cy: indices of the focal lengths and principal point (fx == fy for one-focal models).
        extra: indices of the distortion coefficients, in polynomial order.
        kind, family: the radial map (see :class:`RadialMap`); kind ``"opencv"`` is COLMAP's
            radial + tangential model (:mod:`polarref.camera.opencv`).
        colmap: the COLMAP model with identical maths, or None.
    """

    names: tuple[str, ...]
    fx: int
    fy: int
    cx: int
    cy: int
    extra: tuple[int, ...]
    kind: str
    family: str
    colmap: str | None


def _one_focal(kind: str, family: str, colmap: str | None, extra_names: tuple[str, ...] = ()):
    names = ("f", "cx", "cy") + extra_names
    return ModelSpec(names, 0, 0, 1, 2, tuple(range(3, len(names))), kind, family, colmap)


def _two_focal(kind: str, family: str, colmap: str | None, extra_names: tuple[str, ...] = ()):
    names = ("fx", "fy", "cx", "cy") + extra_names
    return ModelSpec(names, 0, 1, 2, 3, tuple(range(4, len(names))), kind, family, colmap)


MODELS: dict[str, ModelSpec] = {
    "SIMPLE_PINHOLE": _one_focal("perspective", "", "SIMPLE_PINHOLE"),
    "PINHOLE": _two_focal("perspective", "", "PINHOLE"),
    "SIMPLE_RADIAL": _one_focal("perspective", "", "SIMPLE_RADIAL", ("k",)),
    "RADIAL": _one_focal("perspective", "", "RADIAL", ("k1", "k2")),
    "OPENCV": _two_focal("opencv", "", "OPENCV", ("k1", "k2", "p1", "p2")),
    "OPENCV_FISHEYE": _two_focal("angle", "poly", "OPENCV_FISHEYE", ("k1", "k2", "k3", "k4")),
    "SIMPLE_FISHEYE": _one_focal("angle", "poly", "SIMPLE_FISHEYE"),
    "FISHEYE": _two_focal("angle", "poly", "FISHEYE"),
    "PERSPECTIVE": _one_focal("perspective", "", "SIMPLE_PINHOLE"),
    "EQUIDISTANT": _one_focal("angle", "poly", "SIMPLE_FISHEYE"),
    "STEREOGRAPHIC": _one_focal("angle", "stereographic", None),
    "EQUISOLID": _one_focal("angle", "equisolid", None),
    "ORTHOGRAPHIC": _one_focal("angle", "orthographic", None),
}


def radial_map(spec: ModelSpec, params) -> RadialMap:
    """The model's radial map; for OPENCV (not radially symmetric) the radial part k1, k2 only."""
    if spec.kind == "opencv":
        return RadialMap("perspective", "", (float(params[spec.extra[0]]), float(params[spec.extra[1]])))
    return RadialMap(spec.kind, spec.family, tuple(float(params[i]) for i in spec.extra))
