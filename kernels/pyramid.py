"""Image pyramid: Gaussian-prefiltered downsampling of image stacks, and bilinear
upsampling of the unknowns (scaled by the size ratio) between levels (MODEL.md §6).

Pixel centres map between a fine grid (h, w) and a coarse grid (hc, wc) as
x_c = (x + 0.5)·wc/w − 0.5 (and likewise for y)."""

from typing import Any

import warp as wp

from .common import bilinear, from_vec4, overload_unknowns, to_vec4

wp.set_module_options({"enable_backward": False})


@wp.func
def gaussian_mean(fine: wp.array3d(dtype=float), n: int, cy: float, cx: float, iy: int, ix: int, radius: int,
                  inv: float):
    """The mean of image n of ``fine`` around (cy, cx), weighted by exp(−d² · inv) over the
    (2r+1)² pixels around (iy, ix) inside the image (:data:`downsample`)."""
    h = fine.shape[1]
    w = fine.shape[2]
    acc = float(0.0)
    wsum = float(0.0)
    for dy in range(-radius, radius + 1):
        yy = iy + dy
        if yy >= 0 and yy < h:
            ey = float(yy) - cy
            for dx in range(-radius, radius + 1):
                xx = ix + dx
                if xx >= 0 and xx < w:
                    ex = float(xx) - cx
                    wt = wp.exp(-(ex * ex + ey * ey) * inv)
                    acc += wt * fine[n, yy, xx]
                    wsum += wt
    return acc / wsum


@wp.kernel
def downsample(
    row0: int,
    fine: wp.array3d(dtype=float),
    sigma: float,
    radius: int,
    # outputs
    coarse: wp.array3d(dtype=float),
):
    """coarse[n] = fine[n] convolved with a Gaussian of std ``sigma`` (fine pixels),
    sampled at the coarse pixel centres; weights renormalised at the borders. Launch over
    (n × coarse rows, coarse columns)."""
    r, j = wp.tid()
    r = r + row0
    hc = coarse.shape[1]
    wc = coarse.shape[2]
    h = fine.shape[1]
    w = fine.shape[2]
    n = r // hc
    i = r - n * hc
    cx = (float(j) + 0.5) * float(w) / float(wc) - 0.5
    cy = (float(i) + 0.5) * float(h) / float(hc) - 0.5
    ix = int(wp.floor(cx + 0.5))
    iy = int(wp.floor(cy + 0.5))
    coarse[n, i, j] = gaussian_mean(fine, n, cy, cx, iy, ix, radius, 1.0 / (2.0 * sigma * sigma))


#: The most taps along an axis whose Gaussian weights :data:`downsample_rows` keeps from
#: one pixel to the next (radius 4: a pyramid scale down to 1/4).
MEMO_SIDE = 9
memo_taps = wp.types.vector(length=MEMO_SIDE * MEMO_SIDE, dtype=wp.float32)
memo_offsets = wp.types.vector(length=MEMO_SIDE, dtype=wp.float32)


