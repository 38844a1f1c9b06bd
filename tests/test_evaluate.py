"""Evaluation metrics against hand-computed values."""

import io
import math
import re
import struct
import zipfile

import numpy as np
import pytest

from lfsf import evaluate as E
from lfsf._files import json_bytes


def test_disparity_errors_by_hand():
    gt = np.zeros((4, 4))
    est = gt.copy()
    est[0, 0] = 0.1   # bad (> 0.07)
    est[1, 1] = -0.05  # good
    est[2, 2] = 0.07   # exactly at the threshold: not bad
    e = E.disparity_errors(est, gt)
    assert e["pixels"] == 16
    assert e["mse"] == pytest.approx((0.01 + 0.0025 + 0.0049) / 16)
    assert e["mse_x100"] == pytest.approx(100 * e["mse"])
    assert e["badpix_0.07"] == pytest.approx(100 / 16)


def test_border_and_valid_mask_are_left_out():
    gt = np.zeros((10, 10))
    est = np.ones((10, 10))
    est[2:8, 2:8] = 0.0
    assert E.disparity_errors(est, gt, border=2)["mse"] == 0.0
    valid = np.zeros((10, 10), bool)
    valid[5, 5] = True
    e = E.disparity_errors(est, gt, valid=valid)
    assert e["pixels"] == 1 and e["mse"] == 0.0


def test_non_finite_ground_truth_is_skipped_and_non_finite_estimate_is_wrong():
    gt = np.zeros((2, 2))
    gt[0, 0] = np.nan
    est = np.zeros((2, 2))
    est[1, 1] = np.nan
    e = E.disparity_errors(est, gt)
    assert e["pixels"] == 3
    assert e["badpix_0.07"] == pytest.approx(100 / 3)
    assert math.isinf(e["mse"])


def test_flow_end_point_error_by_hand():
    gu, gv = np.zeros((2, 3)), np.zeros((2, 3))
    u, v = gu.copy(), gv.copy()
    u[0, 0], v[0, 0] = 3.0, 4.0  # EPE 5
    e = E.flow_errors(u, v, gu, gv)
    assert e["epe"] == pytest.approx(5 / 6)
    assert e["mse_u"] == pytest.approx(9 / 6)
    assert e["mse_v"] == pytest.approx(16 / 6)


