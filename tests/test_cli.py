"""The command line: outputs, and bad input ending in one clear line with exit status 2."""

import argparse
import io as io_module
import json
import os
import platform
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import lfsf as lfsf_package
from lfsf import Params, SceneFlow, io
from lfsf.cli import main


def lfsf(*args, cwd=None):
    """Run the real command in a subprocess (status, stdout, stderr)."""
    proc = subprocess.run([sys.executable, "-m", "lfsf", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, env={**os.environ, "LFSF_DEVICE": ""})
    return proc.returncode, proc.stdout, proc.stderr


def assert_clean_error(status, err, *needles):
    assert status == 2, err
    assert "Traceback" not in err
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and "error:" in lines[0], err
    for needle in needles:
        assert needle in err, (needle, err)


def test_synth_list():
    status, out, err = lfsf("synth", "--list")
    assert status == 0, err
    for name in ("paper", "slanted", "large_motion", "weak_texture", "random-N"):
        assert name in out


def test_demo_in_colour_estimates_rgb_views_and_writes_the_overview(tmp_path):
    """``lfsf demo --colour``: RGB views (the estimate then takes the colour-edge step),
    the error table of all four variables and the overview picture."""
    status, out, err = lfsf("demo", "--colour", "--size", 64, 48, "--preset", "fast", "--out", tmp_path / "d")
    assert status == 0, err
    assert "RGB views" in err + out
    for name in ("disp1", "disp2", "flow"):
        assert name in out
    assert (tmp_path / "d" / "overview.png").stat().st_size > 1000


def test_demo_quiet_prints_the_error_table_alone_and_takes_the_device_asked(tmp_path):
    """``lfsf demo --quiet``: stdout holds the error table and its notes, nothing of the
    progress (the scene, the times, the files written); ``--device`` is the one used: a
    device the machine lacks is a clear error, status 2."""
    status, out, err = lfsf("demo", "--quiet", "--size", 48, 36, "--grid", 3, "--preset", "fast",
                            "--out", tmp_path / "q")
    assert status == 0, err
    lines = out.strip().splitlines()
    assert lines[0].split()[0] == "variable" and lines[1].split()[0] == "disp1", out
    assert not any(word in out for word in ("rendered", "estimated in", "wrote")), out
    assert (tmp_path / "q" / "overview.png").exists()
    # and the same in 3-D, through the camera that rendered the scene: below the motions' own length
    found = re.search(r"3-D scene flow.*true motions ([0-9.]+) long.*error mean ([0-9.]+)", out)
    assert found and 0 < float(found.group(2)) < float(found.group(1)), out
    status, out, err = lfsf("demo", "--device", "cuda:9", "--size", 48, 36, "--grid", 3, "--preset", "fast",
                            "--out", tmp_path / "d")
    assert_clean_error(status, err, "cuda:9")


def test_synth_renders_a_random_scene_and_names_bad_ones(tmp_path):
    status, _, err = lfsf("synth", "random-5", "--out", tmp_path / "r", "--size", 40, 30, "--grid", 3)
    assert status == 0, err
    with np.load(tmp_path / "r" / "gt.npz") as gt:
        assert np.isfinite(gt["disp1"]).all() and gt["disp1"].shape == (30, 40)
    status, _, err = lfsf("synth", "random-five", "--out", tmp_path / "x")
    assert status == 2 and "random-N" in err and not (tmp_path / "x").exists(), err


def test_synth_renders_a_grid_of_rows_and_columns(tmp_path):
    """--grid ROWSxCOLS renders a rig that is not square (as render_scene's grid=(rows, cols));
    the scene may follow the option (a --grid of several numbers had taken it as one)."""
    status, _, err = lfsf("synth", "--grid", "1x5", "paper", "--out", tmp_path / "s", "--size", 40, 30, "--quiet")
    assert status == 0, err
    assert np.load(tmp_path / "s" / "lf1.npz")["views"].shape == (1, 5, 30, 40)


def test_synth_writes_pair_and_ground_truth(tmp_path):
    status, _, err = lfsf("synth", "slanted", "--out", tmp_path / "s", "--size", 40, 30, "--grid", 3)
    assert status == 0, err
    assert sorted(p.name for p in (tmp_path / "s").iterdir()) == ["gt.npz", "lf1.npz", "lf2.npz"]
    lf1 = io.read_lightfield(tmp_path / "s" / "lf1.npz")
    assert lf1.views.shape == (3, 3, 30, 40) and lf1.views.dtype == np.float32
    with np.load(tmp_path / "s" / "gt.npz") as gt:
        for key in ("disp1", "disp2", "u", "v"):
            assert gt[key].shape == (30, 40) and gt[key].dtype == np.float32
        assert gt["valid"].dtype == bool and gt["occluded"].dtype == bool


def test_synth_adds_sensor_noise_to_the_views_not_the_ground_truth(tmp_path):
    args = ("--size", 40, 30, "--grid", 3)
    assert lfsf("synth", "slanted", "--out", tmp_path / "clean", *args)[0] == 0
    status, _, err = lfsf("synth", "slanted", "--out", tmp_path / "noisy", "--noise", 0.02, *args)
    assert status == 0, err
    clean = [io.read_lightfield(tmp_path / "clean" / f).views for f in ("lf1.npz", "lf2.npz")]
    noisy = [io.read_lightfield(tmp_path / "noisy" / f).views for f in ("lf1.npz", "lf2.npz")]
    n1, n2 = noisy[0] - clean[0], noisy[1] - clean[1]
    assert 0.015 < n1.std() < 0.025 and 0.015 < n2.std() < 0.025
    assert abs(np.corrcoef(n1.ravel(), n2.ravel())[0, 1]) < 0.1  # independent at t1 and t2
    with np.load(tmp_path / "clean" / "gt.npz") as a, np.load(tmp_path / "noisy" / "gt.npz") as b:
        np.testing.assert_array_equal(a["disp1"], b["disp1"])
    status, _, err = lfsf("synth", "slanted", "--out", tmp_path / "bad", "--noise", -1, *args)
    assert status == 2 and "noise" in err and not (tmp_path / "bad").exists(), err


def test_synth_puts_a_folders_images_on_the_objects(tmp_path):
    """``--images FOLDER``: the objects show the folder's images (drawn by
    ``--image-seed``), the ground truth stays the scene's; a folder without images, or
    with a file that is not one, is refused with exit status 2 and nothing written."""
    rng = np.random.default_rng(1)
    photos = tmp_path / "photos"
    photos.mkdir()
    io.write_png(photos / "a.png", (rng.random((40, 60, 3)) * 255).astype(np.uint8))
    io.write_png(photos / "b.png", (rng.random((30, 30)) * 65535).astype(np.uint16))
    args = ("--size", 40, 30, "--grid", 3)
    assert lfsf("synth", "paper", "--out", tmp_path / "plain", *args)[0] == 0
    status, _, err = lfsf("synth", "paper", "--out", tmp_path / "img", "--images", photos, *args)
    assert status == 0, err
    status, _, err = lfsf("synth", "paper", "--out", tmp_path / "img2", "--images", photos, "--image-seed", 4, *args)
    assert status == 0, err
    plain, img, img2 = (io.read_lightfield(tmp_path / d / "lf1.npz").views for d in ("plain", "img", "img2"))
    assert np.abs(img - plain).mean() > 0.05 and np.abs(img2 - img).mean() > 0.01
    with np.load(tmp_path / "plain" / "gt.npz") as a, np.load(tmp_path / "img" / "gt.npz") as b:
        for key in ("disp1", "disp2", "u", "v", "valid", "occluded"):
            np.testing.assert_array_equal(a[key], b[key])
    status, _, err = lfsf("synth", "paper", "--out", tmp_path / "x", "--image-seed", 4, *args)
    assert_clean_error(status, err, "--images")
    (tmp_path / "empty").mkdir()
    status, _, err = lfsf("synth", "paper", "--out", tmp_path / "x", "--images", tmp_path / "empty", *args)
    assert_clean_error(status, err, "no images")
    (photos / "c.png").write_bytes(b"not a png")
    status, _, err = lfsf("synth", "paper", "--out", tmp_path / "x", "--images", photos, *args)
    assert_clean_error(status, err, "c.png")
    assert not (tmp_path / "x").exists()


def test_eval_of_ground_truth_against_itself_is_zero(tmp_path):
    assert main(["synth", "paper", "--out", str(tmp_path), "--size", "48", "36", "--grid", "1", "--quiet"]) == 0
    status, out, err = lfsf("eval", tmp_path / "gt.npz", tmp_path / "gt.npz", "--json", tmp_path / "e.json")
    assert status == 0, err
    report = json.loads((tmp_path / "e.json").read_text())
    assert report["errors"]["disp1"]["mse"] == 0.0
    assert report["errors"]["flow"]["epe"] == 0.0
    assert "flow" in out and "disp2" in out
    # the synthetic ground truth marks the points hidden at t2: scored again without them
    with np.load(tmp_path / "gt.npz") as gt:
        seen = int((gt["valid"] & ~gt["occluded"])[8:-8, 8:-8].sum())
    assert report["errors"]["flow_noc"]["epe"] == 0.0 and report["errors"]["flow_noc"]["pixels"] == seen
    assert report["errors"]["disp2_noc"]["pixels"] == seen and "flow noc" in out


def test_json_dash_writes_the_report_to_stdout_and_the_table_to_stderr(tmp_path, monkeypatch):
    """``--json -`` (a pipe into jq, a script reading the report) had written a file named
    '-'. The JSON is stdout's alone, the same report as a file's; what the command
    prints besides goes to stderr. So for ``lfsf bench``."""
    monkeypatch.chdir(tmp_path)
    assert main(["synth", "paper", "--out", str(tmp_path), "--size", "48", "36", "--grid", "1", "--quiet"]) == 0
    status, out, err = lfsf("eval", tmp_path / "gt.npz", tmp_path / "gt.npz", "--json", "-")
    assert status == 0, err
    assert json.loads(out)["errors"]["flow"]["epe"] == 0.0 and "flow noc" in err
    assert lfsf("eval", tmp_path / "gt.npz", tmp_path / "gt.npz", "--json", tmp_path / "e.json")[0] == 0
    assert json.loads(out) == json.loads((tmp_path / "e.json").read_text())
    assert not (tmp_path / "-").exists()
    # './-' is a file of that name, as for any other command (Path('./-') reads as '-')
    status, out, err = lfsf("eval", tmp_path / "gt.npz", tmp_path / "gt.npz", "--json", "./-")
    assert status == 0 and "flow noc" in out and json.loads((tmp_path / "-").read_text()) == json.loads(
        (tmp_path / "e.json").read_text())
    (tmp_path / "-").unlink()
    status, out, err = lfsf("bench", "kernels", "--size", "16", "12", "--repeats", "1", "--json", "-", "--quiet")
    assert status == 0, err
    rows = json.loads(out)
    assert [r["kernel"] for r in rows][0] == "sample_subaperture" and "| kernel |" in err and "peak RSS" in err
    assert not (tmp_path / "-").exists()


def test_eval_with_no_border(tmp_path, capsys):
    """--border 0 scores every pixel (it had read as no border given: the default 8)."""
    assert main(["synth", "paper", "--out", str(tmp_path), "--size", "48", "36", "--grid", "1", "--quiet"]) == 0
    with np.load(tmp_path / "gt.npz") as gt:
        maps = {k: gt[k] for k in ("disp1", "disp2", "u", "v")}
        valid = int(gt["valid"].sum())
    maps["disp1"] = maps["disp1"].copy()
    maps["disp1"][:4] += 1.0    # (wrong in the top 4 rows only: inside the default border)
    np.savez(tmp_path / "est.npz", **maps)
    for border, pixels in ((0, valid), (None, None)):
        extra = [] if border is None else ["--border", str(border)]
        assert main(["eval", str(tmp_path / "est.npz"), str(tmp_path / "gt.npz"), "--json",
                     str(tmp_path / "e.json"), *extra]) == 0
        report = json.loads((tmp_path / "e.json").read_text())
        out = capsys.readouterr().out
        assert f"(border {8 if border is None else 0} px" in out, out
        assert (report["errors"]["disp1"]["mse"] > 0) == (border == 0)
        assert pixels is None or report["errors"]["disp1"]["pixels"] == pixels


def test_eval_of_a_partial_result_says_what_it_left_out(tmp_path, capsys):
    """A folder with disp1.pfm alone (the others lost) is scored, and the report says
    that δ2 and the flow were not, where the ground truth has them."""
    assert main(["synth", "paper", "--out", str(tmp_path), "--size", "48", "36", "--grid", "1", "--quiet"]) == 0
    with np.load(tmp_path / "gt.npz") as gt:
        disp1 = gt["disp1"]
    (tmp_path / "r").mkdir()
    io.write_pfm(tmp_path / "r" / "disp1.pfm", disp1)
    capsys.readouterr()
    assert main(["eval", str(tmp_path / "r"), str(tmp_path / "gt.npz"), "--json", str(tmp_path / "e.json")]) == 0
    out = capsys.readouterr().out
    assert f"not evaluated, missing from {tmp_path / 'r'}: disp2, flow" in out
    assert json.loads((tmp_path / "e.json").read_text())["not_evaluated"] == ["disp2", "flow"]
    assert main(["eval", str(tmp_path / "gt.npz"), str(tmp_path / "gt.npz")]) == 0
    assert "not evaluated" not in capsys.readouterr().out


@pytest.mark.parametrize("args, needle", [
    (["run", "a.npz", "b.npz", "--out", "x", "--bogus"], "lfsf run: error: unrecognized arguments: --bogus (lfsf run --help"),
    # before the command, lfsf's (the command's own --help lists --quiet)
    (["--quiet", "demo"], "lfsf: error: unrecognized arguments: --quiet (lfsf --help"),
    (["run", "a.npz", "b.npz", "--out", "x", "--device", ""], "lfsf run: error: argument --device: an empty device"),
    (["run", "a.npz", "b.npz", "--out", "x", "--config", ""], "argument --config: an empty file name"),
])
def test_option_errors_are_the_commands_own(args, needle, capsys):
    """An unknown option after a command had been lfsf's ('lfsf: error', lfsf --help);
    --device '' had been the default without a word, --config '' the folder '.'."""
    with pytest.raises(SystemExit) as info:
        main(args)
    assert info.value.code == 2 and needle in capsys.readouterr().err


def test_eval_names_the_values_that_are_not_finite(tmp_path, capsys):
    """A result with a NaN had printed inf (null in the JSON) without a word of why."""
    from lfsf.estimate import SceneFlow

    assert main(["synth", "paper", "--out", str(tmp_path), "--size", "48", "36", "--grid", "3", "--quiet"]) == 0
    with np.load(tmp_path / "gt.npz") as gt:
        maps = {k: gt[k].copy() for k in ("disp1", "disp2", "u", "v")}
    maps["disp1"][18, 24] = np.nan
    SceneFlow(**maps, params=Params.preset("fast"), radius=2.0, device="cpu").save(tmp_path / "r")
    capsys.readouterr()
    assert main(["eval", str(tmp_path / "r"), str(tmp_path / "gt.npz")]) == 0
    out = capsys.readouterr().out
    assert f"{tmp_path / 'r'}: disp1 holds 1 NaN or infinite value; where scored, its errors read inf" in out
    assert "disp2 holds" not in out


def test_eval_says_what_the_ground_truth_lacks(tmp_path, capsys):
    """A gt.npz with half a flow (v, no u) scores no flow and says why; one without a
    'valid' mask scores every pixel and says so. Neither note for a whole gt.npz."""
    assert main(["synth", "paper", "--out", str(tmp_path), "--size", "48", "36", "--grid", "1", "--quiet"]) == 0
    with np.load(tmp_path / "gt.npz") as z:
        gt = dict(z)
    np.savez(tmp_path / "half.npz", **{k: v for k, v in gt.items() if k != "u"})
    np.savez(tmp_path / "all.npz", **{k: v for k, v in gt.items() if k != "valid"})
    capsys.readouterr()
    assert main(["eval", str(tmp_path / "gt.npz"), str(tmp_path / "half.npz"), "--json", str(tmp_path / "e.json")]) == 0
    out = capsys.readouterr().out
    assert f"flow not evaluated: {tmp_path / 'half.npz'} has 'v' but no 'u'" in out
    assert not [ln for ln in out.splitlines() if ln.split()[:1] == ["flow"] and "evaluated" not in ln], out
    assert json.loads((tmp_path / "e.json").read_text())["notes"] == [
        f"flow not evaluated: {tmp_path / 'half.npz'} has 'v' but no 'u'"]
    assert main(["eval", str(tmp_path / "gt.npz"), str(tmp_path / "all.npz")]) == 0
    assert f"every pixel scored (but the border): {tmp_path / 'all.npz'} holds no 'valid' mask" in capsys.readouterr().out
    gt["disp1"][3, 4] = np.nan  # (a truth with holes and no mask: its NaN are left out, and the note says so)
    np.savez(tmp_path / "holes.npz", **{k: v for k, v in gt.items() if k != "valid"})
    assert main(["eval", str(tmp_path / "gt.npz"), str(tmp_path / "holes.npz")]) == 0
    assert (f"every finite pixel scored (but the border): {tmp_path / 'holes.npz'} holds no 'valid' mask; its NaN "
            "or infinite values are left out") in capsys.readouterr().out
    assert main(["eval", str(tmp_path / "gt.npz"), str(tmp_path / "gt.npz")]) == 0
    out = capsys.readouterr().out
    assert "not evaluated" not in out and "every pixel" not in out


def test_eval_of_a_flow_only_result_leaves_its_zero_disparities_out(tmp_path, capsys):
    """They were scored (BadPix 95–100 %) as if estimated."""
    from lfsf.estimate import SceneFlow

    assert main(["synth", "paper", "--out", str(tmp_path), "--size", "48", "36", "--grid", "1", "--quiet"]) == 0
    with np.load(tmp_path / "gt.npz") as gt:
        maps = {k: gt[k] for k in ("u", "v")}
    zeros = np.zeros_like(maps["u"])
    SceneFlow(zeros, zeros, maps["u"], maps["v"], params=Params.preset("flow"), radius=0.0,
              device="cpu").save(tmp_path / "r")
    capsys.readouterr()
    assert main(["eval", str(tmp_path / "r"), str(tmp_path / "gt.npz"), "--json", str(tmp_path / "e.json")]) == 0
    out = capsys.readouterr().out
    assert "not evaluated in" in out and "disp1, disp2 (a flow-only result" in out
    report = json.loads((tmp_path / "e.json").read_text())
    assert "disp1" not in report["errors"] and report["errors"]["flow"]["epe"] == 0.0
    # nor scored when its disp1.pfm is given alone (MSE 2.9, BadPix 98 %, without a word)
    status = main(["eval", str(tmp_path / "r" / "disp1.pfm"), str(tmp_path / "gt.npz")])
    assert status == 2 and "zeros, not an estimate" in capsys.readouterr().err
    # nor are they drawn as a disparity (zeros in the colour map's purple): plain grey, and
    # the picture's text says so
    from PIL import Image

    from lfsf.viz import NOT_ESTIMATED_GREY

    for name in ("disp1", "disp2"):
        assert (io.read_image(tmp_path / "r" / f"{name}.png") == NOT_ESTIMATED_GREY).all()
        assert Image.open(tmp_path / "r" / f"{name}.png").text["Comment"] == (
            f"{name}: not estimated (a flow-only run, one circle)")


@pytest.mark.parametrize("result,report", [("r", "gt.npz"), ("r/disp1.pfm", "gt.npz"), ("r", "link.npz"),
                                           ("r", "r/sceneflow.npz"), ("r", "r/../r/disp1.pfm"),
                                           ("r/disp1.pfm", "r/disp1.pfm")])
def test_an_eval_report_may_not_replace_what_it_reports_on(tmp_path, capsys, result, report):
    """``lfsf eval R GT --json X``: X the ground truth, the result, one of the result
    folder's files or a link to one of them is refused (it silently replaced it)."""
    (tmp_path / "gt.npz").write_bytes(b"the ground truth")
    (tmp_path / "r").mkdir()
    for name in ("sceneflow.npz", "disp1.pfm"):
        (tmp_path / "r" / name).write_bytes(b"a result")
    (tmp_path / "link.npz").symlink_to(tmp_path / "gt.npz")
    status = main(["eval", str(tmp_path / result), str(tmp_path / "gt.npz"), "--json", str(tmp_path / report)])
    err = capsys.readouterr().err
    assert status == 2 and "which it reports on; choose another --json file" in err and err.count("\n") == 1, err
    assert (tmp_path / "gt.npz").read_bytes() == b"the ground truth"
    assert (tmp_path / "r" / "disp1.pfm").read_bytes() == (tmp_path / "r" / "sceneflow.npz").read_bytes() == b"a result"


@pytest.mark.parametrize(
    "args,needles",
    [
        (["synth", "nowhere", "--out", "{tmp}/x"], ["unknown scene 'nowhere'"]),
        (["synth", "paper", "--out", "{tmp}/x", "--device", "cuda:9"], ["device 'cuda:9' is not on this machine"]),
        (["synth", "paper", "--out", "{tmp}/x", "--size", "4", "4"], ["at least 8"]),
        (["eval", "{tmp}/missing", "{tmp}/gt.npz"], ["missing"]),
        (["run", "{tmp}/missing1", "{tmp}/missing2", "--out", "{tmp}/r"], ["missing1"]),
        (["run", "{tmp}/a.npz", "{tmp}/a.npz", "--out", "{tmp}/r", "--device", "quantum"], ["unknown device"]),
        (["frobnicate"], ["invalid choice"]),
        (["bench", "kernels", "--device", "quantum"], ["unknown device"]),
        (["bench", "everything"], ["invalid choice"]),
        (["bench", "pipeline", "--size", "4", "4"], ["at least 8"]),
        (["bench", "pipeline", "--size", "16", "40"], ["at least 17 px"]),
        (["bench", "pipeline", "--inputs", "random"], ["--inputs", "kernels"]),
        (["bench", "kernels", "--inputs", "noise"], ["invalid choice"]),
        (["run", "{tmp}/a.npz", "{tmp}/a.npz", "--out", ""], ["an empty folder name"]),
        (["eval", "{tmp}/r", "{tmp}/gt.npz", "--json", "{tmp}/new/"], ["names a folder, not a file"]),
        (["bench", "kernels", "--json", "{tmp}/new/"], ["names a folder, not a file"]),
        (["bench", "kernels", "--repeats", "100000"], ["at most 1000 timed runs"]),
        # argparse's own errors: one line too, not the usage block before it
        (["run", "{tmp}/a.npz", "{tmp}/b.npz"], ["required: --out", "lfsf run --help"]),
        (["synth", "paper", "--out", "{tmp}/x", "--size", "-80", "60"], ["at least 8 pixels, got -80"]),
        (["synth", "paper", "--out", "{tmp}/x", "--size", "abc", "60"], ["--size: expected a whole number, got 'abc'"]),
        (["bench", "--repeats", "y"], ["--repeats: expected a whole number, got 'y'"]),
        (["synth", "paper", "--out", "{tmp}/x", "--grid", "1000"], ["argument --grid: at most 33 views a side, got 1000"]),
        (["synth", "paper", "--out", "{tmp}/x", "--grid", "3x4x5"], ["argument --grid: expected N or ROWSxCOLS (e.g. 9 "
                                                                    "or 1x9), got '3x4x5'"]),
        (["demo", "--out", "{tmp}/x", "--grid", "40"], ["argument --grid: at most 33 views a side, got 40"]),
        (["decode", "{tmp}/a.npz", "--white", "{tmp}/a.npz", "--out", "{tmp}/x", "--bayer", "CMYK"],
         ["invalid choice: 'CMYK'", "'none'"]),
        (["synth", "paper", "--out", "{tmp}/x", "--images", "{tmp}/a.npz"], ["a.npz: not a folder"]),
        (["decode", "{tmp}/text.raw", "--white", "{tmp}/text.raw", "--out", "{tmp}/x"],
         ["text.raw: cannot read as a raw image (LibRaw could not read it"]),
    ],
)
def test_bad_input_is_one_clear_line_and_status_2(tmp_path, args, needles):
    (tmp_path / "a.npz").write_bytes(b"")
    (tmp_path / "text.raw").write_text("not a raw image\n")
    status, _, err = lfsf(*[a.format(tmp=tmp_path) for a in args])
    assert_clean_error(status, err, *needles)
    assert not (tmp_path / "x").exists() and not (tmp_path / "r").exists()


@pytest.mark.parametrize(
    "args,needle",
    [
        (["synth", "paper", "--out", "{tmp}/x", "--size", "100000", "100000"], "image width must be in 8…8192"),
        (["synth", "paper", "--out", "{tmp}/x", "--supersample", "50"], "supersample must be in 1…16"),
        (["synth", "paper", "--out", "{tmp}/x", "--frames", "300"], "more than the 2,147,483,648"),
        (["synth", "paper", "--out", "{tmp}/x", "--noise", "-1"], "--noise: noise sigma must be a number from 0 to 1"),
        (["synth", "paper", "--out", "{tmp}/x", "--noise", "1000"], "--noise: noise sigma must be a number from 0 to "
                                                                    "1 (intensities in [0, 1]), got 1000"),
        (["demo", "--out", "{tmp}/x", "--size", "320", "9000"], "image height must be in 8…8192"),
        (["demo", "--out", "{tmp}/x", "--size", "16", "12"], "give at least 17 px each way"),
        (["bench", "kernels", "--size", "10000", "10"], "image width must be in 8…8192"),
    ],
)
def test_settings_that_size_a_render_are_bounded_and_checked_before_any_work(tmp_path, capsys, args, needle):
    """Each is one line and status 2, with nothing said (no 'rendering …') before it:
    without the bounds, a Warp allocation error (status 1) or a render that never ends."""
    assert main([a.format(tmp=tmp_path) for a in args]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1 and needle in captured.err, captured
    assert not (tmp_path / "x").exists()


def test_a_preset_in_the_config_file_meets_the_command_line(tmp_path, capsys):
    from lfsf import cli

    (tmp_path / "f.toml").write_text('preset = "flow"\n')
    assert main(["run", "a.npz", "b.npz", "--out", str(tmp_path / "r"), "--preset", "paper",
                 "--config", str(tmp_path / "f.toml")]) == 2
    assert "preset = 'flow' here, but preset 'paper' was given too" in capsys.readouterr().err
    for preset, config, want in ((None, None, "paper"), ("fast", None, "fast"), (None, "f.toml", "flow"),
                                 ("flow", "f.toml", "flow")):
        args = argparse.Namespace(preset=preset, config=config and tmp_path / config)
        assert cli._params(args) == Params.preset(want), (preset, config)
    assert cli._preset_label(argparse.Namespace(preset=None, config="f.toml")) == "the settings of f.toml"
    # an empty name is a mistake, not the default (presets are matched exactly)
    assert main(["run", "a.npz", "b.npz", "--out", str(tmp_path / "r"), "--preset", ""]) == 2
    assert "unknown preset ''" in capsys.readouterr().err


def test_nan_pixels_are_rejected_with_the_file_name(tmp_path):
    views = np.full((3, 3, 10, 12), 0.5, np.float32)
    views[1, 2, 4, 4] = np.nan
    np.savez(tmp_path / "bad.npz", views=views)
    np.savez(tmp_path / "good.npz", views=np.full((3, 3, 10, 12), 0.5, np.float32))
    status, _, err = lfsf("run", tmp_path / "good.npz", tmp_path / "bad.npz", "--out", tmp_path / "r")
    assert_clean_error(status, err, "bad.npz", "NaN")
    assert not (tmp_path / "r").exists()


def test_light_fields_of_different_shapes_are_rejected(tmp_path):
    np.savez(tmp_path / "a.npz", views=np.full((3, 3, 10, 12), 0.5, np.float32))
    np.savez(tmp_path / "b.npz", views=np.full((3, 3, 10, 14), 0.5, np.float32))
    np.savez(tmp_path / "c.npz", views=np.full((5, 5, 10, 12), 0.5, np.float32))
    status, _, err = lfsf("run", tmp_path / "a.npz", tmp_path / "b.npz", "--out", tmp_path / "r")
    assert_clean_error(status, err, "a.npz", "b.npz", "12", "14")
    status, _, err = lfsf("run", tmp_path / "a.npz", tmp_path / "c.npz", "--out", tmp_path / "r")
    assert_clean_error(status, err, "3×3", "5×5")


def test_run_writes_every_result_and_eval_reads_them(tmp_path):
    assert main(["synth", "paper", "--out", str(tmp_path / "s"), "--size", "40", "32", "--grid", "3", "--quiet"]) == 0
    status, _, err = lfsf("run", tmp_path / "s" / "lf1.npz", tmp_path / "s" / "lf2.npz", "--out", tmp_path / "r",
                          "--preset", "fast", "--quiet")
    assert status == 0, err
    names = sorted(p.name for p in (tmp_path / "r").iterdir())
    assert names == ["disp1.pfm", "disp1.png", "disp2.pfm", "disp2.png", "flow.flo", "flow.png", "overview.png",
                     "sceneflow.npz"]
    with np.load(tmp_path / "r" / "sceneflow.npz") as z:
        assert z["disp1"].shape == (32, 40) and z["u"].dtype == np.float32
        np.testing.assert_array_equal(z["disp1"], io.read_pfm(tmp_path / "r" / "disp1.pfm"))
        np.testing.assert_array_equal(z["v"], io.read_flo(tmp_path / "r" / "flow.flo")[..., 1])
        assert "lambda1" in str(z["params"])
    status, out, err = lfsf("eval", tmp_path / "r", tmp_path / "s" / "gt.npz")
    assert status == 0, err and "flow" in out
    # what the result came from, and what made it (a plain run had recorded neither)
    import warp as wp

    sf = SceneFlow.load(tmp_path / "r")
    assert sf.inputs["t1"] == str((tmp_path / "s" / "lf1.npz").resolve()) and sf.inputs["warm_start"] is False
    assert sf.inputs["t2_files"][0][:2] == ["lf2.npz", (tmp_path / "s" / "lf2.npz").stat().st_size]
    assert sf.made_with == {"lfsf": lfsf_package.__version__, "python": platform.python_version(),
                            "numpy": np.__version__, "warp": wp.__version__}


def test_a_config_made_in_a_way_run_does_not_repeat_is_warned_of(tmp_path, capsys):
    """A result of lfsf batch --warm-start given as --config had been re-run from nothing,
    every pixel different, without a word; one made on CUDA is said to round otherwise."""
    from lfsf.estimate import SceneFlow

    assert main(["synth", "paper", "--out", str(tmp_path / "s"), "--size", "40", "32", "--grid", "3", "--quiet"]) == 0
    zeros = np.zeros((32, 40), np.float32)
    SceneFlow(zeros, zeros, zeros, zeros, Params.preset("fast"), 1.0, "cuda:0",
              inputs={"warm_start": True}).save(tmp_path / "made")
    capsys.readouterr()
    assert main(["run", str(tmp_path / "s" / "lf1.npz"), str(tmp_path / "s" / "lf2.npz"), "--out",
                 str(tmp_path / "r"), "--config", str(tmp_path / "made"), "--device", "cpu", "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "made was estimated from the previous pair's result (lfsf batch --warm-start)" in err, err
    assert "made was estimated on cuda:0, this run is on cpu: the CPU and CUDA round differently" in err
    SceneFlow(zeros, zeros, zeros, zeros, Params.preset("fast"), 1.0, "cpu").save(tmp_path / "plain")
    assert SceneFlow.load(tmp_path / "plain").made_with is None   # (as a result saved before they were recorded)
    assert main(["run", str(tmp_path / "s" / "lf1.npz"), str(tmp_path / "s" / "lf2.npz"), "--out",
                 str(tmp_path / "q"), "--config", str(tmp_path / "plain"), "--device", "cpu", "--quiet"]) == 0
    assert "warning" not in capsys.readouterr().err


def test_run_downsamples_the_views_and_the_ground_truth_alike(tmp_path, capsys, monkeypatch):
    """--downsample K: the estimate of the K times smaller views (what the library's
    LightField.downsample gives), scored against the truth shrunk alike with the border
    shrunk too; a factor that leaves no pixel is one clear line."""
    from lfsf import SceneFlow, estimate_scene_flow, read_lightfield, viz
    from lfsf.evaluate import downsample_truth, evaluate, load_ground_truth

    s = tmp_path / "s"
    assert main(["synth", "paper", "--out", str(s), "--size", "64", "48", "--grid", "3", "--quiet"]) == 0
    drawn, overview = [], viz.overview_figure
    monkeypatch.setattr(viz, "overview_figure", lambda *a, **kw: drawn.append(kw["title"]) or overview(*a, **kw))
    assert main(["run", str(s / "lf1.npz"), str(s / "lf2.npz"), "--out", str(tmp_path / "r"), "--preset", "fast",
                 "--downsample", "2", "--gt", str(s / "gt.npz")]) == 0
    out, err = capsys.readouterr()
    assert "lfsf run: views downsampled 64×48 → 32×24 (means of 2×2 px)" in err
    # the overview's title says so too: its δ and flow are in the shrunk views' pixels
    assert drawn == [f"lfsf run: lf1.npz and lf2.npz (32x24 shrunk 2x from 64x48, 3x3 views, preset 'fast') "
                     f"against gt.npz"], drawn
    assert "ground truth shrunk alike" in err
    # the table's line says so too, as lfsf eval's on the same result does
    assert "(border 4 px; estimated on views shrunk 2 times, the ground truth shrunk alike): δ and the flow in the " \
        "shrunk views' pixels, so against a full-size run's MSE ×4, EPE ×2" in out
    saved = SceneFlow.load(tmp_path / "r")
    lf1, lf2 = (read_lightfield(s / name).downsample(2) for name in ("lf1.npz", "lf2.npz"))
    again = estimate_scene_flow(lf1, lf2, "fast", device="cpu")
    np.testing.assert_array_equal(saved.u, again.u)
    np.testing.assert_array_equal(saved.disp1, again.disp1)
    truth, _ = load_ground_truth(s / "gt.npz")
    epe = evaluate(again, downsample_truth(truth, 2), border=4)["flow"]["epe"]
    assert f"{epe:.4f}" in out
    # the result records K: lfsf eval shrinks the truth alike (it had failed on the sizes),
    # and --config RESULT estimates as the result was
    assert main(["eval", str(tmp_path / "r"), str(s / "gt.npz")]) == 0
    out = capsys.readouterr().out
    assert "(border 4 px; estimated on views shrunk 2 times, the ground truth shrunk alike)" in out
    assert f"{epe:.4f}" in out
    assert main(["run", str(s / "lf1.npz"), str(s / "lf2.npz"), "--out", str(tmp_path / "r3"), "--config",
                 str(tmp_path / "r"), "--quiet"]) == 0
    np.testing.assert_array_equal(SceneFlow.load(tmp_path / "r3").u, saved.u)
    with pytest.raises(ValueError, match=r"the estimate is 32×24 but the ground truth is 64×48, 2 times the "
                                         r"estimate's size: views shrunk by lfsf run --downsample 2 \(shrink"):
        evaluate(saved, truth)
    io.write_pfm(tmp_path / "d1.pfm", truth["disp1"])  # (δ1 alone, as an HCI truth: nothing a flow run scores)
    status, _, err = lfsf("run", s / "lf1.npz", s / "lf2.npz", "--out", tmp_path / "r4", "--preset", "flow",
                          "--gt", tmp_path / "d1.pfm")
    assert_clean_error(status, err, "d1.pfm: cannot score this run against it: it holds disp1, and a flow-only run "
                                    "(one circle) estimates u and v; leave --gt out, or give a flow truth")
    for k in ("7", "50"):  # (48 px: 8 at most 6 times smaller)
        status, _, err = lfsf("run", s / "lf1.npz", s / "lf2.npz", "--out", tmp_path / "r2", "--downsample", k)
        assert_clean_error(status, err, f"--downsample {k}: the views of {s / 'lf1.npz'} are 64×48, which that "
                                        f"leaves at {64 // int(k)}×{48 // int(k)}, under the 8×8 px the estimate "
                                        "needs: at most --downsample 6")
        assert not (tmp_path / "r2").exists()


def test_config_file_sets_parameters_and_bad_ones_are_clear_errors(tmp_path):
    np.savez(tmp_path / "a.npz", views=np.full((3, 3, 16, 16), 0.5, np.float32))
    (tmp_path / "bad.toml").write_text("lambda9 = 3\n")
    status, _, err = lfsf("run", tmp_path / "a.npz", tmp_path / "a.npz", "--out", tmp_path / "r",
                          "--config", tmp_path / "bad.toml")
    assert_clean_error(status, err, "bad.toml", "lambda9")
    (tmp_path / "broken.toml").write_text("warps = = 3\n")
    status, _, err = lfsf("run", tmp_path / "a.npz", tmp_path / "a.npz", "--out", tmp_path / "r",
                          "--config", tmp_path / "broken.toml")
    assert_clean_error(status, err, "broken.toml", "TOML")
    status, _, err = lfsf("run", tmp_path / "a.npz", tmp_path / "a.npz", "--out", tmp_path / "r", "--preset", "slow")
    assert_clean_error(status, err, "unknown preset 'slow'")
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("name,content", [("bad.pfm", b"P7\n3 3\n-1\n" + b"\0" * 36),
                                          ("short.pfm", b"Pf\n3 3\n-1\n" + b"\0" * 20),
                                          ("bad.flo", b"ABCD" + b"\0" * 40),
                                          ("short.flo", np.array([202021.25], "<f4").tobytes()
                                           + np.array([4, 4], "<i4").tobytes() + b"\0" * 16)])
def test_corrupt_pfm_and_flo_are_rejected_with_the_file_name(tmp_path, name, content):
    (tmp_path / name).write_bytes(content)
    assert main(["synth", "paper", "--out", str(tmp_path / "g"), "--size", "8", "8", "--grid", "1", "--quiet"]) == 0
    status, _, err = lfsf("eval", tmp_path / name, tmp_path / "g" / "gt.npz", "--json", tmp_path / "e.json")
    assert_clean_error(status, err, name)
    assert not (tmp_path / "e.json").exists()


@pytest.mark.parametrize("args", [
    ["run", "{tmp}/a.npz", "{tmp}/a.npz", "--out", "{tmp}/afile"],
    ["run", "{tmp}/a.npz", "{tmp}/a.npz", "--out", "{tmp}/afile/r"],
    ["synth", "paper", "--out", "{tmp}/afile", "--size", "16", "16", "--grid", "3"],
    ["demo", "--out", "{tmp}/afile", "--size", "24", "24"],
    ["eval", "{tmp}/r", "{tmp}/gt.npz", "--json", "{tmp}/afile/x.json"],
    ["bench", "kernels", "--size", "16", "16", "--json", "{tmp}/afile/x.json"],
])
def test_an_output_under_a_file_is_a_clear_error_before_any_work(tmp_path, args):
    np.savez(tmp_path / "a.npz", views=np.full((3, 3, 16, 16), 0.5, np.float32))
    (tmp_path / "afile").write_text("not a folder")
    status, out, err = lfsf(*[a.format(tmp=tmp_path) for a in args])
    assert_clean_error(status, err, "afile", "not a folder")
    assert "estimated" not in err and "rendered" not in out
    assert (tmp_path / "afile").read_text() == "not a folder"


READ_ONLY = Path("/sys/kernel")


@pytest.mark.skipif(not READ_ONLY.is_dir(), reason="no /sys (a read-only file system to write into)")
@pytest.mark.parametrize("args", [
    ["run", "{tmp}/a.npz", "{tmp}/a.npz", "--out", str(READ_ONLY)],
    ["synth", "paper", "--out", str(READ_ONLY), "--size", "16", "16", "--grid", "3"],
    ["eval", "{tmp}/r", "{tmp}/gt.npz", "--json", str(READ_ONLY / "x.json")],
])
def test_an_output_on_a_read_only_file_system_is_refused_before_any_work(tmp_path, args):
    """As root, os.access says /sys is writable: the run did its work, then failed naming
    its temporary file ([Errno 1] Operation not permitted: '/sys/kernel/.lfsf-set…')."""
    np.savez(tmp_path / "a.npz", views=np.full((3, 3, 16, 16), 0.5, np.float32))
    status, out, err = lfsf(*[a.format(tmp=tmp_path) for a in args])
    assert_clean_error(status, err, str(READ_ONLY), "not writable")
    assert ".lfsf-set" not in err and ".part" not in err and "rendered" not in out


def test_a_full_device_is_named_in_the_error(tmp_path):
    from lfsf._files import write_bytes_atomic

    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full")
    with pytest.raises(OSError, match="No space left on device: '/dev/full'"):
        write_bytes_atomic("/dev/full", b"{}" * 10000)


def test_a_full_disk_is_one_line_and_status_1_not_bad_input(tmp_path, monkeypatch, capsys):
    """A full disk had been "[Errno 28] No space left on device: '…'" and status 2, as if
    the input were at fault; the same run goes through where there is room."""
    import errno

    from lfsf import synth

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "s" / "lf1.npz"))

    monkeypatch.setattr(synth, "write_scene", full)
    assert main(["synth", "paper", "--out", str(tmp_path / "s"), "--size", "16", "16", "--grid", "3"]) == 1
    err = capsys.readouterr().err.splitlines()[-1]
    assert err == (f"lfsf synth: error: {tmp_path / 's' / 'lf1.npz'}: no space left on the device (No space left on "
                   "device): free some, or write the outputs elsewhere (nothing was left half-written)")
    # a file-size limit (ulimit -f, a FAT disk's 4 GB) likewise: it had been "[Errno 27] File too large" and status 2

    def too_large(*args, **kwargs):
        raise OSError(errno.EFBIG, "File too large", str(tmp_path / "s" / "lf1.npz"))

    monkeypatch.setattr(synth, "write_scene", too_large)
    assert main(["synth", "paper", "--out", str(tmp_path / "s"), "--size", "16", "16", "--grid", "3"]) == 1
    err = capsys.readouterr().err.splitlines()[-1]
    assert err.startswith(f"lfsf synth: error: {tmp_path / 's' / 'lf1.npz'}: file too large (File too large): beyond "
                          "the file system's or this process's file-size limit (ulimit -f)"), err


def test_results_are_written_as_one_set_or_not_at_all(tmp_path):
    """A result that cannot be written (here a folder holds its name) leaves none of the
    others behind, and the message names it, not a temporary file."""
    np.savez(tmp_path / "a.npz", views=np.full((3, 3, 16, 16), 0.5, np.float32))
    (tmp_path / "r" / "disp2.png").mkdir(parents=True)
    status, _, err = lfsf("run", tmp_path / "a.npz", tmp_path / "a.npz", "--out", tmp_path / "r", "--preset", "fast")
    assert_clean_error(status, err, "disp2.png", "is a folder")
    assert ".part" not in err
    assert sorted(p.name for p in (tmp_path / "r").iterdir()) == ["disp2.png"]


def test_outputs_are_written_through_symbolic_links_and_into_devices(tmp_path):
    """--json LINK replaced the link with a file (and its target never changed); --json
    /dev/stdout, a link to a device, would have replaced the device."""
    import stat

    from lfsf._files import write_bytes_atomic

    (tmp_path / "target.json").write_text("old")
    (tmp_path / "link.json").symlink_to("target.json")
    write_bytes_atomic(tmp_path / "link.json", b"{}")
    assert (tmp_path / "link.json").is_symlink() and (tmp_path / "target.json").read_bytes() == b"{}"
    (tmp_path / "null").symlink_to("/dev/null")
    write_bytes_atomic(tmp_path / "null", b"{}")
    assert (tmp_path / "null").is_symlink() and stat.S_ISCHR(os.stat("/dev/null").st_mode)
    assert not list(tmp_path.glob(".*.part*"))


def test_an_output_folder_that_is_a_broken_link_is_refused_before_any_work(tmp_path):
    from lfsf._files import output_folder

    (tmp_path / "out").symlink_to(tmp_path / "gone")
    for create in (False, True):
        with pytest.raises(ValueError, match=r"out/r: cannot write results there: .*out is a broken symbolic link"):
            output_folder(tmp_path / "out" / "r", create=create)


def test_an_output_folder_name_too_long_beneath_a_missing_folder_is_refused_before_any_work(tmp_path):
    """stat says "no such file" of a 256-byte name beneath a folder not made yet: the
    name's length is checked, not left to the mkdir after the estimate (which also left
    the folders above it behind)."""
    from lfsf._files import output_folder

    for create in (False, True):
        with pytest.raises(ValueError, match=r"cannot make the output folder: the name q{40}… is 256 bytes long, "
                                             r"more than the 255"):
            output_folder(tmp_path / "x" / ("q" * 256) / "y", create=create)
        assert not (tmp_path / "x").exists()
    assert output_folder(tmp_path / "x" / ("q" * 255)).is_dir()


def test_a_folder_where_a_result_goes_is_refused_before_the_estimate(tmp_path, monkeypatch, capsys):
    from lfsf import estimate

    monkeypatch.setattr(estimate, "estimate_scene_flow", lambda *a, **k: pytest.fail("estimated"))
    np.savez(tmp_path / "a.npz", views=np.full((3, 3, 16, 16), 0.5, np.float32))
    (tmp_path / "r" / "overview.png").mkdir(parents=True)
    assert main(["run", str(tmp_path / "a.npz"), str(tmp_path / "a.npz"), "--out", str(tmp_path / "r")]) == 2
    assert "overview.png: is a folder; overview.png cannot be written there" in capsys.readouterr().err


def test_synth_does_not_leave_an_earlier_renders_preview_beside_its_files(tmp_path):
    """paper's preview.png stayed beside slanted's light fields and ground truth."""
    common = ["--out", str(tmp_path), "--size", "16", "16", "--grid", "1", "--quiet"]
    assert main(["synth", "paper", *common, "--preview"]) == 0 and (tmp_path / "preview.png").is_file()
    assert main(["synth", "slanted", *common]) == 0
    assert not (tmp_path / "preview.png").exists()


def test_synth_preview_is_part_of_its_set_of_files(tmp_path, monkeypatch, capsys):
    """preview.png had been drawn after the three files were in place: a folder in its
    place failed the command (status 2) with them written, and an interrupt while it was
    drawn left the new light fields beside an earlier render's preview. It is now checked
    before the render and written with the others, or none are; the folders made for an
    interrupted render go too."""
    from lfsf import viz

    common = ["--size", "16", "16", "--grid", "3", "--quiet", "--preview"]
    (tmp_path / "a" / "preview.png").mkdir(parents=True)
    assert main(["synth", "paper", "--out", str(tmp_path / "a"), *common]) == 2
    assert "a/preview.png: is a folder" in capsys.readouterr().err
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["preview.png"]
    assert main(["synth", "paper", "--out", str(tmp_path / "b"), *common]) == 0
    before = {p.name: p.read_bytes() for p in (tmp_path / "b").iterdir()}

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(viz, "overview_figure", interrupted)
    assert main(["synth", "slanted", "--out", str(tmp_path / "b"), *common]) == 130
    assert {p.name: p.read_bytes() for p in (tmp_path / "b").iterdir()} == before
    assert main(["synth", "slanted", "--out", str(tmp_path / "c" / "d"), *common]) == 130
    assert not (tmp_path / "c").exists()


def test_a_failed_set_keeps_folders_it_did_not_make_and_a_users_own_preview(tmp_path, monkeypatch):
    """``new/../existing`` names ``existing``: listed by the path as typed, an empty
    folder of the user's had been removed when the set failed. A preview.png with no
    earlier render beside it is the user's: a render without --preview had removed it."""
    from lfsf import synth
    from lfsf._files import file_set

    (tmp_path / "existing").mkdir()
    monkeypatch.chdir(tmp_path)
    with pytest.raises(KeyboardInterrupt):
        with file_set(Path("new/../existing"), ["a.txt"]):
            raise KeyboardInterrupt
    assert (tmp_path / "existing").is_dir()
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "preview.png").write_bytes(b"mine")
    synth.write_scene("slanted", tmp_path / "photos", size=(16, 16), grid=3, device="cpu")
    assert (tmp_path / "photos" / "preview.png").read_bytes() == b"mine"
    synth.write_scene("slanted", tmp_path / "photos", size=(16, 16), grid=3, device="cpu", preview=True)
    synth.write_scene("slanted", tmp_path / "photos", size=(16, 16), grid=3, device="cpu")  # (an earlier render's)
    assert not (tmp_path / "photos" / "preview.png").exists()
    with pytest.raises(ValueError, match="frames .* must be a whole number, got 2.5"):
        synth.write_sequence("slanted", tmp_path / "seq", 2.5, size=(16, 16), grid=3, device="cpu")


def test_synth_refuses_an_earlier_sequences_frames_before_rendering(tmp_path, monkeypatch, capsys):
    from lfsf import synth

    common = ["--out", str(tmp_path), "--size", "16", "16", "--grid", "3", "--quiet"]
    assert main(["synth", "paper", *common, "--frames", "4"]) == 0
    monkeypatch.setattr(synth, "render_sequence", lambda *a, **k: pytest.fail("rendered before the check"))
    assert main(["synth", "paper", *common, "--frames", "3"]) == 2
    assert "holds frames of an earlier sequence (f003.npz)" in capsys.readouterr().err


def test_output_names_near_the_length_limit_still_get_a_temporary_name(tmp_path):
    from lfsf._files import write_bytes_atomic

    target = tmp_path / ("x" * 245 + ".json")
    write_bytes_atomic(target, b"{}")
    assert target.read_bytes() == b"{}"
    assert [p.name for p in tmp_path.iterdir()] == [target.name]


def test_too_long_an_input_name_is_a_clear_error(tmp_path):
    status, _, err = lfsf("run", tmp_path / ("y" * 300 + ".npz"), tmp_path / "b.npz", "--out", tmp_path / "r")
    assert_clean_error(status, err, "too long")


def test_views_with_their_axes_the_wrong_way_round_are_refused(tmp_path):
    """An .npz stored as [y, x, a, b] (views of 9×9 px on a 40×48 grid) had been read and
    estimated, status 0, into maps of 9×9 px."""
    views = np.random.default_rng(0).random((40, 48, 9, 9)).astype(np.float32)
    np.savez(tmp_path / "yxab.npz", views=views)
    status, _, err = lfsf("run", tmp_path / "yxab.npz", tmp_path / "yxab.npz", "--out", tmp_path / "r",
                          "--preset", "fast")
    assert_clean_error(status, err, "yxab.npz", "40×48 views of 9×9 pixels", "[y, x, a, b]")
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("frames", ["1", "0", "-3"])
def test_synth_frames_must_make_a_pair(tmp_path, frames):
    status, _, err = lfsf("synth", "paper", "--out", tmp_path / "s", "--frames", frames, "--size", "16", "16")
    assert_clean_error(status, err, f"--frames must be at least 2 (2: one pair), got {frames}")
    assert not (tmp_path / "s").exists()


def test_json_reports_are_strict_json():
    from lfsf._files import json_bytes

    text = json_bytes({"errors": {"mse": float("nan"), "epe": float("inf"), "n": [1.5, float("-inf")]}}).decode()
    assert json.loads(text, parse_constant=lambda c: pytest.fail(f"non-standard JSON constant {c}")) == {
        "errors": {"mse": None, "epe": None, "n": [1.5, None]}}


def test_ctrl_c_is_held_back_while_a_set_of_outputs_moves_into_place():
    """Also with other threads alive (the CPU launch pool's workers): the kernel may hand a
    process-wide SIGINT to any thread that does not mask it, so masking it in the main
    thread alone let about one interrupt in twenty through (a CI run caught it). Python's
    own handler is installed for the test: a process started in the background by a
    non-interactive shell (``pytest &``) inherits SIGINT ignored, which the held-back
    interrupt rightly respects."""
    import signal
    import threading
    import time

    from lfsf._files import interrupts_held

    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)
    stop = threading.Event()
    others = [threading.Thread(target=stop.wait, daemon=True) for _ in range(4)]
    for thread in others:
        thread.start()
    try:
        for trial in range(200):
            done = []
            with pytest.raises(KeyboardInterrupt):
                with interrupts_held():
                    os.kill(os.getpid(), signal.SIGINT)
                    for _ in range(1000):  # bytecodes at which a pending signal would be raised
                        pass
                    done.append("the body ran to its end")
                # the signal may reach a thread that the scheduler runs only later (on a
                # loaded machine, after the body's end): then it is raised here, as it
                # would be after a real set of moves
                for _ in range(200):
                    time.sleep(0.01)
            assert done, f"trial {trial}: the interrupt was not held back"
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        stop.set()
        signal.signal(signal.SIGINT, inherited)


