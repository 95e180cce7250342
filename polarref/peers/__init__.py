"""Other tools run as references on the same inputs (``colmap_sfm``: pycolmap's SfM)."""
