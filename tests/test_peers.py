"""The peer wrappers of lfsf/peers.py return lfsf's conventions (MODEL.md §1).

Each wrapper must recover a known synthetic shift (flow) or constant disparity (plenpy) in
OUR convention, with the right sign and axis order. The peers are the optional ``peers``
extra, which CI does not install: each test skips when its peer is missing.
"""

import numpy as np
import pytest


@pytest.fixture(scope="module")
def peers():
    pytest.importorskip("scipy")
    from lfsf import peers as module

    return module


INNER = (slice(10, -10), slice(10, -10))


@pytest.mark.parametrize("shift", [(1.3, -0.7), (-0.8, 1.6)])
def test_opencv_tvl1_recovers_a_shift_in_our_convention(peers, shift):
    pytest.importorskip("cv2")
    c1, c2 = peers.shifted_pair(*shift, size=(64, 48))
    u, v = peers.opencv_tvl1(c1, c2)
    assert u.shape == v.shape == (48, 64) and u.dtype == v.dtype == np.float32
    assert abs(float(np.mean(u[INNER])) - shift[0]) < 0.12
    assert abs(float(np.mean(v[INNER])) - shift[1]) < 0.12


@pytest.mark.parametrize("shift", [(1.3, -0.7), (-0.8, 1.6)])
def test_skimage_tvl1_recovers_a_shift_in_our_convention(peers, shift):
    pytest.importorskip("skimage")
    c1, c2 = peers.shifted_pair(*shift, size=(64, 48))
    u, v = peers.skimage_tvl1(c1, c2)
    assert u.shape == v.shape == (48, 64) and u.dtype == v.dtype == np.float32
    assert abs(float(np.mean(u[INNER])) - shift[0]) < 0.12
    assert abs(float(np.mean(v[INNER])) - shift[1]) < 0.12


@pytest.mark.parametrize("name, module", [("opencv_tvl1", "cv2"), ("skimage_tvl1", "skimage")])
def test_flow_peers_take_8_bit_images_and_refuse_counts_as_floats(peers, name, module):
    """uint8 images are scaled as lfsf scales them (OpenCV had clipped 0…255 to an image
    of 255s and returned zero flow); floats far outside [0, 1] are refused."""
    pytest.importorskip(module)
    flow = getattr(peers, name)
    c1, c2 = peers.shifted_pair(1.3, -0.7, size=(64, 48))
    q1, q2 = ((c * 255).round().astype(np.uint8) for c in (c1, c2))
    u, v = flow(q1, q2)
    assert abs(float(np.mean(u[INNER])) - 1.3) < 0.12 and abs(float(np.mean(v[INNER])) + 0.7) < 0.12
    expected = flow(q1 / np.float32(255), q2 / np.float32(255))
    assert np.allclose(u, expected[0], atol=1e-4) and np.allclose(v, expected[1], atol=1e-4)
    with pytest.raises(ValueError, match=r"^c1: values 4\.\d+…247\.\d, where the peers take \[0, 1\]: divide"):
        flow(c1 * 255, c2 * 255)
    with pytest.raises(ValueError, match=r"^c2: integer pixels of dtype int64"):
        flow(q1, q2.astype(np.int64))


def test_plenpy_refuses_a_grid_of_one_row(peers):
    """One row of views leaves plenpy's vertical EPIs a single line: a map of noise
    (MSE 0.99 against 0.58 on the 9×9 grid), without an error of its own."""
    pytest.importorskip("plenpy")
    views = peers.constant_disparity_views(1.0, 9, size=(64, 48))
    with pytest.raises(ValueError, match=r"at least 3 views along each axis of the grid, got 1×9"):
        peers.plenpy_disparity(views[4:5])
    eight = peers.plenpy_disparity((views * 255).round().astype(np.uint8))
    assert abs(float(np.median(eight[INNER])) - float(np.median(peers.plenpy_disparity(views)[INNER]))) < 0.01


