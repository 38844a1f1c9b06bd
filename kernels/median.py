"""Median filtering of the flow after each warp (Wedel et al. 2009), a stabiliser."""

import warp as wp

wp.set_module_options({"enable_backward": False})

#: Windows up to (2·3+1)² values are gathered into registers once per pixel; larger radii
#: read the image for every comparison.
LOCAL_RADIUS = wp.constant(3)
vec49 = wp.types.vector(length=49, dtype=wp.float32)


@wp.func
def select_rank(vals: vec49, n: int, m: int):
    """The m-th smallest of vals[0 … n−1] (insertion sort of the window, then the middle
    value: the order statistic that rank selection finds)."""
    for a in range(1, n):
        key = vals[a]
        b = a - 1
        while b >= 0 and vals[b] > key:
            vals[b + 1] = vals[b]
            b -= 1
        vals[b + 1] = key
    return vals[m]


@wp.func
def gathered_flow_median(x: wp.array2d(dtype=wp.vec4), i: int, j: int, radius: int):
    """The medians of u and v (components 2, 3) over the window, as :func:`window_median`,
    from the window's values gathered once into local vectors (radius ≤ LOCAL_RADIUS;
    each pixel read once for both components)."""
    h = x.shape[0]
    w = x.shape[1]
    side = 2 * radius + 1
    us = vec49()
    vs = vec49()
    c = int(0)
    for dy in range(-radius, radius + 1):
        row = wp.clamp(i + dy, 0, h - 1)
        for dx in range(-radius, radius + 1):
            value = x[row, wp.clamp(j + dx, 0, w - 1)]
            us[c] = value[2]
            vs[c] = value[3]
            c += 1
    n = side * side
    return select_rank(us, n, n // 2), select_rank(vs, n, n // 2)


@wp.func
def window_median(x: wp.array2d(dtype=wp.vec4), i: int, j: int, k: int, radius: int):
    """Median of component k of x over the (2r+1)² window at (i, j), clamped at the borders.

    Rank selection: the value with fewer than m smaller and at least m+1 smaller-or-equal
    values, m = n//2, is the median (no sorting, no scratch memory)."""
    h = x.shape[0]
    w = x.shape[1]
    side = 2 * radius + 1
    n = side * side
    m = n // 2
    result = x[i, j][k]
    for c in range(n):
        vc = x[wp.clamp(i + c // side - radius, 0, h - 1), wp.clamp(j + c % side - radius, 0, w - 1)][k]
        less = int(0)
        equal = int(0)
        for d in range(n):
            vd = x[wp.clamp(i + d // side - radius, 0, h - 1), wp.clamp(j + d % side - radius, 0, w - 1)][k]
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
    x: wp.array2d(dtype=wp.vec4),
    radius: int,
    # outputs
    out: wp.array2d(dtype=wp.vec4),
):
    """out = x with u and v (components 2, 3) median-filtered over a (2r+1)² window;
    δ1 and δ2 are copied. Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    v = x[i, j]
    if radius <= LOCAL_RADIUS:
        mu, mv = gathered_flow_median(x, i, j, radius)
        out[i, j] = wp.vec4(v[0], v[1], mu, mv)
    else:
        out[i, j] = wp.vec4(v[0], v[1], window_median(x, i, j, 2, radius), window_median(x, i, j, 3, radius))
