#!/usr/bin/env python
"""The optical flow under sensor noise: lfsf's ``flow`` preset at several data weights λ3
against OpenCV's DualTVL1 (8-bit input, its defaults), on rendered scenes with Gaussian
noise added to every view (independent at t1 and t2).

Each scene is rendered once (9×9 views; the flow needs the centre view alone) and each
noise level added to it; every method is scored by its mean end-point error over the
ground truth's valid pixels without an 8-px border. The table gives, per noise level,
each λ3's geometric mean of EPE over the first λ3's, OpenCV's over the first λ3's, and on
how many scenes the first λ3 is below OpenCV (docs/accuracy.md, forty-eighth session: the
`flow` preset's lead holds on noise-free views; at σ = 0.02 it is level).

Usage (from the repository root; OpenCV from the ``peers`` extra, skipped without it)::

    python scripts/flow_noise.py                                    # built-in + random-0…5
    python scripts/flow_noise.py --scenes paper random-3 --noise 0 0.02 --lambda3 30 10

Exit status 2 for bad arguments.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from lfsf._errors import ArgumentParser  # noqa: E402  (usage errors in one line)

SCENES = ("paper", "slanted", "large_motion", "weak_texture", *(f"random-{k}" for k in range(6)))


def main(argv=None) -> int:
    from lfsf import Params, estimate_scene_flow, evaluate, synth

    parser = ArgumentParser(prog="flow_noise.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", nargs="+", default=list(SCENES), help="scene names (default: %(default)s)")
    parser.add_argument("--size", nargs=2, type=int, default=(160, 120), metavar=("W", "H"))
    parser.add_argument("--noise", nargs="+", type=float, default=[0.0, 0.01, 0.02], metavar="SIGMA",
                        help="noise levels, intensities in [0, 1] (default: %(default)s)")
    parser.add_argument("--lambda3", nargs="+", type=float, default=[30.0, 20.0, 15.0, 10.0], metavar="L",
                        help="data weights of the flow preset, the first the reference (default: %(default)s)")
    parser.add_argument("--device", default=None)
    args = parser.parse_args(argv)
    for name in args.scenes:
        synth.get_scene(name)  # an unknown scene: one line before any work
    for sigma in args.noise:
        synth.add_noise(np.zeros((1, 1, 2, 2), np.float32), sigma)  # (the same checks)
    presets = [Params.preset("flow").replace(lambda3=lam) for lam in args.lambda3]
    try:
        from lfsf.peers import opencv_tvl1
        opencv_tvl1(np.zeros((16, 16), np.float32), np.zeros((16, 16), np.float32))
    except Exception as exc:  # noqa: BLE001 (no OpenCV: the lfsf columns alone)
        print(f"(no OpenCV: {exc})", file=sys.stderr)
        opencv_tvl1 = None
    rows = {sigma: [] for sigma in args.noise}
    for name in args.scenes:
        lf1, lf2, gt = synth.render_scene(name, size=tuple(args.size), grid=9, device=args.device)
        for sigma in args.noise:
            a, b = synth.add_noise(lf1, sigma, seed=0), synth.add_noise(lf2, sigma, seed=1)

            def epe(u, v):
                return evaluate.flow_errors(u, v, gt["u"], gt["v"], gt["valid"], evaluate.SYNTH_BORDER)["epe"]

            ours = [epe(*(lambda sf: (sf.u, sf.v))(estimate_scene_flow(a, b, p, device=args.device)))
                    for p in presets]
            cv = epe(*opencv_tvl1(a.centre, b.centre)) if opencv_tvl1 else math.nan
            rows[sigma].append((ours, cv))
            print(f"{name} σ={sigma:g}: " + ", ".join(f"λ3={lam:g} {e:.4f}" for lam, e in zip(args.lambda3, ours))
                  + f", OpenCV {cv:.4f}", flush=True)
    print("\n| noise σ | " + " | ".join(f"λ3 = {lam:g}" for lam in args.lambda3) + " | OpenCV | lfsf lower |")
    print("|---" * (len(args.lambda3) + 3) + "|")
    for sigma, results in rows.items():
        base = np.array([r[0][0] for r in results])
        means = [math.exp(np.mean(np.log(np.array([r[0][k] for r in results]) / base)))
                 for k in range(len(args.lambda3))]
        cv = np.array([r[1] for r in results])
        cv_mean = math.exp(np.mean(np.log(cv / base))) if np.all(np.isfinite(cv)) else math.nan
        print(f"| {sigma:g} | " + " | ".join(f"{m:.3f}" for m in means)
              + f" | {cv_mean:.3f} | {int(np.sum(base < cv))} of {len(results)} |")
    return 0


if __name__ == "__main__":
    from lfsf._errors import run_script

    sys.exit(run_script(main, prog="flow_noise.py"))