def test_an_estimates_occlusion_mask_is_scored_against_the_ground_truths():
    """``occluded`` in the estimate as well: precision, recall and F1 over the valid
    pixels without the border, counted by hand; both empty is a perfect score, one empty
    scores 0; a mask that is not bool (or 0 and 1) is an error."""
    z = np.zeros((6, 7))
    gt_occ = np.zeros((6, 7), bool)
    gt_occ[1:3, 1:4] = True  # 6 px
    est_occ = np.zeros((6, 7), bool)
    est_occ[2:4, 1:4] = True  # 6 px, 3 of them right
    est_occ[0, 0] = True  # in the border: not scored
    valid = np.ones((6, 7), bool)
    valid[3, 3] = False  # a wrong mark, not valid: not scored
    gt = {"u": z, "v": z, "valid": valid, "occluded": gt_occ}
    out = E.evaluate({"u": z, "v": z, "occluded": est_occ}, gt, border=0)["occluded"]
    assert out == E.occlusion_scores(est_occ, gt_occ, valid, 0)
    assert out["precision"] == pytest.approx(3 / 6) and out["recall"] == pytest.approx(3 / 6)
    assert (out["pixels"], out["marked_px"], out["occluded_px"]) == (41, 6, 6)
    inner = E.occlusion_scores(est_occ, gt_occ, valid, 1)
    assert inner["precision"] == pytest.approx(3 / 5) and inner["recall"] == pytest.approx(3 / 6)
    assert inner["f1"] == pytest.approx(2 * 0.6 * 0.5 / 1.1) and inner["pixels"] == 19
    none = np.zeros((6, 7), bool)
    # a share of nothing is NaN (it had read 1.0, or 0.0; then None, which its type float did not say)
    assert math.isnan(E.occlusion_scores(none, none)["f1"])
    scores = E.occlusion_scores(none, gt_occ)
    assert math.isnan(scores.pop("precision")) and scores == {"recall": 0.0, "f1": 0.0, "pixels": 42, "marked_px": 0,
                                                              "occluded_px": 6}
    assert math.isnan(E.occlusion_scores(est_occ, none)["recall"]) and E.occlusion_scores(est_occ, none)["f1"] == 0.0
    assert '"recall": null' in json_bytes(E.occlusion_scores(est_occ, none)).decode()  # (JSON has no NaN)
    assert "precision 0.000, recall n/a, F1 0.000" in E.format_table(
        E.evaluate({"u": z, "v": z, "occluded": est_occ}, {**gt, "occluded": np.zeros_like(gt_occ)}, border=0))
    assert "occluded at t2: precision 0.500, recall 0.500, F1 0.500 (6 px marked, 6 occluded of 41)" in E.format_table(
        E.evaluate({"u": z, "v": z, "occluded": est_occ}, gt, border=0))
    assert "occluded" not in E.evaluate({"u": z, "v": z}, gt, border=0)  # no mask in the estimate
    # none marked, none occluded: the scores of 1 say nothing, and the line says so
    still = {**gt, "occluded": np.zeros_like(gt_occ)}
    table = E.format_table(E.evaluate({"u": z, "v": z, "occluded": np.zeros_like(est_occ)}, still, border=0))
    assert "occluded at t2: none marked and none occluded of 41 px" in table and "precision" not in table
    with pytest.raises(ValueError, match="must be bool"):
        E.occlusion_scores(est_occ.astype(float) * 0.5, gt_occ)


def test_a_downsampled_border_leaves_out_at_least_as_much_of_the_scene():
    """K times smaller views keep ⌈border / K⌉ px of border: the HCI benchmark's 15 px are
    8 at half size (7 would score a ring of pixels the full-size border leaves out)."""
    assert E.downsample_border(15, 2) == 8
    assert E.downsample_border(8, 3) == 3
    assert E.downsample_border(8, 2) == 4
    assert E.downsample_border(0, 4) == 0
    assert E.downsample_border(15, 1) == 15


def test_points_hidden_at_t2_are_also_left_out_in_the_noc_rows():
    """With an ``occluded`` mask, δ2 and the flow are scored twice: over every valid pixel
    and over those seen at t2 as well; δ1 and ground truth without the mask only once."""
    z = np.zeros((4, 5))
    occluded = np.zeros((4, 5), bool)
    occluded[0, :2] = True
    valid = np.ones((4, 5), bool)
    valid[3, 4] = False
    u = z.copy()
    u[0, 0] = 3.0  # wrong where hidden: counts in "flow" only
    u[1, 1] = 1.0  # wrong where seen: counts in both
    u[3, 4] = 9.0  # not valid: in neither
    disp2 = z.copy()
    disp2[0, 1] = 0.5
    gt = {"disp1": z, "disp2": z, "u": z, "v": z, "valid": valid, "occluded": occluded}
    est = {"disp1": disp2, "disp2": disp2, "u": u, "v": z}
    out = E.evaluate(est, gt, border=0)
    assert out["flow"]["epe"] == pytest.approx(4 / 19) and out["flow"]["pixels"] == 19
    assert out["flow_noc"]["epe"] == pytest.approx(1 / 17) and out["flow_noc"]["pixels"] == 17
    assert out["disp2"]["mse"] == pytest.approx(0.25 / 19)
    assert out["disp2_noc"]["mse"] == 0.0
    assert "disp1_noc" not in out
    table = E.format_table(out).splitlines()
    assert [line.split("  ")[0] for line in table[1:-1]] == ["disp1", "disp2", "disp2 noc", "u", "v", "flow",
                                                             "flow noc"]
    assert len({len(line) for line in table[:-1]}) == 1  # the columns line up
    assert "'occluded' left out" in table[-1]
    with pytest.raises(ValueError, match="occluded mask has shape"):
        E.evaluate(est, {**gt, "occluded": occluded[:, :4]}, border=0)
    gt.pop("occluded")
    assert set(E.evaluate(est, gt, border=0)) == {"disp1", "disp2", "flow"}
    # every evaluated point hidden at t2: nothing to add, no error
    gt["occluded"] = np.ones((4, 5), bool)
    assert set(E.evaluate(est, gt, border=0)) == {"disp1", "disp2", "flow"}


