"""Accuracy of a scene-flow estimate against ground truth.

Metrics, each over the pixels where the ground truth is valid and finite, with a border
of ``border`` pixels left out:

* every variable: mean squared error (MSE), as in the paper (Fig. 3);
* disparity: MSE×100 and BadPix(0.07) — the share (in %) of pixels whose absolute error
  exceeds 0.07 px per view step — as the HCI 4D light-field benchmark defines them;
* flow: mean end-point error (EPE), ``mean(sqrt((u − u*)² + (v − v*)²))``.

Where the ground truth marks the points hidden at t2 (``occluded``, as ``lfsf synth``
writes it), δ2 and the flow are also scored over the points seen at t2 as well
(``disp2_noc``, ``flow_noc``; "noc" as in KITTI's non-occluded figures): of a point the
t2 frame hides, no view at t2 shows the motion, so the two sets tell apart the errors
of matching and of filling in. Where the estimate marks them too (``SceneFlow.occluded``,
the key ``occluded`` of ``sceneflow.npz``), its mask is scored against the ground
truth's: precision, recall and F1 (:func:`occlusion_scores`).
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lfsf._errors import whole
from lfsf._files import file_name, not_a_file

if TYPE_CHECKING:
    from lfsf.estimate import SceneFlow

VARIABLES = ("disp1", "disp2", "u", "v")
BADPIX_THRESHOLD = 0.07
#: Border left out by default: the HCI benchmark's 15 px for its PFM ground truth, 8 px
#: for our synthetic ground truth.
HCI_BORDER = 15
SYNTH_BORDER = 8


def _float_map(a) -> np.ndarray:
    """A map as float64, a masked array's masked pixels as NaN (np.asarray would drop the
    mask and score what lies under it): not scored in a ground truth, wrong in an
    estimate, as any non-finite value."""
    if np.ma.isMaskedArray(a):
        return np.ma.filled(a.astype(np.float64), np.nan)
    return np.asarray(a, dtype=np.float64)


def _bool_mask(mask, name: str) -> np.ndarray:
    """A ground truth's mask (``valid``, ``occluded``) as given, checked: bool, or
    integers that are all 0 and 1. A float or string mask read by truthiness would count
    NaN and "False" as true (and 255 too, were any nonzero integer taken). A masked
    array's masked pixels are left out of what is scored: not valid, or occluded."""
    if np.ma.isMaskedArray(mask):
        mask = np.ma.filled(mask, mask.dtype.type(name == "occluded"))
    mask = np.asarray(mask)
    if mask.dtype != bool and not (mask.dtype.kind in "iu" and np.isin(mask, (0, 1)).all()):
        raise ValueError(f"the {name} mask must be bool or integers 0 and 1, got dtype {mask.dtype}"
                         + (" with values other than 0 and 1" if mask.dtype.kind in "iu" else
                            f" (of 0.0 and 1.0 only: {name}.astype(bool))"
                            if mask.dtype.kind == "f" and np.isin(mask, (0, 1)).all() else ""))
    return mask


def check_border(border) -> int:
    """``border`` as an int: a whole number of pixels, 0 or more (ValueError otherwise)."""
    if whole(border) is None or border < 0:
        raise ValueError(f"the border must be a whole number of pixels, 0 or more, got {border!r}")
    return whole(border)


def inner_pixels(shape, border) -> np.ndarray:
    """Bool ``shape`` (h, w): the pixels more than ``border`` (:func:`check_border`) from
    every edge, those an evaluation with that border scores."""
    border = check_border(border)
    mask = np.zeros(shape, dtype=bool)
    mask[border:shape[0] - border, border:shape[1] - border] = True
    return mask