def test_negative_numbers_in_any_notation_are_values_not_options(capsys):
    """``-1e-3`` and ``-.5`` are numbers (Python 3.11's argparse took them for unknown
    options: a camera's negative δ0 in scientific notation was refused); an unknown
    option is still one."""
    from lfsf.cli import build_parser

    args = build_parser().parse_args(["points", "r", "--camera", "100", "0.1", "-1e-3", "--principal", "-1.5e2",
                                      "-.5", "--out", "p.ply"])
    assert args.camera == ["100", "0.1", "-1e-3"] and args.principal == [-150.0, -0.5]
    with pytest.raises(SystemExit) as stop:
        build_parser().parse_args(["points", "r", "--camera", "100", "0.1", "-x", "--out", "p.ply"])
    assert stop.value.code == 2 and "unrecognized arguments: -x" in capsys.readouterr().err


def test_ctrl_c_while_the_parser_is_built_is_an_interrupt(monkeypatch, capsys):
    """Ctrl-C in the first moments, while the commands' parser is built, exits 130 with
    one line, as later, not with a traceback."""
    import lfsf.cli as cli

    def interrupted_build():
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", interrupted_build)
    assert cli.main(["demo"]) == 130
    err = capsys.readouterr().err
    assert err.strip() == "lfsf: interrupted", err

    def terminated_build():  # (SIGTERM: the installed command's handler raises Terminated; it read "interrupted")
        import signal

        from lfsf._errors import Terminated
        raise Terminated(signal.SIGTERM)

    monkeypatch.setattr(cli, "build_parser", terminated_build)
    assert cli.main(["demo"]) == 143
    assert capsys.readouterr().err.strip() == "lfsf: terminated"


