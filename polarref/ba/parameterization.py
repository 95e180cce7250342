"""What the solver needs of a landmark parameterization, and the one registry of their names.

A parameterization ("form") turns the problem's cameras and its own point parameters into
residuals and Jacobians. The solver depends on :class:`Parameterization` only; two optional
capabilities are declared as their own Protocols and tested with ``isinstance`` (the forms are
not subclasses, so the Protocols are ``runtime_checkable``):

* :class:`BoundedPoints`: box bounds on the point parameters (parallax forms: omega in
  [0, pi - margin]);
* :class:`Staged`: a residual subset solved first (angular: theta only, then theta and phi);
* :class:`AnchoredJacobians`: parallax forms hand over their anchors' Jacobians factored
  (``anchor_cams`` = (main, associate) camera per point, or None for the generic slot path).

:data:`FORMS` maps every name to its class, imported on first use (the forms import the solver's
helpers); :data:`PARAMS` is the one tuple of names that options, the CLI, the benchmarks and the
compare methods read.
"""

from __future__ import annotations

import importlib
from typing import Protocol, runtime_checkable

import numpy as np

# name -> "module.Class", imported lazily by form_class
FORMS: dict[str, str] = {
    "euclidean": "polarref.ba.euclidean.Euclidean",
    "parallax": "polarref.ba.parallax.Parallax",
    "polar": "polarref.ba.polar.Polar",
    "angular": "polarref.ba.angular.Angular",
}
PARAMS: tuple[str, ...] = tuple(FORMS)
# the SfM mapper's bundle adjusters: every form, and pycolmap's Ceres adjuster as the reference
SFM_BA_NAMES: tuple[str, ...] = (*PARAMS, "colmap")


@runtime_checkable
class Parameterization(Protocol):
    """A landmark parameterization on one (prepared) BA problem.

    Attributes:
        name: its :data:`FORMS` key.
        k: residual components per observation.
        groups: column ranges ``(a, b)`` of one residual row that form one robust-loss block.
        slot_cams: (S, M) camera index of each of an observation's S camera slots.
        slot_cols: S ``(a, b)`` ranges of the 6 camera columns (dtheta, dC) each slot touches.
    """

    name: str
    k: int
    groups: tuple
    slot_cams: np.ndarray
    slot_cols: tuple

    def init_points(self) -> np.ndarray:
        """Initial point parameters (P, d) from the problem."""
        ...

    def evaluate(self, R: np.ndarray, C: np.ndarray, pts: np.ndarray, jac: bool = True,
                 factored: bool = False):
        """(residuals (M, k), res_D_point (M, k, d) or None, [res_D_cam per slot] or None)."""
        ...

    def pixel_residuals(self, R: np.ndarray, C: np.ndarray, pts: np.ndarray) -> np.ndarray:
        """Pixel residuals (M, 2) (the one cost every form reports)."""
        ...

    def retract_points(self, pts: np.ndarray, dp: np.ndarray) -> np.ndarray:
        """Point parameters after the step ``dp`` (P, d)."""
        ...

    def store(self, R: np.ndarray, C: np.ndarray, pts: np.ndarray) -> None:
        """Write the solution back into the problem (points as XYZ)."""
        ...


@runtime_checkable
class BoundedPoints(Protocol):
    def point_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower (d,), upper (d,)) bounds of each point parameter (+-inf where unbounded)."""
        ...


@runtime_checkable
class Staged(Protocol):
    def set_stage(self, theta_only: bool) -> None:
        """Switch between the first-stage residual subset and the full residuals."""
        ...


@runtime_checkable
class AnchoredJacobians(Protocol):
    anchor_cams: tuple[np.ndarray, np.ndarray] | None


def form_class(name: str) -> type:
    """The class registered as ``name`` (ValueError naming the choices otherwise)."""
    if name not in FORMS:
        raise ValueError(f"unknown BA parameterization {name!r}; choose {', '.join(PARAMS)}")
    module, _, cls = FORMS[name].rpartition(".")
    return getattr(importlib.import_module(module), cls)


def make_param(problem, options) -> Parameterization:
    """The parameterization object for ``options.param`` on ``problem``."""
    return form_class(options.param)(problem, options)
