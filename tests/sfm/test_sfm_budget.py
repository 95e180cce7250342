"""Image size and feature budget (sfm.budget.choose): one rule for photo folders, calibrated
scenes and images too large for SIFT's memory; the CLI only refuses a size that does not fit."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import pytest

import polarref.commands.sfm as S
from polarref.core.errors import PolarrefError
from polarref.sfm import budget as B
from polarref.sfm.config import SfMConfig
from polarref.sfm.features import FeatureConfig

SMALL = [(320, 240)] * 3
BIG = SMALL + [(6000, 4000)]


def _choose(features: FeatureConfig, sizes, photos=True, full_size=False):
    return B.choose(features, FeatureConfig(), photos=photos, full_size=full_size, sizes=sizes)


def test_feature_budget_scales_with_the_image_size():
    assert B.scaled_features(3200) == 8192 and B.scaled_features(0) == 8192
    assert B.scaled_features(1600) == 8192 and B.scaled_features(6400) == 16384
    cfg, rule = _choose(FeatureConfig(), SMALL)
    assert (cfg.max_image_size, cfg.max_num_features) == (3200, 8192) and "pycolmap" in rule
    cfg, rule = _choose(FeatureConfig(max_image_size=1600), BIG)
    assert (cfg.max_image_size, cfg.max_num_features) == (1600, 8192) and "1600 given" in rule
    cfg, rule = _choose(FeatureConfig(max_image_size=4800), BIG)
    assert cfg.max_num_features == 12288 and "linear in the side above" in rule
    # asked above the largest image: the budget of the side SIFT really runs on
    assert _choose(FeatureConfig(max_image_size=9600), BIG)[0].max_num_features == 15360
    mine = FeatureConfig(max_num_features=100, max_image_size=1600)
    assert _choose(mine, BIG) == (mine, "as configured")
    rec = B.describe(FeatureConfig(max_image_size=1000), "x", [(2000, 1000), (800, 600)], [10, 30])
    assert (rec.mean_detection_side, rec.mean_keypoints) == (900.0, 20.0)


def test_large_photo_without_a_size_gets_pycolmaps_rule_not_a_given_size(caplog):
    """The stop-38 bug: the CLI's memory bound set 3200 px first, and the photo rule then read it
    as '--max-image-size 3200 given'."""
    args = _parse([])
    cfg = S._config(args)
    got, rule = B.choose(cfg.features, SfMConfig().features, photos=True, full_size=cfg.full_size, sizes=BIG)
    assert (got.max_image_size, got.max_num_features) == (3200, 8192)
    assert rule.startswith("photos: pycolmap's") and "given" not in rule
    assert caplog.text == ""  # pycolmap's own default, not news
    # --max-image-size 0: full size as asked, budget scaled with the largest side (6000 px)
    cfg = S._config(_parse(["--max-image-size", "0"]))
    got, rule = B.choose(cfg.features, SfMConfig().features, photos=True, full_size=cfg.full_size, sizes=BIG)
    assert (got.max_image_size, got.max_num_features) == (0, 15360) and "full size asked" in rule
    # --max-image-size 3200 given: the same numbers, and the rule says it was given
    cfg = S._config(_parse(["--max-image-size", "3200"]))
    got, rule = B.choose(cfg.features, SfMConfig().features, photos=True, full_size=cfg.full_size, sizes=BIG)
    assert (got.max_image_size, got.max_num_features) == (3200, 8192) and "3200 given" in rule


def test_calibrated_scene_bounded_only_above_3200_px(caplog):
    small = FeatureConfig(max_num_features=2048)
    assert _choose(small, SMALL, photos=False) == (small, "as configured")  # nothing changes
    with caplog.at_level(logging.WARNING):
        got, rule = _choose(small, BIG, photos=False)
    assert got.max_image_size == 3200 and got.max_num_features == 2048 and "SIFT memory" in rule
    assert "1 image(s) larger than 3200 px (largest side 6000 px)" in caplog.text
    assert _choose(small, BIG, photos=False, full_size=True) == (small, "as configured")
    # photos with other settings changed: the same memory bound
    assert _choose(small, BIG)[0].max_image_size == 3200


def _parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    S.add_arguments(p)
    return p.parse_args(["d", "--out", "o", *argv])


def _png(path: Path, w: int, h: int) -> Path:
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    Image.new("L", (w, h)).save(path)  # only the header is read
    return path


def test_size_that_does_not_fit_is_refused_with_one_that_does(tmp_path, monkeypatch):
    paths = [_png(tmp_path / f"{i}.png", 320, 240) for i in range(3)] + [_png(tmp_path / "big.png", 6000, 4000)]
    assert B.header_sizes(tmp_path) == [(320, 240)] * 3 + [(6000, 4000)]
    monkeypatch.setattr(S, "_available_bytes", lambda: 2_000_000_000)
    S._refuse_unfitting_size(None, paths)  # no size asked: the budget rule bounds it
    S._refuse_unfitting_size(2000, paths)  # 235 B/px x 2000 x 1333: 0.63 GB fits in 1.6
    with pytest.raises(PolarrefError, match=r"big.png: a 6000x4000 image needs about 5.6 GB for SIFT at full "
                                            r"size.* use --max-image-size 3\d{3} or less"):
        S._refuse_unfitting_size(0, paths)
    with pytest.raises(PolarrefError, match=r"about 2.5 GB for SIFT at 4000 px.* use --max-image-size 3\d{3} "):
        S._refuse_unfitting_size(4000, paths)
    monkeypatch.setattr(S, "_available_bytes", lambda: 64_000_000_000)
    S._refuse_unfitting_size(0, paths)  # it fits: full size as asked