def test_evaluate_uses_common_variables_and_rejects_disjoint_ones():
    gt = {"disp1": np.zeros((20, 20)), "u": np.zeros((20, 20)), "v": np.zeros((20, 20))}
    out = E.evaluate({"disp1": np.zeros((20, 20))}, gt, border=0)
    assert set(out) == {"disp1"}
    with pytest.raises(ValueError, match="no variable in common"):
        E.evaluate({"disp2": np.zeros((20, 20))}, gt)
    # half a flow: said why, where 'u' in both read as a contradiction
    with pytest.raises(ValueError, match=r"; the flow needs u and v together: the estimate has u but not v$"):
        E.evaluate({"u": np.zeros((20, 20))}, gt)
    with pytest.raises(ValueError, match=r"the flow needs u and v together: the ground truth has v but not u$"):
        E.evaluate({"u": np.zeros((20, 20)), "v": np.zeros((20, 20))}, {"v": np.zeros((20, 20))})
    with pytest.raises(ValueError, match="estimate is 3×2"):
        E.evaluate({"disp1": np.zeros((2, 3))}, gt)


def test_hci_ground_truth_scores_itself_perfectly():
    from conftest import data_path

    from lfsf import io

    pfm = data_path("hci-antinous", "gt_disp_lowres.pfm")
    gt, border = E.load_ground_truth(pfm)
    assert border == 15
    out = E.evaluate({"disp1": io.read_pfm(pfm)}, gt, border=border)
    assert out["disp1"]["mse"] == 0.0 and out["disp1"]["pixels"] == (512 - 30) ** 2
    noisy = E.evaluate({"disp1": gt["disp1"] + 0.1}, gt, border=border)
    assert noisy["disp1"]["badpix_0.07"] == pytest.approx(100.0)
    assert noisy["disp1"]["mse_x100"] == pytest.approx(1.0, rel=1e-4)


def test_no_pixels_left_is_an_error_that_says_why():
    gt = {"disp1": np.zeros((48, 64))}
    with pytest.raises(ValueError, match="no pixels left to evaluate: a border of 100 px .* 64×48"):
        E.evaluate({"disp1": np.zeros((48, 64))}, gt, border=100)
    with pytest.raises(ValueError, match="no pixels left .* border of 8 px .* 16×16"):
        E.evaluate({"disp1": np.zeros((16, 16))}, {"disp1": np.zeros((16, 16))})
    gt["valid"] = np.zeros((48, 64), bool)
    with pytest.raises(ValueError, match="no pixels left to evaluate: .*'valid' mask is all false"):
        E.evaluate({"disp1": np.zeros((48, 64))}, gt)


@pytest.mark.parametrize("border", [-3, 2.5, "8", True])
def test_a_border_that_is_not_a_count_of_pixels_is_rejected(border):
    """A fraction was a TypeError from the slicing; a bool would have counted as 1."""
    with pytest.raises(ValueError, match=f"border must be a whole number of pixels, 0 or more, got {border!r}"):
        E.evaluate({"disp1": np.zeros((20, 20))}, {"disp1": np.zeros((20, 20))}, border=border)
    assert E.evaluate({"disp1": np.ones((20, 20))}, {"disp1": np.zeros((20, 20))},
                      border=np.int64(2))["disp1"]["pixels"] == 16 * 16


