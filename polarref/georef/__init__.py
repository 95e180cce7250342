"""Georeferencing: pose priors and ground control points (formats, mapping, check points)."""
