"""Reference incremental SfM (the MOCI pipeline): one module per stage.

features -> matching -> verification -> tracks -> initial_pair -> triangulation / registration
-> mapper (with bundle adjustment) ; pipeline.run_sfm chains them, export hands our
correspondences to pycolmap.
"""

from polarref.sfm.pipeline import PRESETS, SfMConfig, SfMResult, run_sfm, with_ba

__all__ = ["run_sfm", "SfMConfig", "SfMResult", "PRESETS", "with_ba"]
