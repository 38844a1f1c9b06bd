#!/usr/bin/env python
"""Where the joint model's δ1 stands against the stereo-only special case, and how much of
the gap the estimated flow is to blame for.

For each synthetic scene three estimates are scored by δ1 MSE as ``lfsf eval`` scores it
(valid pixels, the 8-px border out):

* **joint**: the two light fields, t1 and t2, as the estimator takes them;
* **stereo only**: the t1 light field given as both t1 and t2 (issue 3's special case);
* **joint, flow held**: the joint model with the flow held at the ground truth inside
  the solver. On every level, before every linearisation and after every median, the
  flow unknowns (u, v) are set to the true flow (resampled to the level as the
  estimator resamples maps), and their primal steps τ are set to 0, so the iterations
  move δ1 and δ2 only. The steps after the last warp (the hidden points' fill, the
  surface fits, the outlines' relabelling) run as they do. An oracle: what the joint
  δ1 would be if the flow were exact.

With t1 = t2 the cross-time rows ρ3 compare a light field with itself: at δ1 = δ2 and
zero flow they vanish for any δ, whatever the interpolation, the occlusions or the
noise. The joint model's ρ3 rows compare two captures, with their own sampling of the
moving surfaces, their own occlusions at t2 and their own noise. Where the joint δ1
loses even with the flow held at the truth, the flow's errors are not the reason.
With ``--static`` and ``--noise``, t2 is the t1 scene, unmoved, with noise of its own:
two captures of a still scene against one capture given twice.

Usage (from the repository root)::

    python scripts/joint_vs_stereo.py                          # the built-in scenes, 160×120
    python scripts/joint_vs_stereo.py --random 32 --json out.json   # built-in + random-0…31
    python scripts/joint_vs_stereo.py paper random-1 --size 320 240 --noise 0.02
    python scripts/joint_vs_stereo.py --noise 0.02 --static   # a still scene captured twice

Exit status 2 for bad arguments.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from lfsf._errors import ArgumentParser  # noqa: E402  (usage errors in one line)
from lfsf._scripts import check_before_runs  # noqa: E402

COLUMNS = ("joint", "stereo only", "joint, flow held")


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(description=__doc__.split("\n\n")[0],
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scenes", nargs="*", help="scene names (default: the built-in scenes)")
    p.add_argument("--random", type=int, default=0, metavar="N",
                   help="also the scenes random-0 … random-(N−1), after the named or built-in ones")
    p.add_argument("--size", type=int, nargs=2, default=(160, 120), metavar=("W", "H"), help="view size (default 160 120)")
    p.add_argument("--grid", type=int, default=9, help="views per side (default 9)")
    p.add_argument("--preset", default="paper", help="lfsf preset (default paper)")
    p.add_argument("--noise", type=float, default=0.0,
                   help="Gaussian noise of this standard deviation on every view, independent at t1 and t2 "
                        "(lfsf.synth.add_noise; the stereo-only run gets t1's twice)")
    p.add_argument("--static", action="store_true",
                   help="t2: the t1 scene again, unmoved, with noise of its own (needs --noise): two "
                        "captures of a still scene, whose true flow is zero")
    p.add_argument("--device", default=None, help="Warp device (default: lfsf's)")
    p.add_argument("--json", metavar="FILE", help="write every scene's figures to FILE")
    return p


@contextlib.contextmanager
def flow_held(u: np.ndarray, v: np.ndarray):
    """Within the block, every :class:`lfsf.solver.LevelSolver` of a scene-flow run (not a
    flow-only one, such as the exposure pilot's) holds its flow at (``u``, ``v``), full-
    resolution maps in pixels, resampled to its level: set before each linearisation and
    after each median, with the flow's primal steps τ at 0 so that the iterations leave
    it alone."""
    from lfsf import device as _device
    from lfsf.estimate import _resize_map
    from lfsf.solver import LevelSolver

    wp = _device.warp()
    height, width = u.shape
    linearise, median = LevelSolver.linearise, LevelSolver.median

    def put(solver) -> None:
        h, w = solver.shape
        x = solver.x.numpy()
        x[..., 2] = _resize_map(u, (h, w), w / width, solver.device)
        x[..., 3] = _resize_map(v, (h, w), h / height, solver.device)
        wp.copy(solver.x, wp.array(x, dtype=wp.vec4, device=solver.device))

    def held_linearise(solver) -> None:
        if solver.flow_only:
            return linearise(solver)
        put(solver)
        linearise(solver)
        tau = solver.tau_x.numpy()
        tau[..., 2:] = 0.0
        wp.copy(solver.tau_x, wp.array(tau, dtype=wp.vec4, device=solver.device))

    def held_median(solver) -> None:
        median(solver)
        if not solver.flow_only:
            put(solver)

    LevelSolver.linearise, LevelSolver.median = held_linearise, held_median
    try:
        yield
    finally:
        LevelSolver.linearise, LevelSolver.median = linearise, median


def disp1_mse(sf, gt) -> float:
    """δ1 MSE of an estimate, as ``lfsf eval`` scores it."""
    from lfsf.evaluate import evaluate

    truth = {k: gt[k] for k in ("disp1", "valid") if k in gt}
    return float(evaluate({"disp1": sf.disp1}, truth)["disp1"]["mse"])


def scene_figures(name: str, args, params) -> dict:
    """The three δ1 MSEs of one scene, and the held run's flow EPE (how near the truth
    the flow stayed through the steps after the last warp)."""
    from lfsf import estimate_scene_flow, synth
    from lfsf.evaluate import evaluate

    lf1, lf2, gt = synth.render_scene(name, size=tuple(args.size), grid=args.grid)
    if args.static:
        lf2 = lf1
        gt = dict(gt, u=np.zeros_like(gt["u"]), v=np.zeros_like(gt["v"]))
    if args.noise > 0:
        lf1, lf2 = synth.add_noise(lf1, args.noise, seed=1), synth.add_noise(lf2, args.noise, seed=2)
    joint = estimate_scene_flow(lf1, lf2, params, device=args.device)
    stereo = estimate_scene_flow(lf1, lf1, params, device=args.device)
    with flow_held(np.asarray(gt["u"], np.float32), np.asarray(gt["v"], np.float32)):
        held = estimate_scene_flow(lf1, lf2, params, device=args.device)
    truth = {k: gt[k] for k in ("u", "v", "valid") if k in gt}
    return {"disp1_mse": [disp1_mse(joint, gt), disp1_mse(stereo, gt), disp1_mse(held, gt)],
            "held_flow_epe": float(evaluate({"u": held.u, "v": held.v}, truth)["flow"]["epe"])}


def summary(table: np.ndarray) -> list[str]:
    """Lines comparing the columns over the scenes: how often each joint run's δ1 is below
    the stereo-only one, and the geometric mean of the ratio."""
    lines = []
    for k, name in ((0, "joint"), (2, "joint, flow held")):
        ratio = table[:, k] / np.maximum(table[:, 1], 1e-12)
        lines.append(f"{name}: δ1 below stereo only's on {int(np.sum(table[:, k] < table[:, 1]))} of {len(table)}; "
                     f"geometric mean of {name} / stereo only {math.exp(float(np.mean(np.log(ratio)))):.3f}")
    return lines


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    from lfsf import Params, synth

    try:
        params = Params.preset(args.preset)
        if args.random < 0:
            raise ValueError(f"--random must be ≥ 0, got {args.random}")
        scenes = (list(args.scenes) or list(synth.SCENES)) + [f"{synth.RANDOM_PREFIX}{k}" for k in range(args.random)]
        for name in scenes:
            synth.get_scene(name)
        if not 0.0 <= args.noise < 0.5:
            raise ValueError(f"--noise must be in [0, 0.5), got {args.noise}")
        if args.grid < 3:
            raise ValueError(f"--grid must be at least 3, got {args.grid}")
        if args.static and args.noise <= 0:
            raise ValueError("--static needs --noise: without it t2 would be t1 itself, the stereo-only case")
        # the render's size and grid, the device and the report's file: before any run, not after
        check_before_runs(args.size, args.grid, device=args.device, output=args.json)
    except ValueError as exc:
        print(f"joint_vs_stereo: error: {exc}", file=sys.stderr)
        return 2
    print(f"{args.preset}, {args.size[0]}×{args.size[1]}, {args.grid}×{args.grid} views"
          + (f", noise σ = {args.noise:g}" if args.noise > 0 else "")
          + (", t2 the still scene captured again" if args.static else "") + "; δ1 MSE")
    print("| scene | " + " | ".join(COLUMNS) + " | held run's flow EPE |")
    print("|---" * (len(COLUMNS) + 2) + "|")
    report = {"size": list(args.size), "grid": args.grid, "preset": args.preset, "noise": args.noise,
              "static": args.static,
              "columns": list(COLUMNS), "scenes": {}}
    for name in scenes:
        start = time.perf_counter()
        figures = scene_figures(name, args, params)
        figures["seconds"] = round(time.perf_counter() - start, 1)
        report["scenes"][name] = figures
        cells = " | ".join(f"{x:.4g}" for x in figures["disp1_mse"])
        print(f"| {name} | {cells} | {figures['held_flow_epe']:.3g} |", flush=True)
    table = np.array([report["scenes"][n]["disp1_mse"] for n in scenes])
    report["summary"] = summary(table)
    for line in report["summary"]:
        print(line)
    if args.json:
        from lfsf._files import write_json_atomic

        write_json_atomic(args.json, report)
    return 0


if __name__ == "__main__":
    from lfsf._errors import run_script

    sys.exit(run_script(main))
