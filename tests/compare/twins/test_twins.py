"""Twins of the paper's datasets (Tables 1-3): presets, exact GT at reduced size, noisy priors."""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from polarref.core.geometry import Rigid3, rotation_angle_deg
from synth.config import TWINS, twin
from synth.conventions import look_at
from synth.priors import draw_priors
from synth.render import render_scene
from synth.scene import load_scene

sys.path.insert(0, str(Path(__file__).parents[2]))
from _synth_reproj import depth_reprojection  # noqa: E402


def _reduced(name: str, **extra):
    """The twin at test size: few views, small images; flight/orbit pattern kept."""
    cfg = twin(name, width=128, height=128 if name == "rosetta" else 96, spp=2, **extra)
    if name == "rosetta":  # 3 passes of 4 views instead of 16 of 41
        return dataclasses.replace(cfg, views=12, comet=dataclasses.replace(cfg.comet, step_deg=30.0,
                                                                              range_period_views=12.0))
    return dataclasses.replace(cfg, views=24 if name == "mappilot" else 30)


def test_twin_presets_match_the_papers_datasets(shared_data):
    sizes = {name: twin(name) for name in TWINS}
    assert {n: c.views for n, c in sizes.items()} == {"rosetta": 631, "poets-park": 857, "mappilot": 493}
    ros = sizes["rosetta"]
    assert ros.width >= 1024 and ros.height >= 1024 and ros.fov_deg <= 15 and ros.comet.orbit == "raster"
    assert Path(ros.mesh).name.startswith("67P") and ros.comet.fill_irradiance == 0  # one Sun
    pp, mp = sizes["poets-park"].uav, sizes["mappilot"].uav
    assert (pp.forward_overlap, pp.side_overlap) == (0.8, 0.7) and pp.oblique_fraction > 0
    assert (mp.forward_overlap, mp.side_overlap) == (0.75, 0.65) and mp.oblique_fraction == 0
    with pytest.raises(ValueError, match="rosetta"):
        twin("rosetta-x")


@pytest.fixture(scope="module")
def reduced_twins(tmp_path_factory, shared_data):
    out = {}
    for name in TWINS:
        cfg = _reduced(name)
        root = tmp_path_factory.mktemp(name)
        render_scene(cfg.scene, root, cfg)
        out[name] = (cfg, load_scene(root))
    return out


@pytest.mark.parametrize("name", list(TWINS))
def test_reduced_twin_renders_with_exact_gt(reduced_twins, name):
    cfg, scene = reduced_twins[name]
    assert len(scene.views) == cfg.views
    pairs = [(0, 1), (1, 2)] if name == "rosetta" else [(0, 1), (2, 3)]
    for i, j in pairs:
        err, n_surface = depth_reprojection(scene, i, j)
        assert len(err) > 0.1 * n_surface, (i, j, len(err), n_surface)
        assert np.mean(err) < 0.1 and np.percentile(err, 99) < 0.5, (np.mean(err), np.percentile(err, 99))
    # The priors sit beside the GT: same image order, off by about their stated sigma.
    pri = scene.meta["priors"]["views"]
    assert len(pri) == cfg.views
    gt_c = np.array([v.cam_from_world.center for v in scene.views])
    err_c = np.linalg.norm(np.array([p["center"] for p in pri]) - gt_c, axis=1)
    sig = np.linalg.norm(np.array([p["center_sigma_m"] for p in pri]), axis=1)
    assert 0.05 < np.median(err_c / sig) < 3.0


def test_rosetta_orbit_stays_on_the_lit_side(reduced_twins):
    cfg, scene = reduced_twins["rosetta"]
    assert len(scene.meta["lights"]) == 1
    sun_travel = np.array(scene.meta["lights"][0]["direction"])
    c = np.array([v.cam_from_world.center for v in scene.views]) - scene.center
    rng_m = np.linalg.norm(c, axis=1)
    phase = np.degrees(np.arccos(np.clip((c / rng_m[:, None]) @ -sun_travel, -1, 1)))
    assert phase.max() < 95.0  # never looking at the night side
    lat = np.degrees(np.arcsin(c[:, 2] / rng_m))
    assert np.ptp(lat) > 40.0 and np.ptp(rng_m) / rng_m.mean() > 0.1  # latitude and range vary


def test_poets_park_oblique_strips_are_tilted(reduced_twins):
    cfg, scene = reduced_twins["poets-park"]
    n_obl = int(round(cfg.views * cfg.uav.oblique_fraction))
    assert n_obl > 0
    axis = np.array([v.cam_from_world.R[2] for v in scene.views])  # optical axis in the world
    tilt = np.degrees(np.arccos(-axis[:, 2]))
    assert np.all(tilt[:-n_obl] < 1e-6) and np.allclose(tilt[-n_obl:], cfg.uav.oblique_strip_deg, atol=1e-6)


def _line_poses(n: int) -> list[Rigid3]:
    return [look_at(np.array([5.0 * k, 0.0, 100.0]), np.array([5.0 * k, 0.0, 0.0]), np.array([1.0, 0, 0]))
            for k in range(n)]


def test_priors_have_the_stated_noise_and_are_seeded():
    cfg = dataclasses.replace(twin("mappilot"), views=3000)
    poses = _line_poses(cfg.views)
    a, b = draw_priors(cfg, poses, np.zeros(3)), draw_priors(cfg, poses, np.zeros(3))
    assert a == b  # deterministic per seed
    other = draw_priors(dataclasses.replace(cfg, seed=1), poses, np.zeros(3))
    assert other["views"][0]["center"] != a["views"][0]["center"]
    d = np.array([v["center"] for v in a["views"]]) - np.array([p.center for p in poses])
    rms = np.sqrt((d ** 2).mean(0))
    p = cfg.priors
    assert np.allclose(rms, [p.position_sigma_m, p.position_sigma_m, p.vertical_sigma_m], rtol=0.35)
    # Drift, not white noise: consecutive errors are correlated about as stated.
    rho = np.corrcoef(d[:-1, 0], d[1:, 0])[0, 1]
    assert abs(rho - p.correlation) < 0.05
    rot = [float(rotation_angle_deg(Rigid3.from_quat(np.array(v["qvec"]), np.zeros(3)).R, q.R))
           for v, q in zip(a["views"], poses)]
    assert 0.5 * p.rotation_sigma_deg * math.sqrt(3) < np.sqrt(np.mean(np.square(rot))) < 1.5 * p.rotation_sigma_deg * math.sqrt(3)


def test_no_priors_by_default():
    from synth.config import preset

    assert draw_priors(preset("comet", "small"), _line_poses(3), np.zeros(3)) is None


def test_cli_refuses_a_twin_of_the_other_scene_kind(tmp_path, capsys):
    from polarref.cli import main

    assert main(["render", "uav", "--preset", "rosetta", "--out", str(tmp_path / "x")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "rosetta" in err[0] and "uav" in err[0]
    assert not (tmp_path / "x").exists()
