#!/usr/bin/env python
"""The flow of whole-image shifts of fine and coarse textures, with the flow search's
region test (``lfsf.estimate.FLOW_INCOHERENT_REGION``), without it, and with the search
off.

Each texture is resized to the view size plus a 20-px margin, and the two centre views
are its crops shifted by whole pixels: the exact flow is the shift everywhere. The
estimate is flow only with the chosen preset's settings (one circle), scored by its mean
end-point error without an 8-px border. A texture finer than the flow search's level
resolves (``gravel``, ``grass``, white noise blurred by 1 px) makes the search's matches
noise; fused, they replaced the right flow of the coarse-to-fine warping, which the
search off shows (docs/accuracy.md, forty-fourth session). A periodic texture
(``brick``) is wrong either way.

Usage (from the repository root; the textures other than ``noise`` need scikit-image)::

    python scripts/fine_textures.py                                 # 160×120, paper
    python scripts/fine_textures.py --size 96 72 --textures noise gravel --shifts 3,3 5,5

Exit status 2 for bad arguments.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from lfsf._errors import ArgumentParser  # noqa: E402  (usage errors in one line)

TEXTURES = ("gravel", "grass", "brick", "camera", "noise")
SHIFTS = ((1, 1), (3, 3), (5, 5), (7, 2))
MARGIN = 20


def texture(name: str, size) -> np.ndarray:
    """The texture ``name`` as float32 in [0, 1], ``size`` (w, h) plus the margin each side."""
    from lfsf._filters import gaussian_blur

    w, h = size[0] + 2 * MARGIN, size[1] + 2 * MARGIN
    if name == "noise":
        image = gaussian_blur(np.random.default_rng(3).random((h, w)), 1.0)
    else:
        import skimage.data
        from skimage.color import rgb2gray
        from skimage.transform import resize

        image = np.asarray(getattr(skimage.data, name)(), np.float64)
        image = rgb2gray(image) if image.ndim == 3 else image
        image = resize(image, (h, w), anti_aliasing=True)
    image = (image - image.min()) / max(float(image.max() - image.min()), 1e-12)
    return image.astype(np.float32)


def shifted_pair(image: np.ndarray, size, shift):
    (w, h), (du, dv) = size, shift
    m = MARGIN
    return image[m:m + h, m:m + w][None, None], image[m - dv:m - dv + h, m - du:m - du + w][None, None]


def epe(t1, t2, params, shift, device, region_test=True) -> float:
    from lfsf import estimate

    test = estimate._incoherent_regions
    if not region_test:
        estimate._incoherent_regions = lambda flow: np.zeros(flow.shape[:2], bool)
    try:
        sf = estimate.estimate_scene_flow(t1, t2, params, device=device)
    finally:
        estimate._incoherent_regions = test
    b = 8
    return float(np.hypot(sf.u - shift[0], sf.v - shift[1])[b:-b, b:-b].mean())


def main(argv=None) -> int:
    p = ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--size", nargs=2, type=int, default=[160, 120], metavar=("W", "H"),
                   help="view size (default 160 120)")
    p.add_argument("--textures", nargs="+", default=list(TEXTURES), help=f"of {', '.join(TEXTURES)} (default all)")
    p.add_argument("--shifts", nargs="+", default=[f"{u},{v}" for u, v in SHIFTS],
                   help="whole-pixel shifts DU,DV (default 1,1 3,3 5,5 7,2)")
    p.add_argument("--preset", default="paper", help="whose settings, flow only (default paper)")
    p.add_argument("--device", default=None, help="cpu or cuda:N (default: as lfsf run)")
    args = p.parse_args(argv)
    try:
        import lfsf
        from lfsf._scripts import check_before_runs

        unknown = [t for t in args.textures if t not in TEXTURES]
        if unknown:
            raise ValueError(f"unknown texture(s) {unknown}; known: {list(TEXTURES)}")
        shifts = []
        for text in args.shifts:
            try:
                du, dv = (int(v) for v in text.split(","))
            except ValueError:
                raise ValueError(f"--shifts {text}: expected DU,DV, two whole numbers of pixels") from None
            if max(abs(du), abs(dv)) > MARGIN:
                raise ValueError(f"--shifts {text}: at most {MARGIN} px each way")
            shifts.append((du, dv))
        if min(args.size) < 32:
            raise ValueError(f"--size must be at least 32×32, got {args.size[0]}×{args.size[1]}")
        check_before_runs(args.size, 1, device=args.device)
        params = lfsf.Params.preset(args.preset).replace(circles=1, samples=(1,))
        if any(t != "noise" for t in args.textures):
            import skimage.data  # noqa: F401
    except ImportError as exc:
        print(f"error: {exc}: the textures other than 'noise' need scikit-image (pip install scikit-image)",
              file=sys.stderr)
        return 2
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    w, h = args.size
    print(f"flow only, {args.preset} settings, {w}×{h}: flow EPE (px) with the region test / without it / "
          "the search off")
    print("| texture | " + " | ".join(f"({du}, {dv})" for du, dv in shifts) + " |")
    print("|---" * (len(shifts) + 1) + "|")
    for name in args.textures:
        image = texture(name, args.size)
        cells = []
        for shift in shifts:
            t1, t2 = shifted_pair(image, args.size, shift)
            cells.append(" / ".join(f"{e:.3f}" for e in (
                epe(t1, t2, params, shift, args.device), epe(t1, t2, params, shift, args.device, region_test=False),
                epe(t1, t2, params.replace(flow_search=False), shift, args.device))))
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    from lfsf._errors import run_script

    sys.exit(run_script(main))
