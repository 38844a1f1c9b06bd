#!/usr/bin/env python
"""Compare lfsf with the peer methods named in the acceptance targets.

Peers (wrapped in ``lfsf/peers.py``, all returning lfsf's conventions, MODEL.md §1):

* flow: OpenCV ``cv2.optflow.DualTVL1OpticalFlow_create()`` (defaults, 8-bit grey input)
  and scikit-image ``skimage.registration.optical_flow_tvl1`` (defaults), on the two
  centre views;
* disparity: plenpy's ``LightField.get_disparity(method="structure_tensor",
  fusion_method="tv_l1")`` on the grey views; at t1 for δ1, at t2 for δ2.

δ2 is indexed by the t1 pixel (MODEL.md §1), while plenpy's t2 map is indexed by the t2
pixel. The bar for δ2 samples plenpy's t2 map at ``p + u_gt(p)`` (ground-truth flow,
bilinear): plenpy is handed the exact correspondence, the most favourable reading for the
peer and so the hardest bar for lfsf. A second, informational row samples it at the
OpenCV flow instead (a pipeline of peers, no oracle).

Targets, per synthetic scene, for every lfsf run that returns the variable:

* flow EPE(lfsf) ≤ ½ · min(EPE OpenCV, EPE scikit-image);
* MSE(δ1 lfsf) ≤ ½ · MSE(δ1 plenpy);  MSE(δ2 lfsf) ≤ ½ · MSE(δ2 plenpy @ p + u_gt);
* the joint model against its special cases, on their own variables: δ1 against stereo
  only (the t1 light field twice), the flow against flow only (M = 1), δ1 and δ2
  against the paper's stereo case (M = 2, N = (1, 1), two views at each time).

Errors by ``lfsf.evaluate`` over ``gt["valid"]`` without an 8-px border (synthetic), and on
HCI antinous without a 15-px border (MSE×100, BadPix(0.07)); on the Lytro scene, the median
absolute difference to EPINET's estimate (views cropped by 11 px per side).

Usage (from the repository root)::

    python scripts/compare_peers.py                        # 4 scenes, 160×120, 9×9
    python scripts/compare_peers.py --size 320 240 --json peers.json
    python scripts/compare_peers.py --real                 # + HCI antinous and Lytro
    python scripts/compare_peers.py --real --no-synth --methods peers
    python scripts/compare_peers.py --methods all --check  # exit 1 if a target fails
    python scripts/compare_peers.py --random 8 --check     # + 8 scenes drawn at random
    python scripts/compare_peers.py --noise 0.01           # sensor noise on every view
    python scripts/compare_peers.py --vignetting 0.05      # every view darkened its own way
    python scripts/compare_peers.py --exposure 0.9 0.03    # t2 at another exposure
    python scripts/compare_peers.py --exposure 0.5 0 --exposure-at t1   # t1 at another exposure
    python scripts/compare_peers.py --config my.toml       # lfsf with other settings
    python scripts/compare_peers.py --colour               # RGB views (the peers: their luma)
    python scripts/compare_peers.py --images skimage       # photographs on the objects
    python scripts/compare_peers.py --independent --scenes # the scenes of a second renderer

``--methods``: ``peers`` (peers only), ``lfsf`` (lfsf only; no bars), ``all`` (default:
peers, and lfsf when ``lfsf.estimate_scene_flow`` exists, else a note). Exit status 1 if a
method raised (its row says why), or with ``--check`` if a target fails or cannot be
checked; 2 for bad arguments.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
import traceback
import zlib
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
DEFAULT_DATA = ROOT.parent / "shared" / "data"

from lfsf._errors import ArgumentParser  # noqa: E402  (usage errors in one line)
from lfsf import peers  # noqa: E402  (the peer wrappers)
from lfsf._files import write_json_atomic  # noqa: E402

SYNTH_BORDER = 8
HCI_BORDER = 15
LYTRO_CROP = 11  # EPINET's estimate = the views without 11 px on every side


# =====================================================================================
# HOOK (lead): the lfsf runs compared with the peers. Wire the exact calls here; nothing
# else in this file needs to change. Each run takes (lf1, lf2, device) and returns a dict
# with any of "disp1", "disp2", "u", "v" (float32 H×W, MODEL.md §1). Targets are checked
# for every run and every variable it returns.
# =====================================================================================

def _lfsf():
    import lfsf

    return lfsf


#: The settings every lfsf run starts from: the `paper` preset, or ``--config FILE.toml``.
SETTINGS = {"params": None}


def lfsf_params(**changes):
    """The lfsf runs' settings (``SETTINGS``, default the `paper` preset), with ``changes``."""
    base = SETTINGS["params"] or _lfsf().Params.preset("paper")
    return base.replace(**changes) if changes else base


