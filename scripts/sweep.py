"""Parameter sweeps of the estimator on the synthetic scenes (exact ground truth).

Each setting runs on every scene (rendered once per scene) and is scored with
``lfsf.evaluate`` over valid pixels with an 8-px border left out. Settings vary one
parameter at a time around a base (``--vary``), or over a full grid of them
(``--cartesian``; ``--grid`` is the views per side). One untimed run of the base on the
first scene comes first, so that the first setting's seconds hold no start-up (Warp's
modules loaded, first allocations).

    python scripts/sweep.py --size 160 120 --base "lambda3=30" \\
        --vary "texture_theta=0,0.5,0.95" --vary "alpha1=0.3,0.5,1" --json sweep.json

Prints a Markdown table: the setting, then per scene δ1 MSE, δ2 MSE, flow EPE and seconds,
and the geometric means over the scenes (lower is better).

How much of a difference is the setting's, and how much chance? The estimator makes
hard choices (which searched value to fuse, which samples an occluder hides), and noise
far below an 8-bit step can tip one; single scenes then move by up to several times and
geometric means over a dozen scenes by up to a tenth (docs/accuracy.md, twenty-third
session). ``--seeds K --perturb SIGMA`` runs every setting on K copies of each scene:
the rendering itself (seed 0) and K − 1 with Gaussian noise of SIGMA added to both light
fields (independent per copy and time, the same copies for every setting). The table
then gives each scene's median over its copies, the geometric means over all scenes and
copies, and, after them, the range of the geometric means taken copy by copy: a setting
whose geometric mean lies inside the base's range has not been shown to matter. In the
JSON, each result's ``scenes`` holds copy 0 (the rendering, as a run without copies
gives it), ``copies`` every copy, ``median`` the table's medians, ``geomean`` the means
over all scenes and copies and ``geomean_range`` the range.

    python scripts/sweep.py --scenes paper slanted random-0 random-1 --seeds 3 \
        --perturb 0.001 --vary "lambda3=20,40"

``--images skimage`` (or a folder) puts photographs on the objects, each scene's drawn
from its name as ``compare_peers.py --images`` draws them: natural images are where the
defaults, tuned on the solid textures, are weakest (docs/accuracy.md).
"""

from __future__ import annotations

import ast
import itertools
import math
import sys
import time
import zlib

import numpy as np

from lfsf._errors import ArgumentParser  # noqa: E402  (usage errors in one line)
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


METRICS = ("disp1", "disp2", "epe")


def perturbed(lf1, lf2, sigma: float, seed: int, name: str):
    """Copy ``seed`` of a scene's pair: the rendering itself for seed 0, else both light
    fields with independent Gaussian noise of ``sigma`` (:func:`lfsf.synth.add_noise`),
    drawn from the scene's name and the seed (the same copy for every setting)."""
    if seed == 0 or sigma == 0:
        return lf1, lf2
    base = (zlib.crc32(name.encode()) + 2 * seed) % 2**32
    return synth.add_noise(lf1, sigma, base), synth.add_noise(lf2, sigma, base + 1)


def score(params: lfsf.Params, data, device, seeds: int = 1, sigma: float = 0.0) -> dict:
    """Per scene the errors of each copy (:func:`perturbed`): {name: [{disp1, disp2, epe,
    seconds}, …]}, copy 0 first."""
    rows = {}
    for name, (lf1, lf2, gt) in data.items():
        rows[name] = []
        for seed in range(seeds):
            a, b = perturbed(lf1, lf2, sigma, seed, name)
            t0 = time.perf_counter()
            sf = lfsf.estimate_scene_flow(a, b, params, device=device)
            seconds = time.perf_counter() - t0
            e = evaluate.evaluate(sf.as_dict(), gt, border=evaluate.SYNTH_BORDER)
            rows[name].append({"disp1": e["disp1"]["mse"], "disp2": e["disp2"]["mse"], "epe": e["flow"]["epe"],
                               "seconds": seconds})
    return rows


def summary(rows: dict) -> tuple[dict, dict]:
    """(geometric means over every scene and copy, {metric: (least, greatest)} of the
    geometric means over the scenes taken copy by copy)."""
    copies = len(next(iter(rows.values())))
    g = {k: geomean([c[k] for r in rows.values() for c in r]) for k in METRICS}
    per_copy = [{k: geomean([r[s][k] for r in rows.values()]) for k in METRICS} for s in range(copies)]
    spread = {k: (min(c[k] for c in per_copy), max(c[k] for c in per_copy)) for k in METRICS}
    return g, spread


def geomean(values) -> float:
    values = [max(v, 1e-12) for v in values]
    return float(math.exp(np.mean(np.log(values))))


