"""Geometric occlusion, from the current scene flow itself (an addition to the paper):
in the side views of each light field (view z-buffers, :func:`splat_views`), and at t2
in the centre view (:func:`splat_depth`, :func:`hidden_at_t2`, :func:`spread_hidden`).

Near a depth edge the nearer surface hides the farther one in the views on its side.
Each point p of the t1 centre view, with disparity δ, lands in view φ at p − δφ (at t2,
at p + u − δ2 φ); a z-buffer of the largest disparity landing on each pixel of each view
then says, for any sample position and disparity, whether a nearer point covers it
(:func:`lfsf.kernels.common.visible`). This asks the geometry, not the residuals: the
test that keeps the better-matching half of the samples (:mod:`lfsf.kernels.data_term`)
favours, where the background has little texture, any disparity that sees no occluder
at all, the foreground's, and fattens it by R times the disparity step.

Geometric occlusion at t2: which points of the t1 centre view are hidden at t2 in the
centre view, from the current scene flow itself (an addition to the paper).

Every pixel p lands at p + (u, v) in the t2 centre view. Nearer points have larger
disparities (``help(lfsf)``, MODEL.md §1), so a z-buffer of the largest disparity landing at each t2 pixel
says who is seen there; p is hidden where a point nearer by more than a margin lands on
the pixel where p lands, and the hidden band then spreads ``reach`` pixels over its own
surface (the band's edge pixels, whose flow is as wrong as the band's). The depth key is δ1, the point's disparity at
t1: it is known from the t1 light field alone, whereas δ2 of a hidden point is itself
unobserved and, while the estimate is wrong, takes the occluder's value (which would hide
the occlusion). The order of depths rarely changes between two frames. This is the test a
photometric one cannot make in weak or repetitive texture, and it is what the light field
buys: the depth order of the points.
"""

import warp as wp

wp.set_module_options({"enable_backward": False})

#: z-buffer value of a t2 pixel on which no point lands.
EMPTY = wp.constant(-1.0e30)


@wp.func
def landing_pixel(v: wp.vec4, i: int, j: int, h: int, w: int):
    """(row, column, inside) of the t2 pixel nearest to p + (u, v), p = (i, j)."""
    tx = int(wp.floor(float(j) + v[2] + 0.5))
    ty = int(wp.floor(float(i) + v[3] + 0.5))
    return ty, tx, ty >= 0 and ty < h and tx >= 0 and tx < w


@wp.func
def surface_rates(sigma: float, depth_sigma: float):
    """(1/2σ², 1/2σ_d²) of :func:`surface_weight`; σ_d = 0: no depth weight (rate 0)."""
    inv_d = float(0.0)
    if depth_sigma > 0.0:
        inv_d = 1.0 / (2.0 * depth_sigma * depth_sigma)
    return wp.vec2(1.0 / (2.0 * sigma * sigma), inv_d)


@wp.func
def surface_weight(dist2: float, dd: float, rates: wp.vec2):
    """exp(−dist²/2σ² − dd²/2σ_d²): a neighbour's weight, near in the image and in
    depth (dd = δ1(q) − δ1(p)), which keeps a fill or fit on p's own surface; ``rates``
    from :func:`surface_rates`."""
    return wp.exp(-dist2 * rates[0] - dd * dd * rates[1])