def test_an_error_raised_while_interrupted_counts_as_the_interrupt(monkeypatch, capsys):
    """numpy's savez closes its zip in a finally: Ctrl-C during a write surfaced as a
    ValueError, reported as bad input (exit 2) instead of an interrupt (130)."""
    import lfsf.cli as cli

    def interrupted_write(args):
        try:
            raise KeyboardInterrupt
        finally:
            raise ValueError("Can't close the ZIP file while there is an open writing handle on it.")

    monkeypatch.setattr(cli, "cmd_synth", interrupted_write)
    parser = cli.build_parser()
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    parser._subparsers._group_actions[0].choices["synth"].set_defaults(func=interrupted_write)
    assert cli.main(["synth", "paper", "--out", "x"]) == 130
    assert "interrupted" in capsys.readouterr().err


@pytest.mark.parametrize("script,args,needle", [
    ("sweep.py", ["--vary", "warps"], "--vary expects"),
    # argparse's own errors, one line too
    ("sweep.py", ["--bogus"], "unrecognized arguments: --bogus (sweep.py --help lists the options)"),
    ("compare_peers.py", ["--size", "160"], "expected 2 arguments"),
    ("gen_median_networks.py", ["--bogus"], "unrecognized arguments: --bogus"),
    ("sweep.py", ["--vary", "warps=-1", "--scenes", "paper"], "warps must be in"),
    ("sweep.py", ["--seeds", "0"], "--seeds must be at least 1"),
    ("sweep.py", ["--seeds", "3"], "needs --perturb"),
    ("sweep.py", ["--perturb", "0.01"], "--perturb needs --seeds"),
    ("sweep.py", ["--perturb", "-0.1"], "--perturb must be a finite number"),
    ("sequence.py", ["--frames", "1"], "--frames must be at least 3"),
    ("lenslet_example.py", ["{tmp}/x", "--preset", "slow"], "unknown preset 'slow'"),
    # each of these was a traceback (status 1), some only after the whole run
    ("lenslet_example.py", ["{tmp}/x", "--pitch", "inf"], "--pitch must be in 8…32"),
    ("compare_peers.py", ["--grid", "0"], "grid rows must be in 1…33, got 0"),
    ("compare_peers.py", ["--device", "gpu"], "unknown device 'gpu'"),
    ("compare_peers.py", ["--json", "{tmp}/gt/x.json"], "is a file, not a folder"),
    ("compare_peers.py", ["--scenes", "--methods", "lfsf"], "nothing to compare: '--scenes' without names"),
    ("compare_peers.py", ["--no-synth", "--methods", "lfsf"], "nothing to compare: --no-synth without --real"),
    ("compare_peers.py", ["--real", "--no-synth", "--data", "{tmp}"], "--real: no real data under"),
    ("fine_textures.py", ["--textures", "wood"], "unknown texture(s) ['wood']"),
    ("fine_textures.py", ["--shifts", "30,0"], "--shifts 30,0: at most 20 px each way"),
    ("fine_textures.py", ["--shifts", "3"], "--shifts 3: expected DU,DV"),
    ("final_steps.py", ["--step", "depth", "--grid", "99"], "grid rows must be in 1…33, got 99"),
    ("flow_noise.py", ["--scenes", "nope"], "unknown scene 'nope'"),
    ("flow_noise.py", ["--noise", "5"], "noise sigma must be a number from 0 to 1"),
    ("hci_breakdown.py", ["{tmp}", "--save", "{tmp}/"], "give a file name ending in .npy"),
    ("hci_breakdown.py", ["{tmp}"], "found no light-field views"),
    ("profile_kernels.py", ["--json", ""], "is a folder, not a file to write"),
    ("bench_decode.py", ["nope"], "expected 'cases' or 'illum [BAYER]'"),
    # tracebacks (status 1), or a --json folder refused only after every run
    ("perturbation_spread.py", ["--size", "0", "48"], "image width must be in 8…8192, got 0"),
    ("perturbation_spread.py", ["--device", "cuda:3"], "device 'cuda:3' is not on this machine"),
    ("perturbation_spread.py", ["--json", "{tmp}"], "is a folder, not a file to write"),
    ("joint_vs_stereo.py", ["--device", "cuda:3"], "device 'cuda:3' is not on this machine"),
    ("joint_vs_stereo.py", ["--json", "{tmp}"], "is a folder, not a file to write"),
    # sizes whose 8-px border leaves nothing to score: refused after the work, or not at all
    ("joint_vs_stereo.py", ["--size", "16", "16", "--grid", "3", "paper"], "--size must be at least 17 17"),
    ("sweep.py", ["--size", "16", "16", "--scenes", "paper"], "--size must be at least 17 17"),
    ("sequence.py", ["--size", "8", "8"], "--size must be at least 17 17"),
    ("lenslet_example.py", ["{tmp}/lx", "--size", "16", "16"], "--size must be at least 17 17"),
    # a grid without disparities: each lfsf row failed, cut mid-sentence, and plenpy still scored
    ("compare_peers.py", ["--grid", "1", "--scenes", "paper", "--size", "96", "72"], "--grid must be at least 2"),
])
def test_scripts_answer_bad_options_in_one_line(tmp_path, script, args, needle):
    (tmp_path / "gt").write_text("a file")
    (tmp_path / "gt_disp_lowres.pfm").write_text("only checked to be there")
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    proc = subprocess.run([sys.executable, os.path.join(root, "scripts", script), *[a.format(tmp=tmp_path) for a in args]],
                          capture_output=True, text=True, env={**os.environ, "LFSF_DEVICE": ""})
    assert_clean_error(proc.returncode, proc.stderr, needle)


