"""Image-driven second-order TGV (MODEL.md §4) and its preconditioned primal–dual steps.

For each unknown x ∈ (δ1, δ2, u, v), packed per pixel as vec4 (or (u, v) as vec2 for
flow only: the kernels on the unknowns are generic over both, see
:data:`lfsf.kernels.common.UNKNOWNS`):

    Φ(x) = min_w α1 Σ|Γ(∇x − w)| + α0 Σ|∇w|,   Γ = exp(−γ|∇I|^β) n nᵀ + n⊥ n⊥ᵀ

with Γ of the centre view at t1 for δ1, u, v and at t2 for δ2 (each unknown's tensor is
an input: the solver may also let the flow's see the disparity's edges and warp the t2
view onto the t1 grid, see :class:`lfsf.Params`). w = (w0, w1) is stored as
two vectors (its x and y components for the unknowns); the duals are y = (y0, y1) for
α1Γ(∇x − w) (|y| ≤ 1) and z = (z00, z01, z10, z11) for α0∇w (Frobenius norm ≤ 1).
Gradients are forward differences with Neumann boundary (zero at the last column/row);
divergences are their exact negative adjoints.

The steps read Γ per unknown (:data:`expand_tensor`, made whenever the tensors change)
so that every array they read holds the unknowns' vectors side by side: on the CPU they
then take 32 floats of a row at once (8 pixels of vec4 unknowns) as Warp vectors, SIMD
code with the same arithmetic per float (640×480, interleaved launches: the dual step
0.47×, the primal step 0.89× the time; bit for bit the same results).
"""

from typing import Any

import warp as wp

from lfsf.device import is_cpu

from .common import at_least, float_run, forward_gradient, lane_vector, overload_unknowns, to_vec4

wp.set_module_options({"enable_backward": False})


@wp.func
def tensor_per_unknown(g1: wp.vec3, g2: wp.vec3, g3: wp.vec3, like: wp.vec4):
    """(Γ00, Γ01, Γ11) as vec4 over the unknowns (δ1, δ2, u, v): ``g1`` for δ1, ``g2`` for
    δ2 and ``g3`` for u and v."""
    return (
        wp.vec4(g1[0], g2[0], g3[0], g3[0]),
        wp.vec4(g1[1], g2[1], g3[1], g3[1]),
        wp.vec4(g1[2], g2[2], g3[2], g3[2]),
    )


@wp.func
def tensor_per_unknown(g1: wp.vec3, g2: wp.vec3, g3: wp.vec3, like: wp.vec2):
    """Flow only: (Γ00, Γ01, Γ11) as vec2 over (u, v), both ``g3``."""
    return (
        wp.vec2(g3[0], g3[0]),
        wp.vec2(g3[1], g3[1]),
        wp.vec2(g3[2], g3[2]),
    )


@wp.func
def reciprocal(v: Any, eps: float):
    r = v
    for k in range(len(v)):
        r[k] = 1.0 / (v[k] + eps)
    return r


@wp.func
def image_gradient(image: wp.array2d(dtype=float), i: int, j: int):
    """∇I at pixel (i, j) for the diffusion tensor: forward differences (Neumann), the
    same pixel pair as the forward difference of the unknowns that Γ(p) weighs. Γ(p)
    then frees exactly the jump across an image edge between p and its right or lower
    neighbour. Central differences freed the jumps on both sides of an edge pixel, and
    the disparity spread its jump over two pixels there (HCI antinous MSE×100 2.99 →
    2.59 with forward differences)."""
    return forward_gradient(image, i, j)