def test_a_scene_flow_is_evaluated_as_its_maps():
    from lfsf import Params
    from lfsf.estimate import SceneFlow

    gt = {k: np.zeros((20, 20), np.float32) for k in E.VARIABLES}
    maps = {**gt, "u": np.full((20, 20), 0.5, np.float32)}
    sf = SceneFlow(**maps, params=Params.preset("fast"), radius=4.0, device="cpu")
    assert E.evaluate(sf, gt, border=2) == E.evaluate(maps, gt, border=2)
    assert E.evaluate(sf, gt, border=2)["flow"]["epe"] == 0.5
    # flow only (one circle): its zero disparities are not estimates, as in a saved result
    sf = SceneFlow(**maps, params=Params.preset("flow"), radius=0.0, device="cpu")
    assert set(E.evaluate(sf, gt, border=2)) == {"flow"}


def test_a_results_disp2_pfm_is_scored_as_disp2(tmp_path):
    """lfsf's own disp2.pfm is δ2 (it had been scored against the truth's δ1, and δ2
    called missing); any other PFM, a benchmark's among them, is δ1."""
    from lfsf import io

    d1, d2 = np.full((20, 20), 0.5, np.float32), np.full((20, 20), -0.25, np.float32)
    for name, a in (("disp1.pfm", d1), ("disp2.pfm", d2), ("mine.pfm", d1)):
        io.write_pfm(tmp_path / name, a)
    assert set(E.load_estimate(tmp_path / "disp2.pfm")) == {"disp2"}
    gt = {"disp1": d1, "disp2": d2}
    assert E.evaluate(E.load_estimate(tmp_path / "disp2.pfm"), gt, border=2)["disp2"]["mse"] == 0.0
    for name in ("disp1.pfm", "mine.pfm"):
        assert E.evaluate(E.load_estimate(tmp_path / name), gt, border=2)["disp1"]["mse"] == 0.0
    # a reference on views cropped by k px a side: the message says so and how to crop
    with pytest.raises(ValueError, match=r"20×20 but the ground truth is 14×16, 3 px left and right, 2 top and "
                                         r"bottom smaller .* crop the estimate's maps \[2:-2, 3:-3\]"):
        E.evaluate({"disp1": d1}, {"disp1": d1[2:-2, 3:-3]})
    with pytest.raises(ValueError, match=r"the ground truth is 10×10$"):  # (half the resolution: no crop)
        E.evaluate({"disp1": d1}, {"disp1": d1[::2, ::2]})
    with pytest.raises(ValueError, match=r"a result's disp2.pfm is δ2 and a PFM ground truth δ1"):
        E.evaluate(E.load_estimate(tmp_path / "disp2.pfm"), {"disp1": d1})


def test_a_folder_without_results_or_truth_is_a_file_not_found(tmp_path):
    """As a missing path is, and as SceneFlow.load's (it had been a ValueError)."""
    for load, needle in ((E.load_estimate, "no sceneflow.npz, disp1.pfm, disp2.pfm or flow.flo in this folder"),
                         (E.load_ground_truth, "no gt.npz or gt_disp_lowres.pfm in this folder")):
        with pytest.raises(FileNotFoundError, match=rf"^{re.escape(str(tmp_path))}: {needle}$"):
            load(tmp_path)
        with pytest.raises(FileNotFoundError, match="no such file"):
            load(tmp_path / "gone")


def test_colour_pfm_is_not_a_disparity_map(tmp_path):
    from lfsf import io

    io.write_pfm(tmp_path / "rgb.pfm", np.zeros((48, 64, 3), np.float32))
    (tmp_path / "r").mkdir()
    io.write_pfm(tmp_path / "r" / "disp1.pfm", np.zeros((48, 64, 3), np.float32))
    for load in (lambda: E.load_estimate(tmp_path / "rgb.pfm"), lambda: E.load_estimate(tmp_path / "r"),
                 lambda: E.load_ground_truth(tmp_path / "rgb.pfm")):
        with pytest.raises(ValueError, match=r"\.pfm: .*3 channels.* needs 1"):
            load()