class _Stream(io_module.StringIO):
    def __init__(self, tty):
        super().__init__()
        self.tty = tty

    def isatty(self):
        return self.tty


@pytest.mark.parametrize("tty", [False, True])
def test_the_estimators_notes_reach_a_log_and_the_progress_only_a_terminal(monkeypatch, tty):
    from lfsf.cli import _Progress
    from lfsf.estimate import Note

    for quiet in (False, True):
        stream = _Stream(tty)
        monkeypatch.setattr(sys, "stderr", stream)
        progress = _Progress(argparse.Namespace(command="run", quiet=quiet))
        progress("level 1/3 (40×30), warp 1/3")
        progress(Note("exposure: not matched, the gain fitted (5.000) is beyond the 4× (either way) that is undone"))
        progress("level 2/3 (80×60), warp 1/3")
        progress.done()
        text = stream.getvalue()
        if quiet:
            assert text == ""
        elif tty:  # the note on a line of its own, the progress overwritten in place
            lines = text.split("\n")
            assert "exposure: not matched" in lines[0] and "level 1/3" in lines[0] and lines[0].startswith("\r")
            assert "level 2/3" in lines[1] and lines[2] == ""
        else:
            assert text == "lfsf run: exposure: not matched, the gain fitted (5.000) is beyond the 4× (either way) " \
                           "that is undone\n"
    # on a narrow terminal a progress line is cut to its width (a line that wraps is not
    # overwritten by the next); a note is whole
    monkeypatch.setattr(sys, "stderr", _Stream(True))
    monkeypatch.setenv("COLUMNS", "30")
    progress = _Progress(argparse.Namespace(command="run", quiet=False))
    progress("level 1/3 (40×30), warp 1/3, iteration 20 of 100")
    progress(Note("a note longer than the terminal is wide, whole"))
    lines = sys.stderr.getvalue().split("\n")
    assert lines[0].startswith("\r[") and lines[0].split("\r")[1].endswith("…") and len(lines[0].split("\r")[1]) == 29
    assert lines[0].endswith("a note longer than the terminal is wide, whole")
    # a terminal that says it is 0 columns wide (`script`, some containers) is taken for
    # one of unknown width: the lines had all been cut to "…"
    import os as _os

    class _Described(_Stream):
        def fileno(self):
            return 2

    monkeypatch.setattr(sys, "stderr", _Described(True))
    monkeypatch.delenv("COLUMNS")
    monkeypatch.setattr(_os, "get_terminal_size", lambda *a: _os.terminal_size((0, 0)))
    progress = _Progress(argparse.Namespace(command="run", quiet=False))
    progress("level 1/3 (40×30), warp 1/3")
    assert sys.stderr.getvalue().endswith("level 1/3 (40×30), warp 1/3"), sys.stderr.getvalue()
    # on an ASCII terminal × is written \xd7, four columns: the line is cut to its width as
    # shown (it had been counted in characters, and wrapped), and ends in "..."

    class _Ascii(_Stream):
        encoding = "ascii"

    monkeypatch.setattr(sys, "stderr", _Ascii(True))
    monkeypatch.setenv("COLUMNS", "40")
    progress = _Progress(argparse.Namespace(command="run", quiet=False))
    progress("level 1/3 (40×30), warp 1/3, iteration 20 of 100")
    shown = sys.stderr.getvalue().split("\r")[1]
    assert shown.startswith("[") and shown.endswith("] level 1/3 (40\\xd730), war...") and len(shown) == 39, shown