@wp.func
def tensor_from_structure(a: float, b: float, c: float, gamma: float, beta: float):
    """Γ = exp(−γ m^β) n nᵀ + n⊥ n⊥ᵀ as (Γ00, Γ01, Γ11) for the structure tensor
    [[a, b], [b, c]] = Σ_k g_k g_kᵀ of a guide's channel gradients g_k: n and m² are its
    leading eigenvector and eigenvalue (Di Zenzo's edge of a multi-channel image; one
    channel: n = g/|g| and m = |g|). Identity where it vanishes."""
    half = 0.5 * (a - c)
    root = wp.sqrt(half * half + b * b)
    lam = 0.5 * (a + c) + root
    t = wp.vec3(1.0, 0.0, 1.0)
    if lam > 1.0e-24:
        # eigenvector of the larger eigenvalue: (λ − c, b), or (b, λ − a), whichever is longer
        nx = lam - c
        ny = b
        if a < c:
            nx = b
            ny = lam - a
        norm = wp.sqrt(nx * nx + ny * ny)
        if norm > 1.0e-30:
            nx = nx / norm
            ny = ny / norm
            e = wp.exp(-gamma * wp.pow(wp.sqrt(lam), beta))
            t = wp.vec3(e * nx * nx + ny * ny, (e - 1.0) * nx * ny, e * ny * ny + nx * nx)
    return t


@wp.func
def tensor_from_gradients(g: wp.vec2, d: wp.vec2, gamma: float, beta: float):
    """:func:`tensor_from_structure` of a two-channel guide with gradients g and d
    (with d = 0, Γ of g alone)."""
    return tensor_from_structure(g[0] * g[0] + d[0] * d[0], g[0] * g[1] + d[0] * d[1],
                                 g[1] * g[1] + d[1] * d[1], gamma, beta)


@wp.kernel
def diffusion_tensor(
    row0: int,
    image: wp.array2d(dtype=float),
    gamma: float,
    beta: float,
    # outputs
    tensor: wp.array2d(dtype=wp.vec3),
):
    """Γ = exp(−γ|∇I|^β) n nᵀ + n⊥ n⊥ᵀ as (Γ00, Γ01, Γ11), n = ∇I/|∇I|; Γ = identity
    where ∇I vanishes. ∇I takes the forward differences with Neumann boundaries that ∇
    takes of the unknowns (:func:`image_gradient`). Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    tensor[i, j] = tensor_from_gradients(image_gradient(image, i, j), wp.vec2(0.0), gamma, beta)


@wp.func
def colour_structure(image: wp.array3d(dtype=float), i: int, j: int):
    """(a, b, c) of the structure tensor [[a, b], [b, c]] of a colour image (3, h, w):
    the mean over the channels of g gᵀ, g their forward differences (:func:`image_gradient`)."""
    a = float(0.0)
    b = float(0.0)
    c = float(0.0)
    for k in range(3):
        g = image_gradient(image[k], i, j)
        a += g[0] * g[0]
        b += g[0] * g[1]
        c += g[1] * g[1]
    third = 1.0 / 3.0
    return wp.vec3(third * a, third * b, third * c)


@wp.kernel
def colour_diffusion_tensor(
    row0: int,
    image: wp.array3d(dtype=float),
    gamma: float,
    beta: float,
    # outputs
    tensor: wp.array2d(dtype=wp.vec3),
):
    """Γ of a colour image, ``image`` (3, h, w) as channel planes (:func:`colour_structure`):
    a grey image (R = G = B = I) gives :func:`diffusion_tensor`'s Γ of I, while an edge
    between colours of equal brightness, which the grey view does not see, stops the
    diffusion too. Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    m = colour_structure(image, i, j)
    tensor[i, j] = tensor_from_structure(m[0], m[1], m[2], gamma, beta)


