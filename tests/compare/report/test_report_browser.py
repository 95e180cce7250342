"""report.html in a real browser: headless Chromium (Debian's ``chromium``) over the DevTools protocol.

Skipped with the reason when no Chromium is installed (``scripts/setup.sh`` installs it as root).
The page is built from the committed comet-small metrics.json; when that file predates the 3D
view, a view built by the same code from a synthetic reconstruction (with a dense cloud) is added.
"""

import shutil

import numpy as np
import pytest

from polarref.compare import schema
from polarref.compare.report import view3d
from polarref.compare.report.browser import check_page, find_chromium
from polarref.compare.report.build import build_report
from polarref.core.data import REPO_ROOT

EXAMPLE = REPO_ROOT / "reports" / "comet-small"

pytestmark = pytest.mark.skipif(find_chromium() is None,
                                reason="no Chromium (apt-get install chromium, or set POLARREF_CHROMIUM)")


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    from test_report_layout import _aligned_pair

    if not (EXAMPLE / "metrics.json").is_file():
        pytest.skip(f"no committed example at {EXAMPLE}")
    d = tmp_path_factory.mktemp("browser") / "comet-small"
    d.mkdir()
    shutil.copy(EXAMPLE / "metrics.json", d / "metrics.json")
    m = schema.load(d / "metrics.json")
    if m.view3d is None:
        est, truth = _aligned_pair()
        m.view3d = view3d.new_view(truth, truth.cameras[1], None, seed=0)
        for r in m.methods[:3]:
            view3d.add_method(m.view3d, r.name, r.label, est, truth, 0)
        _, X = truth.points_array()
        view3d.add_dense(m.view3d, m.methods[0].name, m.methods[0].label,
                         np.repeat(X, 10, 0) + np.random.default_rng(0).normal(scale=0.02, size=(10 * len(X), 3)), None)
        schema.save(m, d / "metrics.json")
    build_report(d)
    return d / "report.html"


def test_report_page_in_headless_chromium(page):
    c = check_page(page, 1280, 800, drag=True)
    assert c.console_errors == []
    assert c.network_requests == []                       # loaded with the network emulated offline
    assert c.images >= 5 and c.broken_images == 0
    t = c.summary_table
    assert t is not None and t.visible and t.width > 300
    assert 0 <= t.top < t.bottom <= 800                   # the whole main table above the fold
    v = c.canvas
    assert v is not None and v.ready and v.drawn > 100
    assert v.dark_pixels > 1000 and v.variance > 10       # not a blank canvas
    assert c.canvas_after_drag is not None and c.canvas_after_drag.hash != v.hash  # orbiting redraws
    assert c.canvas_after_drag.dark_pixels > 1000


def test_the_checks_catch_a_broken_page(tmp_path):
    """Negative control: a remote image, a script error and no summary are all reported."""
    bad = tmp_path / "bad.html"
    bad.write_text('<!DOCTYPE html><html><body><img src="http://192.0.2.1/x.png">'
                   "<script>undefinedFunction()</script></body></html>")
    c = check_page(bad, 1280, 800)
    assert c.broken_images == 1 and c.summary_table is None and c.canvas is None
    assert any("undefinedFunction" in e for e in c.console_errors)
    assert c.network_requests == ["http://192.0.2.1/x.png"]


def test_screenshot_command_writes_the_top_of_the_page(tmp_path):
    import cv2
    from test_report_build import _write, synthetic_metrics

    from polarref.cli import main

    d = _write(tmp_path, synthetic_metrics())
    assert main(["report", str(d), "--screenshot"]) == 0
    img = cv2.imread(str(d / "screenshot.png"))
    assert img.shape == (800, 1280, 3)
    assert img.std() > 5                                  # text and table, not an empty frame
