"""scripts/scene_flow_3d.py: the joint estimate's 3-D scene flow against the peers put together."""

import json

import pytest

from conftest import load_script


def test_scene_flow_3d_scores_both_and_refuses_bad_arguments(tmp_path, capsys):
    """A tiny run scores lfsf and the peers' pipeline through the scene's camera; lfsf's
    3-D flow is the better (the peers' δ from plenpy are off by several per cent of the
    depth), and bad arguments exit with 2 before any run."""
    pytest.importorskip("plenpy")
    pytest.importorskip("cv2")
    script = load_script("scene_flow_3d")
    out = tmp_path / "sf3d.json"
    assert script.main(["paper", "--size", "64", "48", "--grid", "5", "--preset", "fast", "--device", "cpu",
                        "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    scene = report["scenes"]["paper"]
    lfsf, peers = scene["lfsf"], scene["plenpy + opencv"]
    assert lfsf["pixels"] == peers["pixels"] > 1000
    assert 0 < lfsf["epe3d"] < peers["epe3d"] and lfsf["depth1_rel"] < peers["depth1_rel"]
    assert lfsf["epe3d"] < scene["true_mean_3d_motion"]
    assert "| paper |" in capsys.readouterr().out
    assert script.main(["no-such-scene"]) == 2
    assert script.main(["paper", "--preset", "flow"]) == 2
    assert script.main(["--random", "-2"]) == 2
    assert script.main(["paper", "--size", "0", "10"]) == 2
    assert "scene_flow_3d:" in capsys.readouterr().err