def test_run_says_in_its_log_that_it_matched_t2s_exposure(tmp_path):
    """Not on a terminal (a log, a pipe, a batch job) the exposure match is still said."""
    assert main(["synth", "slanted", "--out", str(tmp_path / "s"), "--size", "128", "96", "--grid", "3",
                 "--quiet"]) == 0
    with np.load(tmp_path / "s" / "lf2.npz") as z:
        np.savez(tmp_path / "dark.npz", views=(0.5 * z["views"]).astype(np.float32))
    status, _, err = lfsf("run", tmp_path / "s" / "lf1.npz", tmp_path / "dark.npz", "--out", tmp_path / "r",
                          "--preset", "flow")
    assert status == 0, err
    found = re.search(r"^lfsf run: exposure: t2 matched to t1 by I ↦ ([0-9.]+)·I", err, flags=re.M)
    assert found and abs(float(found.group(1)) - 2.0) < 0.1, err
    status, _, err = lfsf("run", tmp_path / "s" / "lf1.npz", tmp_path / "dark.npz", "--out", tmp_path / "q",
                          "--preset", "flow", "--quiet")
    assert status == 0 and err == "", err


@pytest.mark.parametrize("status", [0, 2, 129, 130, 143])
def test_the_command_ends_at_once_after_an_interrupt(status):
    """``lfsf.cli.entry`` (the installed command): after Ctrl-C (status 130) or SIGTERM
    (143) the process ends without the interpreter's shutdown (no atexit, no thread joins,
    no collection of what the interrupt left half made, whose errors printed tracebacks
    after "interrupted"); any other status exits as usual."""
    code = ("import atexit, lfsf.cli as c; atexit.register(lambda: print('shutdown ran', flush=True)); "
            f"c.main = lambda: {status}; c.entry()")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == status, proc.stderr
    assert ("shutdown ran" in proc.stdout) == (status not in (129, 130, 143)), proc.stdout