def lfsf_joint(lf1, lf2, device):
    """The method itself: joint δ1, δ2, u, v from both light fields."""
    r = _lfsf().estimate_scene_flow(lf1, lf2, params=lfsf_params(), device=device)
    return {"disp1": r.disp1, "disp2": r.disp2, "u": r.u, "v": r.v}


def lfsf_stereo(lf1, lf2, device):
    """Stereo only: the t1 light field twice (no motion); its δ1 is a pure light-field
    disparity, comparable with plenpy's."""
    r = _lfsf().estimate_scene_flow(lf1, lf1, params=lfsf_params(), device=device)
    return {"disp1": r.disp1}


def lfsf_flow(lf1, lf2, device):
    """Flow only: M = 1 circle, the centre view alone, i.e. two-frame flow, comparable
    with the TV-L1 peers. The `paper` preset's schedule, as the joint run's, so that the
    two differ only in the light field (the `flow` preset is the quick one, timed
    against OpenCV by ``lfsf bench peers``)."""
    lfsf = _lfsf()
    params = lfsf_params(circles=1, samples=(1,))
    r = lfsf.estimate_scene_flow(lf1, lf2, params=params, device=device)
    return {"u": r.u, "v": r.v}


def lfsf_two_view(lf1, lf2, device):
    """The paper's stereo case (§4.3: "by choosing M = 2 and N = 1 the model reduces to
    the stereo case"): the centre view and one side view at radius R at each time, i.e.
    scene flow from a stereo pair, with the `paper` preset otherwise. What the light
    field's 17 samples buy over a stereo rig."""
    lfsf = _lfsf()
    params = lfsf_params(circles=2, samples=(1, 1))
    r = lfsf.estimate_scene_flow(lf1, lf2, params=params, device=device)
    return {"disp1": r.disp1, "disp2": r.disp2, "u": r.u, "v": r.v}


LFSF_RUNS = {"lfsf": lfsf_joint, "lfsf-stereo": lfsf_stereo, "lfsf-flow": lfsf_flow, "lfsf-two-view": lfsf_two_view}
#: Runs on the real data (one light field, disparity only).
LFSF_REAL_RUNS = {"lfsf-stereo": lfsf_stereo}

# =====================================================================================


def lfsf_available() -> tuple[bool, str]:
    """Whether ``lfsf.estimate_scene_flow`` exists (and why not)."""
    try:
        lfsf = _lfsf()
        getattr(lfsf, "estimate_scene_flow")
        return True, ""
    except AttributeError:
        return False, "lfsf.estimate_scene_flow does not exist yet"
    except Exception as exc:  # an import error inside the estimator
        return False, f"lfsf.estimate_scene_flow cannot be imported: {type(exc).__name__}: {exc}"


# ------------------------------------------------------------------------------ helpers

def _f(x) -> float | None:
    return None if x is None or (isinstance(x, float) and math.isnan(x)) else float(x)


def _fmt(x, digits=4) -> str:
    if x is None:
        return "–"
    if not math.isfinite(x):
        return str(x)
    return f"{x:.{digits}g}"


def _row(section, scene, method, *, disp1=None, disp2=None, flow=None, seconds=None,
         error=None, **detail):
    return {"section": section, "scene": scene, "method": method,
            "disp1_mse": _f(disp1["mse"]) if disp1 else None,
            "disp2_mse": _f(disp2["mse"]) if disp2 else None,
            "flow_epe": _f(flow["epe"]) if flow else None,
            "seconds": seconds, "error": error,
            "detail": {k: v for k, v in dict(disp1=disp1, disp2=disp2, flow=flow, **detail).items()
                       if v is not None}}


def _error_text(exc: BaseException) -> str:
    """The error's first line, whole (cut at 200 characters, a row had ended mid-sentence)."""
    return f"{type(exc).__name__}: {exc}".splitlines()[0]


def _nonfinite(*arrays) -> int:
    return int(sum(np.count_nonzero(~np.isfinite(a)) for a in arrays))


# ------------------------------------------------------------------------------ synthetic

