"""Synthetic scenes with a known radial distortion (synth/distort.py), and self-calibration on
them: refined k1 and focal length against the exact values, for every BA parameterization."""

import json

import numpy as np
import pytest

from synth.distort import distort, resample, undistort
from polarref.ba.parameterization import PARAMS as FORM_NAMES

K1, K2 = -0.12, 0.02  # the rendered lens
F_START = 1.05  # focal length prior 5 % long; distortion prior 0


def test_undistort_inverts_distort():
    rng = np.random.default_rng(0)
    xu, yu = rng.uniform(-0.6, 0.6, (2, 1000))
    xd, yd = distort(xu, yu, K1, K2)
    x2, y2 = undistort(xd, yd, K1, K2)
    np.testing.assert_allclose(np.c_[x2, y2], np.c_[xu, yu], atol=1e-13)
    assert np.abs(xd - xu).max() > 0.01  # the lens really moves points


def test_resample_puts_content_at_the_distorted_position():
    """A bright dot rendered (undistorted) at a known 3D direction lands where the RADIAL model
    projects that direction; ignoring the distortion misses it by pixels."""
    from polarref.camera import Camera

    f, W, H = 300.0, 320, 240
    big = np.zeros((400, 480, 1), np.float32)
    xu, yu = 0.45, -0.3  # a direction near the corner
    bx, by = xu * f + 240.0, yu * f + 200.0  # its position in the big render (pixel coords)
    yy, xx = np.mgrid[0:400, 0:480] + 0.5
    big[..., 0] = np.exp(-((xx - bx) ** 2 + (yy - by) ** 2) / (2 * 1.5**2))
    img = resample(big, W, H, f, K1, K2)
    v, u = np.unravel_index(np.argmax(img), img.shape[:2])
    w = img[v - 3:v + 4, u - 3:u + 4]
    cu = (w * (np.arange(u - 3, u + 4) + 0.5)[None, :]).sum() / w.sum()
    cv = (w * (np.arange(v - 3, v + 4) + 0.5)[:, None]).sum() / w.sum()
    expect = Camera("RADIAL", W, H, [f, W / 2, H / 2, K1, K2]).project(np.array([xu, yu, 1.0]))
    assert np.hypot(cu - expect[0], cv - expect[1]) < 0.3
    pinhole = np.array([f * xu + W / 2, f * yu + H / 2])
    assert np.hypot(cu - pinhole[0], cv - pinhole[1]) > 3.0


def _distorted_scene(scene: str):
    """Small comet, or small UAV with the camera tilted 30 degrees forward: the nadir block is
    degenerate for self-calibration (flat ground, parallel axes: focal length trades against
    altitude; measured: focal +291 %, k1 = -1.6 from a 5 % focal error)."""
    import dataclasses
    import fcntl

    from polarref.core.data import cache_root
    from synth.config import preset
    from synth.distort import _digest, render_distorted_scene

    cfg = preset(scene, "small")
    name = scene
    if scene == "uav":
        cfg = dataclasses.replace(cfg, uav=dataclasses.replace(cfg.uav, oblique_deg=30.0))
        name = "uav-oblique30"
    root = cache_root() / "scenes"
    root.mkdir(parents=True, exist_ok=True)
    out = root / f"{name}-small-distorted-seed0-{_digest(cfg, K1, K2)}"
    with open(root / f".{out.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        render_distorted_scene(scene, out, cfg, K1, K2)
    return out


@pytest.fixture(scope="module", params=["comet", "uav"])
def distorted(request):
    pytest.importorskip("mitsuba")
    return _distorted_scene(request.param)


def _depth_consistency(root, i, j, k1, k2):
    """Median relative depth disagreement between views i and j through the RADIAL model with
    (k1, k2), over pixels that agree within 1 % (co-visible)."""
    from scipy.ndimage import map_coordinates

    from polarref.camera import Camera
    from synth.scene import load_scene

    s = load_scene(root)
    c = s.camera
    cam = Camera("RADIAL", c.width, c.height, [*c.params[:3], k1, k2])
    di, dj = s.depth(i), s.depth(j)
    v, u = np.nonzero(di > 0)
    ray = cam.unproject(np.stack([u + 0.5, v + 0.5], 1))
    Xw = s.views[i].cam_from_world.inverse().apply(ray / ray[:, 2:3] * di[v, u][:, None])
    Xj = s.views[j].cam_from_world.apply(Xw)
    uv = cam.project(Xj) - 0.5
    ok = np.isfinite(uv).all(1) & (uv.min(1) >= 1) & (uv[:, 0] <= c.width - 2) & (uv[:, 1] <= c.height - 2)
    d = map_coordinates(dj.astype(float), [uv[ok, 1], uv[ok, 0]], order=1)
    rel = np.abs(d - Xj[ok, 2]) / Xj[ok, 2]
    return float(np.median(rel[rel < 0.01]))


@pytest.mark.slow
def test_distorted_depth_is_consistent_with_the_radial_camera(distorted):
    from synth.scene import load_scene

    cam = load_scene(distorted).camera
    assert cam.model == "RADIAL" and cam.params[3:].tolist() == [K1, K2]
    good = _depth_consistency(distorted, 0, 1, K1, K2)
    bad = _depth_consistency(distorted, 0, 1, 0.0, 0.0)  # the lens ignored
    assert good < 5e-5 and bad > 3 * good


@pytest.mark.slow
@pytest.mark.parametrize("ba", list(FORM_NAMES))
def test_refined_distortion_matches_the_rendered_lens(distorted, ba, tmp_path, monkeypatch):
    """Start: focal 5 % long, k1 = k2 = 0 (baseline: k1 off by 0.12). Bounds (set after a
    first measurement on the comet, see notes/i19.md): |k1 - K1| < 0.02, focal within 2.5 %,
    and the lens' radial profile f r D(r) within 4 px of the truth out to the image corner
    (baseline: about 16 px; measured on the comet: euclidean/parallax 0.8, polar 1.9,
    angular 3.0 px)."""
    from polarref.cli import main
    from synth.scene import load_scene

    monkeypatch.setenv("POLARREF_CACHE", str(tmp_path / "cache"))
    cam = load_scene(distorted).camera
    f, cx, cy = (float(v) for v in cam.params[:3])
    out = tmp_path / "out"
    assert main(["sfm", str(distorted), "--out", str(out), "--preset", "small", "--ba", ba,
                 "--camera", f"RADIAL:{f * F_START!r},{cx!r},{cy!r},0,0", "--refine", "focal,dist"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    rep = m["cameras"][0]
    fr, _, _, k1, k2 = rep["refined"]
    assert abs(F_START - 1) > 0.025 and abs(K1) > 0.02  # the start fails the bounds
    assert abs(k1 - K1) < 0.02
    assert rep["focal_error_rel"] < 0.025
    r = np.linspace(0, np.hypot(cx, cy) / f, 50)  # normalized radius out to the corner
    prof = fr * r * (1 + k1 * r**2 + k2 * r**4) - f * r * (1 + K1 * r**2 + K2 * r**4)
    print(f"{distorted.name} {ba}: f {fr:.3f} (err {100 * rep['focal_error_rel']:.3f} %), k1 {k1:.5f}, "
          f"k2 {k2:.5f}, profile max {np.abs(prof).max():.3f} px, rotation error "
          f"{m['metrics']['gt']['rotation_error_deg_mean']:.4f} deg")
    assert np.abs(prof).max() < 4.0
    assert m["metrics"]["registered_images"] == 12