def _mask(shape, valid, border: int, finite: np.ndarray) -> np.ndarray:
    """Pixels to evaluate: ``valid`` (all if None) and ``finite``, less the border.

    Raises ``ValueError`` for a negative border, and when no pixel is left, saying why.
    """
    border = check_border(border)
    if valid is not None:
        valid = _bool_mask(valid, "valid")
    mask = np.ones(shape, dtype=bool) if valid is None else valid.astype(bool)
    if mask.shape != tuple(shape):
        raise ValueError(f"valid mask has shape {mask.shape}, expected {tuple(shape)}")
    mask &= inner_pixels(shape, border) & finite
    if mask.any():
        return mask
    height, width = shape
    inside = np.asarray(valid, dtype=bool) & finite if valid is not None else finite
    if 2 * border >= min(height, width):
        from lfsf.io import _a

        why = f"a border of {border} px leaves nothing of {_a(width)} {width}×{height} map"
    elif valid is not None and not np.any(valid):
        why = "the ground truth's 'valid' mask is all false"
    elif not inside.any():
        why = "the ground truth is NaN or infinite at every valid pixel"
    else:
        why = f"every valid, finite ground-truth pixel lies within the {border}-px border"
    raise ValueError(f"no pixels left to evaluate: {why}")


def _check_pair(name, est, ref):
    if est.ndim == ref.ndim == 2:
        if est.shape != ref.shape:
            dy, dx = est.shape[0] - ref.shape[0], est.shape[1] - ref.shape[1]
            hint = ""
            # a reference made on views cropped by a margin (EPINET's Lytro estimate: 11 px a
            # side), not one of another resolution
            if 0 < dy <= est.shape[0] // 3 and 0 < dx <= est.shape[1] // 3 and dy % 2 == 0 and dx % 2 == 0:
                y, x = dy // 2, dx // 2
                cut = f"{x} px on every side" if x == y else f"{x} px left and right, {y} top and bottom"
                hint = (f", {cut} smaller (a reference made on cropped views?): crop the estimate's maps "
                        f"[{y}:-{y}, {x}:-{x}] to compare them")
            k = ref.shape[0] // max(est.shape[0], 1)
            if k >= 2 and ref.shape[0] // k == est.shape[0] and ref.shape[1] // k == est.shape[1]:
                # (the truth the larger: of views shrunk by --downsample, or finer than the views,
                # as HCI's gt_disp_highres.pfm, 4× its views; "8 times smaller" had read as the truth's)
                hint = (f", {k} times the estimate's size: views shrunk by lfsf run --downsample {k} (shrink the "
                        f"truth alike, evaluate.downsample_truth(gt, {k})), or a truth finer than the views (HCI's "
                        "gt_disp_highres.pfm is 4 times their size: score against gt_disp_lowres.pfm)")
            raise ValueError(f"{name}: the estimate is {est.shape[1]}×{est.shape[0]} but the "
                             f"ground truth is {ref.shape[1]}×{ref.shape[0]}{hint}")
    else:
        raise ValueError(f"{name}: expected 2-D maps, got an estimate of shape {est.shape} and "
                         f"a ground truth of shape {ref.shape}")


def disparity_errors(est, gt, valid=None, border: int = 0) -> dict[str, float]:
    """MSE, MSE×100 and BadPix(0.07) (%) of a disparity map over valid, finite pixels."""
    est = _float_map(est)
    gt = _float_map(gt)
    _check_pair("disparity", est, gt)
    m = _mask(gt.shape, valid, border, np.isfinite(gt))
    n = int(m.sum())
    err = est[m] - gt[m]
    err = np.where(np.isfinite(err), err, np.inf)  # a non-finite estimate counts as wrong
    sq = np.square(err)
    mse = float(np.mean(sq))
    return {
        "mse": mse,
        "mse_x100": 100.0 * mse,
        "badpix_0.07": 100.0 * float(np.mean(np.abs(err) > BADPIX_THRESHOLD)),
        "pixels": n,
    }


def flow_errors(u, v, gt_u, gt_v, valid=None, border: int = 0) -> dict[str, float]:
    """Mean end-point error and the MSE of each component over valid, finite pixels."""
    u, v, gt_u, gt_v = (_float_map(a) for a in (u, v, gt_u, gt_v))
    _check_pair("flow", u, gt_u)
    _check_pair("flow", v, gt_v)
    if v.shape != u.shape:
        raise ValueError(f"flow: v is {v.shape[1]}×{v.shape[0]} but u is {u.shape[1]}×{u.shape[0]}")
    m = _mask(gt_u.shape, valid, border, np.isfinite(gt_u) & np.isfinite(gt_v))
    n = int(m.sum())
    du = u[m] - gt_u[m]
    dv = v[m] - gt_v[m]
    du = np.where(np.isfinite(du), du, np.inf)
    dv = np.where(np.isfinite(dv), dv, np.inf)
    return {
        "epe": float(np.mean(np.hypot(du, dv))),
        "mse_u": float(np.mean(du * du)),
        "mse_v": float(np.mean(dv * dv)),
        "pixels": n,
    }