def run_scene(name, args, use_peers, lfsf_runs, warm):
    """Rows of one synthetic scene."""
    from lfsf import evaluate, synth

    if name.startswith(INDEPENDENT_PREFIX):  # a second renderer's (scripts/independent_scenes.py)
        lf1, lf2, gt = independent_scenes().render_scene(name, size=tuple(args.size), grid=args.grid)
    else:
        scene, images = name, None
        if args.images is not None:  # the scene's geometry and motion, photographs for textures
            images = IMAGES["list"]
            scene = synth.with_images_of_name(name, len(images))
        lf1, lf2, gt = synth.render_scene(scene, size=tuple(args.size), grid=args.grid, colour=args.colour,
                                          device=args.device, images=images)
    if args.vignetting > 0:  # the camera's, at t1 and t2 alike; in the lens, so before exposure and noise
        lf1, lf2 = synth.add_vignetting(lf1, args.vignetting), synth.add_vignetting(lf2, args.vignetting)
    if args.exposure is not None:  # t2 (or t1) captured at another exposure, clipped as a sensor would
        gain, shift = args.exposure
        k = 1 if args.exposure_at == "t1" else 2
        lf = lf1 if k == 1 else lf2
        lf = type(lf)(np.clip(lf.views * np.float32(gain) + np.float32(shift), 0.0, 1.0).astype(np.float32),
                      source=f"{lf.source}, exposure {gain:g}·L{k} {shift:+g}", meta=lf.meta)
        lf1, lf2 = (lf, lf2) if k == 1 else (lf1, lf)
    if args.noise > 0:  # independent at t1 and t2, the same for every method
        seed = zlib.crc32(name.encode())
        lf1, lf2 = synth.add_noise(lf1, args.noise, seed), synth.add_noise(lf2, args.noise, seed + 1)
    valid = gt["valid"]
    occl = gt["occluded"]
    nonocc = valid & ~occl
    b = SYNTH_BORDER

    def d_err(est, key, mask=valid):
        return evaluate.disparity_errors(est, gt[key], mask, b)

    def f_err(u, v, mask=valid):
        return evaluate.flow_errors(u, v, gt["u"], gt["v"], mask, b)

    def seen_at_t2(score, *args):
        """``score`` over the points seen at t2 as well; None where there is none."""
        try:
            return score(*args, nonocc)
        except ValueError:
            return None

    rows = []
    if use_peers:
        # the peers take grey views (their luma, for --colour); lfsf the light fields as rendered
        g1, g2 = lf1.grey(), lf2.grey()
        c1, c2 = g1.centre, g2.centre
        flows = {}
        for method, fn in (("opencv-tvl1", peers.opencv_tvl1), ("skimage-tvl1", peers.skimage_tvl1)):
            try:
                (u, v), s = peers.timed(fn, c1, c2)
                flows[method] = (u, v)
                rows.append(_row("synthetic", name, method, flow=f_err(u, v), seconds=s,
                                 flow_nonoccluded=f_err(u, v, nonocc), nonfinite=_nonfinite(u, v)))
            except Exception as exc:
                rows.append(_row("synthetic", name, method, error=_error_text(exc)))
        try:
            d1, s1 = peers.timed(peers.plenpy_disparity, g1.views)
            d2map, s2 = peers.timed(peers.plenpy_disparity, g2.views)
            d2 = peers.disparity_at_t1_pixels(d2map, gt["u"], gt["v"])
            rows.append(_row("synthetic", name, "plenpy", disp1=d_err(d1, "disp1"),
                             disp2=d_err(d2, "disp2"), seconds=s1 + s2,
                             seconds_t1=s1, seconds_t2=s2,
                             disp2_rule="plenpy(t2 views) sampled at p + u_gt (bilinear)",
                             disp1_nonoccluded=d_err(d1, "disp1", nonocc),
                             disp2_nonoccluded=d_err(d2, "disp2", nonocc),
                             nonfinite=_nonfinite(d1, d2map)))
            if "opencv-tvl1" in flows:
                u, v = flows["opencv-tvl1"]
                d2p = peers.disparity_at_t1_pixels(d2map, u, v)
                cv_s = next(r["seconds"] for r in rows if r["method"] == "opencv-tvl1")
                rows.append(_row("synthetic", name, "plenpy δ2 @ p+u_opencv", disp2=d_err(d2p, "disp2"),
                                 seconds=s2 + cv_s, informational=True,
                                 disp2_rule="plenpy(t2 views) sampled at p + u_opencv (bilinear)"))
        except Exception as exc:
            rows.append(_row("synthetic", name, "plenpy", error=_error_text(exc)))

    for method, fn in lfsf_runs.items():
        try:
            if method not in warm:  # compile kernels etc. outside the timing
                w1, w2, _ = synth.render_scene("paper" if name.startswith(INDEPENDENT_PREFIX) else name,
                                               size=(48, 32), grid=args.grid, colour=args.colour, device=args.device)
                fn(w1, w2, args.device)
                warm.add(method)
            out, s = peers.timed(fn, lf1, lf2, args.device)
            out = {k: np.asarray(v, dtype=np.float32) for k, v in out.items()}
            rows.append(_row(
                "synthetic", name, method, seconds=s,
                disp1=d_err(out["disp1"], "disp1") if "disp1" in out else None,
                disp2=d_err(out["disp2"], "disp2") if "disp2" in out else None,
                flow=f_err(out["u"], out["v"]) if "u" in out and "v" in out else None,
                # the same over the points seen at t2 as well (what :func:`occlusion_table` reads)
                disp1_nonoccluded=seen_at_t2(d_err, out["disp1"], "disp1") if "disp1" in out else None,
                disp2_nonoccluded=seen_at_t2(d_err, out["disp2"], "disp2") if "disp2" in out else None,
                flow_nonoccluded=seen_at_t2(f_err, out["u"], out["v"]) if "u" in out and "v" in out else None,
                nonfinite=_nonfinite(*out.values())))
        except Exception as exc:
            if args.verbose:
                traceback.print_exc()
            rows.append(_row("synthetic", name, method, error=_error_text(exc)))
    return rows


