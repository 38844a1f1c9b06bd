"""Raw → views → scene flow, on synthetic lenslet images with exact ground truth.

    python scripts/lenslet_example.py DIR [--scene paper] [--size 160 120] [--pitch 9.6]
                                      [--kind hex|rect] [--bayer GRBG|none] [--preset paper] [--radius 3]

1. renders the scene's light fields at t1 and t2 (9×9 views, RGB) and records each through
   a micro-lens lattice onto a sensor (lfsf.decode.synthetic_lenslet: main-lens and
   micro-image vignetting, noise, a Bayer mosaic): DIR/raw1.png, DIR/raw2.png and the
   white image DIR/white.png, 16-bit;
2. decodes them as ``lfsf decode`` does into DIR/views1/ and DIR/views2/;
3. estimates scene flow from the decoded views as ``lfsf run`` does into DIR/result/;
4. resamples the ground truth onto the decoded grid (output pixel (x, y) is the
   lattice-plane point (u0 + x, v0 + y), one lens per source pixel) into DIR/gt.npz and
   prints the errors, with those of the same estimate from the source views.

The same steps on the command line, after step 1:

    lfsf decode DIR/raw1.png --white DIR/white.png --out DIR/views1 --views 9 --bayer GRBG
    lfsf decode DIR/raw2.png --white DIR/white.png --out DIR/views2 --views 9 --bayer GRBG
    lfsf run DIR/views1 DIR/views2 --out DIR/result     # R = 3 by itself on 9 decoded views
    lfsf eval DIR/result DIR/gt.npz

(``lfsf run`` keeps its samples off the micro-images' rims on decoded views,
``lfsf.estimate.RIM_FRACTION``; ``--radius`` here sets R for both estimates, from the
decoded and from the source views, for a like comparison.)
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from lfsf._errors import ArgumentParser  # noqa: E402  (usage errors in one line)
from lfsf import synth
from lfsf._errors import run_script
from lfsf._files import output_folder, savez_atomic
from lfsf.decode import Lattice, decode_files, synthetic_lenslet
from lfsf.estimate import estimate_scene_flow
from lfsf.evaluate import SYNTH_BORDER, evaluate, format_table
from lfsf.io import write_png
from lfsf.params import Params


def _bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    h, w = image.shape
    x = np.clip(x, 0, w - 1.001)
    y = np.clip(y, 0, h - 1.001)
    j, i = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - j, y - i
    return ((1 - fy) * ((1 - fx) * image[i, j] + fx * image[i, j + 1])
            + fy * ((1 - fx) * image[i + 1, j] + fx * image[i + 1, j + 1])).astype(np.float32)


def main(argv=None) -> int:
    ap = ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path, help="folder for the example's raw and white images, views and results")
    ap.add_argument("--scene", default="paper", help="the scene rendered (default paper)")
    ap.add_argument("--size", nargs=2, type=int, default=(160, 120), metavar=("W", "H"),
                    help="view size, lenses across and down (default 160 120)")
    ap.add_argument("--pitch", type=float, default=9.6, help="lens pitch in sensor pixels")
    ap.add_argument("--kind", default="hex", choices=("hex", "rect"), help="lens lattice (default hex)")
    ap.add_argument("--bayer", default="GRBG", help="a Bayer pattern, or 'none' for a grey sensor")
    ap.add_argument("--radius", type=float, default=3.0,
                    help="R of the estimate: 3 keeps to the inner 7×7 views, as the rims of the "
                         "micro-images mix in the neighbouring lenses (default 3)")
    ap.add_argument("--preset", default="paper", help="lfsf preset (default paper)")
    args = ap.parse_args(argv)
    # before any work: the sensor is pitch × the view size, so a pitch must be sized too
    if not (math.isfinite(args.pitch) and 8.0 <= args.pitch <= 32.0):  # (a Lytro: ~10, an Illum: ~14)
        raise ValueError(f"--pitch must be in 8…32 sensor pixels (9 views a lens), got {args.pitch}")
    from lfsf._scripts import check_before_runs

    check_before_runs(args.size, 9, colour=args.bayer.lower() != "none")
    if (args.size[0] + 1.2) * args.pitch * (args.size[1] + 1.2) * args.pitch > 2 ** 28:
        raise ValueError(f"a sensor of {args.size[0]}×{args.size[1]} lenses of {args.pitch} px holds more "
                         "than 2^28 pixels; use a smaller --size or --pitch")
    Params.preset(args.preset).replace(radius=args.radius)
    out = output_folder(args.out)
    width, height = args.size
    views = 9
    bayer = None if args.bayer.lower() == "none" else args.bayer

    # 1. the scene and its lenslet images: one lens per source pixel
    lf1, lf2, gt = synth.render_scene(args.scene, size=(width, height), grid=views, colour=bayer is not None)
    lattice = Lattice.regular(args.kind, args.pitch, 0.003, (0.6 * args.pitch, 0.6 * args.pitch))
    sensor = (int((width + 1.2) * args.pitch), int((height + 1.2) * args.pitch))  # plane units are pitches
    for k, lf in ((1, lf1), (2, lf2)):
        raw, white = synthetic_lenslet(lf.views, lattice, sensor, views=views, noise=0.002, white_noise=0.001,
                                       bayer=bayer, seed=k)
        write_png(out / f"raw{k}.png", np.rint(np.clip(raw, 0, 1) * 65535).astype(np.uint16))
    write_png(out / "white.png", np.rint(np.clip(white, 0, 1) * 65535).astype(np.uint16))
    print(f"lenslet images {sensor[0]}×{sensor[1]} ({args.kind}, pitch {args.pitch} px, {args.bayer}) "
          f"of '{args.scene}' at {width}×{height}: {out}/raw1.png, raw2.png, white.png", flush=True)

    # 2. decode
    decoded = []
    for k in (1, 2):
        t0 = time.perf_counter()
        lf, report = decode_files(out / f"raw{k}.png", out / "white.png", out / f"views{k}", views=views,
                                  bayer=bayer)
        decoded.append(lf)
        print(f"decoded raw{k}.png in {time.perf_counter() - t0:.1f} s: {lf.grid[0]}×{lf.grid[1]} views of "
              f"{lf.width}×{lf.height}, lattice {report['lattice']['kind']}, "
              f"pitch {report['lattice']['pitch']:.3f} px", flush=True)

    # 4. the ground truth on the decoded grid
    est = decoded[0].meta["lattice"]
    u0, v0 = decoded[0].meta["plane_origin"]
    su, sv = lattice.plane_position(*lattice.nearest_lens(*est.origin))
    y, x = np.mgrid[0:decoded[0].height, 0:decoded[0].width].astype(np.float64)
    x, y = x + u0 + su, y + v0 + sv
    truth = {k: _bilinear(gt[k], x, y) for k in ("disp1", "disp2", "u", "v")}
    inside = (x >= 0) & (x <= width - 1) & (y >= 0) & (y <= height - 1)
    truth["valid"] = inside & (_bilinear(gt["valid"].astype(np.float32), x, y) > 0.999)
    savez_atomic(out / "gt.npz", compressed=True, **truth)

    # 3. scene flow from the decoded views, and from the source views for comparison
    params = Params.preset(args.preset).replace(radius=args.radius)
    t0 = time.perf_counter()
    sf = estimate_scene_flow(decoded[0], decoded[1], params)
    seconds = time.perf_counter() - t0
    sf.save(out / "result", decoded[0].centre, decoded[1].centre)
    errors = evaluate(sf.as_dict(), truth, border=SYNTH_BORDER)
    print(f"\nscene flow from the decoded views ({seconds:.1f} s), against the ground truth on the decoded grid:")
    print(format_table(errors))
    source = estimate_scene_flow(lf1, lf2, params)
    print("\nthe same from the source views, against their own ground truth:")
    print(format_table(evaluate(source.as_dict(), gt, border=SYNTH_BORDER)))
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