def test_damaged_npz_results_and_ground_truth_name_the_file(tmp_path):
    maps = {k: np.zeros((20, 20), np.float32) for k in E.VARIABLES}
    np.savez_compressed(tmp_path / "sceneflow.npz", **maps)
    whole = (tmp_path / "sceneflow.npz").read_bytes()
    (tmp_path / "short.npz").write_bytes(whole[: len(whole) // 2])
    (tmp_path / "text.npz").write_bytes(b"not a zip archive")
    (tmp_path / "r").mkdir()
    damaged = bytearray(whole)
    name_length, extra_length = struct.unpack("<HH", damaged[26:30])
    start = 30 + name_length + extra_length                 # the first member's deflate data
    damaged[start:start + 2] = b"\xff\xff"                  # block type 0b11: invalid
    (tmp_path / "r" / "sceneflow.npz").write_bytes(bytes(damaged))
    for load in (E.load_estimate, lambda p: E.load_ground_truth(p)[0]):
        with pytest.raises(ValueError, match="short.npz: cannot read as .npz"):
            load(tmp_path / "short.npz")
        with pytest.raises(ValueError, match=r"text.npz: not a valid .npz \(zip\) file"):
            load(tmp_path / "text.npz")
    with pytest.raises(ValueError, match=r"sceneflow.npz: cannot read as .npz \(zlib.error"):
        E.load_estimate(tmp_path / "r")
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f4", "fortran_order": False,
                                                  "shape": (99999, 99999)})
    with zipfile.ZipFile(tmp_path / "huge.npz", "w") as archive:    # 40 GB claimed, 16 bytes held
        archive.writestr("disp1.npy", header.getvalue() + bytes(16))
    for load in (E.load_estimate, lambda p: E.load_ground_truth(p)[0]):
        with pytest.raises(ValueError, match=r"huge.npz: 'disp1' is damaged: its header claims"):
            load(tmp_path / "huge.npz")


def test_maps_that_hold_no_numbers_name_the_file_and_the_map(tmp_path):
    """A record dtype (or bytes) in a ground truth's or a result's map had been a
    TypeError's traceback from deep in the scoring (a fuzzing helper)."""
    maps = {k: np.zeros((20, 20), np.float32) for k in E.VARIABLES}
    for key, bad in (("disp1", np.zeros((20, 20), [("a", "f4"), ("b", "i4")])), ("u", np.zeros((20, 20), "S3"))):
        np.savez(tmp_path / "bad.npz", **{**maps, key: bad})
        for load in (E.load_estimate, lambda p: E.load_ground_truth(p)[0]):
            with pytest.raises(ValueError, match=re.escape(f"bad.npz: '{key}' should hold numbers, got dtype")):
                load(tmp_path / "bad.npz")


def test_hci_breakdown_parts_add_up_to_lfsf_eval():
    """scripts/hci_breakdown.py: its regions and the rest add up to the total, which is
    ``lfsf eval``'s MSE×100 with the benchmark's 15-px border; the part off by more than
    1 holds exactly those pixels."""
    from conftest import load_script

    module = load_script("hci_breakdown")
    rng = np.random.default_rng(3)
    truth = rng.uniform(-3, 3, (512, 512)).astype(np.float32)
    estimate = truth + rng.normal(0, 0.3, truth.shape).astype(np.float32)
    estimate[300, 300] += 5.0   # in the rest, off by more than 1
    estimate[5, 5] += 50.0      # in the border: counted nowhere
    parts = module.breakdown(estimate, truth)
    assert parts["wedge"] + parts["floor"] + parts["head"] + parts["rest"] == pytest.approx(parts["total"], rel=1e-9)
    reference = E.disparity_errors(estimate[15:-15, 15:-15], truth[15:-15, 15:-15])
    assert parts["total"] == pytest.approx(reference["mse_x100"], rel=1e-5)
    assert parts["badpix_0.07"] == pytest.approx(reference["badpix_0.07"], rel=1e-9)
    error = (estimate - truth).astype(np.float64)[15:-15, 15:-15]
    assert parts["off_by_more_than_1"] == pytest.approx(100 * np.sum(error[np.abs(error) > 1] ** 2) / error.size)