def bars_and_targets(rows):
    """Per scene: the bars (½ of the best peer) and each lfsf run's pass/fail."""
    bars, targets = [], []
    for scene in dict.fromkeys(r["scene"] for r in rows if r["section"] == "synthetic"):
        by = {r["method"]: r for r in rows if r["scene"] == scene and not r["error"]}
        epes = [by[m]["flow_epe"] for m in ("opencv-tvl1", "skimage-tvl1")
                if m in by and by[m]["flow_epe"] is not None]
        best_flow = min(epes) if epes else None
        pl = by.get("plenpy", {})
        scene_bars = {
            "flow_epe": (0.5 * best_flow if best_flow is not None else None,
                         "½ · min(EPE opencv-tvl1, EPE skimage-tvl1)"),
            "disp1_mse": (0.5 * pl["disp1_mse"] if pl.get("disp1_mse") is not None else None,
                          "½ · MSE plenpy δ1"),
            "disp2_mse": (0.5 * pl["disp2_mse"] if pl.get("disp2_mse") is not None else None,
                          "½ · MSE plenpy δ2 (t2 map @ p + u_gt)"),
        }
        for key, (bar, rule) in scene_bars.items():
            bars.append({"scene": scene, "metric": key, "bar": bar, "rule": rule})
        # the joint model must beat its special cases on their own variables
        joint = by.get("lfsf")
        for special, key in (("lfsf-stereo", "disp1_mse"), ("lfsf-flow", "flow_epe"),
                             ("lfsf-two-view", "disp1_mse"), ("lfsf-two-view", "disp2_mse")):
            case = by.get(special)
            if joint is None or case is None or joint.get(key) is None or case.get(key) is None:
                continue
            targets.append({"scene": scene, "method": f"lfsf vs {special}", "metric": key, "value": joint[key],
                            "bar": case[key], "rule": f"joint ≤ {special}",
                            "status": "pass" if joint[key] <= case[key] else "FAIL"})
        for r in rows:
            if r["scene"] != scene or not r["method"].startswith("lfsf"):
                continue
            if r["error"]:
                targets.append({"scene": scene, "method": r["method"], "metric": "all",
                                "value": None, "bar": None, "rule": r["error"], "status": "error"})
                continue
            if r["method"] != "lfsf":
                continue  # the peers' bars apply to the joint model; its special cases are compared above
            for key, (bar, rule) in scene_bars.items():
                value = r[key]
                if value is None:
                    continue  # this run does not return that variable
                elif bar is None:
                    status = "no bar"
                else:
                    status = "pass" if value <= bar else "FAIL"
                targets.append({"scene": scene, "method": r["method"], "metric": key,
                                "value": value, "bar": bar, "rule": rule, "status": status})
    return bars, targets


# ------------------------------------------------------------------------------ real data

