"""scripts/profile_kernels.py: per-kernel times of one estimate."""

import json

from conftest import load_script


def test_profile_times_every_kernel_inside_the_run_and_restores_the_launch_paths(tmp_path):
    from lfsf import device

    script = load_script("profile_kernels")
    saved = (device.launch_rows, device.RecordedRows.__call__, device.CapturedLoop.run)
    out = tmp_path / "prof.json"
    assert script.main(["--scene", "random-3", "--size", "48", "32", "--preset", "fast", "--device", "cpu",
                        "--json", str(out)]) == 0
    assert (device.launch_rows, device.RecordedRows.__call__, device.CapturedLoop.run) == saved
    report = json.loads(out.read_text())
    kernels = {row["kernel"]: row for row in report["kernels"]}
    # the iterations' three steps, each once per iteration, and the coefficients once per warp
    steps = {kernels[k]["launches"] for k in ("dual_data_step", "tgv_dual_step", "tgv_primal_step")}
    assert len(steps) == 1 and steps.pop() > 0
    assert 0 < kernels["data_coefficients_groups"]["launches"] < kernels["dual_data_step"]["launches"]
    # every kernel's time lies inside the run's, and the table is sorted by it
    seconds = [row["seconds"] for row in report["kernels"]]
    assert seconds == sorted(seconds, reverse=True) and all(s >= 0 for s in seconds)
    assert 0 < sum(seconds) <= report["seconds"]
    assert not list(tmp_path.glob("*.tmp"))


def test_profile_refuses_a_bad_scene_with_status_2(tmp_path, capsys):
    script = load_script("profile_kernels")
    out = tmp_path / "prof.json"
    assert script.main(["--scene", "nowhere", "--json", str(out)]) == 2
    assert "unknown scene 'nowhere'" in capsys.readouterr().err
    assert script.main(["--size", "8", "8", "--json", str(out)]) == 2
    assert not out.exists()
