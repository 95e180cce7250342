import os
import shutil

import pytest
from hypothesis import settings

from polarref.core.data import data_root

# CI must never see a failure that depends on the run: Hypothesis draws the same examples each time
settings.register_profile("polarref", derandomize=True)
settings.load_profile("polarref")


@pytest.fixture(scope="session")
def shared_data():
    """The reference data folder; tests needing it skip with the reason when absent."""
    root = data_root()
    if root is None:
        where = os.environ.get("POLARREF_DATA") or "../shared/data beside the repo root"
        pytest.skip(f"reference data not found ({where}); set $POLARREF_DATA")
    return root


# ---- ParallaxBA's fake pile (shared data): one reading for every test that uses it -------------
@pytest.fixture(scope="session")
def fakepile_files(shared_data):
    """The fake pile as its files read (``io.parallaxba.ParallaxBAProblem``); shared: do not modify."""
    from polarref.io.parallaxba import read_parallaxba

    return read_parallaxba(shared_data / "parallaxba_fakepile")


@pytest.fixture(scope="session")
def fakepile(shared_data):
    """The fake pile as a prepared ``BAProblem`` (``ba.loaders``, ``ba.prepare``); shared: solve a copy."""
    from polarref.ba import prepare
    from polarref.ba.loaders import load_problem

    p, _ = load_problem(str(shared_data / "parallaxba_fakepile"))
    prepare(p)
    return p


# ---- rendered synthetic scenes (owner: synth/rendering) --------------------------------------
def _cached_scene(scene: str, preset_name: str, seed: int = 0):
    """Render (once, resumably) into the shared cache and return the scene folder Path.

    The folder name carries a short hash of all parameters and of the synth code, so a change
    in either renders a new folder; a file lock serializes concurrent test sessions.
    """
    import fcntl

    from polarref.core.data import cache_root
    from synth.config import preset
    from synth.render import code_version, render_scene

    cfg = preset(scene, preset_name, seed=seed)
    root = cache_root() / "scenes"
    root.mkdir(parents=True, exist_ok=True)
    out = root / f"{scene}-{preset_name}-seed{seed}-{cfg.digest(code_version())}"
    with open(root / f".{out.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        render_scene(scene, out, cfg)
    return out


@pytest.fixture(scope="session")
def comet_small_scene():
    """Folder of the small comet scene (12 views, 320x240), see synth/scene.py for the layout."""
    return _cached_scene("comet", "small")


@pytest.fixture
def small_copy(comet_small_scene, tmp_path):
    """The first 6 views of the small comet scene (images + gt) in a writable folder."""
    dst = tmp_path / "scene"
    (dst / "images").mkdir(parents=True)
    for p in sorted((comet_small_scene / "images").iterdir())[:6]:
        shutil.copy(p, dst / "images" / p.name)
    shutil.copytree(comet_small_scene / "gt", dst / "gt")
    return dst


@pytest.fixture(scope="session")
def uav_small_scene():
    """Folder of the small UAV scene (12 views, 320x240), see synth/scene.py for the layout."""
    return _cached_scene("uav", "small")


# ---- test folders on sys.path (issue 29: tests mirror the packages) ----
# Tests live in one folder per package (tests/ba, tests/compare/report, ...). Test modules import
# helpers from one another by module name (``from test_report_build import synthetic_metrics``,
# ``from _dense_scene import Sphere``); pytest puts only a test file's own folder on sys.path, so
# every test folder is put there once, here (test file names are unique across folders).
import sys as _sys  # noqa: E402
from pathlib import Path as _Path  # noqa: E402

_HERE = _Path(__file__).resolve().parent
for _folder in [_HERE] + sorted(p for p in _HERE.rglob("*") if p.is_dir() and not p.name.startswith((".", "_"))):
    if str(_folder) not in _sys.path:
        _sys.path.append(str(_folder))