def test_arguments_of_the_wrong_kind_are_value_errors():
    """A path or None for the ground truth was an AttributeError; a string estimate a
    TypeError ('disp1 u v' passed the key tests by substring); flow maps of different
    but broadcastable shapes an IndexError; a float mask of NaN counted every pixel."""
    maps = {k: np.zeros((6, 8), np.float32) for k in E.VARIABLES}
    for estimate, gt, needle in ((maps, "gt.npz", "the ground truth must be a dict"),
                                 (maps, None, "the ground truth must be a dict"),
                                 (None, maps, "the estimate must be a dict of maps or a SceneFlow"),
                                 ("disp1 u v", maps, "the estimate must be a dict")):
        with pytest.raises(ValueError, match=needle):
            E.evaluate(estimate, gt, border=0)
    with pytest.raises(ValueError, match=r"flow: v is 8×1 but u is 8×6"):
        E.flow_errors(maps["u"], maps["v"][:1], maps["u"], maps["v"][:1])
    for valid in (np.full((6, 8), np.nan), np.full((6, 8), "False"), np.full((6, 8), 2)):
        with pytest.raises(ValueError, match=r"the valid mask must be bool or integers 0 and 1, got dtype \S+"
                                             r"( with values other than 0 and 1)?$"):
            E.evaluate(maps, {**maps, "valid": valid}, border=0)
    with pytest.raises(ValueError, match=r"got dtype float64 \(of 0\.0 and 1\.0 only: valid\.astype\(bool\)\)$"):
        E.evaluate(maps, {**maps, "valid": np.ones((6, 8))}, border=0)
    ones = np.ones((6, 8), np.uint8)
    assert E.evaluate(maps, {**maps, "valid": ones}, border=0)["disp1"]["pixels"] == 48
    # the occluded mask likewise (a NaN mask had hidden every point: the noc rows vanished)
    for occluded in (np.full((6, 8), np.nan), np.full((6, 8), "False"), np.full((6, 8), 255, np.uint8)):
        with pytest.raises(ValueError, match="the occluded mask must be bool or integers 0 and 1, got dtype"):
            E.evaluate(maps, {**maps, "occluded": occluded}, border=0)
    half = np.zeros((6, 8), np.uint8)
    half[:, :4] = 1
    assert E.evaluate(maps, {**maps, "occluded": half}, border=0)["flow_noc"]["pixels"] == 24



def test_masked_arrays_keep_their_masks():
    """np.asarray drops a masked array's mask: what lay under it was scored."""
    rng = np.random.default_rng(0)
    gt = rng.random((12, 12))
    est = gt + 0.1
    hole = np.zeros((12, 12), bool)
    hole[2:5, 3:9] = True
    est_holes = est.copy()
    est_holes[hole] = 1e3
    # masked ground truth pixels are not scored, as NaN ones are not
    masked_gt = np.ma.masked_array(np.where(hole, -50.0, gt), mask=hole)
    by_nan = E.evaluate({"disp1": est}, {"disp1": np.where(hole, np.nan, gt)}, border=0)
    assert E.evaluate({"disp1": est}, {"disp1": masked_gt}, border=0) == by_nan
    # a masked valid mask's masked pixels are not valid
    valid = np.ma.masked_array(np.ones((12, 12), bool), mask=hole)
    assert E.evaluate({"disp1": est_holes}, {"disp1": gt, "valid": valid}, border=0) == \
        E.evaluate({"disp1": est_holes}, {"disp1": gt, "valid": ~hole}, border=0)
    # a masked estimate pixel is no estimate: wrong, as a NaN is
    masked_est = np.ma.masked_array(est_holes, mask=hole)
    assert E.evaluate({"disp1": masked_est}, {"disp1": gt}, border=0) == \
        E.evaluate({"disp1": np.where(hole, np.nan, est)}, {"disp1": gt}, border=0)
    u = np.ma.masked_array(np.ones((12, 12)), mask=hole)
    flow = E.evaluate({"u": u, "v": np.zeros((12, 12))}, {"u": np.ones((12, 12)), "v": np.zeros((12, 12))},
                    border=0)["flow"]
    assert flow["epe"] == np.inf and flow["pixels"] == 144
    # masked occluded pixels are left out of the noc rows
    occluded = np.ma.masked_array(np.zeros((12, 12), bool), mask=hole)
    noc = E.evaluate({"disp2": est_holes}, {"disp2": gt, "occluded": occluded}, border=0)["disp2_noc"]
    assert noc["pixels"] == 144 - hole.sum() and noc["mse"] == pytest.approx(0.01)


