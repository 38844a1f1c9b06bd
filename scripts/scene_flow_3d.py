#!/usr/bin/env python
"""The 3-D scene flow of the joint estimate against a pipeline of the peers, on synthetic
scenes with exact ground truth.

Scene flow in 3-D needs all four maps at once: X(p, δ1) at t1 and X(p + u, δ2) at t2
(MODEL.md §7, ``lfsf.camera``). The peers each give one part; put together as one would
without lfsf, they are:

* δ1: plenpy's disparity of the t1 light field (structure tensor, TV-L1 fusion, as
  issue 3's bars);
* the flow: OpenCV's DualTVL1 on the two centre views (8-bit, defaults);
* δ2: plenpy's disparity of the t2 light field, sampled at p + (u, v) of that flow.

Both are scored through the camera that rendered the scene (``lfsf synth``'s f, b and
δ0) by :func:`lfsf.camera.scene_flow_errors`: the 3-D end-point error over the valid
pixels, the 8-px border out, its median, and the t1 depth's mean relative error.

Usage (from the repository root; needs the ``peers`` extra)::

    python scripts/scene_flow_3d.py                          # the built-in scenes, 160×120
    python scripts/scene_flow_3d.py --random 8 --size 320 240 --json sf3d.json

Exit status 2 for bad arguments or missing peers.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from lfsf._errors import ArgumentParser  # noqa: E402  (usage errors in one line)
from lfsf._scripts import check_before_runs  # noqa: E402

METHODS = ("lfsf", "plenpy + opencv")


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scenes", nargs="*", help="scene names (default: the built-in scenes)")
    p.add_argument("--random", type=int, default=0, metavar="N",
                   help="also the scenes random-0 … random-(N−1), after the named or built-in ones")
    p.add_argument("--size", type=int, nargs=2, default=(160, 120), metavar=("W", "H"),
                   help="view size (default 160 120)")
    p.add_argument("--grid", type=int, default=9, help="views per side (default 9)")
    p.add_argument("--preset", default="paper", help="lfsf preset (default paper)")
    p.add_argument("--device", default=None, help="Warp device (default: lfsf's)")
    p.add_argument("--json", metavar="FILE", help="write every scene's figures to FILE")
    return p


def peers_maps(lf1, lf2) -> dict:
    """δ1, δ2 and the flow from the peers, as one would put them together: plenpy's
    disparities of each light field, OpenCV's flow, and the t2 disparity read at p + u."""
    from lfsf import peers

    g1, g2 = lf1.grey(), lf2.grey()
    u, v = peers.opencv_tvl1(g1.centre, g2.centre)
    d1 = peers.plenpy_disparity(g1.views)
    d2 = peers.disparity_at_t1_pixels(peers.plenpy_disparity(g2.views), u, v)
    return {"disp1": d1, "disp2": d2, "u": u, "v": v}


def scene_figures(name: str, args, params) -> dict:
    """Each method's 3-D errors on one scene (:func:`lfsf.camera.scene_flow_errors`)."""
    from lfsf import estimate_scene_flow, synth
    from lfsf.camera import Camera, scene_flow_errors

    lf1, lf2, gt = synth.render_scene(name, size=tuple(args.size), grid=args.grid, device=args.device)
    camera = Camera.from_truth(gt)
    sf = estimate_scene_flow(lf1, lf2, params, device=args.device)
    out = {"lfsf": scene_flow_errors(sf, gt, camera)}
    out["plenpy + opencv"] = scene_flow_errors(peers_maps(lf1, lf2), gt, camera)
    out["true_mean_3d_motion"] = out["lfsf"]["motion"]  # (over the same pixels as the errors)
    return out


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    from lfsf import Params, synth

    try:
        params = Params.preset(args.preset)
        if params.flow_only:
            raise ValueError("--preset flow estimates no disparities: 3-D points need δ1 and δ2")
        if args.random < 0:
            raise ValueError(f"--random must be ≥ 0, got {args.random}")
        scenes = (list(args.scenes) or list(synth.SCENES)) + [f"{synth.RANDOM_PREFIX}{k}" for k in range(args.random)]
        for name in scenes:
            synth.get_scene(name)
        if args.grid < 3:
            raise ValueError(f"--grid must be at least 3, got {args.grid}")
        check_before_runs(args.size, args.grid, device=args.device, output=args.json)
        from lfsf import peers

        peers.import_plenpy_lightfield()
        peers._opencv_dual_tvl1()
    except (ValueError, ImportError) as exc:
        print(f"scene_flow_3d: error: {exc}", file=sys.stderr)
        return 2
    print(f"{args.preset}, {args.size[0]}×{args.size[1]}, {args.grid}×{args.grid} views; 3-D scene flow end-point "
          "error (mean / median, the scene's world units) and the t1 depth's mean relative error")
    print("| scene | mean true 3-D motion | " + " | ".join(f"{m}: EPE3D" for m in METHODS)
          + " | lfsf / peers | " + " | ".join(f"{m}: depth error" for m in METHODS) + " |")
    print("|---" * (2 * len(METHODS) + 3) + "|")
    report = {"size": list(args.size), "grid": args.grid, "preset": args.preset, "methods": list(METHODS),
              "scenes": {}}
    for name in scenes:
        start = time.perf_counter()
        figures = scene_figures(name, args, params)
        figures["seconds"] = round(time.perf_counter() - start, 1)
        report["scenes"][name] = figures
        epe = " | ".join(f"{figures[m]['epe3d']:.4g} / {figures[m]['epe3d_median']:.4g}" for m in METHODS)
        depth = " | ".join(f"{100 * figures[m]['depth1_rel']:.3g} %" for m in METHODS)
        ratio = figures["lfsf"]["epe3d"] / max(figures["plenpy + opencv"]["epe3d"], 1e-12)
        print(f"| {name} | {figures['true_mean_3d_motion']:.4g} | {epe} | {ratio:.3f} | {depth} |", flush=True)
    ratios = [report["scenes"][n]["lfsf"]["epe3d"] / max(report["scenes"][n]["plenpy + opencv"]["epe3d"], 1e-12)
              for n in scenes]
    finite = [r for r in ratios if 0 < r < math.inf]  # (a point at or beyond infinity makes a mean inf)
    report["summary"] = (f"lfsf's EPE3D below the peers' on {sum(r < 1 for r in ratios)} of {len(ratios)}; geometric "
                         f"mean of lfsf / peers {math.exp(float(np.mean(np.log(finite)))) if finite else math.nan:.3f}"
                         + (f" (over the {len(finite)} finite ratios)" if len(finite) < len(ratios) else ""))
    print(report["summary"])
    if args.json:
        from lfsf._files import write_json_atomic

        write_json_atomic(args.json, report)
    return 0


if __name__ == "__main__":
    from lfsf._errors import run_script

    sys.exit(run_script(main))
