"""Median filtering of the flow after each warp (Wedel et al. 2009), a stabiliser, over the
pixels of the window on the same surface as the centre pixel.

A window that straddles a depth edge mixes the flows of two objects; the plain median then
moves the edge of the faster one's flow inwards (on a rotating sphere, whose flow is
steepest at its outline, by 1–2 px). With a tolerance τ > 0, only the window's pixels with
|δ1(q) − δ1(p)| ≤ τ take part. Their median is that of the full window after the others
are replaced by +BIG and −BIG in turn; where that leaves an even count, one of the others
becomes the centre pixel's own value, so that ties go to it. τ = 0: every pixel takes
part (the plain median)."""

from typing import Any

import warp as wp

from .common import from_vec4, overload_unknowns, to_vec4
from .median_networks import (median9, median25, median49, pair_medians1, pair_medians2, pair_medians3,
                              sorted_flow_column1, sorted_flow_column2, sorted_flow_column3, vec49)

wp.set_module_options({"enable_backward": False})

#: Windows up to (2·3+1)² values are gathered into registers once per pixel and their
#: median taken by a selection network; larger radii read the image for every comparison.
LOCAL_RADIUS = wp.constant(3)
#: Stands in for the window's pixels off the centre pixel's surface: +BIG and −BIG in turn
#: leave the median of the others as it is.
BIG = wp.constant(1.0e30)


@wp.func
def same_surface(d: float, d1: float, tolerance: float):
    """Whether a pixel whose δ1 is d takes part in the median of a pixel whose δ1 is d1."""
    return tolerance <= 0.0 or wp.abs(d - d1) <= tolerance


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
def gathered_flow_median(x: wp.array2d(dtype=Any), i: int, j: int, radius: int, tolerance: float):
    """The medians of u and v (components 2, 3) over the window's pixels on the centre
    pixel's surface (module docstring), from the window's values gathered once into local
    vectors (radius ≤ LOCAL_RADIUS; each pixel read once for both components)."""
    h = x.shape[0]
    w = x.shape[1]
    centre = to_vec4(x[i, j])
    us = vec49()
    vs = vec49()
    c = int(0)
    others = int(0)
    last = int(0)
    for dy in range(-radius, radius + 1):
        row = wp.clamp(i + dy, 0, h - 1)
        for dx in range(-radius, radius + 1):
            value = to_vec4(x[row, wp.clamp(j + dx, 0, w - 1)])
            if same_surface(value[0], centre[0], tolerance):
                us[c] = value[2]
                vs[c] = value[3]
            else:
                big = BIG
                if others % 2 == 1:
                    big = -BIG
                us[c] = big
                vs[c] = big
                others += 1
                last = c
            c += 1
    if others % 2 == 1:  # the last stand-in was +BIG: the centre's own value instead
        us[last] = centre[2]
        vs[last] = centre[3]
    return network_median(us, radius), network_median(vs, radius)


