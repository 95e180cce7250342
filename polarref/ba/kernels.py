"""Compiled kernels (numba) for the per-iteration sums of the bundle adjuster.

The numpy path (schur.py, anchor_terms.py, the forms' evaluate) is the reference; these
kernels compute the same sums in one pass over observations or entry pairs, without the
gathers that numpy needs to vectorize them: the entry-pair Schur products, the slot Gram
blocks of U, the W / g blocks, the forms' rays and Jacobian chains. Sums are taken in a
different order than in numpy, so results agree to rounding (tests: 1e-9 relative).
``BAOptions.kernels`` picks the path; "auto" uses these when numba imports. Everything runs on
one thread (no ``parallel=True``): the bench compares against one-thread Ceres.

The kernels live in kernels_jit.py (normal equations, Schur), forms_jit.py (the forms'
residuals and Jacobians) and row_map_jit.py (polar's mapped view-angle row) and are reached
as attributes of this module (``kernels.schur_dense``), so numba is imported only when a solve uses them. Compiled code is
cached on disk (``cache=True``, numba's ``__pycache__``); the first call in a fresh
environment compiles (seconds), so the bench calls :func:`warm_up` before timing.
"""

from __future__ import annotations

import logging
import time

import numpy as np

log = logging.getLogger(__name__)

_STATE: dict = {}


def available() -> bool:
    """Whether the compiled kernels import (numba installed and working); cached."""
    if "ok" not in _STATE:
        try:
            from polarref.ba import kernels_jit  # noqa: F401
            _STATE["ok"] = True
        except Exception as exc:  # a broken numba install falls back, it does not crash
            log.debug("BA kernels unavailable (%s: %s); numpy path", type(exc).__name__, exc)
            _STATE["ok"] = False
    return _STATE["ok"]


def numba_version() -> str | None:
    """The installed numba's version (None when the kernels are unavailable)."""
    if not available():
        return None
    import numba
    return numba.__version__


def use_kernels(choice: str) -> bool:
    """Whether a solve with ``BAOptions.kernels == choice`` runs the compiled kernels."""
    if choice == "numpy":
        return False
    if choice == "numba" and not available():
        from polarref.core.errors import PolarrefError
        raise PolarrefError("BA kernels 'numba' requested but numba does not import "
                            "(pip install numba, or use kernels='numpy')")
    return available()


def __getattr__(name: str):
    if name.startswith("_"):
        raise AttributeError(name)
    from polarref.ba import forms_jit, kernels_jit, row_map_jit
    for mod in (kernels_jit, forms_jit, row_map_jit):
        if hasattr(mod, name):
            return getattr(mod, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def warm_up() -> float:
    """Compile (or load from the disk cache) every kernel on tiny inputs; seconds taken."""
    if not available():
        return 0.0
    from polarref.ba.forms_jit import (angular_obs, angular_rows, best_associates, euclidean_jacobians,
                                       euclidean_rays, parallax_jacobians, parallax_points,
                                       parallax_rays, parallax_xyz, pinhole_view_angles,
                                       pixel_rows, theta_row_into)
    from polarref.ba.kernels_jit import (add_cross, back_substitute_rhs, build_anchored,
                                         build_observer, count_behind, mark_pairs, pair_blocks,
                                         pair_keys, point_solve, point_sums,
                                         schur_blocks, schur_dense, slot_gram, slot_w_g)
    t = time.perf_counter()
    f, i = np.zeros, np.zeros
    one = np.zeros(1, np.int64)
    J6, Jp, r = f((1, 2, 6)), f((1, 2, 3)), f((1, 2))
    U, W, g = f((1, 6, 6)), f((1, 6, 3)), f((1, 6))
    z3 = np.zeros((3, 1), np.int64)
    x3 = f((1, 3))
    for cross in (False, True):
        schur_dense(W, f((1, 3, 3)), f((1, 3)), np.array([0, 1], np.int64), one, one, f((6, 6)),
                    g, cross, f((1, 6, 4)), x3, f((1, 3, 3)), z3, np.array([0, 1], np.int64))
    b01 = np.array([0, 1], np.int64)
    pair_keys(b01, one, 1, i(1, np.int64))
    mark_pairs(b01, one, 1, i(1, bool))
    one32 = i(1, np.int32)
    pair_blocks(b01, one, 1, one32, i(1, np.int32))
    schur_blocks(W, f((1, 3, 3)), f((1, 3)), b01, one, one32, U, g, one)
    slot_gram(J6, 0, J6, 0, one, -np.ones(1, np.int64), U)
    slot_gram(J6, 0, Jp, 3, one, one, U)
    slot_w_g(J6, 0, Jp, r, one, one, W, g)
    slot_w_g(Jp, 3, Jp, r, one, one, W, g)
    build_observer(J6, Jp, r, one, one, one, W, g, U)
    add_cross(f((6, 6)), f((1, 6, 4)), x3, f((1, 3, 3)), np.array([0, 1], np.int64), one, one, z3,
              np.array([0, 1], np.int64))
    point_sums(Jp, r, one, f((1, 3, 3)), f((1, 3)))
    back_substitute_rhs(W, g, one, one, i((1, 3)))
    point_solve(f((1, 3)), f((1, 3, 3)))
    for assign in (True, False):
        build_anchored(J6, r, x3, Jp, r, z3, z3, np.array([0, 1], np.int64), W, g, U,
                       f((1, 6, 4)), f((1, 3, 3)), assign)
    R, x1 = np.eye(3)[None].copy(), f(1)
    euclidean_jacobians(Jp, euclidean_rays(R, x3, x3, one, one), R, one)
    parallax_points(R, x3, x3, one, one, True)
    best_associates(one, one, x3, x3)
    count_behind(np.eye(3)[None].copy(), x3, x3, one, one)
    pinhole_view_angles(f((1, 6)), f((1, 2)))
    parallax_rays(R, x3, one, one, x3, x1, x3)
    parallax_xyz(R, x3, x3, one, one, 1e8)
    for dense in (True, False):
        parallax_jacobians(Jp, x3, R, x3, one, one, x3, x3, x1, x1, x1, x3, f((1, 3, 2)), dense)
    i8 = np.ones(1, np.int8)
    cs = f((1, 4))
    angular_obs(R, x3, one, one, x3, x3, x1, x1, x3, x1, f((1, 3, 2)), r, cs, f((1, 2, 2)), x1, i8)
    for jac in (True, False):
        angular_rows(x3, r, cs, f((1, 2, 2)), x1, i8, jac)
        for k in (2, 3):
            res3, J3 = pixel_rows(x3, f((1, 6)), r, k, jac)
        theta_row_into(x3, x1, x1, res3, J3, jac)
    from polarref.ba import row_map_jit, schur_panel_jit, schur_sparse_jit, xspace_jit
    row_map_jit.warm_up()
    schur_panel_jit.warm_up()
    xspace_jit.warm_up()
    schur_sparse_jit.warm_up()
    dt = time.perf_counter() - t
    log.debug("BA kernels ready in %.2f s", dt)
    return dt