def main(argv=None) -> int:
    ap = ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", nargs=2, type=int, default=(160, 120), metavar=("W", "H"),
                    help="view size (default 160 120)")
    ap.add_argument("--grid", dest="views", type=int, default=9, help="N×N views (default 9)")
    ap.add_argument("--scenes", nargs="*", default=None, help="scene names (default: the built-in scenes)")
    ap.add_argument("--preset", default="paper", help="the base's preset (default paper)")
    ap.add_argument("--images", metavar="SOURCE",
                    help="photographs on the objects instead of their solid textures: 'skimage' "
                         "(scikit-image's samples) or a folder of images; each scene's images drawn from "
                         "its name, as compare_peers.py --images draws them")
    ap.add_argument("--base", default="", help="settings applied to every run, e.g. 'lambda3=30,warps=4'")
    ap.add_argument("--vary", action="append", default=[], help="'key=v1,v2,…' (one at a time around the base)")
    ap.add_argument("--cartesian", action="store_true", help="every combination of the --vary values")
    ap.add_argument("--seeds", type=int, default=1, metavar="K",
                    help="copies of each scene: the rendering and K − 1 with --perturb noise (default 1)")
    ap.add_argument("--perturb", type=float, default=0.0, metavar="SIGMA",
                    help="the noise of the copies after the first (intensities in [0, 1]; e.g. 0.001, "
                         "a quarter of an 8-bit step)")
    ap.add_argument("--device", default=None, help="Warp device (default: lfsf's)")
    ap.add_argument("--json", default=None, help="write every run's figures to this file")
    args = ap.parse_args(argv)
    if args.seeds < 1:
        raise ValueError(f"--seeds must be at least 1, got {args.seeds}")
    if not math.isfinite(args.perturb) or args.perturb < 0:
        raise ValueError(f"--perturb must be a finite number ≥ 0, got {args.perturb}")
    if args.seeds > 1 and args.perturb == 0:
        raise ValueError("--seeds above 1 needs --perturb SIGMA > 0 (the copies would be the same)")
    if args.seeds == 1 and args.perturb > 0:
        raise ValueError("--perturb needs --seeds K ≥ 2 (copy 0 is the rendering itself, without noise)")
    if args.json:
        output_file(args.json)  # before the runs, not after them
    from lfsf._scripts import check_before_runs

    check_before_runs(args.size, args.views, device=args.device)

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
            same = [v for v in values if getattr(base, key) == v]
            if same:  # (a value equal to the base is the base's row, run once)
                print(f"note: {key}={same[0]!r} is the base's own value: its runs are the base row", file=sys.stderr)

    scenes = list(dict.fromkeys(args.scenes)) if args.scenes else list(synth.list_scenes())  # (each once)
    for s in scenes:
        synth.get_scene(s)
    images = synth.photographs(args.images) if args.images is not None else None

    def scene_of(name):  # the scene's geometry and motion; photographs for textures with --images
        return name if images is None else synth.with_images_of_name(name, len(images))

    data = {s: synth.render_scene(scene_of(s), size=tuple(args.size), grid=args.views, images=images)
            for s in scenes}
    results = []
    copies = args.seeds > 1
    header = ("| setting | " + " | ".join(f"{s} δ1 / δ2 / EPE / s" for s in scenes)
              + " | gmean δ1 | gmean δ2 | gmean EPE |" + (" range over copies δ1 / δ2 / EPE |" if copies else ""))
    print(f"base: {args.base or '(preset ' + args.preset + ')'}; {args.size[0]}×{args.size[1]}, "
          f"{args.views}×{args.views} views" + (f", photographs from {args.images}" if images else "")
          + (f"; {args.seeds} copies of each scene (noise σ = {args.perturb:g} on all but the first), "
             "per scene their median" if copies else ""), flush=True)
    print(header)
    print("|" + "---|" * (len(scenes) + 4 + copies), flush=True)
    lf1, lf2, _gt = data[scenes[0]]
    lfsf.estimate_scene_flow(lf1, lf2, base, device=args.device)  # (the warm-up, untimed)
    for change in settings:
        params = base.replace(**change)
        rows = score(params, data, args.device, args.seeds, args.perturb)
        g, spread = summary(rows)
        label = ", ".join(f"{k}={v}" for k, v in change.items()) or "base"
        med = {name: {k: float(np.median([c[k] for c in r])) for k in (*METRICS, "seconds")}
               for name, r in rows.items()}
        cells = " | ".join(f"{r['disp1']:.4f} / {r['disp2']:.4f} / {r['epe']:.3f} / {r['seconds']:.1f}"
                           for r in med.values())
        band = (" " + " / ".join(f"{spread[k][0]:.4g}–{spread[k][1]:.4g}" for k in METRICS) + " |") if copies else ""
        print(f"| {label} | {cells} | {g['disp1']:.4f} | {g['disp2']:.4f} | {g['epe']:.4f} |{band}", flush=True)
        result = {"change": change, "scenes": {name: r[0] for name, r in rows.items()}, "geomean": g}
        if copies:
            result["copies"] = rows
            result["median"] = med
            result["geomean_range"] = spread
        results.append(result)
    if args.json:
        report = {"base": args.base, "size": args.size, "views": args.views, "images": args.images, "seeds": args.seeds,
                  "perturb": args.perturb, "results": results}
        write_json_atomic(args.json, report, indent=1, default=str)
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main))
