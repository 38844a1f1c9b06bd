"""Warm starts on a sequence: accuracy and time of each pair estimated from scratch and
started from the previous pair's result (lfsf.estimate.predict_next), on a synthetic
sequence with exact ground truth.

    python scripts/sequence.py [--scene paper] [--frames 5] [--size 320 240] [--preset paper]
                               [--warm-levels 0 2] [--json FILE]

Prints, per pair and mode, δ1 / δ2 MSE, flow EPE and seconds; then the medians. The first
pair has no predecessor, so it is the same in every mode and left out of the medians.
"""

from __future__ import annotations

import statistics
import time

from lfsf._errors import ArgumentParser  # noqa: E402  (usage errors in one line)
from lfsf import synth
from lfsf._errors import run_script
from lfsf._files import output_file, write_json_atomic
from lfsf.estimate import estimate_scene_flow, predict_next
from lfsf.evaluate import SYNTH_BORDER, evaluate
from lfsf.params import Params


def run(scene: str, frames: int, size, preset: str, warm_levels: list[int], device=None) -> list[dict]:
    lfs, gts = synth.render_sequence(scene, frames, size=tuple(size), device=device)
    base = Params.preset(preset)
    modes = [("cold", None)] + [(f"warm (levels {k or 'all'})", k) for k in warm_levels]
    rows = []
    for mode, levels in modes:
        params = base if levels is None else base.replace(warm_levels=levels)
        previous = None
        for k in range(frames - 1):
            init = None if levels is None or previous is None else predict_next(previous)
            t0 = time.perf_counter()
            sf = estimate_scene_flow(lfs[k], lfs[k + 1], params, device=device, init=init)
            seconds = time.perf_counter() - t0
            e = evaluate(sf.as_dict(), gts[k], border=SYNTH_BORDER)
            rows.append(dict(mode=mode, pair=k, seconds=seconds, disp1_mse=e["disp1"]["mse"],
                             disp2_mse=e["disp2"]["mse"], epe=e["flow"]["epe"]))
            print(f"{mode:<18} pair {k}: δ1 {e['disp1']['mse']:.4f}  δ2 {e['disp2']['mse']:.4f}  "
                  f"EPE {e['flow']['epe']:.3f}  {seconds:5.1f} s", flush=True)
            previous = sf
    return rows


def main(argv=None) -> int:
    ap = ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="paper", help="the scene (default paper)")
    ap.add_argument("--frames", type=int, default=5, help="light fields of the sequence, at least 3 (default 5)")
    ap.add_argument("--size", nargs=2, type=int, default=(320, 240), metavar=("W", "H"),
                    help="view size (default 320 240)")
    ap.add_argument("--preset", default="paper", help="lfsf preset (default paper)")
    ap.add_argument("--warm-levels", nargs="+", type=int, default=[0, 2], metavar="K",
                    help="the warm starts compared with the cold one (each pair from scratch): each pair "
                         "started from the one before on its K finest levels, 0 on all of them (default 0 2)")
    ap.add_argument("--device", help="Warp device (default: lfsf's)")
    ap.add_argument("--json", help="write every run's figures to this file")
    args = ap.parse_args(argv)
    if args.frames < 3:
        raise ValueError(f"--frames must be at least 3 (pair 0 is the cold start the others are compared with), "
                         f"got {args.frames}")
    if any(k < 0 for k in args.warm_levels) or len(set(args.warm_levels)) < len(args.warm_levels):
        raise ValueError(f"--warm-levels must be ≥ 0, each once, got {args.warm_levels}")
    synth.get_scene(args.scene)
    Params.preset(args.preset)
    from lfsf._scripts import check_before_runs

    check_before_runs(args.size, 9, device=args.device)
    if args.json:
        output_file(args.json)  # before the runs, not after them
    rows = run(args.scene, args.frames, args.size, args.preset, args.warm_levels, args.device)
    print(f"\nmedians over pairs 1…{args.frames - 2} ({args.scene}, {args.size[0]}×{args.size[1]}, "
          f"preset {args.preset}):")
    print(f"{'mode':<18} {'δ1 MSE':>8} {'δ2 MSE':>8} {'EPE':>7} {'seconds':>8}")
    for mode in dict.fromkeys(r["mode"] for r in rows):
        sel = [r for r in rows if r["mode"] == mode and r["pair"] > 0]
        med = {k: statistics.median(r[k] for r in sel) for k in ("disp1_mse", "disp2_mse", "epe", "seconds")}
        print(f"{mode:<18} {med['disp1_mse']:8.4f} {med['disp2_mse']:8.4f} {med['epe']:7.3f} {med['seconds']:8.1f}")
    if args.json:
        write_json_atomic(args.json, rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