@wp.kernel
def splat_depth(
    row0: int,
    x: wp.array2d(dtype=wp.vec4),
    # outputs
    zbuf: wp.array2d(dtype=float),
):
    """zbuf[t] = max δ1 over the points whose t2 position p + (u, v) is nearest to t
    (rounded). ``zbuf`` must be filled with EMPTY first. A point that stays where it is
    (u = v = 0, stereo) covers only its own pixel. Uses atomics: launch in one piece
    (``bands=1`` on the CPU), over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    v = x[i, j]
    ty, tx, inside = landing_pixel(v, i, j, zbuf.shape[0], zbuf.shape[1])
    if inside:
        wp.atomic_max(zbuf, ty, tx, v[0])


@wp.kernel
def hidden_at_t2(
    row0: int,
    x: wp.array2d(dtype=wp.vec4),
    zbuf: wp.array2d(dtype=float),
    margin: float,
    outside: float,
    # outputs
    hidden: wp.array2d(dtype=float),
):
    """hidden[p] = 1 where the t2 pixel nearest to p + (u, v) is held by a point with δ1
    larger than δ1(p) + margin, else 0; ``outside`` where that pixel lies outside the
    image (p + (u, v) beyond the pixels' edges): 0 for the estimator's test (no t2 view
    to leave out), 1 for the points not seen at t2 (they left the image, as the
    synthetic ground truth's ``occluded`` counts them). Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    v = x[i, j]
    ty, tx, inside = landing_pixel(v, i, j, zbuf.shape[0], zbuf.shape[1])
    out = outside
    if inside:
        out = 0.0
        if zbuf[ty, tx] > v[0] + margin:
            out = 1.0
    hidden[i, j] = out


@wp.kernel
def spread_hidden(
    row0: int,
    x: wp.array2d(dtype=wp.vec4),
    hidden: wp.array2d(dtype=float),
    margin: float,
    reach: int,
    # outputs
    out: wp.array2d(dtype=float),
):
    """out[p] = 1 where a hidden point q lies within ``reach`` pixels of p (a (2r+1)²
    window) on the same surface, |δ1(q) − δ1(p)| ≤ margin: the hidden band's edge pixels,
    whose own (wrong) flow may carry them out of it, join it; the occluder does not.
    Where nothing is hidden (no motion), nothing spreads. Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    h = hidden.shape[0]
    w = hidden.shape[1]
    d = x[i, j][0]
    value = hidden[i, j]
    for dy in range(-reach, reach + 1):
        for dx in range(-reach, reach + 1):
            yy = i + dy
            xx = j + dx
            if yy >= 0 and yy < h and xx >= 0 and xx < w:
                if hidden[yy, xx] > 0.5 and wp.abs(x[yy, xx][0] - d) <= margin:
                    value = 1.0
    out[i, j] = value


@wp.kernel
def splat_views(
    row0: int,
    x: wp.array2d(dtype=wp.vec4),
    component: int,
    flow: int,
    phis: wp.array(dtype=wp.vec2),
    span: int,
    # outputs
    zbuf: wp.array3d(dtype=float),
):
    """zbuf[s, t] = the largest δ = x[p][component] over the points p whose position in
    view φ_s, q − δ φ_s with q = p (``flow`` 0) or q = p + (u, v) (``flow`` 1, components
    2, 3), has t among its bilinear neighbours of non-zero weight (so a sample read within
    a pixel of a nearer point's position counts as covered; a point at a whole position,
    such as every point in the centre view, covers its own pixel only). ``zbuf`` must be filled with EMPTY first.
    Uses atomics only within a view's z-buffer: launch over (samples, rows, ⌈columns /
    span⌉), each thread walking ``span`` points of a row (:func:`lfsf.device.row_span`:
    whole rows on the CPU, 62 against 82 ms a pass at 640×480 with 17 views; one point on
    CUDA), in bands of whole samples (``row0`` is the first sample), which never meet."""
    s, i, c = wp.tid()
    s = s + row0
    h = zbuf.shape[1]
    w = zbuf.shape[2]
    phi = phis[s]
    j_start = c * span
    for j in range(j_start, wp.min(x.shape[1], j_start + span)):
        v = x[i, j]
        d = v[component]
        px = float(j) - d * phi[0]
        py = float(i) - d * phi[1]
        if flow != 0:
            px = px + v[2]
            py = py + v[3]
        j0 = int(wp.floor(px))
        i0 = int(wp.floor(py))
        # the neighbours of non-zero bilinear weight: a whole coordinate covers one pixel
        dxs = wp.where(px > float(j0), 2, 1)
        dys = wp.where(py > float(i0), 2, 1)
        for dy in range(dys):
            for dx in range(dxs):
                ii = i0 + dy
                jj = j0 + dx
                if ii >= 0 and ii < h and jj >= 0 and jj < w:
                    wp.atomic_max(zbuf, s, ii, jj, d)


@wp.kernel
def fill_hidden_motion(
    row0: int,
    hidden: wp.array2d(dtype=float),
    flagged: wp.array2d(dtype=float),
    sigma: float,
    depth_sigma: float,
    radius: int,
    # outputs
    x: wp.array2d(dtype=wp.vec4),
    x_bar: wp.array2d(dtype=wp.vec4),
):
    """Where p is hidden at t2 (``hidden``), no view sees the point at t2: its δ2 and
    flow come from nothing but the regulariser, which there reaches over to the
    occluder. Give it the motion of the points of its own surface around it that are
    seen at t2 instead: δ2 = δ1 + D and (u, v) = U, with D and U the weighted means of
    δ2 − δ1 and (u, v) over the pixels q within ``radius`` (a square window) not hidden,
    weight exp(−|q − p|²/2σ²) · exp(−(δ1(q) − δ1(p))²/2σ_d²) (σ = ``sigma`` px, σ_d =
    ``depth_sigma`` px per view step; 0: no depth weight). The depth weight leaves out
    the occluder, which is nearer. Where ``flagged`` (another test's suspects, e.g. the
    searches') but not ``hidden``, only δ2 is set so, and flagged pixels are no source
    of D. Where the weights sum to 1e-6 or less: D = 0, the flow unchanged. The same in
    x̄. In place: a hidden pixel is written and never read; a flagged one is read only
    for δ1 and the flow, which its write keeps. Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    is_hidden = hidden[i, j] > 0.5
    if is_hidden or flagged[i, j] > 0.5:
        h = x.shape[0]
        w = x.shape[1]
        v = x[i, j]
        rates = surface_rates(sigma, depth_sigma)
        depth = wp.vec2(0.0)  # Σ g·(δ2 − δ1), Σ g over the pixels neither hidden nor flagged
        flow = wp.vec3(0.0)  # Σ g·u, Σ g·v, Σ g over the pixels not hidden
        for ii in range(wp.max(i - radius, 0), wp.min(i + radius + 1, h)):
            for jj in range(wp.max(j - radius, 0), wp.min(j + radius + 1, w)):
                if hidden[ii, jj] <= 0.5:
                    q = x[ii, jj]
                    dd = q[0] - v[0]
                    g = surface_weight(float((ii - i) * (ii - i) + (jj - j) * (jj - j)), dd, rates)
                    flow += g * wp.vec3(q[2], q[3], 1.0)
                    if flagged[ii, jj] <= 0.5:
                        depth += g * wp.vec2(q[1] - q[0], 1.0)
        v[1] = v[0]
        if depth[1] > 1.0e-6:
            v[1] = v[0] + depth[0] / depth[1]
        if is_hidden and flow[2] > 1.0e-6:
            v[2] = flow[0] / flow[2]
            v[3] = flow[1] / flow[2]
        x[i, j] = v
        vb = x_bar[i, j]
        x_bar[i, j] = wp.vec4(vb[0], v[1], v[2], v[3])


@wp.kernel
def surface_motion_fit(
    row0: int,
    x: wp.array2d(dtype=wp.vec4),
    untrusted: wp.array2d(dtype=float),
    sigma: float,
    depth_sigma: float,
    radius: int,
    stride: int,
    ridge: float,
    # outputs
    fit: wp.array2d(dtype=wp.vec4),
):
    """The motion of p's surface, fitted from its neighbours: (u, v) and the depth change
    D = δ2 − δ1 each as an affine function a + b·Δx + c·Δy of the offset Δ = q − p, by
    weighted least squares over the pixels q = p + ``stride``·(k, l), |k|, |l| ≤
    ``radius``, whose match is trusted (``untrusted`` ≤ 0.5), weight
    exp(−(k² + l²)/2σ²) · exp(−(δ1(q) − δ1(p))²/2σ_d²) (σ = ``sigma`` in steps of the
    stride, σ_d = ``depth_sigma``, 0: no depth weight; it keeps the fit on p's own
    surface), with ``ridge``·Σw (``ridge`` > 0) added to the slopes' diagonal (Δ in
    steps): the system stays solvable, and a fit from a thin strip of neighbours stays
    near their mean. fit(p) = (δ1, δ1 + D(p), u(p), v(p)), the fit's values at p; x(p)
    unchanged where the weights sum to 1e-3 or less. A point whose own match went wrong (a surface's rim dragged along with its
    neighbour by the coarse levels) gets its surface's motion carried over, turning and
    scaling included. Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    h = x.shape[0]
    w = x.shape[1]
    v = x[i, j]
    rates = surface_rates(sigma, depth_sigma)
    a = wp.mat33(0.0)  # Σ w·(1, k, l)ᵀ(1, k, l)
    bu = wp.vec3(0.0)  # Σ w·u·(1, k, l)
    bv = wp.vec3(0.0)
    bd = wp.vec3(0.0)
    for l in range(-radius, radius + 1):
        ii = i + l * stride
        if ii >= 0 and ii < h:
            for k in range(-radius, radius + 1):
                jj = j + k * stride
                if jj >= 0 and jj < w:
                    if untrusted[ii, jj] <= 0.5:
                        q = x[ii, jj]
                        dd = q[0] - v[0]
                        g = surface_weight(float(k * k + l * l), dd, rates)
                        e = wp.vec3(1.0, float(k), float(l))
                        a += g * wp.outer(e, e)
                        bu += g * q[2] * e
                        bv += g * q[3] * e
                        bd += g * (q[1] - q[0]) * e
    out = v
    if a[0, 0] > 1.0e-3:
        a[1, 1] = a[1, 1] + ridge * a[0, 0]
        a[2, 2] = a[2, 2] + ridge * a[0, 0]
        inv = wp.inverse(a)
        row = wp.vec3(inv[0, 0], inv[0, 1], inv[0, 2])  # the fit's value at Δ = 0: first row of A⁻¹ times b
        out = wp.vec4(v[0], v[0] + wp.dot(row, bd), wp.dot(row, bu), wp.dot(row, bv))
    fit[i, j] = out
