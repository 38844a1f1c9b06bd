#!/usr/bin/env python
"""How far a scene's errors move when the input moves by far less than any sensor's noise.

Every view of both light fields is multiplied by (1 + ε·n), n ~ N(0, 1) drawn afresh per
pixel and per seed (ε = 1e-6 by default: about 2⁻²⁰, near float32's own resolution). For
each scene the estimate of the rendered pair and of ``--seeds`` perturbed pairs is scored
as ``lfsf eval`` scores it (valid pixels, the 8-px border out), and the table gives each
figure's value on the rendered pair, its range over all runs and that range as a fraction
of the median.

The estimator's choices are discrete in places (the searches' winners and fusions, the
best half of the samples, the occlusion tests, the median filter), and warping from a
slightly different start can settle in another local minimum: where the range is wide, a
single run's figure, and any comparison of two single runs (a setting against another,
the CPU against CUDA, the joint model against a special case) moves by about that much
for no reason in the method. Compare such figures over scenes or seeds, not one by one.

Usage (from the repository root)::

    python scripts/perturbation_spread.py                      # the built-in scenes, 160×120
    python scripts/perturbation_spread.py paper random-1 --size 320 240 --seeds 4 --json out.json
    python scripts/perturbation_spread.py --stereo-only    # also δ1 of the t1 light field given twice
    python scripts/perturbation_spread.py random-14 --flow-only   # also the EPE of flow only (M = 1)

With ``--stereo-only`` each run also estimates the stereo-only special case (the t1
light field, perturbed the same way, given as both t1 and t2) and scores its δ1; with
``--flow-only`` the flow-only case (one circle, the centre views alone: M = 1) and its
EPE. These are the issue's comparisons of the joint model against its special cases,
with the spread of both sides.

Exit status 2 for bad arguments.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from lfsf._errors import ArgumentParser  # noqa: E402  (usage errors in one line)
from lfsf._scripts import check_before_runs  # noqa: E402

FIGURES = (("δ1 MSE", "disp1", "mse"), ("δ2 MSE", "disp2", "mse"), ("EPE", "flow", "epe"))


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(description=__doc__.split("\n\n")[0],
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scenes", nargs="*", help="scene names (default: the built-in scenes)")
    p.add_argument("--size", type=int, nargs=2, default=(160, 120), metavar=("W", "H"), help="view size (default 160 120)")
    p.add_argument("--grid", type=int, default=9, help="views per side (default 9)")
    p.add_argument("--preset", default="paper", help="lfsf preset (default paper)")
    p.add_argument("--seeds", type=int, default=4, help="perturbed runs per scene (default 4)")
    p.add_argument("--epsilon", type=float, default=1e-6, help="relative size of the perturbation (default 1e-6)")
    p.add_argument("--device", default=None, help="Warp device (default: lfsf's)")
    p.add_argument("--stereo-only", action="store_true",
                   help="also score δ1 of the stereo-only case (t1 given twice) in every run")
    p.add_argument("--flow-only", action="store_true",
                   help="also score the EPE of the flow-only case (M = 1) in every run")
    p.add_argument("--json", metavar="FILE", help="write every run's figures to FILE")
    return p


def perturbed(lf, epsilon: float, rng):
    from lfsf import LightField

    views = lf.views * (1.0 + epsilon * rng.standard_normal(lf.views.shape))
    return LightField(views.astype(np.float32), source=f"{lf.source} (perturbed)")


def figures(sf, gt) -> list[float]:
    from lfsf.evaluate import evaluate

    errors = evaluate(sf, gt)
    return [float(errors[group][key]) for _name, group, key in FIGURES]


def evaluate_flow(sf, gt) -> float:
    """The flow EPE of an estimate (of a flow-only run: its disparities are not estimates)."""
    from lfsf.evaluate import evaluate

    truth = {k: gt[k] for k in ("u", "v", "valid") if k in gt}
    return float(evaluate({"u": sf.u, "v": sf.v}, truth)["flow"]["epe"])


def stereo_figure(sf, gt) -> float:
    """δ1 MSE of a stereo-only estimate (its δ2 and flow are not the scene's)."""
    from lfsf.evaluate import evaluate

    truth = {k: gt[k] for k in ("disp1", "valid") if k in gt}
    return float(evaluate({"disp1": sf.disp1}, truth)["disp1"]["mse"])


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    from lfsf import Params, estimate_scene_flow, synth

    try:
        params = Params.preset(args.preset)
        scenes = args.scenes or list(synth.SCENES)
        for name in scenes:
            synth.get_scene(name)
        if args.seeds < 1 or not 0.0 < args.epsilon < 0.1:
            raise ValueError("--seeds must be at least 1 and --epsilon in (0, 0.1)")
        # the render's size and grid, the device and the report's file: before any run, not after
        check_before_runs(args.size, args.grid, device=args.device, output=args.json)
    except ValueError as exc:
        print(f"perturbation_spread: error: {exc}", file=sys.stderr)
        return 2
    report = {"size": list(args.size), "grid": args.grid, "preset": args.preset, "epsilon": args.epsilon,
              "scenes": {}}
    print(f"{args.preset}, {args.size[0]}×{args.size[1]}, {args.grid}×{args.grid} views, {args.seeds} perturbed "
          f"runs a scene, ε = {args.epsilon:g}")
    names = ([name for name, _g, _k in FIGURES] + (["stereo-only δ1 MSE"] if args.stereo_only else [])
             + (["flow-only EPE"] if args.flow_only else []))
    header = " | ".join(f"{name} rendered | range | range/median" for name in names)
    print(f"| scene | {header} |")
    print("|---" * (1 + 3 * len(names)) + "|")
    for name in scenes:
        start = time.perf_counter()
        lf1, lf2, gt = synth.render_scene(name, size=tuple(args.size), grid=args.grid)
        pairs = [(lf1, lf2)]
        for seed in range(args.seeds):
            rng = np.random.default_rng(seed)
            pairs.append((perturbed(lf1, args.epsilon, rng), perturbed(lf2, args.epsilon, rng)))
        runs = []
        for p1, p2 in pairs:
            run = figures(estimate_scene_flow(p1, p2, params, device=args.device), gt)
            if args.stereo_only:
                run.append(stereo_figure(estimate_scene_flow(p1, p1, params, device=args.device), gt))
            if args.flow_only:
                flow = estimate_scene_flow(p1, p2, params.replace(circles=1, samples=(1,)), device=args.device)
                run.append(float(evaluate_flow(flow, gt)))
            runs.append(run)
        table = np.array(runs)
        spread = (table.max(0) - table.min(0)) / np.median(table, 0)
        cells = " | ".join(f"{table[0, k]:.4g} | {table[:, k].min():.4g}–{table[:, k].max():.4g} | {spread[k]:.2f}"
                           for k in range(len(names)))
        print(f"| {name} | {cells} |", flush=True)
        report["scenes"][name] = {"columns": names, "runs": runs, "range_over_median": spread.tolist(),
                                  "seconds": round(time.perf_counter() - start, 1)}
    if args.json:
        from lfsf._files import write_json_atomic

        write_json_atomic(args.json, report)
    return 0


if __name__ == "__main__":
    from lfsf._errors import run_script

    sys.exit(run_script(main))
