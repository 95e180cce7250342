"""Readers and writers for bundle-adjustment and ground-truth camera files.

Every reader raises :class:`FormatError` (a :class:`polarref.core.errors.PolarrefError`) naming the
file and the 1-based line of the first problem found.

Modules: :mod:`polarref.io.bal` (Bundle Adjustment in the Large), :mod:`polarref.io.parallaxba`
(ParallaxBA's Cam.txt / Feature.pmba / intrinsic_matrix.txt), :mod:`polarref.io.pvlba` (PVL-BA
four-file problems and BlocksExchange XML), :mod:`polarref.io.strecha` (Strecha ``*.camera``).
"""

from polarref.io.text import MAX_ABS_VALUE, FormatError, parse_numbers, read_lines, read_tracks

__all__ = ["MAX_ABS_VALUE", "FormatError", "parse_numbers", "read_lines", "read_tracks"]
