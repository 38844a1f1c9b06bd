"""ROF (TV-L2) denoising by the primal–dual algorithm, for the structure–texture
decomposition of Wedel et al. (2009): the texture part of an image f is
``f − θ·u`` with u = argmin_u Σ|∇u| + 1/(2·μ) Σ (u − f)² (MODEL.md §3).

Images are stacks [n, y, x]. The steps run over (n × rows, ⌈columns / span⌉): each thread
walks ``span`` consecutive pixels of a row (:func:`lfsf.device.row_span`: the whole row
on the CPU, where a thread per pixel costs more than the stencil; one pixel on CUDA)."""

import warp as wp

from .common import at_least

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
    """p ← proj_{|p|≤1}(p + σ ∇ū), forward differences with Neumann boundary."""
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
    lowers it with τ)."""
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
    (the margin of a padded structure image; 0 for none)."""
    r, j = wp.tid()
    r = r + row0
    h = f.shape[1]
    n = r // h
    i = r - n * h
    texture[n, i, j] = f[n, i, j] - theta * structure[n, i + offset, j + offset]