def evaluate(estimate: SceneFlow | Mapping[str, np.ndarray], gt: Mapping[str, np.ndarray],
             border: int = SYNTH_BORDER) -> dict[str, dict[str, float]]:
    """Errors of an estimate (a mapping with some of ``disp1, disp2, u, v``) against a
    ground truth (the same keys, optional bool ``valid``). Only variables present in both
    are evaluated; the flow needs both ``u`` and ``v``.

    Returns ``{variable: {metric: value}}``: for ``disp1`` and ``disp2`` the keys
    ``mse`` (px² per view step²), ``mse_x100``, ``badpix_0.07`` (in %) and ``pixels``
    (:func:`disparity_errors`); for ``flow`` ``epe`` (px), ``mse_u``, ``mse_v`` and
    ``pixels`` (:func:`flow_errors`). ``border`` (pixels left out at every edge) is 8 by
    default, as for ``lfsf synth``'s ground truth; the HCI benchmark leaves out 15:
    :func:`load_ground_truth` returns the border that fits the file it reads, which
    ``lfsf eval`` uses. With an ``occluded`` mask in the
    ground truth, ``disp2_noc`` and ``flow_noc`` score δ2 and the flow again over the
    points seen at t2 as well; with one in the estimate too (bool; a SceneFlow's
    ``occluded``), the row ``occluded`` scores it against the truth's
    (:func:`occlusion_scores`: precision, recall, f1, pixels, marked_px, occluded_px,
    and no MSE; precision, recall and f1 are NaN where they would be a share of nothing,
    so that every value is a number, as its type says). A non-finite value in the
    estimate is an infinite error (``mse`` inf, the pixel bad); ``lfsf eval --json``
    writes such values as null.

    Raises ``ValueError`` for maps of different sizes, a negative ``border``, or when the
    border, the ``valid`` mask and non-finite ground truth leave no pixel to evaluate.
    ``estimate`` may also be an :class:`lfsf.SceneFlow`; one estimated with one circle
    (the flow of the centre views alone) is scored on its flow only: its δ1 and δ2 are
    zeros, not estimates, as :func:`load_estimate` drops them from a saved one."""
    if hasattr(estimate, "as_dict"):
        params = getattr(estimate, "params", None)
        occluded = getattr(estimate, "occluded", None)
        estimate = estimate.as_dict()
        if getattr(params, "flow_only", False):
            estimate = {k: estimate[k] for k in ("u", "v")}
        if occluded is not None:
            estimate["occluded"] = occluded
    for name, maps in (("estimate", estimate), ("ground truth", gt)):
        if not isinstance(maps, Mapping):     # (a string passed the `in` tests by substring)
            raise ValueError(f"the {name} must be a dict of maps{' or a SceneFlow' if name == 'estimate' else ''} "
                             f"(load_estimate / load_ground_truth read them from files), got {type(maps).__name__}")
    valid = gt.get("valid")
    out: dict[str, dict[str, float]] = {}
    for name in ("disp1", "disp2"):
        if name in estimate and name in gt:
            out[name] = disparity_errors(estimate[name], gt[name], valid, border)
    if all(k in estimate and k in gt for k in ("u", "v")):
        out["flow"] = flow_errors(estimate["u"], estimate["v"], gt["u"], gt["v"], valid, border)
    if not out:
        halves = [f"the {name} has {' but not '.join(keys)}" for name, maps in (("estimate", estimate), ("ground truth", gt))
                  for keys in (("u", "v"), ("v", "u")) if keys[0] in maps and keys[1] not in maps]
        disp2_only = set(estimate) <= {"disp2", "occluded"} and set(gt) <= {"disp1", "valid"}
        raise ValueError("the estimate and the ground truth have no variable in common "
                         f"(estimate: {sorted(estimate)}, ground truth: {sorted(gt)})"
                         + (f"; the flow needs u and v together: {', '.join(halves)}" if halves else "")
                         + ("; a result's disp2.pfm is δ2 and a PFM ground truth δ1 (to score δ2 against it, "
                            "copy disp2.pfm to another name)" if disp2_only else ""))
    occluded = gt.get("occluded")
    if occluded is not None and ("disp2" in out or "flow" in out):
        occluded = _bool_mask(occluded, "occluded").astype(bool)
        shape = np.shape(gt["disp2"] if "disp2" in out else gt["u"])
        if occluded.shape != tuple(shape):
            raise ValueError(f"occluded mask has shape {occluded.shape}, expected {tuple(shape)}")
        seen = ~occluded
        if valid is not None:
            seen &= _bool_mask(valid, "valid").astype(bool)
        # (a ValueError: every point evaluated is hidden at t2, nothing to add)
        if "disp2" in out:
            with contextlib.suppress(ValueError):
                out["disp2_noc"] = disparity_errors(estimate["disp2"], gt["disp2"], seen, border)
        if "flow" in out:
            with contextlib.suppress(ValueError):
                out["flow_noc"] = flow_errors(estimate["u"], estimate["v"], gt["u"], gt["v"], seen, border)
    if "occluded" in estimate and gt.get("occluded") is not None:
        out["occluded"] = occlusion_scores(estimate["occluded"], gt["occluded"], valid, border)
    return out


