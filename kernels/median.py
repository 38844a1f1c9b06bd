"""Median filtering of the flow after each warp (Wedel et al. 2009), a stabiliser."""

from typing import Any

import warp as wp

from .common import from_vec4, overload_unknowns, to_vec4
from .median_networks import median9, median25, median49, vec49

wp.set_module_options({"enable_backward": False})

#: Windows up to (2·3+1)² values are gathered into registers once per pixel and their
#: median taken by a selection network; larger radii read the image for every comparison.
LOCAL_RADIUS = wp.constant(3)


@wp.func
def network_median(vals: vec49, radius: int):
    """The median of the (2r+1)² first values, r ≤ 3, by the branch-free selection networks
    of :mod:`lfsf.kernels.median_networks`. A 640×480 pass over both flow components:
    7×7 windows 81 ms, 5×5 33 ms, 3×3 10 ms, against 186, 101 and 29 ms by Hoare's
    selection, whose branches the CPU mispredicts on noisy flow (insertion sort: 204 ms
    at 7×7)."""
    result = vals[0]
    if radius == 1:
        result = median9(vals)
    elif radius == 2:
        result = median25(vals)
    elif radius == 3:
        result = median49(vals)
    return result


@wp.func
def gathered_flow_median(x: wp.array2d(dtype=Any), i: int, j: int, radius: int):
    """The medians of u and v (components 2, 3) over the window, as :func:`window_median`,
    from the window's values gathered once into local vectors (radius ≤ LOCAL_RADIUS;
    each pixel read once for both components)."""
    h = x.shape[0]
    w = x.shape[1]
    us = vec49()
    vs = vec49()
    c = int(0)
    for dy in range(-radius, radius + 1):
        row = wp.clamp(i + dy, 0, h - 1)
        for dx in range(-radius, radius + 1):
            value = to_vec4(x[row, wp.clamp(j + dx, 0, w - 1)])
            us[c] = value[2]
            vs[c] = value[3]
            c += 1
    return network_median(us, radius), network_median(vs, radius)


@wp.func
def window_median(x: wp.array2d(dtype=Any), i: int, j: int, k: int, radius: int):
    """Median of component k of x over the (2r+1)² window at (i, j), clamped at the borders.

    Rank selection: the value with fewer than m smaller and at least m+1 smaller-or-equal
    values, m = n//2, is the median (no sorting, no scratch memory)."""
    h = x.shape[0]
    w = x.shape[1]
    side = 2 * radius + 1
    n = side * side
    m = n // 2
    result = to_vec4(x[i, j])[k]
    for c in range(n):
        vc = to_vec4(x[wp.clamp(i + c // side - radius, 0, h - 1), wp.clamp(j + c % side - radius, 0, w - 1)])[k]
        less = int(0)
        equal = int(0)
        for d in range(n):
            vd = to_vec4(x[wp.clamp(i + d // side - radius, 0, h - 1), wp.clamp(j + d % side - radius, 0, w - 1)])[k]
            if vd < vc:
                less += 1
            elif vd == vc:
                equal += 1
        if less <= m and m < less + equal:
            result = vc
    return result


@wp.kernel
def median_flow(
    row0: int,
    x: wp.array2d(dtype=Any),
    radius: int,
    # outputs
    out: wp.array2d(dtype=Any),
):
    """out = x with u and v (components 2, 3) median-filtered over a (2r+1)² window;
    δ1 and δ2 are copied. Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    unknowns = x[i, j]
    v = to_vec4(unknowns)
    if radius <= LOCAL_RADIUS:
        mu, mv = gathered_flow_median(x, i, j, radius)
        out[i, j] = from_vec4(wp.vec4(v[0], v[1], mu, mv), unknowns)
    else:
        out[i, j] = from_vec4(wp.vec4(v[0], v[1], window_median(x, i, j, 2, radius), window_median(x, i, j, 3, radius)),
                              unknowns)


overload_unknowns(median_flow, "x", "out")