def run_real(args, use_peers, lfsf_runs):
    import lfsf
    from lfsf import evaluate, io

    rows = []
    data = Path(args.data)
    hci = data / "hci-antinous"
    if (hci / "gt_disp_lowres.pfm").exists():
        lf = lfsf.read_lightfield(hci)
        gt = io.read_pfm(hci / "gt_disp_lowres.pfm")
        methods = ({"plenpy": lambda: peers.plenpy_disparity(lf.views)} if use_peers else {})
        methods.update({m: (lambda fn=fn: fn(lf, lf, args.device)["disp1"]) for m, fn in lfsf_runs.items()})
        for method, fn in methods.items():
            try:
                d, s = peers.timed(fn)
                d = np.asarray(d, dtype=np.float32)
                e = evaluate.disparity_errors(d, gt, None, HCI_BORDER)
                # sign check against the truth: slope of est vs gt (least squares, inner)
                inner = (slice(HCI_BORDER, -HCI_BORDER),) * 2
                g, x = gt[inner].ravel().astype(np.float64), d[inner].ravel().astype(np.float64)
                ok = np.isfinite(g) & np.isfinite(x)
                slope = float(np.polyfit(g[ok], x[ok], 1)[0])
                rows.append({"section": "real", "scene": "hci-antinous", "method": method,
                             "mse_x100": e["mse_x100"], "badpix_0.07": e["badpix_0.07"],
                             "median_abs_diff_epinet": None, "seconds": s, "error": None,
                             "detail": {"errors": e, "slope_est_vs_gt": slope,
                                        "clipped_at_3": int(np.count_nonzero(np.abs(d) >= 3.0)),
                                        "nonfinite": _nonfinite(d), "size": list(d.shape[::-1])}})
            except Exception as exc:
                if args.verbose:
                    traceback.print_exc()
                rows.append({"section": "real", "scene": "hci-antinous", "method": method,
                             "error": _error_text(exc)})
    else:
        print(f"note: {hci} not present; HCI antinous skipped", file=sys.stderr)

    lytro = data / "lytro-illum-2067"
    if (lytro / "epinet_disparity_estimate.pfm").exists():
        lf = lfsf.read_lightfield(lytro)
        ref = io.read_pfm(lytro / "epinet_disparity_estimate.pfm")
        c = LYTRO_CROP
        methods = ({"plenpy": lambda: peers.plenpy_disparity(lf.views)} if use_peers else {})
        methods.update({m: (lambda fn=fn: fn(lf, lf, args.device)["disp1"]) for m, fn in lfsf_runs.items()})
        for method, fn in methods.items():
            try:
                d, s = peers.timed(fn)
                d = np.asarray(d, dtype=np.float32)[c:-c, c:-c]
                if d.shape != ref.shape:
                    raise ValueError(f"cropped estimate {d.shape} vs EPINET {ref.shape}")
                diff = np.abs(d.astype(np.float64) - ref)
                nonfinite = int(np.count_nonzero(~np.isfinite(diff)))
                diff = np.where(np.isfinite(diff), diff, np.inf)  # non-finite counts as wrong
                rows.append({"section": "real", "scene": "lytro-illum-2067", "method": method,
                             "mse_x100": None, "badpix_0.07": None,
                             "median_abs_diff_epinet": float(np.median(diff)), "seconds": s,
                             "error": None,
                             "detail": {"mean_abs_diff_epinet": float(np.mean(diff[np.isfinite(diff)])),
                                        "share_within_0.07": float(np.mean(diff <= 0.07)),
                                        "est_range_p1_p99": [float(np.nanpercentile(d, 1)),
                                                             float(np.nanpercentile(d, 99))],
                                        "epinet_range_p1_p99": [float(np.percentile(ref, 1)),
                                                                float(np.percentile(ref, 99))],
                                        "nonfinite": nonfinite, "size": list(lf.centre.shape[1::-1])}})
            except Exception as exc:
                if args.verbose:
                    traceback.print_exc()
                rows.append({"section": "real", "scene": "lytro-illum-2067", "method": method,
                             "error": _error_text(exc)})
    else:
        print(f"note: {lytro} not present; Lytro scene skipped", file=sys.stderr)
    return rows


# ------------------------------------------------------------------------------ output

def synth_table(rows) -> str:
    out = ["| scene | method | disp1 MSE | disp2 MSE | flow EPE | seconds |",
           "|---|---|---:|---:|---:|---:|"]
    for r in rows:
        if r["section"] != "synthetic":
            continue
        if r["error"]:
            out.append(f"| {r['scene']} | {r['method']} | error: {r['error']} | | | |")
            continue
        out.append(f"| {r['scene']} | {r['method']} | {_fmt(r['disp1_mse'])} | {_fmt(r['disp2_mse'])} "
                   f"| {_fmt(r['flow_epe'])} | {_fmt(r['seconds'], 3)} |")
    return "\n".join(out)


def bars_table(bars) -> str:
    scenes = list(dict.fromkeys(b["scene"] for b in bars))
    get = {(b["scene"], b["metric"]): b["bar"] for b in bars}
    out = ["| scene | disp1 MSE ≤ | disp2 MSE ≤ | flow EPE ≤ |", "|---|---:|---:|---:|"]
    for s in scenes:
        out.append(f"| {s} | {_fmt(get[(s, 'disp1_mse')])} | {_fmt(get[(s, 'disp2_mse')])} "
                   f"| {_fmt(get[(s, 'flow_epe')])} |")
    return "\n".join(out)


def targets_table(targets) -> str:
    out = ["| scene | method | metric | lfsf | bar | status |", "|---|---|---|---:|---:|---|"]
    for t in targets:
        out.append(f"| {t['scene']} | {t['method']} | {t['metric']} | {_fmt(t['value'])} "
                   f"| {_fmt(t['bar'])} | {t['status']} |")
    return "\n".join(out)