@wp.kernel
def downsample_rows(
    row0: int,
    fine: wp.array3d(dtype=float),
    sigma: float,
    radius: int,
    span: int,
    # outputs
    coarse: wp.array3d(dtype=float),
):
    """:data:`downsample`, a thread walking ``span`` coarse pixels of a row: the window's
    Gaussian weights, the same expression of the same offsets, are computed once and
    kept while the next pixel's offsets from the fine pixels (ex, exactly compared) are
    the same (a whole ratio of sizes: every pixel of the row), not 25 exponentials a
    pixel; the same sums in the same order. Windows of more than MEMO_SIDE taps a side
    take :func:`gaussian_mean`, as :data:`downsample` does. Launch over (n × coarse rows, ⌈coarse columns /
    span⌉)."""
    r, c = wp.tid()
    r = r + row0
    hc = coarse.shape[1]
    wc = coarse.shape[2]
    h = fine.shape[1]
    w = fine.shape[2]
    n = r // hc
    i = r - n * hc
    cy = (float(i) + 0.5) * float(h) / float(hc) - 0.5
    iy = int(wp.floor(cy + 0.5))
    inv = 1.0 / (2.0 * sigma * sigma)
    side = 2 * radius + 1
    offsets = memo_offsets()
    table = memo_taps()
    have = bool(False)
    j0 = c * span
    for j in range(j0, wp.min(wc, j0 + span)):
        cx = (float(j) + 0.5) * float(w) / float(wc) - 0.5
        ix = int(wp.floor(cx + 0.5))
        if side <= MEMO_SIDE:
            acc = float(0.0)
            wsum = float(0.0)
            same = bool(have)
            for dx in range(-radius, radius + 1):
                ex = float(ix + dx) - cx
                if ex != offsets[dx + radius]:
                    same = False
                offsets[dx + radius] = ex
            if not same:
                for dy in range(-radius, radius + 1):
                    ey = float(iy + dy) - cy
                    for dx in range(-radius, radius + 1):
                        ex = offsets[dx + radius]
                        table[(dy + radius) * side + dx + radius] = wp.exp(-(ex * ex + ey * ey) * inv)
                have = True
            for dy in range(-radius, radius + 1):
                yy = iy + dy
                if yy >= 0 and yy < h:
                    for dx in range(-radius, radius + 1):
                        xx = ix + dx
                        if xx >= 0 and xx < w:
                            wt = table[(dy + radius) * side + dx + radius]
                            acc += wt * fine[n, yy, xx]
                            wsum += wt
            coarse[n, i, j] = acc / wsum
        else:
            coarse[n, i, j] = gaussian_mean(fine, n, cy, cx, iy, ix, radius, inv)


@wp.kernel
def upsample(
    row0: int,
    coarse: wp.array3d(dtype=float),
    scale: float,
    # outputs
    fine: wp.array3d(dtype=float),
):
    """fine[n] = scale · coarse[n] interpolated bilinearly at the fine pixel centres.
    Launch over (n × fine rows, fine columns)."""
    r, j = wp.tid()
    r = r + row0
    h = fine.shape[1]
    w = fine.shape[2]
    hc = coarse.shape[1]
    wc = coarse.shape[2]
    n = r // h
    i = r - n * h
    x = (float(j) + 0.5) * float(wc) / float(w) - 0.5
    y = (float(i) + 0.5) * float(hc) / float(h) - 0.5
    fine[n, i, j] = scale * bilinear(coarse[n], x, y)


@wp.kernel
def upsample_unknowns(
    row0: int,
    coarse: wp.array2d(dtype=Any),
    scales: wp.vec4,
    carried: int,
    # outputs
    fine: wp.array2d(dtype=Any),
):
    """The unknowns of a coarser level on this one, on the device: component k of (δ1,
    δ2, u, v) set to scales[k] · ``coarse``'s interpolated bilinearly at the fine pixel
    centres, as :func:`upsample` does each plane, for k < ``carried``; the others left as
    they are (the TGV duals' flow parts, which a level starts at 0). k always counts the
    four of (δ1, δ2, u, v): arrays of vec2 (flow only) hold (u, v) as components 2 and 3
    (:func:`lfsf.kernels.common.to_vec4`), so their scales go in ``scales[2]`` and
    ``scales[3]`` and ``carried`` must be 4 to carry them. Launch over (fine rows, fine
    columns)."""
    i, j = wp.tid()
    i = i + row0
    h = fine.shape[0]
    w = fine.shape[1]
    x = (float(j) + 0.5) * float(coarse.shape[1]) / float(w) - 0.5
    y = (float(i) + 0.5) * float(coarse.shape[0]) / float(h) - 0.5
    up = to_vec4(bilinear(coarse, x, y))
    old = to_vec4(fine[i, j])
    out = wp.vec4(old[0], old[1], old[2], old[3])
    for k in range(4):
        if k < carried:
            out[k] = up[k] * scales[k]
    fine[i, j] = from_vec4(out, fine[i, j])


overload_unknowns(upsample_unknowns, "coarse", "fine")
