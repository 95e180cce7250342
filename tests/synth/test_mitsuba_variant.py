import json
import os
import subprocess
import sys

import numpy as np
import pytest

from synth import mitsuba_variant as mv

pytest.importorskip("mitsuba")


def test_llvm_major_parses_debian_names():
    assert mv.llvm_major("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1") == 19
    assert mv.llvm_major("/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1") == 15
    assert mv.llvm_major("/usr/lib/llvm-17/lib/libLLVM-17.so") == 17
    assert mv.llvm_major("libfoo.so") is None


def test_missing_llvm_path_falls_back(monkeypatch):
    monkeypatch.delenv("POLARREF_MITSUBA_VARIANT", raising=False)
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", "/definitely/missing/libLLVM.so.19.1")
    choice = mv.choose_variant()
    assert choice.variant == mv.SCALAR
    assert "does not exist" in choice.reason


def test_forced_scalar_is_honoured(monkeypatch):
    monkeypatch.setenv("POLARREF_MITSUBA_VARIANT", "scalar_rgb")
    assert mv.choose_variant().variant == "scalar_rgb"


def test_old_llvm_is_probed_not_trusted(monkeypatch):
    # libLLVM 14/15 abort drjit; the probe must run in a child and report failure, not kill us.
    old = [p for p in ("/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1",
                       "/usr/lib/x86_64-linux-gnu/libLLVM-14.so.1") if os.path.isfile(p)]
    if not old:
        pytest.skip("no libLLVM 14/15 on this machine to probe")
    ok, why = mv.probe(mv.LLVM, old[0], timeout=120)
    assert not ok and "failed" in why


def test_fallback_renders_and_doctor_says_so():
    env = {**os.environ, "DRJIT_LIBLLVM_PATH": "/definitely/missing/libLLVM.so.19.1"}
    env.pop("POLARREF_MITSUBA_VARIANT", None)
    code = ("from synth.mitsuba_variant import load_mitsuba\n"
            "mi, c = load_mitsuba()\n"
            "s = mi.load_dict({'type': 'scene', 'integrator': {'type': 'direct'}, 'sensor': {'type': 'perspective',"
            " 'film': {'type': 'hdrfilm', 'width': 4, 'height': 4}}, 'l': {'type': 'constant'}})\n"
            "import numpy as np; img = np.array(mi.render(s, spp=1, seed=0))\n"
            "print(\"VARIANT\", mi.variant())\n")
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "VARIANT scalar_rgb" in proc.stdout, proc.stdout
    proc = subprocess.run([sys.executable, "-m", "polarref", "doctor", "--json"], env=env,
                          capture_output=True, text=True, timeout=300)
    report = json.loads(proc.stdout)
    assert report["mitsuba_variant"] == "scalar_rgb"
    assert "does not exist" in report["mitsuba_variant_reason"]


def test_child_process_reports_the_choice_of_its_parent(monkeypatch):
    """load_mitsuba hands DRJIT_LIBLLVM_PATH to child processes (Dask workers, isolated methods);
    their scene.json must still name the origin the parent saw, or a render's metadata depends on
    the process that wrote it (seen: serial vs Dask renders differing in scene.json only)."""
    from polarref.core.data import REPO_ROOT

    monkeypatch.delenv("POLARREF_MITSUBA_VARIANT", raising=False)
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    monkeypatch.delenv(mv._FOUND_BY_US, raising=False)
    monkeypatch.setattr(mv, "_CHOICE", None)
    parent = mv.choose_variant()
    if parent.llvm_path is None:
        pytest.skip(f"no LLVM variant here ({parent.reason}); nothing is handed to children")
    monkeypatch.setattr(mv, "_CHOICE", parent)
    mv.load_mitsuba()  # sets the variables a child inherits
    code = "from synth.mitsuba_variant import choose_variant as c; print(c().reason)"
    child = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO_ROOT,
                           env=dict(os.environ), timeout=120)
    assert child.returncode == 0, child.stderr
    assert child.stdout.strip() == parent.reason
    # a path the user sets is still reported as the user's
    monkeypatch.delenv(mv._FOUND_BY_US)
    assert "(DRJIT_LIBLLVM_PATH)" in mv.choose_variant().reason