@wp.kernel
def joint_diffusion_tensor(
    row0: int,
    image: wp.array2d(dtype=float),
    x_hat: wp.array2d(dtype=Any),
    weight: float,
    gamma: float,
    beta: float,
    # outputs
    tensor: wp.array2d(dtype=wp.vec3),
):
    """Γ of the two-channel guide (I, weight·δ1) (:func:`tensor_from_gradients`; δ1 is
    component 0 of ``x_hat``): edges of the image and of the disparity both stop the
    diffusion. With weight 0 it equals :func:`diffusion_tensor`. Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    h = x_hat.shape[0]
    w = x_hat.shape[1]
    dx = 0.5 * (to_vec4(x_hat[i, wp.min(j + 1, w - 1)])[0] - to_vec4(x_hat[i, wp.max(j - 1, 0)])[0])
    dy = 0.5 * (to_vec4(x_hat[wp.min(i + 1, h - 1), j])[0] - to_vec4(x_hat[wp.max(i - 1, 0), j])[0])
    tensor[i, j] = tensor_from_gradients(image_gradient(image, i, j), weight * wp.vec2(dx, dy), gamma, beta)


@wp.kernel
def tgv_preconditioner(
    row0: int,
    data_colsum: wp.array2d(dtype=Any),
    tensor1: wp.array2d(dtype=wp.vec3),
    tensor2: wp.array2d(dtype=wp.vec3),
    tensor3: wp.array2d(dtype=wp.vec3),
    alpha0: Any,
    alpha1: float,
    eps: float,
    step_ratio: float,
    # outputs
    tau_x: wp.array2d(dtype=Any),
    tau_w0: wp.array2d(dtype=Any),
    tau_w1: wp.array2d(dtype=Any),
    sigma_y: wp.array2d(dtype=Any),
):
    """Diagonal preconditioners of Pock & Chambolle (2011), α = 1: τ = 1/Σ_row|K| per
    primal column (data part given), σ = 1/Σ_col|K| per TGV dual row: σ_y from the larger
    sum of the two rows of y(p), one step for both (σ_z = 1/(2α0) of each unknown, which the
    dual step takes as σ_z·α0 = 1/(2c), one constant for all ``alpha0``), so that
    each projection onto a ball is the proximal step in the preconditioned metric; then τ·c
    and σ/c for the step ratio c (:class:`lfsf.Params` ``step_ratio``). Launch over
    (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    h = tensor1.shape[0]
    w = tensor1.shape[1]
    a = float(0.0)
    b = float(0.0)
    if j < w - 1:
        a = 1.0
    if i < h - 1:
        b = 1.0
    colsum = data_colsum[i, j]
    g00, g01, g11 = tensor_per_unknown(tensor1[i, j], tensor2[i, j], tensor3[i, j], colsum)
    # x(p) in the rows y(p) (−Γ(a, b)ᵀ), y(p − e_x) (Γ col 0) and y(p − e_y) (Γ col 1)
    col = wp.abs(a * g00 + b * g01) + wp.abs(a * g01 + b * g11)
    count = a + b
    if j > 0:
        h00, h01, h11 = tensor_per_unknown(tensor1[i, j - 1], tensor2[i, j - 1], tensor3[i, j - 1], colsum)
        col += wp.abs(h00) + wp.abs(h01)
        count += 1.0
    if i > 0:
        k00, k01, k11 = tensor_per_unknown(tensor1[i - 1, j], tensor2[i - 1, j], tensor3[i - 1, j], colsum)
        col += wp.abs(k01) + wp.abs(k11)
        count += 1.0
    tau_x[i, j] = step_ratio * reciprocal(colsum + alpha1 * col, eps)
    tau_w0[i, j] = step_ratio * reciprocal(alpha1 * (wp.abs(g00) + wp.abs(g01)) + alpha0 * count, eps)
    tau_w1[i, j] = step_ratio * reciprocal(alpha1 * (wp.abs(g01) + wp.abs(g11)) + alpha0 * count, eps)
    row0_sum = a * wp.abs(g00) + b * wp.abs(g01) + wp.abs(a * g00 + b * g01) + wp.abs(g00) + wp.abs(g01)
    row1_sum = a * wp.abs(g01) + b * wp.abs(g11) + wp.abs(a * g01 + b * g11) + wp.abs(g01) + wp.abs(g11)
    # one step for both components of y(p): its projection onto |y| ≤ 1 is the prox of the
    # dual only in a metric that treats them alike (σ_y0 ≠ σ_y1 made the iteration settle
    # above the minimum); the smaller of the two keeps Pock–Chambolle's bound
    sigma_y[i, j] = reciprocal(alpha1 * wp.max(row0_sum, row1_sum), eps) / step_ratio


#: Floats the TGV steps' vector path takes at once on the CPU: 8 pixels of vec4 unknowns
#: or 16 of vec2 (flow only), held in Warp vectors of this length (SIMD code).
TGV_FLOATS = 32
floats = lane_vector(TGV_FLOATS)


@wp.kernel
def expand_tensor(
    row0: int,
    tensor1: wp.array2d(dtype=wp.vec3),
    tensor2: wp.array2d(dtype=wp.vec3),
    tensor3: wp.array2d(dtype=wp.vec3),
    # outputs
    g00: wp.array2d(dtype=Any),
    g01: wp.array2d(dtype=Any),
    g11: wp.array2d(dtype=Any),
):
    """Γ's entries per unknown (:func:`tensor_per_unknown`): Γ00, Γ01, Γ11 of ``tensor1``
    for δ1, ``tensor2`` for δ2 and ``tensor3`` for u and v (flow only: ``tensor3`` for
    both), in the unknowns' type, as the TGV steps read them. Launch over (rows,
    columns)."""
    i, j = wp.tid()
    i = i + row0
    a, b, c = tensor_per_unknown(tensor1[i, j], tensor2[i, j], tensor3[i, j], g00[i, j])
    g00[i, j] = a
    g01[i, j] = b
    g11[i, j] = c


@wp.func
def load_floats(ptr: wp.uint64, at: wp.int64):
    """TGV_FLOATS floats from float ``at`` of a contiguous array (:func:`float_run`)."""
    run = float_run(ptr, at, TGV_FLOATS)
    v = floats()
    for f in range(TGV_FLOATS):
        v[f] = run[f]
    return v


@wp.func
def store_floats(ptr: wp.uint64, at: wp.int64, v: floats):
    run = float_run(ptr, at, TGV_FLOATS)
    for f in range(TGV_FLOATS):
        run[f] = v[f]


@wp.func
def dual_step_floats(x_bar: Any, w0_bar: Any, w1_bar: Any, g00: Any, g01: Any, g11: Any, sigma_y: Any, sza: float,
                     alpha1: float, at: wp.int64, right: wp.int64, below: wp.int64, y0: Any, y1: Any, z00: Any,
                     z01: Any, z10: Any, z11: Any):
    """:data:`tgv_dual_step` on the TGV_FLOATS floats from float ``at`` of every array, as
    vectors: their right neighbours from float ``right``, those below from ``below``."""
    xv = load_floats(x_bar.ptr, at)
    wv0 = load_floats(w0_bar.ptr, at)
    wv1 = load_floats(w1_bar.ptr, at)
    gx = load_floats(x_bar.ptr, right) - xv
    gy = load_floats(x_bar.ptr, below) - xv
    dx0 = load_floats(w0_bar.ptr, right) - wv0
    dy0 = load_floats(w0_bar.ptr, below) - wv0
    dx1 = load_floats(w1_bar.ptr, right) - wv1
    dy1 = load_floats(w1_bar.ptr, below) - wv1
    r0 = gx - wv0
    r1 = gy - wv1
    a00 = load_floats(g00.ptr, at)
    a01 = load_floats(g01.ptr, at)
    a11 = load_floats(g11.ptr, at)
    sy = load_floats(sigma_y.ptr, at)
    n0 = load_floats(y0.ptr, at) + alpha1 * wp.cw_mul(sy, wp.cw_mul(a00, r0) + wp.cw_mul(a01, r1))
    n1 = load_floats(y1.ptr, at) + alpha1 * wp.cw_mul(sy, wp.cw_mul(a01, r0) + wp.cw_mul(a11, r1))
    m00 = load_floats(z00.ptr, at) + sza * dx0
    m01 = load_floats(z01.ptr, at) + sza * dy0
    m10 = load_floats(z10.ptr, at) + sza * dx1
    m11 = load_floats(z11.ptr, at) + sza * dy1
    ky = floats()
    kz = floats()
    for f in range(TGV_FLOATS):
        ky[f] = 1.0 / at_least(wp.sqrt(n0[f] * n0[f] + n1[f] * n1[f]), 1.0)
        kz[f] = 1.0 / at_least(wp.sqrt(m00[f] * m00[f] + m01[f] * m01[f] + m10[f] * m10[f] + m11[f] * m11[f]), 1.0)
    store_floats(y0.ptr, at, wp.cw_mul(n0, ky))
    store_floats(y1.ptr, at, wp.cw_mul(n1, ky))
    store_floats(z00.ptr, at, wp.cw_mul(m00, kz))
    store_floats(z01.ptr, at, wp.cw_mul(m01, kz))
    store_floats(z10.ptr, at, wp.cw_mul(m10, kz))
    store_floats(z11.ptr, at, wp.cw_mul(m11, kz))


@wp.func
def gamma_y(
    g00: wp.array2d(dtype=Any),
    g01: wp.array2d(dtype=Any),
    g11: wp.array2d(dtype=Any),
    y0: wp.array2d(dtype=Any),
    y1: wp.array2d(dtype=Any),
    i: int,
    j: int,
):
    """Γ·y at a pixel, per unknown: (Γ00 y0 + Γ01 y1, Γ01 y0 + Γ11 y1)."""
    a = y0[i, j]
    b = y1[i, j]
    return wp.cw_mul(g00[i, j], a) + wp.cw_mul(g01[i, j], b), wp.cw_mul(g01[i, j], a) + wp.cw_mul(g11[i, j], b)


@wp.func
def gamma_y_floats(g00: Any, g01: Any, g11: Any, y0: Any, y1: Any, at: wp.int64):
    """:func:`gamma_y` of the TGV_FLOATS floats from float ``at``, as vectors."""
    a = load_floats(y0.ptr, at)
    b = load_floats(y1.ptr, at)
    a00 = load_floats(g00.ptr, at)
    a01 = load_floats(g01.ptr, at)
    a11 = load_floats(g11.ptr, at)
    return wp.cw_mul(a00, a) + wp.cw_mul(a01, b), wp.cw_mul(a01, a) + wp.cw_mul(a11, b)


@wp.func
def primal_step_floats(data_grad: Any, y0: Any, y1: Any, z00: Any, z01: Any, z10: Any, z11: Any, g00: Any,
                       g01: Any, g11: Any, tau_x: Any, tau_w0: Any, tau_w1: Any, alpha0: Any, alpha1: float,
                       at: wp.int64, left: wp.int64, above: wp.int64, has_below: bool, has_above: bool, x: Any,
                       w0: Any, w1: Any, x_bar: Any, w0_bar: Any, w1_bar: Any):
    """:data:`tgv_primal_step` on the TGV_FLOATS floats from float ``at`` of every
    array, as vectors, for pixels that all have a right and a left neighbour in the row
    (the left ones from float ``left``); the row above from float ``above`` where
    ``has_above``, a row below where ``has_below``. The divergences add their terms in
    the pixel-by-pixel code's order."""
    h0, h1 = gamma_y_floats(g00, g01, g11, y0, y1, at)
    l0, l1 = gamma_y_floats(g00, g01, g11, y0, y1, left)
    div_h = floats() + h0
    div_h = div_h - l0
    div_z0 = floats() + load_floats(z00.ptr, at)
    div_z0 = div_z0 - load_floats(z00.ptr, left)
    div_z1 = floats() + load_floats(z10.ptr, at)
    div_z1 = div_z1 - load_floats(z10.ptr, left)
    if has_below:
        div_h = div_h + h1
        div_z0 = div_z0 + load_floats(z01.ptr, at)
        div_z1 = div_z1 + load_floats(z11.ptr, at)
    if has_above:
        u0, u1 = gamma_y_floats(g00, g01, g11, y0, y1, above)
        div_h = div_h - u1
        div_z0 = div_z0 - load_floats(z01.ptr, above)
        div_z1 = div_z1 - load_floats(z11.ptr, above)
    x_old = load_floats(x.ptr, at)
    w0_old = load_floats(w0.ptr, at)
    w1_old = load_floats(w1.ptr, at)
    x_new = x_old - wp.cw_mul(load_floats(tau_x.ptr, at), load_floats(data_grad.ptr, at) - alpha1 * div_h)
    w0_new = w0_old + wp.cw_mul(load_floats(tau_w0.ptr, at), alpha1 * h0 + wp.cw_mul(alpha0, div_z0))
    w1_new = w1_old + wp.cw_mul(load_floats(tau_w1.ptr, at), alpha1 * h1 + wp.cw_mul(alpha0, div_z1))
    store_floats(x.ptr, at, x_new)
    store_floats(w0.ptr, at, w0_new)
    store_floats(w1.ptr, at, w1_new)
    store_floats(x_bar.ptr, at, 2.0 * x_new - x_old)
    store_floats(w0_bar.ptr, at, 2.0 * w0_new - w0_old)
    store_floats(w1_bar.ptr, at, 2.0 * w1_new - w1_old)


#: Registers a CUDA thread of the primal step may take: capped at 128 it ran in 51 µs
#: against 59 (H200, 640×480: 0.55 of the copy bandwidth against 0.49; at 96, 66 µs). The
#: CPU ignores it.
PRIMAL_REGISTERS = 128


def _tgv_steps(vector: bool):
    """The TGV dual and primal steps, with the vector path (``vector``: the CPU's, where a
    thread walks a row) or without it (CUDA, a thread per pixel: there the path would
    never run, but its code would still take registers, 124 → 255 with spills for the dual
    step on sm_90)."""

    @wp.kernel
    def tgv_dual_step(
        row0: int,
        x_bar: wp.array2d(dtype=Any),
        w0_bar: wp.array2d(dtype=Any),
        w1_bar: wp.array2d(dtype=Any),
        g00: wp.array2d(dtype=Any),
        g01: wp.array2d(dtype=Any),
        g11: wp.array2d(dtype=Any),
        sigma_y: wp.array2d(dtype=Any),
        sigma_z: float,
        alpha0: float,
        alpha1: float,
        span: int,
        # outputs
        y0: wp.array2d(dtype=Any),
        y1: wp.array2d(dtype=Any),
        z00: wp.array2d(dtype=Any),
        z01: wp.array2d(dtype=Any),
        z10: wp.array2d(dtype=Any),
        z11: wp.array2d(dtype=Any),
    ):
        """y ← proj(y + σ_y α1 Γ(∇x̄ − w̄)),  z ← proj(z + σ_z α0 ∇w̄), with Γ per unknown
        (``g00``, ``g01``, ``g11``: :data:`expand_tensor`). Launch over (rows, ⌈columns /
        span⌉): a thread walks ``span`` pixels of a row. Where a thread's span holds them, it
        takes TGV_FLOATS floats of every array at once (8 pixels of vec4 unknowns) whose
        right neighbours are all in the row, as vectors (SIMD code on the CPU), with the
        same arithmetic per float; the arrays must then be stored contiguously, all of
        the same shape (offsets are taken from ``x_bar``'s). At the last
        row the row below is the row itself, whose differences are exactly 0, as the
        pixel-by-pixel code's are."""
        i, c = wp.tid()
        i = i + row0
        h = x_bar.shape[0]
        w = x_bar.shape[1]
        j0 = c * span
        end = wp.min(w, j0 + span)
        xb = x_bar[i, j0]
        k = len(xb)  # floats per pixel
        chunk = int(TGV_FLOATS) // int(k)  # pixels per vector
        down = wp.min(i + 1, h - 1)
        sza = sigma_z * alpha0
        j = j0
        if wp.static(vector):
            while j + chunk <= end and j + chunk <= w - 1:
                at = (wp.int64(i) * wp.int64(w) + wp.int64(j)) * wp.int64(k)
                dual_step_floats(x_bar, w0_bar, w1_bar, g00, g01, g11, sigma_y, sza, alpha1, at, at + wp.int64(k),
                                 (wp.int64(down) * wp.int64(w) + wp.int64(j)) * wp.int64(k), y0, y1, z00, z01, z10, z11)
                j += chunk
        # the rest pixel by pixel, each one's values carried from the last pixel's right
        # neighbour (loaded once)
        if j < end:
            xb = x_bar[i, j]
            wb0 = w0_bar[i, j]
            wb1 = w1_bar[i, j]
        while j < end:
            zero = type(xb)(0.0)
            gx = zero
            gy = zero
            dx0 = zero
            dy0 = zero
            dx1 = zero
            dy1 = zero
            xr = xb
            wr0 = wb0
            wr1 = wb1
            if j < w - 1:
                xr = x_bar[i, j + 1]
                wr0 = w0_bar[i, j + 1]
                wr1 = w1_bar[i, j + 1]
                gx = xr - xb
                dx0 = wr0 - wb0
                dx1 = wr1 - wb1
            if i < h - 1:
                gy = x_bar[i + 1, j] - xb
                dy0 = w0_bar[i + 1, j] - wb0
                dy1 = w1_bar[i + 1, j] - wb1
            r0 = gx - wb0
            r1 = gy - wb1
            a00 = g00[i, j]
            a01 = g01[i, j]
            a11 = g11[i, j]
            sy = sigma_y[i, j]
            n0 = y0[i, j] + alpha1 * wp.cw_mul(sy, wp.cw_mul(a00, r0) + wp.cw_mul(a01, r1))
            n1 = y1[i, j] + alpha1 * wp.cw_mul(sy, wp.cw_mul(a01, r0) + wp.cw_mul(a11, r1))
            m00 = z00[i, j] + sza * dx0
            m01 = z01[i, j] + sza * dy0
            m10 = z10[i, j] + sza * dx1
            m11 = z11[i, j] + sza * dy1
            sy = zero
            sz = zero
            for q in range(len(xb)):
                sy[q] = 1.0 / at_least(wp.sqrt(n0[q] * n0[q] + n1[q] * n1[q]), 1.0)
                sz[q] = 1.0 / at_least(wp.sqrt(m00[q] * m00[q] + m01[q] * m01[q] + m10[q] * m10[q] + m11[q] * m11[q]),
                                     1.0)
            y0[i, j] = wp.cw_mul(n0, sy)
            y1[i, j] = wp.cw_mul(n1, sy)
            z00[i, j] = wp.cw_mul(m00, sz)
            z01[i, j] = wp.cw_mul(m01, sz)
            z10[i, j] = wp.cw_mul(m10, sz)
            z11[i, j] = wp.cw_mul(m11, sz)
            xb = xr
            wb0 = wr0
            wb1 = wr1
            j += 1

    @wp.kernel(cuda_max_registers=PRIMAL_REGISTERS)
    def tgv_primal_step(
        row0: int,
        data_grad: wp.array2d(dtype=Any),
        y0: wp.array2d(dtype=Any),
        y1: wp.array2d(dtype=Any),
        z00: wp.array2d(dtype=Any),
        z01: wp.array2d(dtype=Any),
        z10: wp.array2d(dtype=Any),
        z11: wp.array2d(dtype=Any),
        g00: wp.array2d(dtype=Any),
        g01: wp.array2d(dtype=Any),
        g11: wp.array2d(dtype=Any),
        tau_x: wp.array2d(dtype=Any),
        tau_w0: wp.array2d(dtype=Any),
        tau_w1: wp.array2d(dtype=Any),
        alpha0: Any,
        alpha1: float,
        span: int,
        # outputs
        x: wp.array2d(dtype=Any),
        w0: wp.array2d(dtype=Any),
        w1: wp.array2d(dtype=Any),
        x_bar: wp.array2d(dtype=Any),
        w0_bar: wp.array2d(dtype=Any),
        w1_bar: wp.array2d(dtype=Any),
    ):
        """x ← x − τ_x (Kᵀq − α1 div(Γy)),  w ← w − τ_w (−α1 Γy − α0 div z), then the
        over-relaxation x̄ = 2x_new − x_old (likewise w̄), with Γ per unknown (``g00``,
        ``g01``, ``g11``: :data:`expand_tensor`). Launch over (rows, ⌈columns / span⌉): a
        thread walks ``span`` pixels of a row, TGV_FLOATS floats at once where they fit
        (pixels with both row neighbours; see :data:`tgv_dual_step`), the arrays then
        stored contiguously, all of ``x``'s shape."""
        i, c = wp.tid()
        i = i + row0
        h = x.shape[0]
        w = x.shape[1]
        j0 = c * span
        end = wp.min(w, j0 + span)
        k = len(x[i, j0])  # floats per pixel
        chunk = int(TGV_FLOATS) // int(k)  # pixels per vector
        row_at = wp.int64(i) * wp.int64(w)
        above_at = wp.int64(wp.max(i - 1, 0)) * wp.int64(w)
        j = j0
        # Γy of the pixel to the left, carried from the last pixel (computed once)
        l0, l1 = gamma_y(g00, g01, g11, y0, y1, i, wp.max(j0 - 1, 0))
        # α0 of each float of a vector (the unknowns' values repeated; unused without the vector path)
        alpha0_floats = floats()
        if wp.static(vector):
            for p in range(chunk):
                for q in range(k):
                    alpha0_floats[int(p) * int(k) + int(q)] = alpha0[q]
        while j < end:
            if wp.static(vector) and j >= 1 and j + chunk <= end and j + chunk <= w - 1:
                at = (row_at + wp.int64(j)) * wp.int64(k)
                primal_step_floats(data_grad, y0, y1, z00, z01, z10, z11, g00, g01, g11, tau_x, tau_w0, tau_w1,
                                   alpha0_floats, alpha1, at, at - wp.int64(k),
                                   (above_at + wp.int64(j)) * wp.int64(k), i < h - 1, i > 0, x, w0, w1, x_bar, w0_bar,
                                   w1_bar)
                j += chunk
                l0, l1 = gamma_y(g00, g01, g11, y0, y1, i, j - 1)
            else:
                h0, h1 = gamma_y(g00, g01, g11, y0, y1, i, j)
                div_h = type(h0)(0.0)
                div_z0 = div_h
                div_z1 = div_h
                if j < w - 1:
                    div_h += h0
                    div_z0 += z00[i, j]
                    div_z1 += z10[i, j]
                if j > 0:
                    div_h -= l0
                    div_z0 -= z00[i, j - 1]
                    div_z1 -= z10[i, j - 1]
                if i < h - 1:
                    div_h += h1
                    div_z0 += z01[i, j]
                    div_z1 += z11[i, j]
                if i > 0:
                    u0, u1 = gamma_y(g00, g01, g11, y0, y1, i - 1, j)
                    div_h -= u1
                    div_z0 -= z01[i - 1, j]
                    div_z1 -= z11[i - 1, j]
                x_old = x[i, j]
                w0_old = w0[i, j]
                w1_old = w1[i, j]
                x_new = x_old - wp.cw_mul(tau_x[i, j], data_grad[i, j] - alpha1 * div_h)
                w0_new = w0_old + wp.cw_mul(tau_w0[i, j], alpha1 * h0 + wp.cw_mul(alpha0, div_z0))
                w1_new = w1_old + wp.cw_mul(tau_w1[i, j], alpha1 * h1 + wp.cw_mul(alpha0, div_z1))
                x[i, j] = x_new
                w0[i, j] = w0_new
                w1[i, j] = w1_new
                x_bar[i, j] = 2.0 * x_new - x_old
                w0_bar[i, j] = 2.0 * w0_new - w0_old
                w1_bar[i, j] = 2.0 * w1_new - w1_old
                l0 = h0
                l1 = h1
                j += 1

    return tgv_dual_step, tgv_primal_step


#: The TGV steps with their vector path (the CPU) …
tgv_dual_step, tgv_primal_step = _tgv_steps(True)
#: … and pixel by pixel only (CUDA).
tgv_dual_step_pixel, tgv_primal_step_pixel = _tgv_steps(False)


def tgv_kernels(device: str):
    """(dual step, primal step) for a device: with the vector path on the CPU, pixel by
    pixel on CUDA."""
    if is_cpu(device):
        return tgv_dual_step, tgv_primal_step
    return tgv_dual_step_pixel, tgv_primal_step_pixel


# the kernels on the unknowns, for vec4 (δ1, δ2, u, v) and vec2 (u, v; flow only)
overload_unknowns(joint_diffusion_tensor, "x_hat")
overload_unknowns(tgv_preconditioner, "data_colsum", "tau_x", "tau_w0", "tau_w1", "sigma_y", values=("alpha0",))
overload_unknowns(expand_tensor, "g00", "g01", "g11")
for _dual, _primal in ((tgv_dual_step, tgv_primal_step), (tgv_dual_step_pixel, tgv_primal_step_pixel)):
    overload_unknowns(_dual, "x_bar", "w0_bar", "w1_bar", "g00", "g01", "g11", "sigma_y", "y0", "y1", "z00", "z01",
                      "z10", "z11")
    overload_unknowns(_primal, "data_grad", "y0", "y1", "z00", "z01", "z10", "z11", "g00", "g01", "g11", "tau_x",
                      "tau_w0", "tau_w1", "x", "w0", "w1", "x_bar", "w0_bar", "w1_bar", values=("alpha0",))
