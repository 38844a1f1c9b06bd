"""Whether t2 shows what t1 shows: after the estimate, the t2 centre view warped by the
flow should look like the t1 centre view.

Two light fields of different scenes (a batch folder whose files sort into unrelated
pairs, a cut in a video), or of one scene moved beyond ``Params.flow_range``, give maps
of no meaning without a word. The check compares I1(p) with I2(p + u) on the centre
views reduced by block means of :data:`MISMATCH_REDUCTION` pixels (sensor noise
averaged out), each standardised by its median and median absolute deviation (an
exposure or tone change undone): the median absolute difference, over that of I1 with
itself shifted by a third of the image (what two unrelated images of its kind differ by).
"""

from __future__ import annotations

import numpy as np

#: t2 is said not to match where the mismatch (module docstring) exceeds this.
#: Fifty-second session, `fast` preset: 24 + 24 related pairs from three renderers (with
#: noise up to σ ≈ 0.032, vignetting with an exposure change, blur, t2 at 1.4× the
#: exposure, a looming object), 0.005–0.28 (0.28: the looming object, 0.21: a weak
#: texture under the strongest noise); 11 pairs of unrelated scenes or moved 40 px
#: (flow_range 24), 0.54–0.97.
PAIR_MISMATCH = 0.45
#: Block size of the reduction.
MISMATCH_REDUCTION = 4
#: Pixels left out along the edges (flows that leave the image read its edge there).
MISMATCH_BORDER = 8


def _bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``image`` at (x, y), the coordinates clamped to the image."""
    h, w = image.shape
    x = np.clip(x, 0, w - 1)
    y = np.clip(y, 0, h - 1)
    x0 = np.floor(x).astype(np.intp)
    y0 = np.floor(y).astype(np.intp)
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    fx, fy = x - x0, y - y0
    top = image[y0, x0] * (1 - fx) + image[y0, x1] * fx
    return top * (1 - fy) + (image[y1, x0] * (1 - fx) + image[y1, x1] * fx) * fy


def _reduced(image: np.ndarray, factor: int) -> np.ndarray:
    h, w = (image.shape[0] // factor) * factor, (image.shape[1] // factor) * factor
    return image[:h, :w].reshape(h // factor, factor, w // factor, factor).mean(axis=(1, 3))


def _standardised(image: np.ndarray) -> np.ndarray:
    middle = np.median(image)
    spread = np.median(np.abs(image - middle))
    return (image - middle) / spread if spread > 0 else image - middle


def mismatch(centre1: np.ndarray, centre2: np.ndarray, u: np.ndarray, v: np.ndarray) -> float | None:
    """How unlike I1(p) the flow's I2(p + u) is (module docstring): about 0 for a pair of
    one scene, about 1 for unrelated images. ``centre1``, ``centre2``: grey (H, W) centre
    views; ``u``, ``v``: the flow in pixels. None where the views are too small to tell
    (under 8 reduced pixels a side within the border) or I1 is flat."""
    centre1 = np.asarray(centre1, np.float64)
    h, w = centre1.shape
    inner = (slice(MISMATCH_BORDER, h - MISMATCH_BORDER), slice(MISMATCH_BORDER, w - MISMATCH_BORDER))
    if min(h, w) - 2 * MISMATCH_BORDER < 8 * MISMATCH_REDUCTION:
        return None
    yy, xx = np.mgrid[0:h, 0:w]
    warped = _bilinear(np.asarray(centre2, np.float64), xx + np.asarray(u, np.float64),
                       yy + np.asarray(v, np.float64))
    one = _standardised(_reduced(centre1[inner], MISMATCH_REDUCTION))
    two = _standardised(_reduced(warped[inner], MISMATCH_REDUCTION))
    apart = np.median(np.abs(one - np.roll(one, (one.shape[0] // 3, one.shape[1] // 3), axis=(0, 1))))
    if not apart > 0:
        return None
    return float(np.median(np.abs(one - two)) / apart)


def mismatch_warning(centre1, centre2, u, v, sources: tuple[str, str], flow_range: float) -> str | None:
    """A sentence for the user where t2 does not match t1 (:data:`PAIR_MISMATCH`), else None."""
    found = mismatch(centre1, centre2, u, v)
    if found is None or found <= PAIR_MISMATCH:
        return None
    return (f"{sources[1]} does not match {sources[0]} after the estimated flow (mismatch {found:.2f}, where "
            f"pairs of one scene stay under {PAIR_MISMATCH:g} and unrelated images come near 1): two different "
            f"scenes (a batch's files paired in the wrong order, a cut in a video), or a motion beyond flow_range "
            f"({flow_range:g} px)? The maps mean little then (lfsf.pairing)")
