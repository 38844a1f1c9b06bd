#!/usr/bin/env python
"""The estimator's last steps, each measured against the same run without it.

``--step colour``: the colour-edge step (``Params.colour_median_radius``), on RGB
renderings. ``--step depth``: the median of the depth change δ2 − δ1 over one surface
(``Params.depth_change_radius``), on grey renderings (RGB with ``--colour``).

Each synthetic scene is estimated twice with the same settings, with the step (the
default) and without it (its radius 0). The steps act once, at the end, on δ1 and δ2,
so the two runs share everything before them and their difference is the step's alone
(the flow is the same bit for bit). Errors by ``lfsf.evaluate`` over valid pixels
without an 8-px border; the table gives both runs' δ1 and δ2 MSE, their ratios, and the
geometric means of the ratios.

Usage (from the repository root)::

    python scripts/final_steps.py --step colour                      # built-in scenes, 160×120
    python scripts/final_steps.py --step depth --scenes --random 16 --random-from 48
    python scripts/final_steps.py --step depth --size 320 240 --json depth.json

Exit status 2 for bad arguments.
"""


from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from lfsf._errors import ArgumentParser  # noqa: E402  (usage errors in one line)
from lfsf._scripts import check_before_runs  # noqa: E402

from compare_peers import selected_scenes  # noqa: E402  (the same scene selection)

#: --step: (the setting that switches it off, whether the scenes are rendered in RGB)
STEPS = {"colour": ("colour_median_radius", True), "depth": ("depth_change_radius", False)}


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(description=__doc__.split("\n\n")[0],
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--step", choices=sorted(STEPS), required=True, help="which step to measure")
    p.add_argument("--colour", action="store_true", help="RGB renderings (always for --step colour)")
    p.add_argument("--size", nargs=2, type=int, default=[160, 120], metavar=("W", "H"),
                   help="size of the views (default 160 120)")
    p.add_argument("--grid", type=int, default=9, help="views per side (default 9)")
    p.add_argument("--preset", default="paper", help="lfsf preset (default paper)")
    p.add_argument("--scenes", nargs="*", default=None,
                   help="built-in names or random-N (default: the built-in ones; '--scenes' alone: none)")
    p.add_argument("--random", type=int, default=0, metavar="N", help="add N scenes drawn at random")
    p.add_argument("--random-from", type=int, default=0, metavar="SEED", help="first random seed (default 0)")
    p.add_argument("--device", default=None, help="Warp device (default: lfsf's)")
    p.add_argument("--json", metavar="FILE", help="write the rows and the geometric means to FILE")
    return p


def main(argv=None) -> int:
    import lfsf
    from lfsf import evaluate, synth
    from lfsf._files import write_json_atomic

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        scenes = selected_scenes(args)
        if not scenes:
            raise ValueError("no scenes: name some after --scenes, or give --random N")
        params = lfsf.Params.preset(args.preset)
        setting, colour = STEPS[args.step]
        colour = colour or args.colour
        if getattr(params, setting) <= 0:
            raise ValueError(f"preset {args.preset!r} has the step off ({setting} = 0)")
        # (the errors leave out an 8-px border: smaller views leave nothing to evaluate)
        if min(args.size) < 32 or args.grid < 2:
            raise ValueError("--size needs at least 32×32 pixels and --grid at least 2 views per side")
        check_before_runs(args.size, args.grid, colour=colour, device=args.device, output=args.json)
    except ValueError as err:
        parser.error(str(err))  # exit status 2
    rows = []
    print("| scene | δ1 MSE with / without | ratio | δ2 MSE with / without | ratio | seconds |")
    print("|---|---|---:|---|---:|---:|")
    for name in scenes:
        lf1, lf2, gt = synth.render_scene(name, size=tuple(args.size), grid=args.grid, colour=colour,
                                          device=args.device)
        errors = {}
        if name == scenes[0]:  # an untimed run first: the first scene's seconds hold no start-up
            lfsf.estimate_scene_flow(lf1, lf2, params, device=args.device)
        t0 = time.perf_counter()
        for label, settings in (("with", params), ("without", params.replace(**{setting: 0}))):
            sf = lfsf.estimate_scene_flow(lf1, lf2, settings, device=args.device)
            e = evaluate.evaluate(sf.as_dict(), gt)
            errors[label] = (e["disp1"]["mse"], e["disp2"]["mse"], e["flow"]["epe"])
        seconds = (time.perf_counter() - t0) / 2
        (d1, d2, epe), (d1_off, d2_off, epe_off) = errors["with"], errors["without"]
        row = {"scene": name, "disp1_mse": d1, "disp1_mse_without": d1_off, "disp2_mse": d2,
               "disp2_mse_without": d2_off, "flow_epe": epe, "flow_epe_without": epe_off,
               "disp1_ratio": d1 / d1_off if d1_off > 0 else math.nan,
               "disp2_ratio": d2 / d2_off if d2_off > 0 else math.nan, "seconds": seconds}
        rows.append(row)
        print(f"| {name} | {d1:.5f} / {d1_off:.5f} | {row['disp1_ratio']:.3f} | {d2:.5f} / {d2_off:.5f} | "
              f"{row['disp2_ratio']:.3f} | {seconds:.1f} |", flush=True)
    summary = {}
    for key in ("disp1_ratio", "disp2_ratio"):
        ratios = np.array([r[key] for r in rows], np.float64)
        ratios = ratios[np.isfinite(ratios) & (ratios > 0)]
        if len(ratios):
            summary[key] = {"geometric_mean": float(np.exp(np.mean(np.log(ratios)))),
                            "worse": int(np.sum(ratios > 1.001)), "max": float(ratios.max()), "scenes": len(ratios)}
            s = summary[key]
            print(f"{key}: geometric mean {s['geometric_mean']:.3f}, worse on {s['worse']} of {s['scenes']}, "
                  f"at most {s['max']:.3f}")
    if args.json:
        write_json_atomic(args.json, {"step": args.step, "setting": setting, "colour": colour, "size": args.size,
                                      "grid": args.grid, "preset": args.preset, "rows": rows, "summary": summary})
    return 0


if __name__ == "__main__":
    from lfsf._errors import run_script

    sys.exit(run_script(main))