def occlusion_table(rows, targets) -> str | None:
    """Where the joint flow misses its bar: the same comparison over the pixels whose
    point is seen at t2 too (ground truth's ``occluded`` left out), for the joint run
    and the TV-L1 peers. A miss that is gone there lies in points the t2 frame hides,
    whose motion no view at t2 shows. None when no flow bar was missed."""
    missed = [t["scene"] for t in targets
              if t["method"] == "lfsf" and t["metric"] == "flow_epe" and t["status"] == "FAIL"]
    if not missed:
        return None
    out = ["| scene | lfsf EPE, all / seen at t2 | ½ best peer, all / seen at t2 | seen at t2 |",
           "|---|---:|---:|---|"]
    for scene in missed:
        by = {r["method"]: r for r in rows if r["scene"] == scene and not r["error"]}
        joint = by["lfsf"]["detail"].get("flow_nonoccluded", {}).get("epe")
        peer = [by[m]["detail"]["flow_nonoccluded"]["epe"] for m in ("opencv-tvl1", "skimage-tvl1")
                if m in by and "flow_nonoccluded" in by[m]["detail"]]
        best_all = min(by[m]["flow_epe"] for m in ("opencv-tvl1", "skimage-tvl1")
                       if m in by and by[m]["flow_epe"] is not None)
        bar = 0.5 * min(peer) if peer else None
        status = "–" if joint is None or bar is None else ("pass" if joint <= bar else "FAIL")
        out.append(f"| {scene} | {_fmt(by['lfsf']['flow_epe'])} / {_fmt(joint)} | {_fmt(0.5 * best_all)} / "
                   f"{_fmt(bar)} | {status} |")
    return "\n".join(out)


def real_table(rows) -> str:
    out = ["| scene | method | MSE×100 | BadPix(0.07) % | median abs diff to EPINET | seconds |",
           "|---|---|---:|---:|---:|---:|"]
    for r in rows:
        if r["section"] != "real":
            continue
        if r.get("error"):
            out.append(f"| {r['scene']} | {r['method']} | error: {r['error']} | | | |")
            continue
        out.append(f"| {r['scene']} | {r['method']} | {_fmt(r['mse_x100'])} | {_fmt(r['badpix_0.07'])} "
                   f"| {_fmt(r['median_abs_diff_epinet'])} | {_fmt(r['seconds'], 3)} |")
    return "\n".join(out)


# ------------------------------------------------------------------------------ main

def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(description=__doc__.split("\n\n")[0],
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--size", nargs=2, type=int, default=[160, 120], metavar=("W", "H"),
                   help="size of the synthetic views (default 160 120)")
    p.add_argument("--grid", type=int, default=9, help="views per side (default 9)")
    p.add_argument("--scenes", nargs="*", default=None,
                   help="synthetic scenes: built-in names or random-N (default: the built-in ones; "
                        "'--scenes' alone: none, e.g. with --random)")
    p.add_argument("--random", type=int, default=0, metavar="N",
                   help="add N scenes drawn at random (lfsf.synth.random_scene): random-SEED, from "
                        "--random-from on")
    p.add_argument("--random-from", type=int, default=0, metavar="SEED",
                   help="first random scene's seed (default 0)")
    p.add_argument("--independent", action="store_true",
                   help="add the scenes of a second renderer, written apart from lfsf.synth "
                        "(scripts/independent_scenes.py, indep-NAME; needs scikit-image); with '--scenes' "
                        "alone, those only. Some of their bars are missed (docs/accuracy.md): --check "
                        "then exits 1")
    p.add_argument("--colour", action="store_true",
                   help="RGB views (default grey); the peers get their luma, lfsf the colour")
    p.add_argument("--noise", type=float, default=0.0, metavar="SIGMA",
                   help="Gaussian noise of this standard deviation (intensities in [0, 1]) on every "
                        "view of the synthetic scenes, independent at t1 and t2 (default 0)")
    p.add_argument("--vignetting", type=float, default=0.0, metavar="K",
                   help="every view of the synthetic scenes times a smooth gain field of its own, "
                        "1 − 2K at worst (lfsf.synth.add_vignetting: a lens's vignetting, view-dependent "
                        "shading), the same at t1 and t2; the centre view is untouched (default 0)")
    p.add_argument("--exposure", type=float, nargs=2, default=None, metavar=("GAIN", "OFFSET"),
                   help="t2's views of the synthetic scenes at another exposure, clip(GAIN·L2 + "
                        "OFFSET, 0, 1), for every method (default: the same exposure; the real data "
                        "are stereo, one light field twice)")
    p.add_argument("--exposure-at", choices=("t2", "t1"), default="t2",
                   help="which light field --exposure changes (default t2; t1: the first capture the darker "
                        "or brighter one, which lfsf matches t2 to)")
    p.add_argument("--images", metavar="SOURCE",
                   help="photographs instead of the scenes' solid textures, each object showing one drawn "
                        "from SOURCE: 'skimage' (scikit-image's sample photographs) or a folder of PNG, JPEG "
                        "or TIFF files (synth.with_images; the geometry and ground truth are the scene's)")
    p.add_argument("--config", metavar="FILE.toml",
                   help="settings for every lfsf run, as `lfsf run --config` reads them (default: the "
                        "`paper` preset), e.g. `match_exposure = false`")
    p.add_argument("--methods", choices=("all", "peers", "lfsf"), default="all",
                   help="peers, lfsf, or both (default; lfsf only when it exists)")
    p.add_argument("--real", action="store_true",
                   help="also HCI antinous (MSE×100, BadPix) and the Lytro scene (vs EPINET)")
    p.add_argument("--no-synth", action="store_true", help="skip the synthetic scenes")
    p.add_argument("--data", default=str(DEFAULT_DATA), help="real data folder (default ../shared/data)")
    p.add_argument("--device", default=None, help="Warp device for rendering and lfsf (default: lfsf's)")
    p.add_argument("--json", metavar="FILE", help="write the rows, bars and targets to FILE")
    p.add_argument("--check", action="store_true",
                   help="exit 1 unless every lfsf target is checked and passes")
    p.add_argument("--verbose", action="store_true", help="print tracebacks of failing methods")
    return p


