"""scripts/perturbation_spread.py: the spread of a scene's errors under tiny input changes."""

import json

from conftest import load_script


def test_perturbation_spread_scores_every_run_and_refuses_bad_arguments(tmp_path, capsys):
    """A tiny run scores the rendered pair and each perturbed one (δ1, δ2, EPE as lfsf
    eval does, the stereo-only case's δ1 and the flow-only case's EPE) and writes them; an unknown scene or a seed count of 0 exits with 2."""
    script = load_script("perturbation_spread")
    out = tmp_path / "spread.json"
    assert script.main(["paper", "--size", "32", "24", "--grid", "3", "--seeds", "2", "--preset", "fast",
                        "--device", "cpu", "--stereo-only", "--flow-only", "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    runs = report["scenes"]["paper"]["runs"]
    assert report["scenes"]["paper"]["columns"][-2:] == ["stereo-only δ1 MSE", "flow-only EPE"]
    assert len(runs) == 3 and all(len(r) == 5 and all(v >= 0 for v in r) for r in runs)
    assert "| paper |" in capsys.readouterr().out
    assert script.main(["no-such-scene"]) == 2
    assert script.main(["paper", "--seeds", "0"]) == 2
    assert "unknown scene" in capsys.readouterr().err
