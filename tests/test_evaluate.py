"""Evaluation metrics against hand-computed values."""

import math

import numpy as np
import pytest

from lfsf import evaluate as E


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


def test_evaluate_uses_common_variables_and_rejects_disjoint_ones():
    gt = {"disp1": np.zeros((20, 20)), "u": np.zeros((20, 20)), "v": np.zeros((20, 20))}
    out = E.evaluate({"disp1": np.zeros((20, 20))}, gt, border=0)
    assert set(out) == {"disp1"}
    with pytest.raises(ValueError, match="no variable in common"):
        E.evaluate({"disp2": np.zeros((20, 20))}, gt)
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