@pytest.mark.parametrize("signame, status, said", [("SIGINT", 130, "interrupted"), ("SIGTERM", 143, "terminated")])
def test_a_signal_whose_exception_is_lost_in_a_finaliser_still_ends_the_command(signame, status, said):
    """A signal whose handler runs inside a ``__del__`` (a Warp array freed as it came)
    raises there, where Python drops the exception: it had printed "Exception ignored in
    …" with a traceback and the command went on to status 0. It is sent again and ends
    the command as any other."""
    code = ("import signal, time, lfsf.cli as c\n"
            "class Freed:\n"
            f"    def __del__(self): signal.raise_signal(signal.{signame})\n"
            "def command():\n"
            "    Freed()\n"
            "    time.sleep(5)\n"
            "    return 0\n"
            "c.main = lambda: c.run_script(command, prog='lfsf x')\n"
            "c.entry()\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert (proc.returncode, proc.stderr) == (status, f"lfsf x: {said}\n")


@pytest.mark.parametrize("signame, status, said", [("SIGINT", 130, "interrupted"), ("SIGTERM", 143, "terminated")])
def test_a_signal_lost_in_a_finaliser_during_an_estimate_ends_the_command_at_once(signame, status, said):
    """Inside a command, the estimate's own guard (lfsf.estimate_scene_flow) sees the
    command's signal handlers, not Python's, and had kept such a signal to raise as the
    estimate ended: lfsf run went on to the end of the estimate (minutes; under a
    scheduler's SIGTERM, up to its SIGKILL). It leaves it to the command's guard, which
    sends it again at once."""
    code = ("import signal, time, lfsf.cli as c\n"
            "from lfsf._errors import interrupts_kept\n"
            "class Freed:\n"
            f"    def __del__(self): signal.raise_signal(signal.{signame})\n"
            "def command():\n"
            "    with interrupts_kept():\n"
            "        Freed()\n"
            "        time.sleep(5)\n"
            "        print('ran to its end', flush=True)\n"
            "    return 0\n"
            "c.main = lambda: c.run_script(command, prog='lfsf x')\n"
            "c.entry()\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    # (nothing on stdout: ended within the body, not at its end)
    assert (proc.returncode, proc.stderr, proc.stdout) == (status, f"lfsf x: {said}\n", "")


def test_a_signal_between_the_commands_end_and_the_exit_is_the_commands_interrupt():
    """Between the command's handlers being put back and its end (here, main returning)
    a SIGTERM had the default action: the process died by the signal without a word."""
    code = ("import os, signal, lfsf.cli as c\n"
            "c.main = lambda: (os.kill(os.getpid(), signal.SIGTERM), 0)[1]\n"
            "c.entry()\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert (proc.returncode, proc.stderr) == (143, "lfsf: terminated\n")


@pytest.mark.parametrize("signame", ["SIGINT", "SIGTERM"])
def test_a_signal_during_the_shutdown_after_the_command_ended_changes_nothing(signame):
    """Once the command has ended (status 0, its results written and reported), a Ctrl-C
    or SIGTERM in the interpreter's shutdown (here from an atexit handler, as it joins the
    thread pool) had printed a traceback or turned the status into 130/143."""
    code = ("import atexit, os, signal, time, lfsf.cli as c; "
            f"atexit.register(lambda: (os.kill(os.getpid(), signal.{signame}), time.sleep(0.2))); "
            "c.main = lambda: 0; c.entry()")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0 and proc.stderr == "", (proc.returncode, proc.stderr)


def test_sigterm_is_held_back_while_a_set_of_outputs_moves_into_place():
    """SIGTERM (``kill``, ``timeout``, a job limit) is held back as Ctrl-C is, and then
    ends the command as an interrupt does: :class:`Terminated`, a KeyboardInterrupt."""
    import signal

    from lfsf._errors import Terminated, terminate_as_interrupt
    from lfsf._files import interrupts_held

    before = signal.getsignal(signal.SIGTERM)
    done = []
    with pytest.raises(Terminated):
        with terminate_as_interrupt():
            with interrupts_held():
                os.kill(os.getpid(), signal.SIGTERM)
                for _ in range(1000):  # bytecodes at which a pending signal would be raised
                    pass
                done.append("the body ran to its end")
    assert done
    assert signal.getsignal(signal.SIGTERM) == before  # (restored on the way out)


@pytest.mark.parametrize("name,status,said", [("SIGTERM", 143, "terminated"), ("SIGHUP", 129, "hung up (SIGHUP)")])
def test_sigterm_while_results_are_written_leaves_none_and_exits_143(tmp_path, monkeypatch, capsys, name, status,
                                                                       said):
    """A SIGTERM that comes while ``lfsf run`` writes its results (here once the first file
    is in the temporary folder) removes that folder, as Ctrl-C does, and the command ends
    with "terminated" and status 143: killed outright, it left a hidden ``.lfsf-set.*``
    folder of partial files, which ``lfsf batch`` then refused to replace. So does a
    SIGHUP (an ssh session gone), with status 129."""
    import signal

    views = np.random.default_rng(0).random((3, 3, 24, 32)).astype(np.float32)
    np.savez(tmp_path / "a.npz", views=views)
    write_pfm = io.write_pfm

    def write_then_terminated(path, *args, **kwargs):
        write_pfm(path, *args, **kwargs)
        os.kill(os.getpid(), getattr(signal, name))

    monkeypatch.setattr(io, "write_pfm", write_then_terminated)
    out = tmp_path / "r"
    got = main(["run", str(tmp_path / "a.npz"), str(tmp_path / "a.npz"), "--out", str(out), "--preset", "flow",
                "--quiet"])
    assert got == status
    assert capsys.readouterr().err.strip() == f"lfsf run: {said}"
    assert not out.exists()  # (nor the output folder it made for them)
    assert not list(tmp_path.rglob(".lfsf-set*"))


def test_the_temporary_folders_of_killed_runs_are_removed(tmp_path):
    """A process killed outright (SIGKILL, the out-of-memory killer) leaves its temporary
    folder; the next set written into the same folder removes those of processes of this
    machine that are gone, and leaves a live one's, another machine's and any other."""
    from lfsf import _files

    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    host = _files._host()
    other = ("0" if host[0] != "0" else "1") + host[1:]  # another machine's
    names = {"dead": f".lfsf-set.{host}-{gone}.abc", "live": f".lfsf-set.{host}-{os.getppid()}.abc",
             "elsewhere": f".lfsf-set.{other}-{gone}.abc", "older": ".lfsf-set.abc123"}
    for name in names.values():
        (tmp_path / name).mkdir()
        (tmp_path / name / "disp1.pfm").write_bytes(b"partial")
    with _files.file_set(tmp_path, ["a.txt"]) as tmp:
        assert tmp.name.startswith(f".lfsf-set.{host}-{os.getpid()}.")
        (tmp / "a.txt").write_text("new")
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == sorted([names["live"], names["elsewhere"], names["older"], "a.txt"])


def test_a_warning_is_one_line_of_the_command(tmp_path):
    """A warning (here: an HCI folder's parameters.cfg that is no INI file, ignored) is
    printed as ``lfsf run: warning: …`` on one line, not as Python's file, line and source."""
    views = np.random.default_rng(0).random((3, 3, 24, 32)).astype(np.float32)
    io.write_lightfield(views, tmp_path / "hci")
    (tmp_path / "hci" / "parameters.cfg").write_text("garbage [[[\n")
    status, _, err = lfsf("run", tmp_path / "hci", tmp_path / "hci", "--out", tmp_path / "r", "--preset", "fast",
                          "--quiet")
    assert status == 0, err
    assert err.splitlines() == [f"lfsf run: warning: {tmp_path / 'hci' / 'parameters.cfg'}: ignored, not an INI "
                                "file (File contains no section headers)",
                                f"lfsf run: warning: {tmp_path / 'hci'}: 9 HCI views with no grid given "
                                "(parameters.cfg's num_cams_x and num_cams_y) are read as a 3×3 grid; a rig of "
                                "one row or column of 9 cameras needs them"], err


def test_a_reader_that_goes_away_does_not_cost_the_results(tmp_path):
    """``lfsf demo | head -1``: once the reader has closed the pipe, what the demo prints
    is dropped, and it still writes its files and ends with status 0 (it had ended in
    "[Errno 32] Broken pipe", status 2, with nothing written)."""
    proc = subprocess.Popen([sys.executable, "-m", "lfsf", "demo", "--size", "24", "24", "--grid", "9", "--preset",
                             "fast", "--out", str(tmp_path / "d")], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env={**os.environ, "LFSF_DEVICE": ""})
    first = proc.stdout.readline()
    proc.stdout.close()
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=300) == 0, err
    assert first.startswith(b"lfsf demo: scene 'paper'") and err == ""
    assert len(list((tmp_path / "d").iterdir())) == 8


def test_memory_that_runs_out_is_one_line_and_status_1(capsys):
    """numpy's MemoryError and Warp's failed allocation (a RuntimeError) end a command in
    one line with status 1 (they were a traceback of 16 frames); any other RuntimeError
    stays a traceback, a bug to see."""
    from lfsf._errors import run_script

    def numpy_out():
        np.empty((1 << 40, 1 << 20), np.float32)

    def warp_out():
        raise RuntimeError("Failed to allocate 79872000 bytes on device 'cpu'")

    for fn, said in ((numpy_out, "Unable to allocate"), (warp_out, "Failed to allocate 79872000 bytes on device 'cpu'")):
        assert run_script(fn, prog="lfsf run") == 1
        err = capsys.readouterr().err
        assert err.startswith(f"lfsf run: error: out of memory ({said}") and err.count("\n") == 1, err
    with pytest.raises(RuntimeError, match="a bug"):
        run_script(lambda: (_ for _ in ()).throw(RuntimeError("a bug")), prog="lfsf run")


def test_run_with_ground_truth_prints_the_errors_and_draws_them(tmp_path, capsys):
    """``lfsf run --gt``: the errors as ``lfsf eval`` prints them, and the truth and the
    errors in overview.png (two more rows); a ground truth of another size is refused
    before any work, as one line."""
    from lfsf.evaluate import evaluate, format_table, load_estimate

    assert main(["synth", "paper", "--out", str(tmp_path / "s"), "--size", "48", "36", "--grid", "3",
                 "--quiet"]) == 0
    lf1, lf2, gt = (str(tmp_path / "s" / n) for n in ("lf1.npz", "lf2.npz", "gt.npz"))
    capsys.readouterr()
    assert main(["run", lf1, lf2, "--out", str(tmp_path / "r"), "--preset", "fast", "--gt", gt, "--quiet"]) == 0
    out = capsys.readouterr().out
    with np.load(gt) as z:
        truth = {k: z[k] for k in z.files}
    assert format_table(evaluate(load_estimate(tmp_path / "r"), truth, border=8)).splitlines()[1] in out
    assert out.startswith(f"{tmp_path / 'r'} against {gt} (border 8 px)\n")
    assert main(["run", lf1, lf2, "--out", str(tmp_path / "plain"), "--preset", "fast", "--quiet"]) == 0
    with_truth, plain = (io.read_image(tmp_path / d / "overview.png") for d in ("r", "plain"))
    assert with_truth.shape[1] == plain.shape[1] and with_truth.shape[0] > plain.shape[0] + 2 * 36
    np.savez(tmp_path / "small.npz", disp1=np.zeros((12, 16), np.float32))
    status = main(["run", lf1, lf2, "--out", str(tmp_path / "x"), "--gt", str(tmp_path / "small.npz")])
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1 and "'disp1' is 16×12, and the light field's views" in err, err
    assert not (tmp_path / "x").exists()
    # nothing to score (a flow-only run against δ1 alone): refused before the estimate, not
    # after it (evaluate's own checks, the border's too, tried on the truth itself)
    from lfsf.io import write_pfm

    write_pfm(tmp_path / "gt_disp_lowres.pfm", np.zeros((36, 48), np.float32))
    status = main(["run", lf1, lf2, "--out", str(tmp_path / "x"), "--preset", "flow", "--gt",
                   str(tmp_path / "gt_disp_lowres.pfm"), "--quiet"])
    err = capsys.readouterr().err
    assert status == 2 and "cannot score this run against it: it holds disp1, and a flow-only run" in err, err
    assert not (tmp_path / "x").exists()
    # a flow-only run against the whole truth: the table of the flow, and (as lfsf eval
    # says) which variables it leaves out and why; it said nothing of them
    assert main(["run", lf1, lf2, "--out", str(tmp_path / "f"), "--preset", "flow", "--gt", gt, "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "\ndisp1 " not in out and "\nflow " in out, out
    assert out.rstrip().endswith(f"not evaluated in {tmp_path / 'f'}: disp1, disp2 (a flow-only result, "
                                 "--preset flow or one sampling circle: its disparities are zeros, not estimates)")
    # and the line naming what it wrote says which of its files hold no estimate
    assert main(["run", lf1, lf2, "--out", str(tmp_path / "g"), "--preset", "flow"]) == 0
    assert "files to" in (err := capsys.readouterr().err) and err.rstrip().endswith(
        "(disp1 and disp2: zeros, not estimated by a flow-only run)"), err


def test_compare_peers_without_a_peer_says_so_in_one_line(tmp_path):
    """A missing peer, or OpenCV without its contrib modules (plain opencv-python has no
    cv2.optflow), is one line naming what to install before any run (it was a
    ModuleNotFoundError traceback); `lfsf bench peers` gives such a peer a row saying so."""
    (tmp_path / "cv2.py").write_text("__version__ = '4.9.0'  # OpenCV without its contrib modules\n")
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = {**os.environ, "LFSF_DEVICE": "", "PYTHONPATH": str(tmp_path)}
    proc = subprocess.run([sys.executable, os.path.join(root, "scripts", "compare_peers.py"), "--size", "48", "40",
                           "--scenes", "slanted"], capture_output=True, text=True, env=env)
    assert_clean_error(proc.returncode, proc.stderr, "OpenCV 4.9.0 lacks its contrib modules (cv2.optflow)",
                       "--methods lfsf")
    code = ("import json, lfsf.bench as b; print(json.dumps([r for r in b.bench_peers((48, 40), 'cpu', 1) "
            "if r['method'] == 'opencv DualTVL1']))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert proc.returncode == 0, proc.stderr
    (row,) = json.loads(proc.stdout)
    assert row["epe"] is None and "lacks its contrib modules" in row["note"], row


def test_the_machine_in_a_temporary_folders_name_is_its_whole_name(monkeypatch):
    """Host names that differ only in what a cut-down name dropped are two machines
    (``ip-10-0-1-23`` and ``ip-10-0-12-3`` were one, and each took the other's live
    folders for a dead process's)."""
    import socket

    from lfsf import _files

    names = {}
    for host in ("ip-10-0-1-23.ec2.internal", "ip-10-0-12-3.ec2.internal", "gpu-a100-partition-node01",
                 "gpu-a100-partition-node02"):
        monkeypatch.setattr(socket, "gethostname", lambda host=host: host)
        names[host] = _files._host()
    assert len(set(names.values())) == 4 and all(len(n) == 12 for n in names.values())


def test_a_signal_while_the_handlers_are_put_back_leaves_none_swapped():
    """interrupts_held: a SIGINT whose handler raises just after SIGINT's own handler is
    back still puts SIGTERM's back (it was left swallowing every later SIGTERM); and
    where both came while held, SIGTERM is the one delivered first."""
    import signal

    from lfsf import _files
    from lfsf._errors import Terminated, terminate_as_interrupt

    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)
    before = signal.getsignal(signal.SIGTERM)
    try:
        restore = _files._restore

        def restore_then_interrupted(handlers):
            def first_then_signal(items):
                if not items:
                    return
                (s, h), rest = items[0], items[1:]
                try:
                    signal.signal(s, h)
                    if s == signal.SIGINT:
                        raise KeyboardInterrupt  # (as the handler would, once SIGINT's is back)
                finally:
                    restore(rest)
            first_then_signal(sorted(handlers, key=lambda item: item[0] != signal.SIGINT))

        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(_files, "_restore", restore_then_interrupted)
            with pytest.raises(KeyboardInterrupt):
                with _files.interrupts_held():
                    pass
        assert signal.getsignal(signal.SIGTERM) == before and signal.getsignal(signal.SIGINT) is signal.default_int_handler
        # (a plain KeyboardInterrupt, SIGINT delivered first, is caught here and fails the test
        # by name: escaping, it had ended the whole pytest session without naming one)
        with pytest.raises(KeyboardInterrupt) as delivered:
            with terminate_as_interrupt():
                with _files.interrupts_held():
                    os.kill(os.getpid(), signal.SIGINT)
                    os.kill(os.getpid(), signal.SIGTERM)
                    for _ in range(1000):
                        pass
        assert isinstance(delivered.value, Terminated)
        assert signal.getsignal(signal.SIGTERM) == before
    finally:
        signal.signal(signal.SIGINT, inherited)


def test_an_eval_report_may_not_replace_the_truth_read_from_a_folder(tmp_path, capsys):
    """GT given as a folder is read from its gt.npz (or gt_disp_lowres.pfm): --json naming
    that file is refused too (it replaced the truth)."""
    (tmp_path / "scene").mkdir()
    (tmp_path / "scene" / "gt.npz").write_bytes(b"the ground truth")
    (tmp_path / "est.npz").write_bytes(b"a result")
    status = main(["eval", str(tmp_path / "est.npz"), str(tmp_path / "scene"), "--json",
                   str(tmp_path / "scene" / "gt.npz")])
    assert status == 2 and "which it reports on" in capsys.readouterr().err
    assert (tmp_path / "scene" / "gt.npz").read_bytes() == b"the ground truth"


def test_a_results_pictures_say_what_their_colours_mean(tmp_path):
    """disp1.png, disp2.png and flow.png draw no scale: each says its own in its PNG text
    (the disparities' range, shared by both, and the flow's full-colour magnitude), which
    viewers and PIL show; the pixels are those of the colour maps as before."""
    import re

    from PIL import Image

    from lfsf import viz
    from lfsf.estimate import SceneFlow, _colour_range

    rng = np.random.default_rng(0)
    d1, d2 = (rng.uniform(-2, 2, (24, 32)).astype(np.float32) for _ in range(2))
    u, v = (rng.uniform(-3, 3, (24, 32)).astype(np.float32) for _ in range(2))
    SceneFlow(d1, d2, u, v, params=Params.preset("fast"), radius=1.0, device="cpu").save(tmp_path)
    lo, hi = _colour_range(d1, d2)
    for name, d in (("disp1", d1), ("disp2", d2)):
        comment = Image.open(tmp_path / f"{name}.png").text["Comment"]
        assert f"in px per view step: {lo:.4g} (dark purple) to {hi:.4g} (yellow)" in comment, comment
        assert np.array_equal(io.read_image(tmp_path / f"{name}.png"), viz.disparity_to_color(d, lo, hi))
    comment = Image.open(tmp_path / "flow.png").text["Comment"]
    said = float(re.search(r"full colour at \|\(u,v\)\| = ([0-9.]+) px", comment).group(1))
    assert said == pytest.approx(float(np.hypot(u.astype(np.float64), v.astype(np.float64)).max()), rel=1e-3)
    assert np.array_equal(io.read_image(tmp_path / "flow.png"), viz.flow_to_color(u, v))


def test_results_never_replace_what_the_run_reads(tmp_path):
    """lfsf run and decode refuse, before any work, an output that is one of their inputs:
    a light field named sceneflow.npz in --out, a result file linked to an input, a
    ground truth that is an earlier result's disp1.pfm, a raw image named as a view of the
    folder it decodes into (each had been replaced by the results, status 0)."""
    import hashlib

    import imageio.v3 as iio

    assert main(["synth", "paper", "--out", str(tmp_path / "d"), "--size", "24", "20", "--grid", "3", "--quiet"]) == 0
    d = tmp_path / "d"
    (tmp_path / "r").mkdir()
    shutil.copy(d / "lf1.npz", tmp_path / "r" / "sceneflow.npz")
    (tmp_path / "l").mkdir()
    (tmp_path / "l" / "flow.flo").symlink_to(d / "lf2.npz")
    (tmp_path / "g").mkdir()
    shutil.copy(d / "gt.npz", tmp_path / "g" / "disp1.pfm")  # (any file: refused before it is read)
    (tmp_path / "dc").mkdir()
    for k in range(2):
        iio.imwrite(tmp_path / "dc" / f"input_Cam00{k}.png", np.full((64, 64), 1000 * (k + 1), np.uint16))
    digest = {p: hashlib.md5(p.read_bytes()).hexdigest() for p in tmp_path.rglob("*") if p.is_file()}
    for args, needle in (
            (["run", "r/sceneflow.npz", "d/lf2.npz", "--out", "r"], "r/sceneflow.npz: read by this run, and the results "
                                                                    "would replace it"),
            (["run", "d/lf1.npz", "d/lf2.npz", "--out", "l"], "l/flow.flo: a link to"),
            (["run", "d/lf1.npz", "d/lf2.npz", "--out", "g", "--gt", "g/disp1.pfm"], "g/disp1.pfm: read by this run"),
            (["decode", "dc/input_Cam000.png", "--white", "dc/input_Cam001.png", "--out", "dc"], "read by this run")):
        status, _, err = lfsf(*args, "--quiet", cwd=tmp_path)
        assert_clean_error(status, err, needle)
    assert {p: hashlib.md5(p.read_bytes()).hexdigest() for p in tmp_path.rglob("*") if p.is_file()} == digest


def test_a_closed_or_ascii_stdout_and_a_closed_stderr_are_no_failure(tmp_path):
    """``lfsf eval … >&-`` had ended in a traceback (print to a stdout that is None),
    ``2>&-`` silently with status 1 before any work, and an ASCII stdout with status 2 on
    the "×" of "MSE×100" (the --json report unwritten); a full stdout names stdout."""
    gt = {k: np.zeros((20, 20), np.float32) for k in ("disp1", "disp2", "u", "v")}
    np.savez(tmp_path / "gt.npz", **gt)
    command = f"{shlex.quote(sys.executable)} -m lfsf eval gt.npz gt.npz --border 2 --json e.json"
    env = {**os.environ, "LFSF_DEVICE": ""}
    for redirect, extra in ((">&-", {}), ("2>&-", {}), ("", {"PYTHONIOENCODING": "ascii"})):
        (tmp_path / "e.json").unlink(missing_ok=True)
        proc = subprocess.run(["bash", "-c", f"{command} {redirect}"], cwd=tmp_path, capture_output=True, text=True,
                              env={**env, **extra})
        assert proc.returncode == 0 and "Traceback" not in proc.stderr, (redirect, proc.stderr)
        assert (tmp_path / "e.json").exists()
    assert r"MSE\xd7100" in proc.stdout
    # the stream put in place of a closed one passes to child processes (a batch's Dask workers
    # had started without a stderr, and every pair failed), and the library runs without one
    probe = ("import os, subprocess, sys; from lfsf.cli import _usable_streams; _usable_streams(); "
             "print(os.get_inheritable(2), subprocess.run([sys.executable, '-c', 'import sys; print(sys.stderr "
             "is not None)'], capture_output=True, text=True).stdout.strip())")
    proc = subprocess.run(["bash", "-c", f"{shlex.quote(sys.executable)} -c {shlex.quote(probe)} 2>&-"],
                          capture_output=True, text=True, env=env)
    assert proc.stdout.split() == ["True", "True"], (proc.stdout, proc.stderr)
    library = "import lfsf.device as d; d.warp(); print('ok')"
    proc = subprocess.run(["bash", "-c", f"{shlex.quote(sys.executable)} -c {shlex.quote(library)} 2>&-"],
                          capture_output=True, text=True, env=env)
    assert proc.returncode == 0 and proc.stdout == "ok\n", (proc.returncode, proc.stdout)
    if os.path.exists("/dev/full"):
        proc = subprocess.run(["bash", "-c", f"{command} > /dev/full"], cwd=tmp_path, capture_output=True, text=True,
                              env=env)
        assert proc.returncode == 1 and "error: <stdout>: no space left on the device" in proc.stderr, proc.stderr


def test_a_hung_up_terminal_or_a_failing_stderr_does_not_end_the_work():
    """Writing to a terminal that has hung up raises EIO (an ssh session gone): dropped, as
    a reader gone is, so that the SIGHUP that follows ends the command with 129 (it had
    ended with status 1 on the message's own print); any failure of stderr is dropped;
    a full stdout names stdout."""
    import errno

    from lfsf.cli import _PipeSafe

    class Failing(io_module.StringIO):
        def __init__(self, code):
            super().__init__()
            self.code = code

        def write(self, text):
            raise OSError(self.code, os.strerror(self.code))

        def fileno(self):
            raise io_module.UnsupportedOperation("no descriptor")

    assert _PipeSafe(Failing(errno.EIO), "stdout").write("line\n") == 5
    assert _PipeSafe(Failing(errno.ENOSPC), "stderr").write("line\n") == 5
    with pytest.raises(OSError, match=r"No space left on device: '<stdout>'"):
        _PipeSafe(Failing(errno.ENOSPC), "stdout").write("line\n")


def test_run_warns_before_the_work_where_memory_will_not_do(tmp_path, monkeypatch, capsys):
    """Where the estimate's host memory (cli.memory_needed) is more than the machine has
    free, `lfsf run` says so before the work, with what --downsample 2 would need; with
    enough free, nothing."""
    from lfsf import cli, synth
    from lfsf.io import write_lightfield

    lf1, lf2, _ = synth.render_scene("paper", size=(48, 36), grid=5, device="cpu")
    write_lightfield(lf1, tmp_path / "lf1.npz")
    write_lightfield(lf2, tmp_path / "lf2.npz")
    needed = cli.memory_needed(48, 36, 2 * 25, 9)
    small = max(cli.memory_needed(24, 18, 2 * 25, 9), cli.MEMORY_FIXED + 48 * 36 * cli.MEMORY_PER_VALUE * 2 * 25)
    for free, warned in ((needed * 0.9, True), (needed * 1.1, False)):
        monkeypatch.setattr(cli, "_memory_available", lambda free=free: free)
        assert cli.main(["run", str(tmp_path / "lf1.npz"), str(tmp_path / "lf2.npz"), "--out", str(tmp_path / "r"),
                         "--preset", "fast", "--device", "cpu", "--quiet"]) == 0
        err = capsys.readouterr().err
        said = (f"warning: this estimate needs about {needed / 1e9:.1f} GB of memory, and {free / 1e9:.1f} GB are "
                f"free: it may run out (--downsample 2: about {small / 1e9:.1f} GB)")
        assert (said in err) is warned, err
    # on views already shrunk by --downsample 2, the next step is 4
    monkeypatch.setattr(cli, "_memory_available", lambda: 1.0)
    assert cli.main(["run", str(tmp_path / "lf1.npz"), str(tmp_path / "lf2.npz"), "--out", str(tmp_path / "r2"),
                     "--preset", "fast", "--device", "cpu", "--quiet", "--downsample", "2"]) == 0
    assert "it may run out (--downsample 4: about" in capsys.readouterr().err
