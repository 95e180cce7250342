"""polarref: reference-and-verification suite for polar-coordinate photogrammetry."""

__version__ = "0.1.0"
