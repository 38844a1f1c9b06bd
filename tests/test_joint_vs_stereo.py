"""scripts/joint_vs_stereo.py: the joint δ1 against stereo only, and with the flow held at the truth."""

import json

from conftest import load_script


def test_joint_vs_stereo_holds_the_flow_and_refuses_bad_arguments(tmp_path, capsys):
    """A tiny run scores the three δ1 MSEs; the held run's flow ends within a few
    hundredths of a pixel of the truth (the joint run's is half a pixel off), the
    solver's methods are its own again afterwards, and bad arguments exit with 2."""
    from lfsf.solver import LevelSolver

    script = load_script("joint_vs_stereo")
    linearise, median = LevelSolver.linearise, LevelSolver.median
    out = tmp_path / "jvs.json"
    assert script.main(["paper", "--size", "48", "36", "--grid", "5", "--preset", "fast", "--device", "cpu",
                        "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    scene = report["scenes"]["paper"]
    assert len(scene["disp1_mse"]) == 3 and all(0 <= v < 1 for v in scene["disp1_mse"])
    assert scene["held_flow_epe"] < 0.05
    assert (LevelSolver.linearise, LevelSolver.median) == (linearise, median)
    assert "| paper |" in capsys.readouterr().out
    assert script.main(["no-such-scene"]) == 2
    assert script.main(["paper", "--noise", "-1"]) == 2
    assert script.main(["--random", "-2"]) == 2
    assert script.main(["paper", "--static"]) == 2
    assert script.main(["paper", "--size", "0", "10"]) == 2
    assert "joint_vs_stereo:" in capsys.readouterr().err
