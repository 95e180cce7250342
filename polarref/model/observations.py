"""The one observation type: which image sees which point where.

Every flat observation list in polarref (a bundle-adjustment problem, the BAL / ParallaxBA /
PVL-BA readers, the reprojection metrics) is an :class:`Observations`: three parallel arrays
indexed by observation. Indices are 0-based positions into the owner's image and point arrays,
not ids; ``uv`` is in the owner's pixel convention (COLMAP's everywhere except BAL's raw
centred coordinates, which :class:`polarref.io.bal.BALProblem` documents).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from polarref.core.errors import PolarrefError


class ObservationsError(PolarrefError):
    """Observation arrays of the wrong shape, with NaN pixels, or with out-of-range indices."""


@dataclass(eq=False)
class Observations:
    """M observations as parallel arrays.

    Attributes:
        image: (M,) int64 image (camera) index of each observation.
        point: (M,) int64 point index of each observation.
        uv: (M, 2) float64 observed pixel.
    """

    image: np.ndarray
    point: np.ndarray
    uv: np.ndarray

    @staticmethod
    def from_arrays(image, point, uv) -> "Observations":
        """Coerce to int64 / float64 arrays and check the shapes agree (not the values)."""
        image = np.asarray(image)
        point = np.asarray(point)
        uv = np.asarray(uv, dtype=np.float64)
        if uv.size == 0:
            uv = uv.reshape(0, 2)
        if image.ndim != 1 or point.ndim != 1 or uv.ndim != 2 or uv.shape[1] != 2:
            raise ObservationsError(f"observations: expected image (M,), point (M,), uv (M, 2); got "
                                    f"{image.shape}, {point.shape}, {uv.shape}")
        if not (len(image) == len(point) == len(uv)):
            raise ObservationsError(f"observations: lengths differ (image {len(image)}, point "
                                    f"{len(point)}, uv {len(uv)})")
        for name, a in (("image", image), ("point", point)):
            if a.size and not np.issubdtype(a.dtype, np.integer):
                if not (np.isfinite(a).all() and np.all(a == np.round(a))):
                    raise ObservationsError(f"observations: {name} indices are not integers")
        return Observations(image.astype(np.int64), point.astype(np.int64), uv)

    @staticmethod
    def empty() -> "Observations":
        return Observations(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2)))

    def __len__(self) -> int:
        return len(self.image)

    def __eq__(self, other: object) -> bool:
        """Exactly equal arrays (NaN pixels never compare equal)."""
        if not isinstance(other, Observations):
            return NotImplemented
        return (np.array_equal(self.image, other.image) and np.array_equal(self.point, other.point)
                and np.array_equal(self.uv, other.uv))

    __hash__ = None  # mutable arrays

    def validate(self, num_images: int | None = None, num_points: int | None = None,
                 finite: bool = True) -> "Observations":
        """Raise :class:`ObservationsError` naming the first problem; return ``self``.

        Checks shapes, indices in ``0..num_images-1`` / ``0..num_points-1`` (when given) and,
        with ``finite``, that every pixel is finite.
        """
        Observations.from_arrays(self.image, self.point, self.uv)
        for name, idx, n in (("image", self.image, num_images), ("point", self.point, num_points)):
            if len(idx) and idx.min() < 0:
                k = int(np.argmax(idx < 0))
                raise ObservationsError(f"observation {k}: negative {name} index {int(idx[k])}")
            if n is not None and len(idx) and idx.max() >= n:
                k = int(np.argmax(idx >= n))
                raise ObservationsError(f"observation {k}: {name} index {int(idx[k])} out of range "
                                        f"0..{n - 1}")
        if finite and len(self.uv) and not np.isfinite(self.uv).all():
            k = int(np.argmax(~np.isfinite(self.uv).all(1)))
            raise ObservationsError(f"observation {k}: non-finite pixel {self.uv[k].tolist()}")
        return self

    # ---- selection -----------------------------------------------------------------------
    def select(self, which) -> "Observations":
        """The observations picked by a boolean mask (M,) or an index array, in that order."""
        which = np.asarray(which)
        return Observations(self.image[which], self.point[which], self.uv[which])

    def copy(self) -> "Observations":
        return Observations(self.image.copy(), self.point.copy(), self.uv.copy())

    def of_image(self, i: int) -> np.ndarray:
        """Indices (K,) of the observations of image ``i``, in input order."""
        return np.flatnonzero(self.image == i)

    def of_point(self, j: int) -> np.ndarray:
        """Indices (K,) of the observations of point ``j``, in input order."""
        return np.flatnonzero(self.point == j)

    def by_image(self) -> list[tuple[int, np.ndarray]]:
        """(image index, its observations' indices ascending) per observed image, ascending;
        negative image indices (no image) are left out. For work done image by image."""
        order = np.argsort(self.image, kind="stable")
        images, starts = np.unique(self.image[order], return_index=True)
        ends = np.r_[starts[1:], len(order)]
        return [(int(i), order[a:b]) for i, a, b in zip(images, starts, ends) if i >= 0]

    def order_by_point(self) -> np.ndarray:
        """Permutation (M,) sorting by point, then image (the solver's layout)."""
        return np.lexsort((self.image, self.point))

    def slot_in_image(self, num_images: int) -> np.ndarray:
        """(M,) position of each observation among its image's observations (input order):
        the keypoint index when an image's keypoints are its observations."""
        order = np.argsort(self.image, kind="stable")
        starts = np.searchsorted(self.image[order], np.arange(num_images + 1))
        slot = np.empty(len(self), np.int64)
        for i in range(num_images):
            slot[order[starts[i]:starts[i + 1]]] = np.arange(starts[i + 1] - starts[i])
        return slot