def downsample_truth(gt: Mapping, factor: int) -> dict[str, np.ndarray]:
    """A ground truth (:func:`load_ground_truth`'s dict) for views shrunk by
    :meth:`lfsf.LightField.downsample` with the same ``factor``: δ1, δ2, u and v the
    means of ``factor`` × ``factor`` blocks divided by ``factor`` (disparities in px per
    view step and flows in px of the smaller views), ``valid`` where the whole block is,
    ``occluded`` where any of it is. A block holding a NaN (no ground truth) is NaN, and
    so left out. Other keys are dropped. The border to leave out shrinks too: the HCI
    benchmark's 15 px are 8 at half size (``lfsf eval --border``, ``evaluate(border=…)``)."""
    from lfsf.io import _check_factor, block_mean

    if not isinstance(gt, Mapping):
        raise ValueError(f"the ground truth must be a dict of maps (load_ground_truth), got {type(gt).__name__}")
    k = _check_factor(factor, "the ground truth")
    shapes = {name: np.shape(gt[name]) for name in (*VARIABLES, "valid", "occluded") if gt.get(name) is not None}
    if any(len(shape) != 2 for shape in shapes.values()) or len(set(shapes.values())) > 1:
        raise ValueError(f"the ground truth's maps must be 2-D and of one size, got {shapes}")
    shape = next(iter(shapes.values()), (0, 0))
    if shape[0] // k < 1 or shape[1] // k < 1:
        raise ValueError(f"the ground truth: a factor of {k} leaves nothing of its {shape[1]}×{shape[0]} maps")
    out: dict[str, np.ndarray] = {}
    for name in VARIABLES:
        if name in gt:
            out[name] = block_mean(_float_map(gt[name]), k) / np.float32(k)
    for name, keep in (("valid", lambda m: m == 1.0), ("occluded", lambda m: m > 0.0)):
        if gt.get(name) is not None:
            out[name] = keep(block_mean(_bool_mask(gt[name], name).astype(np.float32), k))
    return out