#: The photographs of ``--images`` (loaded once, by :func:`lfsf.synth.photographs`).
IMAGES: dict = {"list": None}


def selected_scenes(args) -> list[str]:
    """The synthetic scenes to run: ``--scenes`` (default the built-in ones), then
    ``--random`` N scenes ``random-SEED`` from ``--random-from`` on. ValueError names any
    that is not a scene."""
    from lfsf import synth

    if args.random < 0 or args.random_from < 0:
        raise ValueError("--random and --random-from must be ≥ 0")
    scenes = list(synth.list_scenes() if args.scenes is None else args.scenes)
    scenes += [f"{synth.RANDOM_PREFIX}{args.random_from + k}" for k in range(args.random)]
    if getattr(args, "independent", False):  # (other scripts' arguments lack it)
        scenes += [INDEPENDENT_PREFIX + name for name in independent_scenes().ALL]
    unknown = []
    for name in scenes:
        if name.startswith(INDEPENDENT_PREFIX):
            if name[len(INDEPENDENT_PREFIX):] not in independent_scenes().ALL:
                unknown.append(name)
            continue
        try:
            synth.get_scene(name)
        except ValueError:
            unknown.append(name)
    if unknown:
        raise ValueError(f"unknown scene(s) {unknown}; known: {list(synth.list_scenes())}, "
                         f"{synth.RANDOM_PREFIX}N and {INDEPENDENT_PREFIX}NAME (NAME one of "
                         f"{independent_scenes().ALL})")
    if ((getattr(args, "colour", False) or getattr(args, "images", None) is not None)
            and any(s.startswith(INDEPENDENT_PREFIX) for s in scenes)):
        raise ValueError("the independent scenes are grey, with textures of their own: not with --colour or --images")
    return scenes


#: The scene names' prefix of the second renderer (``--independent``).
INDEPENDENT_PREFIX = "indep-"


