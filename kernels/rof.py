"""ROF (TV-L2) denoising by the primal–dual algorithm, for the structure–texture
decomposition of Wedel et al. (2009): the texture part of an image f is
``f − θ·u`` with u = argmin_u Σ|∇u| + 1/(2·μ) Σ (u − f)² (MODEL.md §3).

Images are stacks [n, y, x]; launches run over (n × rows, columns)."""

import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.kernel
def rof_dual_step(
    row0: int,
    u_bar: wp.array3d(dtype=float),
    sigma: float,
    # outputs
    p: wp.array3d(dtype=wp.vec2),
):
    """p ← proj_{|p|≤1}(p + σ ∇ū), forward differences with Neumann boundary."""
    r, j = wp.tid()
    r = r + row0
    h = u_bar.shape[1]
    w = u_bar.shape[2]
    n = r // h
    i = r - n * h
    v = u_bar[n, i, j]
    g = wp.vec2(0.0)
    if j < w - 1:
        g[0] = u_bar[n, i, j + 1] - v
    if i < h - 1:
        g[1] = u_bar[n, i + 1, j] - v
    q = p[n, i, j] + sigma * g
    p[n, i, j] = q / wp.max(1.0, wp.length(q))


@wp.kernel
def rof_primal_step(
    row0: int,
    f: wp.array3d(dtype=float),
    p: wp.array3d(dtype=wp.vec2),
    tau: float,
    mu: float,
    # outputs
    u: wp.array3d(dtype=float),
    u_bar: wp.array3d(dtype=float),
):
    """u ← (u + τ div p + (τ/μ) f) / (1 + τ/μ);  ū ← 2u_new − u_old."""
    r, j = wp.tid()
    r = r + row0
    h = f.shape[1]
    w = f.shape[2]
    n = r // h
    i = r - n * h
    div = float(0.0)
    if j < w - 1:
        div += p[n, i, j][0]
    if j > 0:
        div -= p[n, i, j - 1][0]
    if i < h - 1:
        div += p[n, i, j][1]
    if i > 0:
        div -= p[n, i - 1, j][1]
    old = u[n, i, j]
    new = (old + tau * div + (tau / mu) * f[n, i, j]) / (1.0 + tau / mu)
    u[n, i, j] = new
    u_bar[n, i, j] = 2.0 * new - old


@wp.kernel
def texture_part(
    row0: int,
    f: wp.array3d(dtype=float),
    structure: wp.array3d(dtype=float),
    theta: float,
    # outputs
    texture: wp.array3d(dtype=float),
):
    """texture = f − θ·structure."""
    r, j = wp.tid()
    r = r + row0
    h = f.shape[1]
    n = r // h
    i = r - n * h
    texture[n, i, j] = f[n, i, j] - theta * structure[n, i, j]