def downsample_border(border: int, factor: int) -> int:
    """The border of views shrunk ``factor`` times (:func:`downsample_truth`) that leaves
    out at least as much of the scene as ``border`` px at full size: the HCI benchmark's
    15 are 8 at half size."""
    return -(-int(border) // int(factor))


def occlusion_scores(est, gt, valid=None, border: int = 0) -> dict[str, float]:
    """How an estimate's mask of the points not seen at t2 (``occluded``, bool) meets the
    ground truth's, over the ``valid`` pixels without ``border``: precision (the share of
    the points marked that are occluded), recall (the share of the occluded points
    marked), their harmonic mean F1, the pixels scored, and of them the points marked
    (``marked_px``) and the points occluded (``occluded_px``). A share of nothing is NaN
    (null in JSON): precision where none is marked, recall where none is occluded, F1
    (2·hits / (marked + occluded)) where neither is (not 1.0 or 0.0, which would claim a
    score; not None, which the type ``float`` of every value does not allow)."""
    est = _bool_mask(est, "estimate's occluded").astype(bool)
    gt = _bool_mask(gt, "occluded").astype(bool)
    if est.shape != gt.shape:
        raise ValueError(f"the occluded masks differ in shape: estimate {est.shape}, ground truth {gt.shape}")
    mask = _mask(gt.shape, valid, border, np.ones(gt.shape, bool))
    e, g = est[mask], gt[mask]
    hits = int(np.count_nonzero(e & g))
    marked, occluded = int(np.count_nonzero(e)), int(np.count_nonzero(g))
    precision = hits / marked if marked else math.nan
    recall = hits / occluded if occluded else math.nan
    f1 = 2 * hits / (marked + occluded) if marked + occluded else math.nan
    return {"precision": precision, "recall": recall, "f1": f1, "pixels": int(mask.sum()), "marked_px": marked,
            "occluded_px": occluded}


def _file_in(folder: Path, name: str) -> bool:
    """Whether ``folder`` holds the file ``name``; a ValueError where something else is
    there by that name (a folder, a link to nothing: they had been said to be missing)."""
    path = folder / name
    if not os.path.lexists(path):
        return False
    if path.is_file():
        return True
    raise ValueError(f"{path}: {not_a_file(path)}, where a file was expected")


def load_estimate(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a result: a folder written by ``lfsf run`` (``sceneflow.npz``, else
    ``disp1.pfm``/``disp2.pfm``/``flow.flo``), or a ``.npz`` / ``.pfm`` / ``.flo`` file. A
    ``.pfm`` is δ1 (disp1), but for one named ``disp2.pfm``, which is δ2."""
    from lfsf import io

    path = file_name(path, "a result's file or folder")
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or folder")
    if path.is_dir():
        if _file_in(path, "sceneflow.npz"):
            return load_estimate(path / "sceneflow.npz")
        out: dict[str, np.ndarray] = {}
        for name in ("disp1", "disp2"):
            if _file_in(path, f"{name}.pfm"):
                out[name] = _read_disparity_pfm(path / f"{name}.pfm")
        if _file_in(path, "flow.flo"):
            flow = io.read_flo(path / "flow.flo")
            out["u"], out["v"] = flow[..., 0], flow[..., 1]
        if not out:
            raise FileNotFoundError(f"{path}: no sceneflow.npz, disp1.pfm, disp2.pfm or flow.flo in this folder")
        return out
    suffix = path.suffix.lower()
    if suffix == ".npz":
        out = _load_npz(path, VARIABLES + ("occluded",))
        if flow_only(path):     # its δ1 and δ2 are zeros, not estimates: scored they read as failures
            out.pop("disp1", None)
            out.pop("disp2", None)
        return out
    if suffix == ".pfm":
        if path.name.lower() in ("disp1.pfm", "disp2.pfm") and flow_only(path.parent):
            # (scored, the zeros read as a failed estimate: MSE 2.9, BadPix 98 %)
            raise ValueError(f"{path}: zeros, not an estimate: {path.parent / 'sceneflow.npz'} beside it is a "
                             "flow-only result (--preset flow or one sampling circle); evaluate its flow.flo, or "
                             "the folder")
        # (lfsf's own disp2.pfm is δ2; any other PFM is taken as δ1, as a benchmark's is)
        return {"disp2" if path.name.lower() == "disp2.pfm" else "disp1": _read_disparity_pfm(path)}
    if suffix == ".flo":
        flow = io.read_flo(path)
        return {"u": flow[..., 0], "v": flow[..., 1]}
    raise ValueError(f"{path}: not a result (expected a folder, .npz, .pfm or .flo)")


def _recorded(path: str | os.PathLike) -> dict:
    """What a result (a folder of ``lfsf run`` or its ``sceneflow.npz``) records of how it
    was made (:meth:`lfsf.estimate.SceneFlow.save`: the settings, the inputs, …), {}
    where there is no ``sceneflow.npz`` or it records nothing that reads."""
    import json

    from lfsf import io

    path = Path(path)
    path = path / "sceneflow.npz" if path.is_dir() else path
    if path.suffix.lower() != ".npz" or not path.is_file():
        return {}
    try:
        _, arrays = io._read_npz_arrays(path, ("params",))
        record = json.loads(str(arrays["params"]))
    except (KeyError, TypeError, ValueError, RecursionError):  # (RecursionError: nested 10⁵ deep)
        return {}
    return record if isinstance(record, dict) else {}


def recorded_settings(path: str | os.PathLike) -> dict | None:
    """The settings a result (a folder of ``lfsf run`` or its ``sceneflow.npz``) records
    it was estimated with (:meth:`lfsf.estimate.SceneFlow.save`), as a dict of
    :class:`lfsf.params.Params` fields; None where there is no ``sceneflow.npz`` or it
    records none that reads."""
    settings = _recorded(path).get("params")
    return settings if isinstance(settings, dict) else None


def recorded_downsample(path: str | os.PathLike) -> int:
    """The factor ``lfsf run --downsample`` shrank a result's views by (a folder of
    ``lfsf run`` or its ``sceneflow.npz``; 1 where none is recorded): its maps are that
    many times smaller than the light fields, and a ground truth of the light fields'
    size is shrunk alike to score them (:func:`downsample_truth`)."""
    return downsample_of(_recorded(path).get("inputs"))


def downsample_of(inputs) -> int:
    """The factor ``lfsf run --downsample`` recorded in a result's ``inputs`` (the dict of
    its ``sceneflow.npz``, ``SceneFlow.inputs``; 1 where none, or none that reads)."""
    factor = inputs.get("downsample", 1) if isinstance(inputs, dict) else 1
    # (10⁴⁰⁰ had been an OverflowError's traceback where the camera is shrunk)
    ok = isinstance(factor, int) and not isinstance(factor, bool) and 1 <= factor <= MAX_DOWNSAMPLE
    return factor if ok else 1


#: The largest ``--downsample`` factor a result's record is taken with (views of 17 px,
#: the estimate's least, from 65536).
MAX_DOWNSAMPLE = 1 << 12


def flow_only(path: str | os.PathLike) -> bool:
    """Whether a result (a folder of ``lfsf run`` or its ``sceneflow.npz``) was estimated
    with one circle (``--preset flow``): its disparities are zeros, not estimates."""
    settings = recorded_settings(path)
    return settings is not None and settings.get("circles") == 1


#: The files :func:`load_ground_truth` reads from a folder, the first there.
GT_FILES = ("gt.npz", "gt_disp_lowres.pfm")


def load_ground_truth(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], int]:
    """Read ground truth: a ``gt.npz`` of ``lfsf synth`` or an HCI ``gt_disp_lowres.pfm``
    (disparity at t1 only), or a folder holding one (:data:`GT_FILES`, the first found).
    Returns the arrays and the default border for that kind."""
    path = file_name(path, "a ground truth's file or folder")
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    if path.is_dir():
        for name in GT_FILES:
            if _file_in(path, name):
                return load_ground_truth(path / name)
        raise FileNotFoundError(f"{path}: no gt.npz or gt_disp_lowres.pfm in this folder")
    suffix = path.suffix.lower()
    if suffix == ".pfm":
        name = path.name.lower()
        if "depth" in name and "disp" not in name:
            # (HCI ships gt_depth_lowres.pfm beside gt_disp_lowres.pfm: depths scored as disparities
            # had given an MSE of 3.7 without a word)
            raise ValueError(f"{path}: a depth map by its name (as HCI's gt_depth_lowres.pfm), where lfsf scores "
                             "disparities in px per view step: give the disparity map beside it "
                             "(gt_disp_lowres.pfm), or rename the file if it holds disparities")
        return {"disp1": _read_disparity_pfm(path)}, HCI_BORDER
    if suffix == ".npz":
        return _load_npz(path, VARIABLES + ("valid", "occluded")), SYNTH_BORDER
    raise ValueError(f"{path}: not a ground truth (expected gt.npz or a .pfm disparity)")


def _read_disparity_pfm(path: Path) -> np.ndarray:
    from lfsf import io

    disparity = io.read_pfm(path)
    if disparity.ndim != 2:
        raise ValueError(f"{path}: a colour PFM ('PF', {disparity.shape[2]} channels) where a "
                         f"disparity map needs 1 channel ('Pf')")
    return disparity


def _load_npz(path: Path, keys) -> dict[str, np.ndarray]:
    from lfsf import io

    _, out = io._read_npz_arrays(path, keys)
    if not any(k in out for k in VARIABLES):
        raise ValueError(f"{path}: holds none of the keys {', '.join(VARIABLES)}")
    for k, a in out.items():
        if a.ndim != 2:
            raise ValueError(f"{path}: '{k}' should be a 2-D map, got shape {a.shape}")
        if a.dtype.kind not in "biuf":   # (a record or string dtype: a TypeError deep in the scoring)
            raise ValueError(f"{path}: '{k}' should hold numbers, got dtype {a.dtype}")
        if a.dtype.kind == "f" and a.dtype.itemsize > 4 and a.size:
            # (1e300 had overflowed in the scoring, with NumPy's warning, and filled the table)
            largest = float(np.max(np.abs(a), initial=0.0, where=np.isfinite(a)))
            if largest > float(np.finfo(np.float32).max):
                raise ValueError(f"{path}: '{k}' holds {largest:.3g}, beyond float32's range (lfsf's maps are "
                                 "float32)")
    return out


def format_table(errors: Mapping[str, Mapping[str, float]]) -> str:
    """A small fixed-width table of :func:`evaluate`'s result (a ``noc`` row, where there
    is one, right under its variable's)."""
    def fixed(value: float, width: int, decimals: int) -> str:
        """``value`` right-aligned in ``width`` with ``decimals``, or in %g where that
        does not fit (an MSE of 1e40 had printed 41 digits)."""
        text = f"{value:>{width}.{decimals}f}"
        for digits in (3, 2, 1):
            if len(text) <= width:
                break
            text = f"{value:>{width}.{digits}g}"
        return text

    lines = [f"{'variable':<9} {'MSE':>10} {'MSE×100':>9} {'BadPix.07':>9} {'EPE':>8} {'pixels':>8}"]
    order = [n for base in ("disp1", "disp2", "flow") for n in (base, base + "_noc") if n in errors]
    for name in order + [n for n in errors if n not in order and n != "occluded"]:
        e = errors[name]
        if name == "flow_noc":
            lines.append(f"{'flow noc':<9} {'':>10} {'':>9} {'':>9} {fixed(e['epe'], 8, 4)} {e['pixels']:>8d}")
        elif name == "flow":
            lines.append(f"{'u':<9} {fixed(e['mse_u'], 10, 5)} {'':>9} {'':>9} {'':>8} {e['pixels']:>8d}")
            lines.append(f"{'v':<9} {fixed(e['mse_v'], 10, 5)} {'':>9} {'':>9} {'':>8} {e['pixels']:>8d}")
            lines.append(f"{'flow':<9} {'':>10} {'':>9} {'':>9} {fixed(e['epe'], 8, 4)} {e['pixels']:>8d}")
        else:
            label = name.replace("_noc", " noc")
            lines.append(f"{label:<9} {fixed(e['mse'], 10, 5)} {fixed(e['mse_x100'], 9, 3)} {e['badpix_0.07']:>8.2f}% "
                         f"{'':>8} {e['pixels']:>8d}")
    if any(name.endswith("_noc") for name in errors):
        lines.append("noc: the points seen at t2 as well (the ground truth's 'occluded' left out)")
    if "occluded" in errors:
        e = errors["occluded"]
        if e["marked_px"] == e["occluded_px"] == 0:  # (no score: nothing to tell apart)
            lines.append(f"occluded at t2: none marked and none occluded of {e['pixels']} px")
        else:
            def score(value):
                return "n/a" if math.isnan(value) else f"{value:.3f}"

            lines.append(f"occluded at t2: precision {score(e['precision'])}, recall {score(e['recall'])}, F1 "
                         f"{score(e['f1'])} ({e['marked_px']} px marked, {e['occluded_px']} occluded of {e['pixels']})")
    return "\n".join(lines)