def test_importing_plenpy_leaves_imageios_plugin_order_alone():
    """plenpy's import reorders imageio's plugins for the whole process; after it, lfsf
    read grey views with alpha as a KeyError. In a fresh interpreter (the import happens
    once), the order after the import is the order before it."""
    import subprocess
    import sys

    pytest.importorskip("plenpy")
    code = ("import imageio.config as c\n"
            "order = lambda: (list(c.known_plugins),\n"
            "                 [list(e.priority) for l in c.known_extensions.values() for e in l])\n"
            "before = order()\n"
            "from lfsf.peers import import_plenpy_lightfield\n"
            "import_plenpy_lightfield()\n"
            "import plenpy\n"
            "assert order() == before\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr


def test_shifted_pair_is_flow_in_our_convention(peers):
    # c2(p + u) == c1(p): sampling c2 at p + u gives back c1 (away from the border)
    c1, c2 = peers.shifted_pair(2.0, -1.0, size=(64, 48))
    assert np.allclose(c2[INNER[0].start - 1:-11, 12:-8], c1[INNER], atol=1e-5)


@pytest.mark.parametrize("delta", [0.5, -1.0])
def test_plenpy_disparity_recovers_a_constant_disparity_in_our_convention(peers, delta):
    pytest.importorskip("plenpy")
    views = peers.constant_disparity_views(delta, grid=9, size=(48, 48))
    d = peers.plenpy_disparity(views)
    assert d.shape == (48, 48) and d.dtype == np.float32
    med = float(np.median(d[INNER]))
    # plenpy underestimates by 3-7 % on 9×9 views (its own bias, see the docstring)
    assert np.sign(med) == np.sign(delta)
    assert abs(med - delta) < 0.1 * abs(delta)


def test_plenpy_axes_are_ours(peers):
    pytest.importorskip("plenpy")
    views = peers.constant_disparity_views(1.0, grid=9, size=(48, 48))
    swapped = peers.plenpy_disparity(views.transpose(0, 1, 3, 2))  # image axes only
    assert abs(float(np.median(swapped[INNER]))) < 0.5


def test_plenpy_nan_guard(peers):
    pytest.importorskip("plenpy")
    views = peers.constant_disparity_views(0.5, grid=9, size=(48, 48))
    # same result as the literal one-call version on ordinary input
    assert np.array_equal(peers.plenpy_disparity(views), peers.plenpy_disparity(views, nan_guard=False))
    # an exactly flat (black) patch: 0/0 in plenpy's structure tensor. Large enough that some
    # pixels have no finite estimate on any EPI (a 16-px patch had none such: the guard's
    # fill went untested, a mutation helper found)
    views = peers.constant_disparity_views(0.5, grid=9, size=(64, 48))
    views[:, :, 8:40, 8:56] = 0.0
    raw = peers.plenpy_disparity(views, nan_guard=False)
    guarded = peers.plenpy_disparity(views)
    assert not np.isfinite(raw).all()  # (the fusion spreads plenpy's NaNs over the whole map)
    assert np.isfinite(guarded).all()
    finite = np.isfinite(raw)
    assert np.array_equal(raw[finite], guarded[finite])
    assert abs(float(np.median(guarded[42:, 8:56])) - 0.5) < 0.1  # (the textured rows keep their δ)


def test_disparity_at_t1_pixels_samples_at_p_plus_u(peers):
    h, w = 20, 30
    ramp = np.tile(np.arange(w, dtype=np.float32), (h, 1)) + 100 * np.arange(h, dtype=np.float32)[:, None]
    u = np.full((h, w), 2.5, np.float32)
    v = np.full((h, w), -1.0, np.float32)
    out = peers.disparity_at_t1_pixels(ramp, u, v)
    inner = (slice(2, -2), slice(2, -4))
    assert np.allclose(out[inner], (ramp + 2.5 - 100.0)[inner], atol=1e-4)


def _compare_peers_script():
    from conftest import load_script

    return load_script("compare_peers")


def test_compare_peers_selects_built_in_and_random_scenes(capsys):
    script = _compare_peers_script()

    def scenes(*argv):
        return script.selected_scenes(script.build_parser().parse_args(list(argv)))

    assert scenes() == ["paper", "slanted", "large_motion", "weak_texture"]
    assert scenes("--random", "2") == ["paper", "slanted", "large_motion", "weak_texture", "random-0", "random-1"]
    assert scenes("--scenes", "--random", "2", "--random-from", "7") == ["random-7", "random-8"]
    assert scenes("--scenes", "slanted", "random-3") == ["slanted", "random-3"]
    with pytest.raises(ValueError, match="random-N"):
        scenes("--scenes", "paper", "randm-3")
    assert script.main(["--scenes", "nope", "--methods", "peers"]) == 2
    assert "unknown scene" in capsys.readouterr().err
    assert script.main(["--noise", "-0.01", "--methods", "peers"]) == 2
    assert "--noise" in capsys.readouterr().err
    assert script.main(["--vignetting", "0.6", "--methods", "peers"]) == 2
    assert "--vignetting" in capsys.readouterr().err


def _views_handed_over(scene, *options, runs=1):
    """The (t1, t2) views every method gets from ``compare_peers.run_scene`` on ``scene``
    at 48×32 with 3×3 views and the given options, ``runs`` times (a recording method)."""
    script = _compare_peers_script()
    args = script.build_parser().parse_args(["--size", "48", "32", "--grid", "3", *options])
    seen = []

    def fake(lf1, lf2, device):
        seen.append((lf1.views.copy(), lf2.views.copy()))
        return {"u": np.zeros(lf1.centre.shape, np.float32), "v": np.zeros(lf1.centre.shape, np.float32)}

    for _ in range(runs):
        rows = script.run_scene(scene, args, False, {"fake": fake}, {"fake"})
        assert rows[0]["method"] == "fake" and rows[0]["flow_epe"] is not None
    return seen


def test_compare_peers_noise_reaches_every_method_reproducibly():
    """``--noise`` hands every method the same noisy pair, independent at t1 and t2."""
    from lfsf import synth

    seen = _views_handed_over("weak_texture", "--noise", "0.02", runs=2)
    clean1, clean2, _ = synth.render_scene("weak_texture", size=(48, 32), grid=3)
    (a1, a2), (b1, b2) = seen
    np.testing.assert_array_equal(a1, b1)
    np.testing.assert_array_equal(a2, b2)
    n1, n2 = a1 - clean1.views, a2 - clean2.views
    inner = (clean1.views > 0.1) & (clean1.views < 0.9) & (clean2.views > 0.1) & (clean2.views < 0.9)
    assert abs(n1[inner].std() - 0.02) < 0.002 and abs(n2[inner].std() - 0.02) < 0.002
    assert abs(np.corrcoef(n1[inner], n2[inner])[0, 1]) < 0.1


def test_compare_peers_vignetting_darkens_both_times_alike():
    """``--vignetting`` hands every method both light fields times the same gain fields,
    their centre views untouched."""
    from lfsf import synth

    seen = _views_handed_over("weak_texture", "--vignetting", "0.1")
    clean1, clean2, _ = synth.render_scene("weak_texture", size=(48, 32), grid=3)
    g = synth.vignetting_gains((3, 3), (48, 32), 0.1)
    (a1, a2), = seen
    np.testing.assert_allclose(a1, np.clip(clean1.views * g, 0, 1), rtol=1e-6)
    np.testing.assert_allclose(a2, np.clip(clean2.views * g, 0, 1), rtol=1e-6)
    np.testing.assert_array_equal(a1[1, 1], clean1.views[1, 1])


def test_compare_peers_occlusion_table_compares_the_points_seen_at_t2():
    """A missed flow bar is broken down over the points seen at t2: the joint run's and
    the peers' EPE there, against the same rule (½ of the better peer)."""
    script = _compare_peers_script()

    def row(scene, method, epe, seen):
        return script._row("synthetic", scene, method, flow={"epe": epe}, flow_nonoccluded={"epe": seen})

    rows = [row("a", "opencv-tvl1", 0.20, 0.10), row("a", "skimage-tvl1", 0.30, 0.08), row("a", "lfsf", 0.15, 0.03),
            row("b", "opencv-tvl1", 0.20, 0.10), row("b", "skimage-tvl1", 0.30, 0.08), row("b", "lfsf", 0.15, 0.05),
            row("c", "opencv-tvl1", 0.20, 0.10), row("c", "skimage-tvl1", 0.30, 0.08), row("c", "lfsf", 0.05, 0.05)]
    _bars, targets = script.bars_and_targets(rows)
    table = script.occlusion_table(rows, targets)
    lines = table.splitlines()[2:]
    assert [line.split("|")[1].strip() for line in lines] == ["a", "b"]  # c meets its bar
    assert lines[0] == "| a | 0.15 / 0.03 | 0.1 / 0.04 | pass |"  # 0.03 ≤ ½ · min(0.10, 0.08)
    assert lines[1] == "| b | 0.15 / 0.05 | 0.1 / 0.04 | FAIL |"
    # no figure over the points seen at t2 (e.g. none is): no verdict
    rows[5]["detail"].pop("flow_nonoccluded")
    assert script.occlusion_table(rows, targets).splitlines()[3] == "| b | 0.15 / – | 0.1 / 0.04 | – |"
    assert script.occlusion_table(rows[6:], script.bars_and_targets(rows[6:])[1]) is None


def test_compare_peers_exposure_changes_t2_for_every_method(capsys):
    """``--exposure GAIN OFFSET`` hands every method t2 at another exposure,
    clip(GAIN·L2 + OFFSET, 0, 1), and t1 as rendered; a GAIN ≤ 0 is refused."""
    from lfsf import synth

    script = _compare_peers_script()
    seen = _views_handed_over("paper", "--exposure", "1.2", "-0.05")
    clean1, clean2, _ = synth.render_scene("paper", size=(48, 32), grid=3)
    (a1, a2), = seen
    np.testing.assert_array_equal(a1, clean1.views)
    np.testing.assert_allclose(a2, np.clip(clean2.views * 1.2 - 0.05, 0.0, 1.0), atol=1e-6)
    assert script.main(["--exposure", "0", "0.1", "--methods", "peers"]) == 2
    assert "--exposure" in capsys.readouterr().err



def test_compare_peers_exposure_at_t1_changes_t1_for_every_method():
    """``--exposure-at t1``: t1 at the other exposure, t2 as rendered."""
    from lfsf import synth

    seen = _views_handed_over("paper", "--exposure", "0.5", "0.02", "--exposure-at", "t1")
    clean1, clean2, _ = synth.render_scene("paper", size=(48, 32), grid=3)
    (a1, a2), = seen
    np.testing.assert_allclose(a1, np.clip(clean1.views * 0.5 + 0.02, 0.0, 1.0), atol=1e-6)
    np.testing.assert_array_equal(a2, clean2.views)


def test_compare_peers_config_sets_every_lfsf_run(tmp_path, monkeypatch, capsys):
    """``--config FILE.toml`` sets the settings of every lfsf run (over the `paper`
    preset; the flow-only and two-view runs keep their own circles); a missing file or an
    unknown setting is refused with exit status 2."""
    import lfsf

    script = _compare_peers_script()
    config = tmp_path / "m.toml"
    config.write_text("match_exposure = false\nwarps = 2\n")
    seen = []

    def fake(lf1, lf2, params=None, device=None):
        seen.append(params)
        raise RuntimeError("stop here")

    monkeypatch.setattr(lfsf, "estimate_scene_flow", fake)
    args = ["--size", "48", "32", "--grid", "3", "--scenes", "paper", "--methods", "lfsf", "--config", str(config)]
    script.main(args)
    capsys.readouterr()
    assert len(seen) == 4  # joint, stereo only, flow only, two-view
    assert all(p.match_exposure is False and p.warps == 2 for p in seen)
    assert sorted(p.circles for p in seen) == [1, 2, 3, 3]
    assert script.main(args[:-1] + [str(tmp_path / "none.toml")]) == 2
    assert "--config" in capsys.readouterr().err
    config.write_text("no_such_setting = 1\n")
    assert script.main(args) == 2
    assert "no_such_setting" in capsys.readouterr().err
    script.SETTINGS["params"] = None


def test_compare_peers_images_put_photographs_on_every_scene(tmp_path, capsys, monkeypatch):
    """``--images DIR`` hands every method the scene rendered with the folder's images
    as textures (synth.with_images, seeded by the scene's name), with the scene's own
    ground truth; a folder without images is refused with exit status 2."""
    import zlib

    import imageio.v3 as iio

    from lfsf import synth

    rng = np.random.default_rng(0)
    photos = [(rng.random((30, 40, 3)) * 255).astype(np.uint8), (rng.random((25, 35)) * 65535).astype(np.uint16)]
    iio.imwrite(tmp_path / "a.png", photos[0])
    iio.imwrite(tmp_path / "b.png", photos[1])
    (tmp_path / "notes.txt").write_text("not an image")
    script = _compare_peers_script()
    loaded = synth.photographs(str(tmp_path))
    assert [a.shape for a in loaded] == [(30, 40, 3), (25, 35, 3)]
    np.testing.assert_allclose(loaded[1][..., 1], photos[1] / 65535.0, atol=1e-6)
    args = script.build_parser().parse_args(["--size", "48", "32", "--grid", "3", "--images", str(tmp_path)])
    monkeypatch.setitem(script.IMAGES, "list", loaded)
    seen = []

    def fake(lf1, lf2, device):
        seen.append((lf1.views.copy(), lf2.views.copy()))
        return {"u": np.zeros(lf1.centre.shape, np.float32), "v": np.zeros(lf1.centre.shape, np.float32)}

    rows = script.run_scene("slanted", args, False, {"fake": fake}, {"fake"})
    want1, want2, gt = synth.render_scene(synth.with_images("slanted", 2, seed=zlib.crc32(b"slanted")),
                                          size=(48, 32), grid=3, images=loaded)
    (a1, a2), = seen
    np.testing.assert_array_equal(a1, want1.views)
    np.testing.assert_array_equal(a2, want2.views)
    _, _, gt_plain = synth.render_scene("slanted", size=(48, 32), grid=3)
    assert rows[0]["flow_epe"] is not None
    np.testing.assert_array_equal(gt["u"], gt_plain["u"])
    empty = tmp_path / "empty"
    empty.mkdir()
    assert script.main(["--images", str(empty), "--methods", "peers"]) == 2
    assert "no images" in capsys.readouterr().err


def test_compare_peers_bars_and_targets_follow_the_issues_rules():
    """``bars_and_targets`` on rows made up to sit on either side of each rule: the flow
    bar is ½ of the *better* of OpenCV and skimage, δ1's and δ2's ½ of plenpy's own δ1
    and δ2; the joint run must be at most its special cases on their own variables
    (stereo only on δ1, flow only on the flow, two-view on δ1 and δ2), and the peers'
    bars apply to the joint run alone. A run without a bar is "no bar", a failed run
    "error", and real-data rows make no synthetic target."""
    script = _compare_peers_script()

    def row(scene, method, disp1=None, disp2=None, flow=None, section="synthetic", error=None):
        return script._row(section, scene, method, error=error, disp1=disp1 and {"mse": disp1},
                           disp2=disp2 and {"mse": disp2}, flow=flow and {"epe": flow})

    rows = [row("a", "opencv-tvl1", flow=0.30), row("a", "skimage-tvl1", flow=0.20),
            row("a", "plenpy", disp1=0.010, disp2=0.030),
            row("a", "lfsf", disp1=0.007, disp2=0.010, flow=0.12),
            row("a", "lfsf-stereo", disp1=0.006), row("a", "lfsf-flow", flow=0.20),
            row("a", "lfsf-two-view", disp1=0.5, disp2=0.005, flow=0.9),
            row("b", "lfsf", disp1=0.001, flow=0.01), row("c", "lfsf", error="RuntimeError: no"),
            row("hci", "lfsf", disp1=0.02, section="real")]
    bars, targets = script.bars_and_targets(rows)
    bar = {(b["scene"], b["metric"]): b["bar"] for b in bars}
    assert bar[("a", "flow_epe")] == pytest.approx(0.10)  # ½ · min(0.30, 0.20)
    assert bar[("a", "disp1_mse")] == pytest.approx(0.005) and bar[("a", "disp2_mse")] == pytest.approx(0.015)
    status = {(t["scene"], t["method"], t["metric"]): t["status"] for t in targets}
    assert status == {
        ("a", "lfsf vs lfsf-stereo", "disp1_mse"): "FAIL",  # 0.007 > 0.006
        ("a", "lfsf vs lfsf-flow", "flow_epe"): "pass",  # 0.12 ≤ 0.20
        ("a", "lfsf vs lfsf-two-view", "disp1_mse"): "pass",
        ("a", "lfsf vs lfsf-two-view", "disp2_mse"): "FAIL",  # 0.010 > 0.005
        ("a", "lfsf", "flow_epe"): "FAIL",  # 0.12 > 0.10 (it would pass OpenCV's half alone)
        ("a", "lfsf", "disp1_mse"): "FAIL",  # 0.007 > 0.005 (it would pass plenpy's whole)
        ("a", "lfsf", "disp2_mse"): "pass",  # 0.010 ≤ 0.015 (not δ1's bar, 0.005)
        ("b", "lfsf", "disp1_mse"): "no bar", ("b", "lfsf", "flow_epe"): "no bar",
        ("c", "lfsf", "all"): "error"}, status


def test_compare_peers_check_passes_only_when_every_target_does(monkeypatch, capsys):
    """``--check`` exits 0 when every target passes, 1 when one fails or has no bar (lfsf
    alone, without the peers), 1 when no target was checked at all."""
    script = _compare_peers_script()
    made = {}

    def fake_scene(name, args, use_peers, lfsf_runs, warm):
        return [script._row("synthetic", name, method, **fields) for method, fields in made[name]]

    monkeypatch.setattr(script, "run_scene", fake_scene)
    monkeypatch.setattr(script, "lfsf_available", lambda: (True, ""))
    monkeypatch.setattr(script, "import_peers", lambda: None)   # (they need not be installed: skimage was)
    peers_rows = [("opencv-tvl1", {"flow": {"epe": 0.3}}), ("skimage-tvl1", {"flow": {"epe": 0.2}}),
                  ("plenpy", {"disp1": {"mse": 0.01}, "disp2": {"mse": 0.03}})]
    joint = ("lfsf", {"disp1": {"mse": 0.001}, "disp2": {"mse": 0.002}, "flow": {"epe": 0.05}})
    argv = ["--scenes", "paper", "--size", "48", "32", "--grid", "3", "--check"]
    made["paper"] = peers_rows + [joint]
    assert script.main(argv) == 0
    made["paper"] = peers_rows + [("lfsf", {**joint[1], "flow": {"epe": 0.15}})]
    assert script.main(argv) == 1
    assert "1 of 3 targets not met" in capsys.readouterr().err
    made["paper"] = [joint]  # lfsf alone: its targets have no bar
    assert script.main(argv + ["--methods", "lfsf"]) == 1
    made["paper"] = peers_rows
    assert script.main(argv) == 1
    assert "no lfsf target was checked" in capsys.readouterr().err


def test_compare_peers_scores_over_the_border_and_samples_plenpys_t2_map_at_the_true_flow(monkeypatch):
    """``run_scene`` scores every method without the 8-px border (a method wrong only
    there scores 0), and plenpy's δ2 is its t2 map sampled at p + u with the ground
    truth's (u, v), in that order."""
    script = _compare_peers_script()
    args = script.build_parser().parse_args(["--size", "48", "40", "--grid", "3"])
    from lfsf import synth

    _lf1, _lf2, gt = synth.render_scene("paper", size=(48, 40), grid=3)
    sampled = []

    def at_t1(d2map, u, v):
        sampled.append((u.copy(), v.copy()))
        return np.zeros_like(d2map)

    monkeypatch.setattr(script.peers, "opencv_tvl1", lambda c1, c2: (np.zeros_like(c1), np.zeros_like(c1)))
    monkeypatch.setattr(script.peers, "skimage_tvl1", lambda c1, c2: (np.zeros_like(c1), np.zeros_like(c1)))
    monkeypatch.setattr(script.peers, "plenpy_disparity", lambda views: np.zeros(views.shape[2:4], np.float32))
    monkeypatch.setattr(script.peers, "disparity_at_t1_pixels", at_t1)

    def wrong_in_the_border(lf1, lf2, device):
        out = {k: gt[k].astype(np.float32).copy() for k in ("disp1", "disp2", "u", "v")}
        for a in out.values():
            a[:8] += 5.0
            a[:, -8:] -= 5.0
        return out

    rows = script.run_scene("paper", args, True, {"lfsf": wrong_in_the_border}, {"lfsf"})
    lfsf_row = next(r for r in rows if r["method"] == "lfsf")
    assert lfsf_row["disp1_mse"] == 0.0 and lfsf_row["disp2_mse"] == 0.0 and lfsf_row["flow_epe"] == 0.0
    np.testing.assert_array_equal(sampled[0][0], gt["u"])
    np.testing.assert_array_equal(sampled[0][1], gt["v"])
