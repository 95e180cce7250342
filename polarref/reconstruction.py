"""Moved to :mod:`polarref.model` (issue 11); this name stays so existing imports keep working."""

from polarref.model.reconstruction import Image, Point3D, Reconstruction

__all__ = ["Image", "Point3D", "Reconstruction"]
