"""ROF (TV-L2) denoising by the primal–dual algorithm, for the structure–texture
decomposition of Wedel et al. (2009): the texture part of an image f is
``f − θ·u`` with u = argmin_u Σ|∇u| + 1/(2·μ) Σ (u − f)² (MODEL.md §3).

Images are stacks [n, y, x]. The steps run over (n × rows, ⌈columns / span⌉): each thread
walks ``span`` consecutive pixels of a row (:func:`lfsf.device.row_span`: the whole row
on the CPU, where a thread per pixel costs more than the stencil; one pixel on CUDA).
On the CPU the estimator runs their *lanes* versions, which take a row's pixels in
groups of 8 as Warp vectors (SIMD code): the same arithmetic per pixel, 0.54–0.58× the
time (34 images of 672×512)."""

import warp as wp

from .common import at_least, lane_vector

wp.set_module_options({"enable_backward": False})


@wp.kernel
def rof_dual_step(
    row0: int,
    u_bar: wp.array3d(dtype=float),
    sigma: float,
    span: int,
    # outputs
    p: wp.array3d(dtype=wp.vec2),
):
    """p ← proj_{|p|≤1}(p + σ ∇ū), forward differences with Neumann boundary, on each of
    the n images of ū (n, h, w). Launch over (n·h, ⌈w / span⌉): a thread walks ``span``
    pixels of a row."""
    r, c = wp.tid()
    r = r + row0
    h = u_bar.shape[1]
    w = u_bar.shape[2]
    n = r // h
    i = r - n * h
    j0 = c * span
    down = i < h - 1
    v = u_bar[n, i, j0]
    for j in range(j0, wp.min(w, j0 + span)):
        g = wp.vec2(0.0)
        right = v
        if j < w - 1:
            right = u_bar[n, i, j + 1]
            g[0] = right - v
        if down:
            g[1] = u_bar[n, i + 1, j] - v
        q = p[n, i, j] + sigma * g
        p[n, i, j] = q / at_least(wp.length(q), 1.0)
        v = right


@wp.kernel
def rof_primal_step(
    row0: int,
    f: wp.array3d(dtype=float),
    p: wp.array3d(dtype=wp.vec2),
    tau: float,
    mu: float,
    relax: float,
    span: int,
    # outputs
    u: wp.array3d(dtype=float),
    u_bar: wp.array3d(dtype=float),
):
    """u ← (u + τ div p + (τ/μ) f) / (1 + τ/μ);  ū ← u_new + ϑ(u_new − u_old), ϑ = ``relax``
    (1 for the plain algorithm; the accelerated one of Chambolle & Pock (2011, Alg. 2)
    lowers it with τ), on each of the n images of f (n, h, w). Launch over (n·h, ⌈w /
    span⌉): a thread walks ``span`` pixels of a row."""
    r, c = wp.tid()
    r = r + row0
    h = f.shape[1]
    w = f.shape[2]
    n = r // h
    i = r - n * h
    j0 = c * span
    k = tau / mu
    left = float(0.0)  # p_x of the pixel to the left (0 at the border)
    if j0 > 0:
        left = p[n, i, j0 - 1][0]
    for j in range(j0, wp.min(w, j0 + span)):
        pc = p[n, i, j]
        div = -left
        if j < w - 1:
            div += pc[0]
        if i < h - 1:
            div += pc[1]
        if i > 0:
            div -= p[n, i - 1, j][1]
        old = u[n, i, j]
        new = (old + tau * div + k * f[n, i, j]) / (1.0 + k)
        u[n, i, j] = new
        u_bar[n, i, j] = new + relax * (new - old)
        left = pc[0]


@wp.func
def reflect_index(i: int, size: int):
    """(index, edge) of the odd reflection of index i about the image's first or last
    pixel (edge −1 where i is inside)."""
    if i < 0:
        return -i, 0
    if i > size - 1:
        return 2 * (size - 1) - i, size - 1
    return i, -1


@wp.kernel
def pad_odd(
    row0: int,
    f: wp.array3d(dtype=float),
    pad: int,
    # outputs
    out: wp.array3d(dtype=float),
):
    """out = f padded by ``pad`` pixels on every side by odd (point) reflection about the
    border pixels, f(−k) = 2 f(0) − f(k), axis after axis (NumPy's ``np.pad(f, pad,
    "reflect", reflect_type="odd")``): a ramp runs on past the border instead of
    stopping at it. ``pad`` < the image's height and width. Launch over (n × padded
    rows, padded columns)."""
    r, c = wp.tid()
    r = r + row0
    h = f.shape[1]
    w = f.shape[2]
    hp = out.shape[1]
    n = r // hp
    i, ei = reflect_index(r - n * hp - pad, h)
    j, ej = reflect_index(c - pad, w)
    v = f[n, i, j]
    if ei >= 0 and ej >= 0:
        v = 4.0 * f[n, ei, ej] - 2.0 * f[n, ei, j] - 2.0 * f[n, i, ej] + v
    elif ei >= 0:
        v = 2.0 * f[n, ei, j] - v
    elif ej >= 0:
        v = 2.0 * f[n, i, ej] - v
    out[n, r - n * hp, c] = v


