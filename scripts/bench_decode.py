"""lfsf decode on synthetic lenslet images: accuracy of the four test cases, and time on an
Illum-sized sensor.

    python scripts/bench_decode.py cases            # PSNR, lattice errors (tests' settings)
    python scripts/bench_decode.py illum [GRBG]     # 7728×5368, hexagonal, pitch 14.29 px

The lenslet images come from lfsf.decode.synthetic_lenslet, rendered from a known light
field, so the decoded views are compared with the truth.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from lfsf.decode import Lattice, calibrate, decode, synthetic_lenslet  # noqa: E402


def cases() -> None:
    import test_decode as T

    for kind in ("hex", "rect"):
        for bayer in (None, "GRBG"):
            true = T.CASES[kind]
            field = T._texture_field(3, colour=bayer is not None)
            raw, white = synthetic_lenslet(field, true, (520, 400), views=9, vignetting=0.4, noise=0.003,
                                           white_noise=0.001, bayer=bayer)
            t = time.perf_counter()
            lf = decode(raw, white, views=9, bayer=bayer, device="cpu")
            seconds = time.perf_counter() - t
            psnr, misfit = T._psnr_inner(lf, true, field, 9)
            est = lf.meta["lattice"]
            print(f"{kind:4s} bayer={str(bayer):5s} PSNR {psnr:.1f} dB  origin misfit {misfit:.4f} pitch  "
                  f"pitch err {est.pitch - true.pitch:+.4f} px  rotation err "
                  f"{(est.rotation - true.rotation) * 1e3:+.3f} mrad  fit RMS {est.residual:.3f} px  "
                  f"views {lf.shape}  {seconds:.2f} s", flush=True)


def illum(bayer: str | None) -> None:
    from conftest import wave_texture

    textures = [wave_texture(s, 6, (0.2, 0.7), 0.08) for s in (3, 4, 5)]

    def field(u, v, xi, eta):
        planes = [t(u + 0.3 * xi, v + 0.3 * eta) for t in (textures if bayer else textures[:1])]
        return np.stack(planes, -1) if bayer else planes[0]

    true = Lattice.regular("hex", 14.29, 0.0021, (7.4, 3.9))
    t = time.perf_counter()
    raw, white = synthetic_lenslet(field, true, (7728, 5368), views=13, noise=0.003, white_noise=0.001,
                                   bayer=bayer)
    print(f"synthesised in {time.perf_counter() - t:.1f} s", flush=True)
    decode(raw[:600, :800], white[:600, :800], views=13, bayer=bayer, device="cpu")  # warm-up: kernel loads
    t = time.perf_counter()
    lattice = calibrate(white, bayer=bayer)
    print(f"calibrate {time.perf_counter() - t:.1f} s: {lattice.describe()}", flush=True)
    t = time.perf_counter()
    lf = decode(raw, white, views=13, bayer=bayer, lattice=lattice, device="cpu")
    print(f"devignette{', demosaic' if bayer else ''}, sample, resample {time.perf_counter() - t:.1f} s: "
          f"{lf.shape}", flush=True)
    t = time.perf_counter()
    lf = decode(raw, white, views=13, bayer=bayer, device="cpu")
    print(f"decode total {time.perf_counter() - t:.1f} s", flush=True)
    est = lf.meta["lattice"]
    u0, v0 = lf.meta["plane_origin"]
    su, sv = true.plane_position(*true.nearest_lens(*est.origin))
    y, x = np.mgrid[0:lf.height, 0:lf.width]
    err = [np.mean((lf.views[a, b] - field(x + u0 + su, y + v0 + sv, b - 6, a - 6)) ** 2)
           for a in range(3, 10) for b in range(3, 10)]
    print(f"PSNR inner 7×7: {10 * np.log10(1 / np.mean(err)):.1f} dB")


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] in ("-h", "--help"):
        print(__doc__)
        return 0
    what = argv[0] if argv else "cases"
    if what == "cases" and len(argv) <= 1:
        cases()
    elif what == "illum" and len(argv) <= 2:
        illum(argv[1] if len(argv) > 1 and argv[1] != "grey" else None)
    else:
        raise ValueError(f"expected 'cases' or 'illum [BAYER]', got {' '.join(argv)!r} (see --help)")
    return 0


if __name__ == "__main__":
    from lfsf._errors import run_script

    sys.exit(run_script(main))