@wp.func
def window_pixel(x: wp.array2d(dtype=Any), i: int, j: int, c: int, side: int, radius: int):
    """The c-th pixel (row-major) of the side × side window at (i, j), clamped at the
    borders, as (δ1, δ2, u, v)."""
    row = wp.clamp(i + c // side - radius, 0, x.shape[0] - 1)
    return to_vec4(x[row, wp.clamp(j + c % side - radius, 0, x.shape[1] - 1)])


@wp.func
def rank_count(v: float, vc: float, less: int, equal: int):
    """The counts of values below and equal to vc, with v counted in."""
    if v < vc:
        return less + 1, equal
    if v == vc:
        return less, equal + 1
    return less, equal


@wp.func
def window_median(x: wp.array2d(dtype=Any), i: int, j: int, k: int, radius: int, tolerance: float):
    """Median of component k of x over the (2r+1)² window at (i, j), clamped at the borders,
    over the pixels on the centre pixel's surface (module docstring; with the centre value
    counted twice where their count is even).

    Rank selection: the value with fewer than m smaller and at least m+1 smaller-or-equal
    values, m = n//2, is the median (no sorting, no scratch memory)."""
    side = 2 * radius + 1
    n_window = side * side
    centre = to_vec4(x[i, j])
    d1 = centre[0]
    n = int(0)
    for c in range(n_window):
        if same_surface(window_pixel(x, i, j, c, side, radius)[0], d1, tolerance):
            n += 1
    extra = 1 - n % 2  # the centre's value once more where the count is even
    m = (n + extra) // 2
    result = centre[k]
    for c in range(n_window):
        value = window_pixel(x, i, j, c, side, radius)
        if same_surface(value[0], d1, tolerance):
            vc = value[k]
            less = int(0)
            equal = int(0)
            if extra == 1:
                less, equal = rank_count(centre[k], vc, less, equal)
            for d in range(n_window):
                other = window_pixel(x, i, j, d, side, radius)
                if same_surface(other[0], d1, tolerance):
                    less, equal = rank_count(other[k], vc, less, equal)
            if less <= m and m < less + equal:
                result = vc
    return result


@wp.kernel
def median_flow(
    row0: int,
    x: wp.array2d(dtype=Any),
    radius: int,
    tolerance: float,
    # outputs
    out: wp.array2d(dtype=Any),
):
    """out = x with u and v (components 2, 3) median-filtered over the pixels of a (2r+1)²
    window whose δ1 is within ``tolerance`` of the centre's (all of them where it is 0);
    δ1 and δ2 are copied. Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    unknowns = x[i, j]
    v = to_vec4(unknowns)
    if radius <= LOCAL_RADIUS:
        mu, mv = gathered_flow_median(x, i, j, radius, tolerance)
        out[i, j] = from_vec4(wp.vec4(v[0], v[1], mu, mv), unknowns)
    else:
        out[i, j] = from_vec4(wp.vec4(v[0], v[1], window_median(x, i, j, 2, radius, tolerance),
                                      window_median(x, i, j, 3, radius, tolerance)), unknowns)


overload_unknowns(median_flow, "x", "out")


@wp.kernel
def sorted_flow_columns(
    row0: int,
    x: wp.array2d(dtype=Any),
    radius: int,
    # outputs
    cu: wp.array3d(dtype=float),
    cv: wp.array3d(dtype=float),
    depth: wp.array2d(dtype=wp.vec2),
):
    """The first pass of :func:`flow_median_pairs`: u and v of the 2r+1 rows i − r … i + r
    of column j (clamped at the borders), sorted, to cu[i, j, 0 … 2r] and cv[i, j, 0 …
    2r], and their least and greatest δ1 to depth[i, j]. Launch over (rows, columns);
    1 ≤ r ≤ LOCAL_RADIUS."""
    i, j = wp.tid()
    i = i + row0
    if radius == 1:
        sorted_flow_column1(x, i, j, cu, cv, depth)
    elif radius == 2:
        sorted_flow_column2(x, i, j, cu, cv, depth)
    else:
        sorted_flow_column3(x, i, j, cu, cv, depth)


@wp.func
def one_surface(depth: wp.array2d(dtype=wp.vec2), i: int, first: int, last: int, d1: float, tolerance: float):
    """Whether every pixel of the window columns first … last (clamped) of row i's window
    takes part in the median of a pixel whose δ1 is d1 (:func:`same_surface`), from the
    columns' least and greatest δ1."""
    w = depth.shape[1]
    lo = d1
    hi = d1
    for j in range(first, last + 1):
        extent = depth[i, wp.clamp(j, 0, w - 1)]
        lo = wp.min(lo, extent[0])
        hi = wp.max(hi, extent[1])
    return tolerance <= 0.0 or (hi - d1 <= tolerance and d1 - lo <= tolerance)


@wp.kernel
def flow_median_pairs(
    row0: int,
    x: wp.array2d(dtype=Any),
    radius: int,
    tolerance: float,
    cu: wp.array3d(dtype=float),
    cv: wp.array3d(dtype=float),
    depth: wp.array2d(dtype=wp.vec2),
    # outputs
    out: wp.array2d(dtype=Any),
):
    """:func:`median_flow` (the same values, for finite δ1; of −0 and +0, equal, either
    may come out where the other did), a thread for the
    pixels (i, 2p) and (i, 2p + 1), from the window columns that
    :func:`sorted_flow_columns` sorted into cu and cv: where every pixel of a window is on
    the centre pixel's surface (its δ1 within ``tolerance`` of the centre's, by the
    columns' δ1 extents in ``depth``; always, flow only or at tolerance 0), the plain
    median of the two windows, which share 2r columns
    (:func:`lfsf.kernels.median_networks.pair_medians3` and its kin); at the pixels whose
    window straddles a depth edge, :func:`gathered_flow_median`. Min/max operations a
    window and component for the plain median: 32 to sort its column, half of the pair's
    324 for the shared ranks and 14 for its own column, 208 against 614 at radius 3; 72
    against 212 at radius 2. Launch over (rows, ⌈columns / 2⌉); 1 ≤ r ≤ LOCAL_RADIUS."""
    i, p = wp.tid()
    i = i + row0
    w = x.shape[1]
    j = 2 * p
    ul = float(0.0)
    ur = float(0.0)
    vl = float(0.0)
    vr = float(0.0)
    if radius == 1:
        ul, ur = pair_medians1(cu, i, j, w)
        vl, vr = pair_medians1(cv, i, j, w)
    elif radius == 2:
        ul, ur = pair_medians2(cu, i, j, w)
        vl, vr = pair_medians2(cv, i, j, w)
    else:
        ul, ur = pair_medians3(cu, i, j, w)
        vl, vr = pair_medians3(cv, i, j, w)
    left = x[i, j]
    a = to_vec4(left)
    if not one_surface(depth, i, j - radius, j + radius, a[0], tolerance):
        ul, vl = gathered_flow_median(x, i, j, radius, tolerance)
    out[i, j] = from_vec4(wp.vec4(a[0], a[1], ul, vl), left)
    if j + 1 < w:
        right = x[i, j + 1]
        b = to_vec4(right)
        if not one_surface(depth, i, j + 1 - radius, j + 1 + radius, b[0], tolerance):
            ur, vr = gathered_flow_median(x, i, j + 1, radius, tolerance)
        out[i, j + 1] = from_vec4(wp.vec4(b[0], b[1], ur, vr), right)


overload_unknowns(sorted_flow_columns, "x")
overload_unknowns(flow_median_pairs, "x", "out")


#: Colour spread floor of :func:`guided_median_edges`' separation test (intensities in
#: [0, 1]): two groups of flat colour are not told apart by less than this.
SEPARATION_FLOOR = wp.constant(0.01)


@wp.func
def group_split(values: vec49, colours: wp.array2d(dtype=wp.vec3), i: int, j: int, radius: int, split: float,
                separation: float):
    """Whether the window's pixels above ``split`` and those below it differ in colour by
    more than ``separation`` times the spread of colour within the groups: |m_near −
    m_far|² > κ² (s² + SEPARATION_FLOOR²), with m the groups' mean colours and s² the mean
    of the two groups' mean squared distances to their means (the floor keeps two flat
    groups from passing on a tiny difference)."""
    h = colours.shape[0]
    w = colours.shape[1]
    n_near = float(0.0)
    n_far = float(0.0)
    sum_near = wp.vec3(0.0)
    sum_far = wp.vec3(0.0)
    sq_near = float(0.0)
    sq_far = float(0.0)
    c = int(0)
    for dy in range(-radius, radius + 1):
        row = wp.clamp(i + dy, 0, h - 1)
        for dx in range(-radius, radius + 1):
            colour = colours[row, wp.clamp(j + dx, 0, w - 1)]
            if values[c] >= split:
                n_near += 1.0
                sum_near += colour
                sq_near += wp.dot(colour, colour)
            else:
                n_far += 1.0
                sum_far += colour
                sq_far += wp.dot(colour, colour)
            c += 1
    apart = False
    if n_near > 0.0 and n_far > 0.0:
        mean_near = sum_near / n_near
        mean_far = sum_far / n_far
        spread = 0.5 * (wp.max(sq_near / n_near - wp.dot(mean_near, mean_near), 0.0)
                        + wp.max(sq_far / n_far - wp.dot(mean_far, mean_far), 0.0))
        gap = mean_near - mean_far
        apart = wp.dot(gap, gap) > separation * separation * (spread + SEPARATION_FLOOR * SEPARATION_FLOOR)
    return apart


@wp.func
def guided_median_at(x: wp.array2d(dtype=wp.vec4), colours: wp.array2d(dtype=wp.vec3), i: int, j: int, k: int,
                     radius: int, colour_sigma: float, jump: float, separation: float):
    """Component k of x at (i, j) after :func:`guided_median_edges`' step."""
    h = x.shape[0]
    w = x.shape[1]
    own = x[i, j][k]
    values = vec49()
    lo = own
    hi = own
    c = int(0)
    for dy in range(-radius, radius + 1):
        row = wp.clamp(i + dy, 0, h - 1)
        for dx in range(-radius, radius + 1):
            v = x[row, wp.clamp(j + dx, 0, w - 1)][k]
            values[c] = v
            lo = wp.min(lo, v)
            hi = wp.max(hi, v)
            c += 1
    result = own
    if hi - lo > jump and group_split(values, colours, i, j, radius, 0.5 * (lo + hi), separation):
        # the colour weights, only at the depth edges that pass (most pixels do not)
        centre = colours[i, j]
        inv_c = 1.0 / (2.0 * colour_sigma * colour_sigma)
        inv_s = 1.0 / (2.0 * float(radius * radius))
        weights = vec49()
        total = float(0.0)
        c = int(0)
        for dy in range(-radius, radius + 1):
            row = wp.clamp(i + dy, 0, h - 1)
            for dx in range(-radius, radius + 1):
                gap = colours[row, wp.clamp(j + dx, 0, w - 1)] - centre
                g = wp.exp(-wp.dot(gap, gap) * inv_c - float(dy * dy + dx * dx) * inv_s)
                weights[c] = g
                total += g
                c += 1
        # the weighted median: the least value with at least half the weight at or below it
        result = hi
        for a in range(c):
            va = values[a]
            if va < result:
                below = float(0.0)
                for b in range(c):
                    if values[b] <= va:
                        below += weights[b]
                if below >= 0.5 * total:
                    result = va
    return result


@wp.kernel
def guided_median_edges(
    row0: int,
    x: wp.array2d(dtype=wp.vec4),
    colours: wp.array2d(dtype=wp.vec3),
    radius: int,
    colour_sigma: float,
    jump: float,
    separation: float,
    # outputs
    out: wp.array2d(dtype=wp.vec4),
):
    """δ1 and δ2 (components 0, 1) of x snapped to the colour edges of the t1 centre view
    where they jump: each takes, at its own depth edges, the median of its (2r+1)² window
    (r ≤ LOCAL_RADIUS, clamped at the borders) weighted by exp(−|c(q) − c(p)|²/2σ_c² −
    |q − p|²/2r²), c the colour. A step at a depth edge is taken where the window's
    values span more than ``jump`` and the colours of its two depth groups (above and
    below the middle of that span) are apart (:func:`group_split`, ``separation``);
    elsewhere the value is kept. Where the surfaces' colours do not differ (the same
    texture in front and behind) the colours cannot place the edge, and a weighted median
    would move it by the window's majority. The flow (components 2, 3) is copied, and so
    is all of x where r < 1 (an r above LOCAL_RADIUS is taken as LOCAL_RADIUS: the window's
    buffer holds no more). Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    v = x[i, j]
    r = wp.min(radius, LOCAL_RADIUS)
    if r < 1:
        out[i, j] = v
    else:
        out[i, j] = wp.vec4(guided_median_at(x, colours, i, j, 0, r, colour_sigma, jump, separation),
                            guided_median_at(x, colours, i, j, 1, r, colour_sigma, jump, separation), v[2], v[3])


@wp.kernel
def remove_speckles(
    row0: int,
    x: wp.array2d(dtype=wp.vec4),
    radius: int,
    depth: float,
    support: int,
    # outputs
    out: wp.array2d(dtype=wp.vec4),
):
    """δ1 and δ2 (components 0 and 1 of x) each cleared of speckles: where fewer than
    ``support`` of the (2r + 1)² window's pixels in the image (r = ``radius`` ≤ 3, p
    itself counted) hold a value within ``depth`` of p's (|x(q) − x(p)| < ``depth``), p
    takes the median of the window read clamped to the image, else keeps its value; u
    and v as they are.
    A depth that no surface around shares is a match of the data alone (an alias, a
    fusion's stray pick), as a stereo matcher's speckle filter takes it. Launch over
    (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    h = x.shape[0]
    w = x.shape[1]
    v = x[i, j]
    # the window gathered once for both unknowns, as gathered_flow_median does
    d1s = vec49()
    d2s = vec49()
    n = int(0)
    near1 = int(0)
    near2 = int(0)
    for dy in range(-radius, radius + 1):
        ii = i + dy
        for dx in range(-radius, radius + 1):
            jj = j + dx
            q = x[wp.clamp(ii, 0, h - 1), wp.clamp(jj, 0, w - 1)]
            d1s[n] = q[0]
            d2s[n] = q[1]
            n += 1
            if ii >= 0 and ii < h and jj >= 0 and jj < w:
                if wp.abs(q[0] - v[0]) < depth:
                    near1 += 1
                if wp.abs(q[1] - v[1]) < depth:
                    near2 += 1
    out_v = v
    if near1 < support:
        out_v[0] = network_median(d1s, radius)
    if near2 < support:
        out_v[1] = network_median(d2s, radius)
    out[i, j] = out_v