@wp.kernel
def texture_part(
    row0: int,
    f: wp.array3d(dtype=float),
    structure: wp.array3d(dtype=float),
    theta: float,
    offset: int,
    # outputs
    texture: wp.array3d(dtype=float),
):
    """texture = f − θ·structure, the structure read ``offset`` pixels down and right
    (the margin of a padded structure image; 0 for none), on each of the n images of f
    (n, h, w). Launch over (n·h, w): the n images' rows one after another (a 3-D launch
    over (n, h, w) would read its indices wrongly)."""
    r, j = wp.tid()
    r = r + row0
    h = f.shape[1]
    n = r // h
    i = r - n * h
    texture[n, i, j] = f[n, i, j] - theta * structure[n, i + offset, j + offset]


@wp.kernel
def scale_values(
    row0: int,
    factor: float,
    # outputs
    stack: wp.array3d(dtype=float),
):
    """stack ×= ``factor`` (the texture parts' contrast normalised), in place. Launch over
    (n × rows, columns)."""
    r, j = wp.tid()
    r = r + row0
    h = stack.shape[1]
    n = r // h
    i = r - n * h
    stack[n, i, j] = stack[n, i, j] * factor


#: Pixels per group of the ROF steps that work on groups of a row at once (the CPU):
#: :data:`rof_dual_lanes`, :data:`rof_primal_lanes`.
ROF_LANES = 8
rof_lane = lane_vector(ROF_LANES)


@wp.kernel
def rof_dual_lanes(
    row0: int,
    u_bar: wp.array3d(dtype=rof_lane),
    width: int,
    sigma: float,
    # outputs
    px: wp.array3d(dtype=rof_lane),
    py: wp.array3d(dtype=rof_lane),
):
    """:func:`rof_dual_step` on groups of :data:`ROF_LANES` pixels of a row at once (SIMD
    code on the CPU), the same arithmetic per pixel: images as (n, rows, groups) vectors,
    a row's pixel j in lane j % L of group j // L, ``width`` pixels a row (lanes past it
    are left out of every pixel's stencil), p as its x and y parts. Launch over (n ×
    rows, 1): a thread walks a row."""
    r, c = wp.tid()
    r = r + row0
    h = u_bar.shape[1]
    groups = u_bar.shape[2]
    n = r // h
    i = r - n * h
    down = i < h - 1
    v = u_bar[n, i, 0]
    for g in range(groups):
        nxt = v
        if g + 1 < groups:
            nxt = u_bar[n, i, g + 1]
        # forward differences: the right neighbour of lane k is lane k + 1, of the last lane
        # the next group's first
        gx = rof_lane()
        for k in range(1, ROF_LANES):  # (constant bounds: Warp unrolls the loop; ROF_LANES − 1 it would not)
            gx[k - 1] = v[k] - v[k - 1]
        gx[ROF_LANES - 1] = nxt[0] - v[ROF_LANES - 1]
        if (g + 1) * ROF_LANES > width - 1:  # the row's last pixel has none (Neumann)
            for k in range(ROF_LANES):
                if g * ROF_LANES + k >= width - 1:
                    gx[k] = 0.0
        gy = rof_lane()
        if down:
            gy = u_bar[n, i + 1, g] - v
        qx = px[n, i, g] + sigma * gx
        qy = py[n, i, g] + sigma * gy
        d = rof_lane()
        for k in range(ROF_LANES):
            d[k] = at_least(wp.sqrt(qx[k] * qx[k] + qy[k] * qy[k]), 1.0)
        px[n, i, g] = wp.cw_div(qx, d)
        py[n, i, g] = wp.cw_div(qy, d)
        v = nxt


@wp.kernel
def rof_primal_lanes(
    row0: int,
    f: wp.array3d(dtype=rof_lane),
    px: wp.array3d(dtype=rof_lane),
    py: wp.array3d(dtype=rof_lane),
    width: int,
    tau: float,
    mu: float,
    relax: float,
    # outputs
    u: wp.array3d(dtype=rof_lane),
    u_bar: wp.array3d(dtype=rof_lane),
):
    """:func:`rof_primal_step` on groups of :data:`ROF_LANES` pixels of a row at once, as
    :data:`rof_dual_lanes`. Launch over (n × rows, 1)."""
    r, c = wp.tid()
    r = r + row0
    h = f.shape[1]
    groups = f.shape[2]
    n = r // h
    i = r - n * h
    k = tau / mu
    last = float(0.0)  # p_x of the pixel left of the group (0 at the border)
    for g in range(groups):
        pxc = px[n, i, g]
        pyc = py[n, i, g]
        left = rof_lane()
        left[0] = last
        for l in range(1, ROF_LANES):
            left[l] = pxc[l - 1]
        div = -left
        if (g + 1) * ROF_LANES <= width - 1:
            div = div + pxc
        else:  # the row's last pixel has no p_x of its own (Neumann)
            for l in range(ROF_LANES):
                if g * ROF_LANES + l < width - 1:
                    div[l] = div[l] + pxc[l]
        if i < h - 1:
            div = div + pyc
        if i > 0:
            div = div - py[n, i - 1, g]
        old = u[n, i, g]
        new = wp.cw_div(old + tau * div + k * f[n, i, g], rof_lane(1.0 + k))
        u[n, i, g] = new
        u_bar[n, i, g] = new + relax * (new - old)
        last = pxc[ROF_LANES - 1]
