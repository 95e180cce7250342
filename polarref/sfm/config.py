"""Every setting of the SfM pipeline in one frozen record, and its named presets."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from polarref.sfm import features as F
from polarref.sfm.mapper import MapperConfig
from polarref.sfm.matching import MatchConfig
from polarref.sfm.state import TriangulationConfig
from polarref.sfm.verification import VerifyConfig


@dataclass(frozen=True)
class SfMConfig:
    """Every setting of the pipeline; change with ``dataclasses.replace``."""

    features: F.FeatureConfig = field(default_factory=F.FeatureConfig)
    matching: MatchConfig = field(default_factory=MatchConfig)
    verification: VerifyConfig = field(default_factory=VerifyConfig)
    triangulation: TriangulationConfig = field(default_factory=TriangulationConfig)
    mapper: MapperConfig = field(default_factory=MapperConfig)
    track_conflicts: str = "drop"   # track with 2 keypoints of one image: "drop" it or "split" it (tracks.py);
    #                                 split: more points, rotations within +-0.005 deg of drop on our scenes
    use_cache: bool = True          # reuse features/matches from cache_dir
    camera_mode: str = "per-model"  # EXIF cameras (no camera given): per-model | single | per-image
    cache_dir: str = ""             # "" = polarref.core.data.cache_root() / "sfm"
    # images left out of a model that still share verified pairs start another model, up to
    # this many models in all (COLMAP's incremental mapper does the same; 1 = one model only)
    max_models: int = 10
    # threads of the front end (features, matching, verification) in this process; 0 = every
    # core it may use (polarref.sfm.frontend; the results do not depend on it)
    threads: int = 0
    # features.max_image_size 0 asked for on purpose (--max-image-size 0): full resolution even
    # for photo folders and images over 3200 px, which sfm/budget.py otherwise detects at 3200 px
    full_size: bool = False


PRESETS: dict[str, SfMConfig] = {
    "default": SfMConfig(),
    # 12-view 320x240 test scenes: fewer features is plenty.
    # (contrast 0.02: 0.01 gave 0.153 vs 0.132 deg on the small comet, though 0.012 vs 0.018 on the small UAV)
    "small": SfMConfig(features=F.FeatureConfig(max_num_features=2048, contrast_threshold=0.02)),
    # Strecha fountain (3072x2048): detect at 1024 px (keypoints rescaled to full resolution).
    "fountain": SfMConfig(features=F.FeatureConfig(max_num_features=8192, contrast_threshold=0.02,
                                                   max_image_size=1024)),
}


def with_ba(config: SfMConfig, ba: str) -> SfMConfig:
    return dataclasses.replace(config, mapper=dataclasses.replace(config.mapper, ba=ba))
