"""`polarref ba` reads PVL-BA problems (BlocksExchange XML and the four-file folder) alike."""

import json

import numpy as np
import pytest

from polarref.ba.loaders import load_problem
from polarref.cli import main


def test_xml_and_folder_give_the_same_problem_and_solution(shared_data, tmp_path):
    from polarref.io.pvlba import read_blocks_exchange, write_pvlba

    xml = shared_data / "pvl_ba_bench_sample" / "sample_at.xml"
    write_pvlba(read_blocks_exchange(xml), tmp_path / "pvl")
    a, _ = load_problem(str(xml))
    b, _ = load_problem(str(tmp_path / "pvl"))
    assert a.num_observations == b.num_observations == 105
    assert np.abs(a.obs_uv - b.obs_uv).max() < 1e-6
    outs = []
    for src, name in ((xml, "xml.json"), (tmp_path / "pvl", "dir.json")):
        assert main(["ba", str(src), "--param", "euclidean", "--out", str(tmp_path / name)]) == 0
        outs.append(json.loads((tmp_path / name).read_text()))
    # Initial RMS ~0.57 px per image point (io verification); per residual component that is ~0.40.
    assert 0.3 < outs[0]["initial_rms_px"] < 0.5
    assert outs[0]["final_cost"] < outs[0]["initial_cost"]
    assert outs[0]["final_cost"] == pytest.approx(outs[1]["final_cost"], rel=1e-6)
