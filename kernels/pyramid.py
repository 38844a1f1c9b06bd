"""Image pyramid: Gaussian-prefiltered downsampling of image stacks, and bilinear
upsampling of the unknowns (scaled by the size ratio) between levels (MODEL.md §6).

Pixel centres map between a fine grid (h, w) and a coarse grid (hc, wc) as
x_c = (x + 0.5)·wc/w − 0.5 (and likewise for y)."""

from typing import Any

import warp as wp

from .common import bilinear, from_vec4, overload_unknowns, to_vec4

wp.set_module_options({"enable_backward": False})


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
    inv = 1.0 / (2.0 * sigma * sigma)
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
    coarse[n, i, j] = acc / wsum


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
