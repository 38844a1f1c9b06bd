"""Discrete disparity search (a plane sweep over the light field's samples), used to
start and to rescue the variational disparities where coarse-to-fine warping cannot
reach them: small objects vanish at coarse levels, and a disparity error e moves the
outer samples by R·e pixels, far outside the range of the linearisation.

For a disparity candidate δ the per-pixel matching cost of the samples s ≥ 1 is the mean
absolute difference of the warped samples to the centre view (the stereo residual ρ1,
or ρ2 at p + û); costs are then summed over a small window before the choice.
"""

import warp as wp

from .common import HALF_PLANES, bilinear, half_plane_residuals, inside

wp.set_module_options({"enable_backward": False})


@wp.kernel
def disparity_cost(
    row0: int,
    samples: wp.array3d(dtype=float),
    phis: wp.array(dtype=wp.vec2),
    candidates: wp.array(dtype=float),
    base: wp.array2d(dtype=float),
    offset: wp.array2d(dtype=wp.vec4),
    span: int,
    # outputs
    cost: wp.array3d(dtype=float),
):
    """cost[k, p] = the least, over the half-planes of samples (split by lines through
    φ = 0 at multiples of 45°), mean |L(q − δ_k φ_s, φ_s) − L(q, 0)| over the samples
    s ≥ 1 of that half, with q = p + (u, v) of ``offset`` (components 2, 3) and δ_k =
    candidates[k] + base[p]. Taking the best half makes the cost indifferent to an
    occluder on one side. Samples whose warped position leaves the image are left out
    (cost 1 where none remain). Launch over (candidates × rows, ⌈columns / span⌉)
    (:func:`lfsf.device.row_span`)."""
    r, c0 = wp.tid()
    r = r + row0
    h = cost.shape[1]
    w = cost.shape[2]
    k = r // h
    i = r - k * h
    j0 = c0 * span
    for j in range(j0, wp.min(w, j0 + span)):
        o = offset[i, j]
        qx = float(j) + o[2]
        qy = float(i) + o[3]
        d = candidates[k] + base[i, j]
        centre = bilinear(samples[0], qx, qy)
        sums, counts, total, count = half_plane_residuals(samples, phis, qx, qy, d, centre)
        c = float(1.0)
        for m in range(HALF_PLANES):
            if counts[m] > 0.0:
                c = wp.min(c, sums[m] / counts[m])
        cost[k, i, j] = c


@wp.kernel
def box_sum(
    row0: int,
    values: wp.array3d(dtype=float),
    radius: int,
    span: int,
    # outputs
    out: wp.array3d(dtype=float),
):
    """Mean of each slice over a (2r+1)² window, clamped at the borders. Launch over
    (slices × rows, ⌈columns / span⌉) (:func:`lfsf.device.row_span`)."""
    r, c = wp.tid()
    r = r + row0
    h = values.shape[1]
    w = values.shape[2]
    k = r // h
    i = r - k * h
    side = float(2 * radius + 1)
    j0 = c * span
    for j in range(j0, wp.min(w, j0 + span)):
        acc = float(0.0)
        for dy in range(-radius, radius + 1):
            for dx in range(-radius, radius + 1):
                acc += values[k, wp.clamp(i + dy, 0, h - 1), wp.clamp(j + dx, 0, w - 1)]
        out[k, i, j] = acc / (side * side)


@wp.kernel
def select_disparity(
    row0: int,
    cost: wp.array3d(dtype=float),
    candidates: wp.array(dtype=float),
    # outputs
    best: wp.array2d(dtype=float),
    best_cost: wp.array2d(dtype=float),
):
    """Winner-take-all over the candidates, refined by a parabola through the minimum
    and its neighbours (candidates evenly spaced). Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    n = cost.shape[0]
    kmin = int(0)
    cmin = cost[0, i, j]
    for k in range(1, n):
        c = cost[k, i, j]
        if c < cmin:
            cmin = c
            kmin = k
    d = candidates[kmin]
    if kmin > 0 and kmin < n - 1:
        cl = cost[kmin - 1, i, j]
        cr = cost[kmin + 1, i, j]
        curv = cl - 2.0 * cmin + cr
        if curv > 1.0e-12:
            step = candidates[kmin + 1] - candidates[kmin]
            d = d + 0.5 * (cl - cr) / curv * step
    best[i, j] = d
    best_cost[i, j] = cmin


@wp.kernel
def flow_cost(
    row0: int,
    centre1: wp.array2d(dtype=float),
    centre2: wp.array2d(dtype=float),
    candidates: wp.array(dtype=wp.vec2),
    base: wp.array2d(dtype=wp.vec4),
    span: int,
    # outputs
    cost: wp.array3d(dtype=float),
):
    """cost[k, p] = |I1(p) − I2(p + u_k)| with u_k = candidates[k] + (u, v) of ``base``
    (components 2, 3): the flow residual ρ3 at φ = 0; 1 where p + u_k leaves the image.
    Launch over (candidates × rows, ⌈columns / span⌉) (:func:`lfsf.device.row_span`)."""
    r, c = wp.tid()
    r = r + row0
    h = cost.shape[1]
    k = r // h
    i = r - k * h
    w = cost.shape[2]
    u_k = candidates[k]
    j0 = c * span
    for j in range(j0, wp.min(w, j0 + span)):
        b = base[i, j]
        x = float(j) + b[2] + u_k[0]
        y = float(i) + b[3] + u_k[1]
        value = float(1.0)
        if inside(centre2, x, y):
            value = wp.abs(centre1[i, j] - bilinear(centre2, x, y))
        cost[k, i, j] = value


@wp.kernel
def select_flow(
    row0: int,
    cost: wp.array3d(dtype=float),
    half: int,
    # outputs
    best: wp.array2d(dtype=wp.vec2),
):
    """Winner-take-all over a (2n+1)² grid of whole-pixel candidates (k = (dy+n)(2n+1) +
    (dx+n)), refined by a parabola along each axis. Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    side = 2 * half + 1
    kmin = int(0)
    cmin = cost[0, i, j]
    for k in range(1, side * side):
        c = cost[k, i, j]
        if c < cmin:
            cmin = c
            kmin = k
    ky = kmin // side
    kx = kmin - ky * side
    dx = float(kx - half)
    dy = float(ky - half)
    if kx > 0 and kx < side - 1:
        cl = cost[kmin - 1, i, j]
        cr = cost[kmin + 1, i, j]
        curv = cl - 2.0 * cmin + cr
        if curv > 1.0e-12:
            dx = dx + 0.5 * (cl - cr) / curv
    if ky > 0 and ky < side - 1:
        cu = cost[kmin - side, i, j]
        cd = cost[kmin + side, i, j]
        curv = cu - 2.0 * cmin + cd
        if curv > 1.0e-12:
            dy = dy + 0.5 * (cu - cd) / curv
    best[i, j] = wp.vec2(dx, dy)
