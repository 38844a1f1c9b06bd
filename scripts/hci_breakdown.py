#!/usr/bin/env python
"""Where HCI antinous's disparity error lies: MSE×100 split by region and by size.

Runs the estimator on the HCI light field given as both t1 and t2 (stereo), as the
issue's check does, and splits the MSE×100 (15-px border out) into parts that add up
to the total:

* ``wedge``: rows 150–224, columns 283–334, the wall between the jaw, the neck and the
  shoulder, seen in few views;
* ``floor``: rows 420 on, the floor in shadow at the bottom (its disparity rises by
  3.4 px per view step over 55 rows);
* ``head``: rows 0–149, columns 300–379, the wall right of the head;
* ``rest``: everything else;

and, across regions, the part carried by the pixels off by more than 1 px per view
step (most of them single pixels on the bust's outline).

``--set NAME=VALUE`` changes a :class:`lfsf.Params` setting (VALUE as JSON: ``--set
alpha1=0.35 --set samples=[1,8,16]``). ``--from-truth`` starts on the finest level
from the ground truth, without the searches: what the energy keeps of a perfect start
(seventeenth session: MSE×100 1.26 there, against 2.32 from the usual start).

Usage (from the repository root)::

    python scripts/hci_breakdown.py
    python scripts/hci_breakdown.py --set alpha1=0.35 --set gamma=20
    python scripts/hci_breakdown.py --from-truth --save truth_start.npy

Exit status 2 for bad arguments or a missing light field.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from lfsf._errors import ArgumentParser  # noqa: E402  (usage errors in one line)
from lfsf._scripts import check_before_runs  # noqa: E402

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "hci-antinous"
BORDER = 15
#: (name, rows, columns) of the regions, in the 512×512 views; the rest is ``rest``
REGIONS = (("wedge", slice(150, 225), slice(283, 335)),
           ("floor", slice(420, None), slice(None)),
           ("head", slice(0, 150), slice(300, 380)))


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(description=__doc__.split("\n\n")[0],
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("data", nargs="?", default=str(DATA), help=f"the HCI folder (default {DATA})")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="a Params setting, VALUE as JSON (repeatable)")
    p.add_argument("--preset", default="paper", help="lfsf preset (default paper)")
    p.add_argument("--from-truth", action="store_true",
                   help="start the finest level from the ground truth, without the searches")
    p.add_argument("--save", metavar="FILE", help="write δ1 to FILE (.npy)")
    p.add_argument("--device", default=None, help="Warp device (default: lfsf's)")
    return p


def breakdown(disparity: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """MSE×100 (border out) in total, per region and for the pixels off by more than 1;
    the regions and ``rest`` add up to ``total``."""
    error = np.zeros_like(truth, dtype=np.float64)
    inner = (slice(BORDER, -BORDER), slice(BORDER, -BORDER))
    error[inner] = (np.asarray(disparity, np.float64) - truth)[inner]
    count = error[inner].size
    squared = error ** 2
    out = {"total": 100.0 * squared.sum() / count}
    rest = np.ones(truth.shape, bool)
    for name, rows, cols in REGIONS:
        out[name] = 100.0 * squared[rows, cols].sum() / count
        rest[rows, cols] = False
    out["rest"] = 100.0 * squared[rest].sum() / count
    out["off_by_more_than_1"] = 100.0 * squared[np.abs(error) > 1.0].sum() / count
    out["badpix_0.07"] = 100.0 * float(np.mean(np.abs(error[inner]) > 0.07))
    return out


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    import lfsf
    from lfsf import io

    overrides = {}
    for item in args.set:
        name, sep, value = item.partition("=")
        if not sep:
            print(f"error: --set wants NAME=VALUE, got {item!r}", file=sys.stderr)
            return 2
        try:
            overrides[name] = json.loads(value)
        except json.JSONDecodeError:
            overrides[name] = value
        if isinstance(overrides[name], list):
            overrides[name] = tuple(overrides[name])
    data = Path(args.data)
    truth_file = data / "gt_disp_lowres.pfm"
    if not truth_file.is_file():
        print(f"error: {truth_file}: not found (the HCI antinous folder with its ground truth)", file=sys.stderr)
        return 2
    try:
        params = lfsf.Params.preset(args.preset).replace(**overrides)
        params.validate()
        if args.save and not args.save.endswith(".npy"):   # np.save would add it: '.npy' alone for 'dir/'
            raise ValueError(f"--save {args.save}: give a file name ending in .npy")
        check_before_runs(device=args.device, output=args.save)
    except (TypeError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    lf = lfsf.read_lightfield(data)
    truth = io.read_pfm(truth_file)
    init = None
    if args.from_truth:
        zero = np.zeros_like(truth)
        params = params.replace(warm_levels=1, disparity_search=False, flow_search=False)
        init = {"disp1": truth, "disp2": truth, "u": zero, "v": zero}
    start = time.perf_counter()
    result = lfsf.estimate_scene_flow(lf, lf, params=params, device=args.device, init=init)
    seconds = time.perf_counter() - start
    parts = breakdown(result.disp1, truth)
    settings = ", ".join(f"{k}={v}" for k, v in overrides.items()) or "defaults"
    print(f"HCI antinous, {args.preset} ({settings}){', from the truth' if args.from_truth else ''}: "
          f"{seconds:.1f} s")
    print("| MSE×100 | wedge | floor | head | rest | off by > 1 | BadPix(0.07) |")
    print("|---|---|---|---|---|---|---|")
    print(f"| {parts['total']:.3f} | {parts['wedge']:.3f} | {parts['floor']:.3f} | {parts['head']:.3f} | "
          f"{parts['rest']:.3f} | {parts['off_by_more_than_1']:.3f} | {parts['badpix_0.07']:.2f} % |")
    if args.save:  # (atomically; its folder made if missing, as for every --json)
        from lfsf._files import atomic_path

        with atomic_path(args.save) as tmp:
            np.save(tmp, result.disp1)
    return 0


if __name__ == "__main__":
    from lfsf._errors import run_script

    sys.exit(run_script(main))
