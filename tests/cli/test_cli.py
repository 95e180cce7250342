import json
import os
import subprocess
import sys

import pytest

from polarref import __version__
from polarref.cli import main


def run_cli(*args, env=None):
    return subprocess.run([sys.executable, "-m", "polarref", *args], capture_output=True,
                          text=True, env={**os.environ, **(env or {})}, timeout=300)


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"polarref {__version__}"


@pytest.mark.parametrize("argv", [["no-such-command"], ["doctor", "--no-such-option"], []])
def test_bad_usage_exits_2(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert "usage: polarref" in capsys.readouterr().err


def test_doctor_reports_everything():
    proc = run_cli("doctor", "--json")
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    for key in ("python", "numpy", "scipy", "sympy", "mitsuba", "drjit", "pycolmap", "cv2",
                "mitsuba_variant", "mitsuba_variant_reason", "pycolmap_cuda", "data"):
        assert key in report
    assert report["broken_commands"] == {}
    assert report["mitsuba_variant"] in ("llvm_ad_rgb", "scalar_rgb")


def test_doctor_missing_data_dir(tmp_path):
    proc = run_cli("doctor", "--json", env={"POLARREF_DATA": str(tmp_path / "absent")})
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report["data"] is None
    assert "absent" in report["data_reason"]


def test_doctor_survives_missing_component(tmp_path):
    # A fake 'pycolmap' that fails to import stands in for a missing optional component.
    (tmp_path / "pycolmap.py").write_text("raise ImportError('simulated missing pycolmap')\n")
    env = {"PYTHONPATH": f"{tmp_path}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    proc = run_cli("doctor", "--json", env=env)
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report["pycolmap"].startswith("missing")
    assert report["pycolmap_cuda"].startswith("unknown")