def test_a_depth_map_is_not_scored_as_disparity(tmp_path):
    """HCI ships gt_depth_lowres.pfm beside gt_disp_lowres.pfm: a depth map, by its name,
    is refused rather than scored as disparities; a disparity map of any name is read."""
    from lfsf import io as lio

    depth = np.full((20, 20), 1.5, np.float32)
    lio.write_pfm(tmp_path / "gt_depth_lowres.pfm", depth)
    with pytest.raises(ValueError, match=r"gt_depth_lowres.pfm: a depth map by its name .*\(gt_disp_lowres.pfm\)"):
        E.load_ground_truth(tmp_path / "gt_depth_lowres.pfm")
    for name in ("gt_disp_lowres.pfm", "depth_as_disparity.pfm", "mine.pfm"):
        lio.write_pfm(tmp_path / name, depth)
        truth, border = E.load_ground_truth(tmp_path / name)
        np.testing.assert_array_equal(truth["disp1"], depth)


def test_a_result_folder_with_a_folder_or_a_dangling_link_in_a_files_place_says_so(tmp_path):
    """A folder named sceneflow.npz (or a link to nothing) had been "no sceneflow.npz …
    in this folder"; the same for a ground truth's gt.npz."""
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "sceneflow.npz").mkdir()
    with pytest.raises(ValueError, match=r"r/sceneflow.npz: a folder, where a file was expected"):
        E.load_estimate(tmp_path / "r")
    (tmp_path / "g").mkdir()
    (tmp_path / "g" / "gt.npz").symlink_to(tmp_path / "nowhere")
    with pytest.raises(ValueError, match=r"g/gt.npz: a link to nothing \(or a loop of links\), where a file"):
        E.load_ground_truth(tmp_path / "g")


def test_a_ground_truth_beyond_float32_is_refused_and_wide_errors_fit_the_table(tmp_path):
    """1e300 in a float64 gt.npz had overflowed in the scoring with NumPy's warning, and an
    MSE of 1e40 had printed 41 digits in its column."""
    np.savez(tmp_path / "gt.npz", disp1=np.full((4, 5), 1e300))
    with pytest.raises(ValueError, match=r"gt.npz: 'disp1' holds 1e\+300, beyond float32's range"):
        E.load_ground_truth(tmp_path / "gt.npz")
    np.savez(tmp_path / "gt.npz", disp1=np.full((4, 5), 1e30), u=np.array([[np.inf, 1.0]]))
    assert E.load_ground_truth(tmp_path / "gt.npz")[0]["disp1"][0, 0] == 1e30   # (within float32: taken)
    table = E.format_table({"disp1": {"mse": 1e40, "mse_x100": 1e42, "badpix_0.07": 100.0, "pixels": 20},
                            "flow": {"mse_u": 0.1, "mse_v": 1e30, "epe": 1e15, "pixels": 20}})
    widths = {len(line) for line in table.splitlines()}
    assert widths == {len(table.splitlines()[0])} and "1e+40" in table and "1e+15" in table, table
