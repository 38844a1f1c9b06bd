"""Parameter sweeps of the estimator on the synthetic scenes (exact ground truth).

Each setting runs on every scene (rendered once per scene) and is scored with
``lfsf.evaluate`` over valid pixels with an 8-px border left out. Settings vary one
parameter at a time around a base (``--vary``), or over a full grid (``--grid``).

    python scripts/sweep.py --size 160 120 --base "lambda3=30" \\
        --vary "texture_theta=0,0.5,0.95" --vary "alpha1=0.3,0.5,1" --json sweep.json

Prints a Markdown table: the setting, then per scene δ1 MSE, δ2 MSE, flow EPE and seconds,
and the geometric means over the scenes (lower is better).
"""

from __future__ import annotations

import argparse
import ast
import itertools
import math
import sys
import time

import numpy as np

import lfsf
from lfsf import evaluate, synth
from lfsf._errors import run_script
from lfsf._files import output_file, write_json_atomic


def parse_assignments(text: str) -> dict:
    """``"a=1,b=(1,8),c=True"`` → dict, values as Python literals."""
    out = {}
    if not text:
        return out
    for part in split_top(text):
        key, eq, value = part.partition("=")
        if not eq:
            raise ValueError(f"expected key=value, got {part!r}")
        out[key.strip()] = _literal(value)
    return out


def _literal(text: str):
    try:
        return ast.literal_eval(text.strip())
    except (ValueError, SyntaxError):
        raise ValueError(f"not a Python literal: {text.strip()!r} (numbers, True/False, tuples)") from None


def split_top(text: str, sep: str = ",") -> list[str]:
    """Split on `sep` outside brackets."""
    parts, depth, cur = [], 0, ""
    for ch in text:
        depth += ch in "([{"
        depth -= ch in ")]}"
        if ch == sep and depth == 0:
            parts.append(cur)
            cur = ""
        else:
            cur += ch
    if cur.strip():
        parts.append(cur)
    return parts


def parse_vary(text: str) -> tuple[str, list]:
    key, eq, values = text.partition("=")
    if not eq or not values.strip():
        raise ValueError(f"--vary expects 'key=v1,v2,…', got {text!r}")
    return key.strip(), [_literal(v) for v in split_top(values)]


def score(params: lfsf.Params, data, device) -> dict:
    rows = {}
    for name, (lf1, lf2, gt) in data.items():
        t0 = time.perf_counter()
        sf = lfsf.estimate_scene_flow(lf1, lf2, params, device=device)
        seconds = time.perf_counter() - t0
        e = evaluate.evaluate(sf.as_dict(), gt, border=evaluate.SYNTH_BORDER)
        rows[name] = {"disp1": e["disp1"]["mse"], "disp2": e["disp2"]["mse"], "epe": e["flow"]["epe"],
                      "seconds": seconds}
    return rows


def geomean(values) -> float:
    values = [max(v, 1e-12) for v in values]
    return float(math.exp(np.mean(np.log(values))))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", nargs=2, type=int, default=(160, 120), metavar=("W", "H"))
    ap.add_argument("--grid", dest="views", type=int, default=9, help="N×N views")
    ap.add_argument("--scenes", nargs="*", default=None)
    ap.add_argument("--preset", default="paper")
    ap.add_argument("--base", default="", help="settings applied to every run, e.g. 'lambda3=30,warps=4'")
    ap.add_argument("--vary", action="append", default=[], help="'key=v1,v2,…' (one at a time around the base)")
    ap.add_argument("--cartesian", action="store_true", help="every combination of the --vary values")
    ap.add_argument("--device", default=None)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    if args.json:
        output_file(args.json)  # before the runs, not after them

    base = lfsf.Params.preset(args.preset).replace(**parse_assignments(args.base))
    varies = [parse_vary(v) for v in args.vary]
    for key, values in varies:
        for value in values:
            base.replace(**{key: value})  # each value checked before any run
    settings: list[dict] = [{}]
    if args.cartesian and varies:
        keys = [k for k, _ in varies]
        settings = [dict(zip(keys, combo)) for combo in itertools.product(*[vals for _, vals in varies])]
    else:
        for key, values in varies:
            settings += [{key: v} for v in values if getattr(base, key) != v]

    scenes = args.scenes or list(synth.list_scenes())
    for s in scenes:
        synth.get_scene(s)
    data = {s: synth.render_scene(s, size=tuple(args.size), grid=args.views) for s in scenes}
    results = []
    header = "| setting | " + " | ".join(f"{s} δ1 / δ2 / EPE / s" for s in scenes) + " | gmean δ1 | gmean δ2 | gmean EPE |"
    print(f"base: {args.base or '(preset ' + args.preset + ')'}; {args.size[0]}×{args.size[1]}, "
          f"{args.views}×{args.views} views", flush=True)
    print(header)
    print("|" + "---|" * (len(scenes) + 4), flush=True)
    for change in settings:
        params = base.replace(**change)
        rows = score(params, data, args.device)
        g = {k: geomean([r[k] for r in rows.values()]) for k in ("disp1", "disp2", "epe")}
        label = ", ".join(f"{k}={v}" for k, v in change.items()) or "base"
        cells = " | ".join(f"{r['disp1']:.4f} / {r['disp2']:.4f} / {r['epe']:.3f} / {r['seconds']:.1f}"
                           for r in rows.values())
        print(f"| {label} | {cells} | {g['disp1']:.4f} | {g['disp2']:.4f} | {g['epe']:.4f} |", flush=True)
        results.append({"change": change, "scenes": rows, "geomean": g})
    if args.json:
        report = {"base": args.base, "size": args.size, "views": args.views, "results": results}
        write_json_atomic(args.json, report, indent=1, default=str)
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main))