def independent_scenes():
    """``scripts/independent_scenes.py``, imported once."""
    import importlib.util

    module = sys.modules.get("lfsf_independent_scenes")
    if module is None:
        spec = importlib.util.spec_from_file_location("lfsf_independent_scenes", HERE / "independent_scenes.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        sys.modules["lfsf_independent_scenes"] = module
    assert module.PREFIX == INDEPENDENT_PREFIX
    return module


def import_peers() -> None:
    """Import the three peers: OpenCV's DualTVL1, scikit-image's TV-L1 and plenpy (an
    ImportError naming the one missing)."""
    peers._opencv_dual_tvl1()
    import skimage.registration  # noqa: F401

    peers.import_plenpy_lightfield()


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if min(args.size) < 32:
        print("error: --size must be at least 32 32", file=sys.stderr)
        return 2
    if not math.isfinite(args.noise) or args.noise < 0:
        print(f"error: --noise must be a finite number ≥ 0, got {args.noise}", file=sys.stderr)
        return 2
    if not (math.isfinite(args.vignetting) and 0 <= args.vignetting < 0.5):
        print(f"error: --vignetting must be in [0, 0.5), got {args.vignetting}", file=sys.stderr)
        return 2
    if args.exposure is not None and not (all(map(math.isfinite, args.exposure)) and args.exposure[0] > 0):
        print(f"error: --exposure needs a finite GAIN > 0 and a finite OFFSET, got {args.exposure}", file=sys.stderr)
        return 2
    SETTINGS["params"] = None
    if args.config is not None:
        try:
            SETTINGS["params"] = _lfsf().Params.from_toml(args.config, base=_lfsf().Params.preset("paper"))
        except (OSError, ValueError) as exc:
            print(f"error: --config: {exc}", file=sys.stderr)
            return 2
    IMAGES["list"] = None
    try:
        from lfsf._scripts import check_before_runs

        # (a bad --grid was a traceback; a bad --json was refused only after the runs)
        check_before_runs(args.size, args.grid, colour=args.colour, device=args.device, output=args.json)
        if args.grid < 2:  # (lfsf's runs failed each in its row; plenpy still gave a δ1, and a bar from it)
            raise ValueError(f"--grid must be at least 2 (the disparities need 2 rows and 2 columns of views), "
                             f"got {args.grid}")
        scenes = selected_scenes(args)
        if not args.real and (args.no_synth or not scenes):
            raise ValueError("nothing to compare: " + ("--no-synth without --real" if args.no_synth else
                                                       "'--scenes' without names takes none; name some, add "
                                                       "--random N") + ", or compare the real data with --real")
        data = Path(args.data)
        if args.real and not ((data / "hci-antinous" / "gt_disp_lowres.pfm").exists()
                              or (data / "lytro-illum-2067" / "epinet_disparity_estimate.pfm").exists()):
            # (it had printed an empty table and exited 0)
            raise ValueError(f"--real: no real data under {data} (hci-antinous/ or lytro-illum-2067/, as "
                             "../shared/data/README.md lists them); give their folder with --data")
        if args.images is not None:
            from lfsf import synth

            IMAGES["list"] = synth.photographs(args.images)
    except (OSError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2

    use_peers = args.methods in ("all", "peers")
    notes = []
    lfsf_runs = {}
    if args.methods in ("all", "lfsf"):
        ok, why = lfsf_available()
        if ok:
            lfsf_runs = dict(LFSF_RUNS)
        else:
            notes.append(f"lfsf not run: {why}")
            if args.methods == "lfsf":
                print(f"error: {why}", file=sys.stderr)
                return 2
    if use_peers:  # import the peers once, outside the timings (and before any run: all three are needed)
        try:
            import_peers()
        except ImportError as exc:
            print(f"error: the peers need OpenCV contrib, scikit-image and plenpy (pip install -e '.[peers]'): "
                  f"{exc}; or compare lfsf alone with --methods lfsf", file=sys.stderr)
            return 2

    rows = []
    if not args.no_synth:
        warm: set = set()
        for name in scenes:
            t0 = time.perf_counter()
            rows += run_scene(name, args, use_peers, lfsf_runs, warm)
            print(f"[{name}: {time.perf_counter() - t0:.1f} s]", file=sys.stderr, flush=True)
    if args.real:
        real_runs = {m: fn for m, fn in LFSF_REAL_RUNS.items() if m in lfsf_runs}
        rows += run_real(args, use_peers, real_runs)

    bars, targets = bars_and_targets(rows)
    w, h = args.size
    if not args.no_synth:
        inputs = "".join([f", noise σ = {args.noise:g}" if args.noise > 0 else "",
                          f", vignetting {args.vignetting:g}" if args.vignetting > 0 else "",
                          f", {args.exposure_at} at clip({args.exposure[0]:g}·L{args.exposure_at[1]} "
                          f"{args.exposure[1]:+g})" if args.exposure else "",
                          f", lfsf settings from {args.config}" if args.config else "",
                          f", photographs from {args.images}" if args.images else ""])
        print(f"## Synthetic scenes, {w}×{h}, {args.grid}×{args.grid} {'RGB ' if args.colour else ''}views "
              f"(valid pixels, {SYNTH_BORDER}-px border{inputs})\n")
        print(synth_table(rows))
        if use_peers:
            print("\n### Bars lfsf must meet (½ of the best peer)\n")
            print(bars_table(bars))
        if targets:
            print("\n### Targets\n")
            print(targets_table(targets))
        occlusion = occlusion_table(rows, targets)
        if occlusion:
            print("\n### Missed flow bars, over the points seen at t2 as well (informational)\n")
            print(occlusion)
    if args.real:
        print(f"\n## Real data (HCI: {HCI_BORDER}-px border; Lytro: views cropped by {LYTRO_CROP} px "
              "to EPINET's frame)\n")
        print(real_table(rows))
    for n in notes:
        print(f"\nnote: {n}")
    print("\nversions: " + ", ".join(f"{k} {v}" for k, v in peers.versions().items()))

    if args.json:
        settings = dataclasses.asdict(lfsf_params()) if args.methods in ("all", "lfsf") and lfsf_runs else None
        doc = {"args": {k: v for k, v in vars(args).items()}, "lfsf_params": settings, "versions": peers.versions(),
               "opencv_tvl1_parameters": peers.opencv_tvl1_parameters() if use_peers else None,
               "notes": notes, "rows": rows, "bars": bars, "targets": targets}
        write_json_atomic(args.json, doc, indent=1, default=float)
        print(f"wrote {args.json}", file=sys.stderr)

    failed = [r for r in rows if r.get("error")]
    if failed:
        print(f"error: {len(failed)} run{'s' if len(failed) > 1 else ''} failed (their rows say why)", file=sys.stderr)
        return 1
    if args.check:
        if not targets:
            print("--check: no lfsf target was checked (none of its runs: --methods peers, or no scene)",
                  file=sys.stderr)
            return 1
        missed = [t for t in targets if t["status"] != "pass"]
        if missed:
            print(f"--check: {len(missed)} of {len(targets)} targets not met (the targets table says which)",
                  file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    from lfsf._errors import run_script

    sys.exit(run_script(main))
