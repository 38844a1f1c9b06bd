"""NumPy references of the Warp kernels in :mod:`lfsf.kernels`, written from the formulas
of MODEL.md and the kernels' docstrings (not from the kernel code): vectorised over
pixels, float64. Used by ``tests/test_kernels.py`` and ``tests/test_search_kernels.py``.

Conventions: images are (h, w) arrays, pixel (i, j) has its centre at (x, y) = (j, i).
Per-pixel vec4 fields are (h, w, 4) arrays ordered (δ1, δ2, u, v).
"""

from __future__ import annotations

import math

import numpy as np


# --- interpolation ------------------------------------------------------------------------


def hat_weights(pos: np.ndarray, n: int) -> np.ndarray:
    """Linear-interpolation weights of the n grid nodes 0…n−1 at the positions ``pos``,
    clamped to [0, n−1]: the tent max(0, 1 − |pos − k|). Shape pos.shape + (n,)."""
    p = np.clip(np.asarray(pos, np.float64), 0.0, n - 1)
    return np.maximum(0.0, 1.0 - np.abs(p[..., None] - np.arange(n)))


def bilinear(img: np.ndarray, x, y) -> np.ndarray:
    """Bilinear interpolation of img at (x, y) (x = column), positions clamped to the image."""
    img = np.asarray(img, np.float64)
    h, w = img.shape
    x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
    wx = hat_weights(x, w)
    wy = hat_weights(y, h)
    return np.einsum("...i,ij,...j->...", wy, img, wx)


def bilinear_gradient(img: np.ndarray, x, y) -> tuple[np.ndarray, np.ndarray]:
    """(∂x, ∂y) at (x, y): central differences of bilinear samples one pixel apart."""
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    gx = 0.5 * (bilinear(img, x + 1.0, y) - bilinear(img, x - 1.0, y))
    gy = 0.5 * (bilinear(img, x, y + 1.0) - bilinear(img, x, y - 1.0))
    return gx, gy


def catmull_rom(img: np.ndarray, x, y) -> np.ndarray:
    """Catmull–Rom interpolation of img at (x, y) from the 4 × 4 pixels around, for
    positions whose 4 × 4 pixels lie in the image (1 ≤ x < w − 2, 1 ≤ y < h − 2): along
    each axis the cubic Hermite segment between pixels k and k + 1 with the slopes
    (p[k+1] − p[k−1]) / 2 and (p[k+2] − p[k]) / 2."""
    img = np.asarray(img, np.float64)
    x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
    j, i = np.floor(x).astype(int), np.floor(y).astype(int)

    def segment(p0, p1, p2, p3, t):
        m1, m2 = 0.5 * (p2 - p0), 0.5 * (p3 - p1)
        return ((2 * t**3 - 3 * t**2 + 1) * p1 + (t**3 - 2 * t**2 + t) * m1 + (-2 * t**3 + 3 * t**2) * p2
                + (t**3 - t**2) * m2)

    rows = [segment(*(img[i + a, j + b] for b in (-1, 0, 1, 2)), x - j) for a in (-1, 0, 1, 2)]
    return segment(*rows, y - i)


def lookup_with_gradient(img: np.ndarray, x, y, cubic: bool = False):
    """The data term's lookup (value, ∂x, ∂y): the value by Catmull–Rom where its 4 × 4
    pixels lie in the image when ``cubic``, else (and always within a pixel of the
    border) the clamped bilinear value; the gradient always :func:`bilinear_gradient`."""
    x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
    h, w = np.shape(img)
    value = bilinear(img, x, y)
    gx, gy = bilinear_gradient(img, x, y)
    if cubic:
        interior = (x >= 1.0) & (y >= 1.0) & (x < w - 2.0) & (y < h - 2.0)
        value = np.where(interior, catmull_rom(img, np.where(interior, x, 1.0), np.where(interior, y, 1.0)), value)
    return value, gx, gy


def inside(shape: tuple[int, int], x, y) -> np.ndarray:
    """True where (x, y) lies within the pixel centres of an image of ``shape`` (h, w)."""
    h, w = shape
    return (x >= 0) & (y >= 0) & (x <= w - 1) & (y <= h - 1)


# --- finite differences (MODEL.md §4) -------------------------------------------------------


def grad(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Forward differences along x (axis 1) and y (axis 0) of a (h, w, ...) array, zero at
    the last column/row (Neumann)."""
    a = np.asarray(a, np.float64)
    gx = np.zeros_like(a)
    gy = np.zeros_like(a)
    gx[:, :-1] = a[:, 1:] - a[:, :-1]
    gy[:-1] = a[1:] - a[:-1]
    return gx, gy


def div(px: np.ndarray, py: np.ndarray) -> np.ndarray:
    """Divergence, the negative adjoint of :func:`grad`: ⟨grad a, p⟩ = −⟨a, div p⟩."""
    px = np.asarray(px, np.float64)
    py = np.asarray(py, np.float64)
    out = np.zeros_like(px)
    out[:, :-1] += px[:, :-1]
    out[:, 1:] -= px[:, :-1]
    out[:-1] += py[:-1]
    out[1:] -= py[:-1]
    return out


def gradient_matrix(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Dense matrices Dx, Dy (hw × hw) of the forward differences of :func:`grad` acting on
    a row-major flattened (h, w) image."""
    n = h * w
    dx = np.zeros((n, n))
    dy = np.zeros((n, n))
    for i in range(h):
        for j in range(w):
            k = i * w + j
            if j < w - 1:
                dx[k, k] = -1.0
                dx[k, k + 1] = 1.0
            if i < h - 1:
                dy[k, k] = -1.0
                dy[k, k + w] = 1.0
    return dx, dy


# --- sampling (MODEL.md §2) ----------------------------------------------------------------


def sample_subaperture(views: np.ndarray, phis: np.ndarray) -> np.ndarray:
    """L(·, φ_s) for views [a, b, y, x]: bilinear over the four nearest views, φ = (ξ, η)
    from the grid centre ((rows−1)/2, (cols−1)/2), angular position clamped to the grid."""
    views = np.asarray(views, np.float64)
    rows, cols = views.shape[:2]
    phis = np.asarray(phis, np.float64)
    wa = hat_weights(0.5 * (rows - 1) + phis[:, 1], rows)  # (S, rows)
    wb = hat_weights(0.5 * (cols - 1) + phis[:, 0], cols)  # (S, cols)
    return np.einsum("sa,sb,abyx->syx", wa, wb, views)


# --- ROF / structure–texture (MODEL.md §3) -------------------------------------------------


def rof_dual_step(u_bar: np.ndarray, p: np.ndarray, sigma: float) -> np.ndarray:
    """p ← proj_{|p|≤1}(p + σ∇ū) for stacks u_bar (n, h, w), p (n, h, w, 2)."""
    gx, gy = grad(np.moveaxis(u_bar, 0, -1))
    g = np.stack([np.moveaxis(gx, -1, 0), np.moveaxis(gy, -1, 0)], -1)
    q = p + sigma * g
    return q / np.maximum(1.0, np.linalg.norm(q, axis=-1, keepdims=True))


def stack_div(p: np.ndarray) -> np.ndarray:
    """div of a stack of vector fields p (n, h, w, 2) → (n, h, w)."""
    d = div(np.moveaxis(p[..., 0], 0, -1), np.moveaxis(p[..., 1], 0, -1))
    return np.moveaxis(d, -1, 0)


def rof_primal_step(f, p, u, tau, mu, relax=1.0):
    """u_new = prox of τ/(2μ)‖· − f‖² at u + τ div p; returns (u_new, u_new + ϑ(u_new − u))."""
    v = u + tau * stack_div(p)
    new = (v + (tau / mu) * f) / (1.0 + tau / mu)
    return new, new + relax * (new - u)


def rof_solve(f: np.ndarray, mu: float, iterations: int, tau: float, sigma: float, accelerate: bool = False):
    """Primal–dual ROF: (u, p) after ``iterations`` steps from u = ū = f, p = 0. With
    ``accelerate``, Chambolle & Pock (2011) Alg. 2 for the 1/μ-strongly convex fidelity:
    after each step ϑ = 1/√(1 + 2τ/μ), τ ← ϑτ, σ ← σ/ϑ (else ϑ = 1, steps fixed)."""
    f = np.asarray(f, np.float64)
    u = f.copy()
    u_bar = f.copy()
    p = np.zeros(f.shape + (2,))
    for _ in range(iterations):
        p = rof_dual_step(u_bar, p, sigma)
        relax = 1.0 / math.sqrt(1.0 + 2.0 * tau / mu) if accelerate else 1.0
        u, u_bar = rof_primal_step(f, p, u, tau, mu, relax)
        tau, sigma = relax * tau, sigma / relax
    return u, p


def rof_energy(u: np.ndarray, f: np.ndarray, mu: float) -> float:
    """Σ|∇u| + 1/(2μ) Σ(u − f)² of a stack (n, h, w) (isotropic TV, forward differences)."""
    gx, gy = grad(np.moveaxis(u, 0, -1))
    return float(np.sum(np.hypot(gx, gy)) + np.sum((u - f) ** 2) / (2.0 * mu))


# --- pyramid (MODEL.md §6) -----------------------------------------------------------------


def coarse_centre(k, n_from: int, n_to: int):
    """Centre of pixel k of a grid of n_from pixels, in pixel coordinates of a grid of
    n_to pixels covering the same extent: (k + 0.5)·n_to/n_from − 0.5."""
    return (np.asarray(k, np.float64) + 0.5) * n_to / n_from - 0.5


def downsample(fine: np.ndarray, size: tuple[int, int], sigma: float, radius: int) -> np.ndarray:
    """Gaussian-weighted average of the fine pixels within ``radius`` of the fine pixel
    nearest each coarse centre, weights exp(−d²/2σ²) from the mapped coarse centre and
    renormalised over the pixels inside the image. fine (n, h, w) → (n, hc, wc)."""
    fine = np.asarray(fine, np.float64)
    _, h, w = fine.shape
    hc, wc = size

    def axis_weights(n_c, n_f):
        c = coarse_centre(np.arange(n_c), n_c, n_f)  # coarse centre in fine coordinates
        nearest = np.floor(c + 0.5)
        k = np.arange(n_f)
        d = k[None, :] - c[:, None]
        window = np.abs(k[None, :] - nearest[:, None]) <= radius
        return np.where(window, np.exp(-d * d / (2.0 * sigma * sigma)), 0.0)

    wy = axis_weights(hc, h)  # (hc, h)
    wx = axis_weights(wc, w)  # (wc, w)
    num = np.einsum("ai,nij,bj->nab", wy, fine, wx)
    den = np.einsum("ai,bj->ab", wy, wx)
    return num / den


def upsample(coarse: np.ndarray, size: tuple[int, int], scale: float) -> np.ndarray:
    """scale · bilinear(coarse) at the fine pixel centres mapped to coarse coordinates
    (clamped). coarse (n, hc, wc) → (n, h, w)."""
    coarse = np.asarray(coarse, np.float64)
    _, hc, wc = coarse.shape
    h, w = size
    wy = hat_weights(coarse_centre(np.arange(h), h, hc), hc)  # (h, hc)
    wx = hat_weights(coarse_centre(np.arange(w), w, wc), wc)  # (w, wc)
    return scale * np.einsum("ia,nab,jb->nij", wy, coarse, wx)


# --- data term (MODEL.md §3, §5) -------------------------------------------------------------


#: Occlusion test (data_term.visible_half): half-planes with normals at m·45°, m = 0…7, and
#: the least rise of the mean residual (intensities in [0, 1]) that counts as an occlusion.
HALF_PLANES = 8
OCCLUSION_FLOOR = 0.01
#: The centre view at t2 counts as occluded where |I1(p) − J2| exceeds this many times the
#: mean residual of the t2 samples kept (plus OCCLUSION_FLOOR).
CENTRE_OCCLUSION_FACTOR = 3.0


def half_plane_members(phis) -> np.ndarray:
    """(8, S) bool: sample s lies in half-plane m, φ_s·n_m ≥ −1e-3|φ_s| with
    n_m = (cos m·45°, sin m·45°). φ = 0 lies in every half-plane."""
    phis = np.asarray(phis, np.float64)
    ang = np.arange(HALF_PLANES) * (np.pi / 4.0)
    normals = np.stack([np.cos(ang), np.sin(ang)], -1)  # (8, 2)
    dots = normals @ phis.T  # (8, S)
    return dots >= -1e-3 * np.linalg.norm(phis, axis=-1)[None, :]


def visible_half(samples, phis, qx, qy, disparity, centre, ratio, cubic=False) -> dict:
    """The occlusion test of one light field, per pixel (MODEL.md addition, data_term docs).

    e_s = |L(q − δφ_s, φ_s) − centre| for the samples s ≥ 1 whose warped position lies in
    the image; mean_all = their mean; mean_m = the mean over those in half-plane m. The best
    half is the m of the lowest mean_m (the first such m), if it is below mean_all; it is an
    occlusion when mean_m < ratio·mean_all and mean_all − mean_m ≥ OCCLUSION_FLOOR, else
    best = −1 (no occlusion, also where no sample is in the image or ratio ≤ 0).

    Returns {best (h, w) int, mean_all (h, w), means (8, h, w) (inf where a half holds no
    sample), count (h, w), members (8, S), kept_mean (h, w): the mean residual of the
    samples kept (mean_all, or the best half's mean where occluded; 0 without samples)}.
    ``cubic``: the samples read as the data term reads them (:func:`lookup_with_gradient`).
    """
    samples = np.asarray(samples, np.float64)
    phis = np.asarray(phis, np.float64)
    n, h, w = samples.shape
    qx, qy, disparity, centre = np.broadcast_arrays(*(np.asarray(a, np.float64) for a in (qx, qy, disparity, centre)))
    members = half_plane_members(phis)
    total = np.zeros((h, w))
    count = np.zeros((h, w))
    sums = np.zeros((HALF_PLANES, h, w))
    counts = np.zeros((HALF_PLANES, h, w))
    for s in range(1, n):
        xi, eta = phis[s]
        x, y = qx - disparity * xi, qy - disparity * eta
        valid = inside((h, w), x, y)
        e = np.where(valid, np.abs(lookup_with_gradient(samples[s], x, y, cubic)[0] - centre), 0.0)
        total += e
        count += valid
        sums += members[:, s, None, None] * e
        counts += members[:, s, None, None] * valid
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_all = np.where(count > 0, total / np.maximum(count, 1), 0.0)
        means = np.where(counts > 0, sums / np.maximum(counts, 1), np.inf)
    m_best = np.argmin(means, axis=0)
    best_mean = np.take_along_axis(means, m_best[None], 0)[0]
    occluded = ((count > 0) & (ratio > 0) & (best_mean < mean_all) & (best_mean < ratio * mean_all)
                & (mean_all - best_mean >= OCCLUSION_FLOOR))
    best = np.where(occluded, m_best, -1)
    kept_mean = np.where(occluded, best_mean, mean_all)
    return dict(best=best, mean_all=mean_all, means=means, count=count, members=members, kept_mean=kept_mean)


def kept_samples(best: np.ndarray, members: np.ndarray) -> np.ndarray:
    """(S, h, w) bool: sample s is used at p (no occlusion there, or s in the best half)."""
    keep = members[np.maximum(best, 0)]  # (h, w, S)
    return np.moveaxis(keep, -1, 0) | (best < 0)[None]


def data_coefficients(samples1, samples2, phis, weights, x_hat, occlusion_ratio=0.0, details=None, hidden2=None,
                      zbufs=None, margin=0.0, cubic=False):
    """A1…A9 (9, S, h, w), row weights (3, S, h, w) and data column sums (h, w, 4).

    W1 = L(p − δ̂1 φ, φ, t1), W2 = L(p + û − δ̂2 φ, φ, t2), J2 = L(p + û, 0, t2); sample 0 is
    the centre view; w_k = λ_k, or 0 where a warped position of row k leaves the image.
    Occlusion (``occlusion_ratio`` > 0): both light fields are tested against the point's
    appearance at t1, I1(p) (:func:`visible_half`): t1 at q = p with δ̂1, t2 at q = p + û
    with δ̂2. Samples outside the best half of t1 get w1 = 0, of t2 get w2 = 0, and w3 = 0
    if left out of either. The centre view at t2 is itself taken as occluded where
    |I1(p) − J2| > CENTRE_OCCLUSION_FACTOR·(mean residual of the t2 samples kept) +
    OCCLUSION_FLOOR, where there are t2 samples in the image to tell (none with the centre
    view alone, M = 1): then every w2 is 0 (the stereo rows at t2 compare with J2) and so is
    w3 of the centre sample (the flow row I1 − J2). ``details``, a dict, receives the two
    occlusion tests ("t1", "t2") and the centre test ("centre_occluded", "centre_margin"
    = |I1 − J2| − threshold). ``hidden2`` (h, w): where > 0.5 the point is hidden at t2
    (the geometric test, :func:`hidden_at_t2`) and every w2 and w3 is 0. ``zbufs`` = (Z1,
    Z2), view z-buffers (S, h, w) of δ̂1 at p and of δ̂2 at p + û (:func:`splat_views`):
    then sample s is kept in light field k where :func:`visible` by Z_k[s] (with
    ``margin``) instead of by the best half; the best half of t2 still gives the residual
    of the centre test. ``cubic``: the values of W1, W2 and J2 by Catmull–Rom
    (:func:`lookup_with_gradient`, ``Params.cubic``), else bilinear; the gradients are
    bilinear samples' central differences either way.
    """
    samples1 = np.asarray(samples1, np.float64)
    samples2 = np.asarray(samples2, np.float64)
    x_hat = np.asarray(x_hat, np.float64)
    n, h, w = samples1.shape
    py, px = np.mgrid[0:h, 0:w].astype(np.float64)
    d1, d2, u, v = (x_hat[..., k] for k in range(4))
    xj, yj = px + u, py + v
    i1 = samples1[0]
    j2, gjx, gjy = lookup_with_gradient(samples2[0], xj, yj, cubic)
    in_j = inside((h, w), xj, yj)
    occ1 = visible_half(samples1, phis, px, py, d1, i1, occlusion_ratio, cubic)
    occ2 = visible_half(samples2, phis, xj, yj, d2, i1, occlusion_ratio, cubic)
    keep1 = kept_samples(occ1["best"], occ1["members"])
    keep2 = kept_samples(occ2["best"], occ2["members"])
    if zbufs is not None:
        for s in range(n):
            xi, eta = (float(c) for c in phis[s])
            keep1[s] = visible(zbufs[0][s], px - d1 * xi, py - d1 * eta, d1, margin)
            keep2[s] = visible(zbufs[1][s], xj - d2 * xi, yj - d2 * eta, d2, margin)
    centre_margin = np.abs(i1 - j2) - (CENTRE_OCCLUSION_FACTOR * occ2["kept_mean"] + OCCLUSION_FLOOR)
    centre_occluded = (occlusion_ratio > 0) & (occ2["count"] > 0) & (centre_margin > 0)
    in_j = in_j & ~centre_occluded
    keep2[0] &= in_j
    if hidden2 is not None:
        keep2 &= ~(np.asarray(hidden2) > 0.5)[None]
    if details is not None:
        details.update(t1=occ1, t2=occ2, centre_occluded=centre_occluded, centre_margin=centre_margin)
    A = np.zeros((9, n, h, w))
    W = np.zeros((3, n, h, w))
    for s in range(n):
        xi, eta = (float(c) for c in phis[s])
        lam = weights[s]
        x1, y1 = px - d1 * xi, py - d1 * eta
        x2, y2 = xj - d2 * xi, yj - d2 * eta
        w1, g1x, g1y = lookup_with_gradient(samples1[s], x1, y1, cubic)
        w2, g2x, g2y = lookup_with_gradient(samples2[s], x2, y2, cubic)
        A[0, s] = -(xi * g1x + eta * g1y)
        A[1, s] = i1 - w1
        A[2, s] = -(xi * g2x + eta * g2y)
        A[3, s] = j2 - w2
        A[4, s] = g2x
        A[5, s] = g2y
        A[6, s] = w1 - w2
        A[7, s] = gjx - g2x
        A[8, s] = gjy - g2y
        in1 = inside((h, w), x1, y1) & keep1[s]
        in2 = inside((h, w), x2, y2) & keep2[s]
        W[0, s] = np.where(in1, lam[0], 0.0)
        W[1, s] = np.where(in2 & in_j, lam[1], 0.0)
        W[2, s] = np.where(in1 & in2, lam[2], 0.0)
    colsum = np.zeros((h, w, 4))
    for coeff, (_, col) in data_jacobian(A, W).values():
        colsum[..., col] += np.sum(np.abs(coeff), axis=0)
    return A, W, colsum


def data_jacobian(A, W) -> dict:
    """The nonzero entries of the data rows of K, per sample and pixel:
    {name: (coefficient (S, h, w), (row k, column of (δ1, δ2, u, v)))}; row k of sample s
    at p is w_k·ρ_k, linear part only. Built from the linearised ρ_k of MODEL.md §3."""
    w1, w2, w3 = W
    return {
        "q1_d1": (w1 * -A[0], (0, 0)),
        "q2_d2": (w2 * -A[2], (1, 1)),
        "q2_u": (w2 * A[7], (1, 2)),
        "q2_v": (w2 * A[8], (1, 3)),
        "q3_d1": (w3 * A[0], (2, 0)),
        "q3_d2": (w3 * -A[2], (2, 1)),
        "q3_u": (w3 * -A[4], (2, 2)),
        "q3_v": (w3 * -A[5], (2, 3)),
    }


def data_residuals(A, delta):
    """Linearised ρ1, ρ2, ρ3 (each (S, h, w)) for Δ = x − x̂ (h, w, 4)."""
    dd1, dd2, du, dv = (delta[..., k] for k in range(4))
    rho1 = A[1] - A[0] * dd1
    rho2 = A[3] - A[2] * dd2 + A[7] * du + A[8] * dv
    rho3 = A[6] + A[0] * dd1 - A[2] * dd2 - A[4] * du - A[5] * dv
    return np.stack([rho1, rho2, rho3])


def data_K_apply(A, W, delta):
    """K Δ of the data rows (3, S, h, w): the linear part of w_k ρ_k."""
    out = np.zeros((3,) + A.shape[1:])
    for coeff, (row, col) in data_jacobian(A, W).values():
        out[row] += coeff * delta[None, ..., col]
    return out


def data_K_transpose(A, W, q):
    """Kᵀ q (h, w, 4) summed over the samples, for q (3, S, h, w)."""
    out = np.zeros(A.shape[2:] + (4,))
    for coeff, (row, col) in data_jacobian(A, W).values():
        out[..., col] += np.sum(coeff * q[row], axis=0)
    return out


def dual_data_step(A, W, q, x_bar, x_hat, eps):
    """q_k ← clip(q_k + σ_k w_k ρ_k(x̄), −1, 1), σ_k = 1/(Σ_col |K_row k| + ε) with
    |K_row k| = w_k·|coefficients of ρ_k|; returns (q_new, Kᵀ q_new)."""
    rho = data_residuals(A, np.asarray(x_bar, np.float64) - np.asarray(x_hat, np.float64))
    rowsum = np.zeros_like(q)
    for coeff, (row, col) in data_jacobian(A, W).values():
        rowsum[row] += np.abs(coeff)
    sigma = 1.0 / (rowsum + eps)
    q_new = np.clip(q + sigma * W * rho, -1.0, 1.0)
    return q_new, data_K_transpose(A, W, q_new)


# --- TGV (MODEL.md §4, §5) -------------------------------------------------------------------


def central_gradient(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Central differences with clamped (replicated) borders."""
    p = np.pad(np.asarray(img, np.float64), 1, mode="edge")
    return 0.5 * (p[1:-1, 2:] - p[1:-1, :-2]), 0.5 * (p[2:, 1:-1] - p[:-2, 1:-1])


def diffusion_tensor(img: np.ndarray, gamma: float, beta: float) -> np.ndarray:
    """Γ = exp(−γ|∇I|^β) n nᵀ + n⊥ n⊥ᵀ as a (h, w, 2, 2) array, ∇I by forward differences
    (:func:`grad`); identity where ∇I = 0."""
    gx, gy = grad(img)
    mag = np.hypot(gx, gy)
    flat = mag <= 1e-12
    safe = np.where(flat, 1.0, mag)
    n = np.stack([np.where(flat, 1.0, gx / safe), np.where(flat, 0.0, gy / safe)], -1)
    nperp = np.stack([-n[..., 1], n[..., 0]], -1)
    e = np.where(flat, 1.0, np.exp(-gamma * safe**beta))
    return e[..., None, None] * n[..., :, None] * n[..., None, :] + nperp[..., :, None] * nperp[..., None, :]


def _tensor_from_structure(J: np.ndarray, gamma: float, beta: float) -> np.ndarray:
    """Γ = exp(−γ m^β) n nᵀ + n⊥ n⊥ᵀ (h, w, 2, 2) of a structure tensor J (h, w, 2, 2): n
    and m² its leading eigenvector and eigenvalue (numpy.linalg.eigh); identity where J
    vanishes."""
    lam, vec = np.linalg.eigh(J)
    m = np.sqrt(np.maximum(lam[..., 1], 0.0))
    n = vec[..., :, 1]
    nperp = np.stack([-n[..., 1], n[..., 0]], -1)
    e = np.exp(-gamma * m**beta)
    t = e[..., None, None] * n[..., :, None] * n[..., None, :] + nperp[..., :, None] * nperp[..., None, :]
    t[lam[..., 1] <= 1e-24] = np.eye(2)
    return t


def joint_diffusion_tensor(img: np.ndarray, disparity: np.ndarray, weight: float, gamma: float,
                           beta: float) -> np.ndarray:
    """Γ of the two-channel guide (I, weight·δ) as (h, w, 2, 2): n and m² the leading
    eigenvector and eigenvalue of ∇I∇Iᵀ + weight²∇δ∇δᵀ (numpy.linalg.eigh), Γ =
    exp(−γ m^β) n nᵀ + n⊥ n⊥ᵀ; identity where both gradients vanish. ∇I by forward
    differences (:func:`grad`), ∇δ by central ones."""
    gx, gy = grad(img)
    dx, dy = central_gradient(disparity)
    dx, dy = weight * dx, weight * dy
    J = np.empty(gx.shape + (2, 2))
    J[..., 0, 0] = gx * gx + dx * dx
    J[..., 0, 1] = J[..., 1, 0] = gx * gy + dx * dy
    J[..., 1, 1] = gy * gy + dy * dy
    return _tensor_from_structure(J, gamma, beta)


def colour_diffusion_tensor(img: np.ndarray, gamma: float, beta: float) -> np.ndarray:
    """Γ of a colour image (h, w, 3) as (h, w, 2, 2): n and m² the leading eigenvector and
    eigenvalue of the channels' mean ∇I∇Iᵀ (numpy.linalg.eigh; Di Zenzo), Γ =
    exp(−γ m^β) n nᵀ + n⊥ n⊥ᵀ; identity where every channel's gradient vanishes. ∇I by
    forward differences (:func:`grad`)."""
    J = np.zeros(img.shape[:2] + (2, 2))
    channels = img.shape[2]
    for k in range(channels):
        gx, gy = grad(img[..., k])
        J[..., 0, 0] += gx * gx / channels
        J[..., 0, 1] += gx * gy / channels
        J[..., 1, 1] += gy * gy / channels
    J[..., 1, 0] = J[..., 0, 1]
    return _tensor_from_structure(J, gamma, beta)


def tensor_components(t: np.ndarray) -> np.ndarray:
    """(h, w, 2, 2) → (h, w, 3) = (Γ00, Γ01, Γ11), the layout of the kernels."""
    return np.stack([t[..., 0, 0], t[..., 0, 1], t[..., 1, 1]], -1)


def alpha0_of(alpha0, k: int) -> float:
    """α0 of unknown k of (δ1, δ2, u, v): one value for all, or one per unknown."""
    return float(np.broadcast_to(np.asarray(alpha0, np.float64), (4,))[k])


def tgv_matrix(tensor: np.ndarray, alpha0: float, alpha1: float) -> np.ndarray:
    """Dense K of the TGV part for one unknown on an (h, w) grid.

    Columns: [x, w0, w1] (3·hw); rows: [y0, y1] = α1 Γ(∇x − w) (2·hw), then
    [z00, z01, z10, z11] = α0 (∂x w0, ∂y w0, ∂x w1, ∂y w1) (4·hw). ``tensor`` is
    (h, w, 3) = (Γ00, Γ01, Γ11) per pixel.
    """
    h, w = tensor.shape[:2]
    n = h * w
    dx, dy = gradient_matrix(h, w)
    g00 = np.diag(tensor[..., 0].ravel())
    g01 = np.diag(tensor[..., 1].ravel())
    g11 = np.diag(tensor[..., 2].ravel())
    eye = np.eye(n)
    zero = np.zeros((n, n))
    # ∇x − w as two blocks of rows
    r0 = np.hstack([dx, -eye, zero])
    r1 = np.hstack([dy, zero, -eye])
    y0 = alpha1 * (g00 @ r0 + g01 @ r1)
    y1 = alpha1 * (g01 @ r0 + g11 @ r1)
    z00 = alpha0 * np.hstack([zero, dx, zero])
    z01 = alpha0 * np.hstack([zero, dy, zero])
    z10 = alpha0 * np.hstack([zero, zero, dx])
    z11 = alpha0 * np.hstack([zero, zero, dy])
    return np.vstack([y0, y1, z00, z01, z10, z11])


def per_unknown(tensor1: np.ndarray, tensor2: np.ndarray, k: int, tensor3: np.ndarray | None = None) -> np.ndarray:
    """Γ used for unknown k of (δ1, δ2, u, v): tensor2 for δ2, tensor3 (default tensor1)
    for u and v, tensor1 for δ1."""
    if k == 1:
        return tensor2
    if k >= 2 and tensor3 is not None:
        return tensor3
    return tensor1


def tgv_preconditioner(data_colsum, tensor1, tensor2, alpha0, alpha1, eps, tensor3=None):
    """τ_x, τ_w0, τ_w1, σ_y (each (h, w, 4)) from the exact abs row/column sums of
    :func:`tgv_matrix` (``alpha0`` one value or one per unknown; data column sums added to
    τ_x; σ_y from the larger of y's two rows), and σ_z (one per z row, (4, h, w, 4))."""
    h, w = tensor1.shape[:2]
    out = {k: np.zeros((h, w, 4)) for k in ("tau_x", "tau_w0", "tau_w1", "sigma_y")}
    zrows = np.zeros((4, h, w, 4))
    for k in range(4):
        K = np.abs(tgv_matrix(per_unknown(tensor1, tensor2, k, tensor3), alpha0_of(alpha0, k), alpha1))
        col = K.sum(axis=0).reshape(3, h, w)
        row = K.sum(axis=1).reshape(6, h, w)
        out["tau_x"][..., k] = 1.0 / (data_colsum[..., k] + col[0] + eps)
        out["tau_w0"][..., k] = 1.0 / (col[1] + eps)
        out["tau_w1"][..., k] = 1.0 / (col[2] + eps)
        # both components of y(p) share the step of the larger row sum (the projection
        # onto |y| ≤ 1 is the prox only in a metric that treats them alike)
        out["sigma_y"][..., k] = 1.0 / (np.maximum(row[0], row[1]) + eps)
        zrows[..., k] = row[2:]
    return out, zrows


def _pack(x, w0, w1, k):
    """Column vector [x, w0, w1] of unknown k."""
    return np.concatenate([x[..., k].ravel(), w0[..., k].ravel(), w1[..., k].ravel()])


def tgv_dual_step(x_bar, w0_bar, w1_bar, tensor1, tensor2, sigma_y, sigma_z, alpha0, alpha1,
                  y0, y1, z00, z01, z10, z11, tensor3=None):
    """D ← proj(D + Σ K P̄) per unknown with K = :func:`tgv_matrix`: y = (y0, y1) onto
    |y| ≤ 1, z = (z00, z01, z10, z11) onto Frobenius norm ≤ 1. Returns the six new duals."""
    h, w = x_bar.shape[:2]
    duals = [np.array(a, np.float64) for a in (y0, y1, z00, z01, z10, z11)]
    for k in range(4):
        K = tgv_matrix(per_unknown(tensor1, tensor2, k, tensor3), alpha0_of(alpha0, k), alpha1)
        kp = (K @ _pack(x_bar, w0_bar, w1_bar, k)).reshape(6, h, w)
        steps = [sigma_y[..., k]] * 2 + [sigma_z] * 4
        new = [duals[m][..., k] + steps[m] * kp[m] for m in range(6)]
        ny = np.maximum(1.0, np.hypot(new[0], new[1]))
        nz = np.maximum(1.0, np.sqrt(sum(a * a for a in new[2:])))
        for m in range(6):
            duals[m][..., k] = new[m] / (ny if m < 2 else nz)
    return duals


def tgv_primal_step(data_grad, y0, y1, z00, z01, z10, z11, tensor1, tensor2, tau_x, tau_w0, tau_w1,
                    alpha0, alpha1, x, w0, w1, tensor3=None):
    """P_new = P − T (Kᵀ D + (data_grad, 0, 0)) per unknown with K = :func:`tgv_matrix`;
    returns (x, w0, w1, x̄, w̄0, w̄1) with P̄ = 2 P_new − P."""
    h, w = x.shape[:2]
    outs = [np.array(a, np.float64) for a in (x, w0, w1)]
    for k in range(4):
        K = tgv_matrix(per_unknown(tensor1, tensor2, k, tensor3), alpha0_of(alpha0, k), alpha1)
        d = np.concatenate([a[..., k].ravel() for a in (y0, y1, z00, z01, z10, z11)])
        kt = (K.T @ d).reshape(3, h, w)
        kt[0] += data_grad[..., k]
        taus = (tau_x[..., k], tau_w0[..., k], tau_w1[..., k])
        for m in range(3):
            outs[m][..., k] = outs[m][..., k] - taus[m] * kt[m]
    bars = [2.0 * new - np.asarray(old, np.float64) for new, old in zip(outs, (x, w0, w1))]
    return (*outs, *bars)


# --- median (Wedel et al. 2009) ------------------------------------------------------------


def median_flow(x: np.ndarray, radius: int, tolerance: float = 0.0) -> np.ndarray:
    """u, v (components 2, 3) median-filtered over (2r+1)² windows with replicated
    borders, over the window's pixels whose δ1 is within ``tolerance`` of the centre's
    (all where it is 0), with the centre's value once more where their count is even;
    δ1, δ2 copied."""
    x = np.asarray(x, np.float64)
    out = x.copy()
    side = 2 * radius + 1
    h, w = x.shape[:2]

    def windows(a):
        padded = np.pad(a, radius, mode="edge")
        return np.lib.stride_tricks.sliding_window_view(padded, (side, side)).reshape(h, w, -1)

    d1 = windows(x[..., 0])
    for k in (2, 3):
        values = windows(x[..., k])
        for i in range(h):
            for j in range(w):
                keep = np.abs(d1[i, j] - x[i, j, 0]) <= tolerance if tolerance > 0 else np.ones(side * side, bool)
                chosen = values[i, j][keep]
                if chosen.size % 2 == 0:
                    chosen = np.append(chosen, x[i, j, k])
                out[i, j, k] = np.median(chosen)
    return out


def guided_median_edges(x: np.ndarray, colours: np.ndarray, radius: int, colour_sigma: float, jump: float,
                        separation: float, floor: float = 0.01) -> np.ndarray:
    """δ1 and δ2 of x (h, w, 4) snapped to the colour edges (kernels/median.py
    guided_median_edges): per component, over the (2r+1)² window clamped at the borders,
    where max − min > ``jump`` and the colours (h, w, 3) of the values ≥ the middle of
    that range and of those below it have means apart by more than ``separation`` ×
    √(mean of the two groups' mean squared distances to their means + floor²), the
    median weighted by exp(−|Δc|²/2σ_c² − |Δp|²/2r²) (sort, cumulative sum, first value
    with half of the weight at or below it); elsewhere the value as it was. Explicit loops."""
    x = np.asarray(x, np.float64)
    colours = np.asarray(colours, np.float64)
    h, w = x.shape[:2]
    out = x.copy()
    for i in range(h):
        for j in range(w):
            rows = [min(max(i + dy, 0), h - 1) for dy in range(-radius, radius + 1) for _ in range(-radius, radius + 1)]
            cols = [min(max(j + dx, 0), w - 1) for _ in range(-radius, radius + 1) for dx in range(-radius, radius + 1)]
            offsets = [(dy, dx) for dy in range(-radius, radius + 1) for dx in range(-radius, radius + 1)]
            cw = colours[rows, cols]
            wt = np.array([math.exp(-np.sum((c - colours[i, j]) ** 2) / (2 * colour_sigma ** 2)
                                    - (dy * dy + dx * dx) / (2.0 * radius * radius)) for c, (dy, dx) in zip(cw, offsets)])
            for k in (0, 1):
                v = x[rows, cols, k]
                lo, hi = v.min(), v.max()
                if hi - lo <= jump:
                    continue
                near = v >= 0.5 * (lo + hi)
                if near.all() or not near.any():
                    continue
                m_near, m_far = cw[near].mean(0), cw[~near].mean(0)
                spread = 0.5 * (np.mean(np.sum((cw[near] - m_near) ** 2, 1)) + np.mean(np.sum((cw[~near] - m_far) ** 2, 1)))
                if np.sum((m_near - m_far) ** 2) <= separation ** 2 * (spread + floor ** 2):
                    continue
                order = np.argsort(v, kind="stable")
                cum = np.cumsum(wt[order])
                out[i, j, k] = v[order][np.argmax(cum >= 0.5 * cum[-1])]
    return out


# --- the linearised problem of one warp (MODEL.md §3–§5) -----------------------------------


class LinearisedProblem:
    """E(x, w) = Σ_s Σ_k w_k|ρ_k(x)| + α1 Σ|Γ(∇x − w)| + α0 Σ|∇w| for fixed coefficients
    A (9, S, h, w), weights W (3, S, h, w), linearisation point x̂ (h, w, 4) and tensors
    (Γ00, Γ01, Γ11) (h, w, 3) each: tensor1 for δ1, tensor2 for δ2, tensor3 (default
    tensor1) for u and v; α0 one value or one per unknown."""

    def __init__(self, A, W, x_hat, tensor1, tensor2, alpha0, alpha1, tensor3=None):
        self.A, self.W = np.asarray(A, np.float64), np.asarray(W, np.float64)
        self.x_hat = np.asarray(x_hat, np.float64)
        t1, t2 = np.asarray(tensor1, np.float64), np.asarray(tensor2, np.float64)
        t3 = t1 if tensor3 is None else np.asarray(tensor3, np.float64)
        self.tensor1, self.tensor2, self.tensor3 = t1, t2, t3
        self.G = [np.stack([t1[..., m], t2[..., m], t3[..., m], t3[..., m]], -1) for m in range(3)]
        self.alpha0, self.alpha1 = np.asarray(alpha0, np.float64), alpha1  # (broadcast over the unknowns)
        self.b = self.W * data_residuals(self.A, np.zeros_like(self.x_hat))

    def K(self, x, w0, w1):
        """K P as the seven dual blocks (q, y0, y1, z00, z01, z10, z11), without −b."""
        A, W, G, a0, a1 = self.A, self.W, self.G, self.alpha0, self.alpha1
        delta = x - self.x_hat
        kd = W * (data_residuals(A, delta) - data_residuals(A, np.zeros_like(delta)))
        gx, gy = grad(x)
        r0, r1 = gx - w0, gy - w1
        d0x, d0y = grad(w0)
        d1x, d1y = grad(w1)
        return [kd, a1 * (G[0] * r0 + G[1] * r1), a1 * (G[1] * r0 + G[2] * r1),
                a0 * d0x, a0 * d0y, a0 * d1x, a0 * d1y]

    def KT(self, q, y0, y1, z00, z01, z10, z11):
        """Kᵀ D as (x, w0, w1)."""
        G, a0, a1 = self.G, self.alpha0, self.alpha1
        h0 = G[0] * y0 + G[1] * y1
        h1 = G[1] * y0 + G[2] * y1
        return (data_K_transpose(self.A, self.W, q) - a1 * div(h0, h1),
                -a1 * h0 - a0 * div(z00, z01), -a1 * h1 - a0 * div(z10, z11))

    def energy(self, x, w0, w1) -> float:
        kp = self.K(*(np.asarray(a, np.float64) for a in (x, w0, w1)))
        return float(np.sum(np.abs(kp[0] + self.b)) + np.sum(np.hypot(kp[1], kp[2]))
                     + np.sum(np.sqrt(kp[3] ** 2 + kp[4] ** 2 + kp[5] ** 2 + kp[6] ** 2)))

    def preconditioners(self, eps: float, step_ratio: float = 1.0) -> dict:
        """Pock–Chambolle (α = 1) steps from the abs row/column sums of K: σ of the data
        rows (3, S, h, w), σ_y0, σ_y1, σ_z and τ_x, τ_w0, τ_w1 (each (h, w, 4)); every τ
        multiplied and every σ divided by ``step_ratio``."""
        rowsum = np.zeros_like(self.b)
        colsum = np.zeros_like(self.x_hat)
        for coeff, (row, col) in data_jacobian(self.A, self.W).values():
            rowsum[row] += np.abs(coeff)
            colsum[..., col] += np.sum(np.abs(coeff), axis=0)
        tgv, _ = tgv_preconditioner(colsum, self.tensor1, self.tensor2, self.alpha0, self.alpha1, eps, self.tensor3)
        steps = dict(tgv, sigma_q=1.0 / (rowsum + eps), sigma_z=1.0 / (2.0 * self.alpha0))
        return {k: v * step_ratio if k.startswith("tau") else v / step_ratio for k, v in steps.items()}

    def solve(self, iterations: int, steps: dict | None = None, seed: int = 0):
        """Chambolle–Pock from x = x̂, w = 0: with ``steps`` (see :meth:`preconditioners`)
        the diagonally preconditioned iteration of MODEL.md §5, else scalar steps
        τ = σ = 0.99/‖K‖. Returns (x, w0, w1)."""
        shape = self.x_hat.shape
        if steps is None:
            r = np.random.default_rng(seed)
            P = [r.standard_normal(shape) for _ in range(3)]
            for _ in range(60):  # power iteration for ‖K‖²
                P = list(self.KT(*self.K(*P)))
                norm = np.sqrt(sum(np.sum(p * p) for p in P))
                P = [p / norm for p in P]
            step = 0.99 / np.sqrt(norm)
            sigma = [step] * 7
            tau = [step] * 3
        else:
            sigma = [steps["sigma_q"], steps["sigma_y"], steps["sigma_y"]] + [steps["sigma_z"]] * 4
            tau = [steps["tau_x"], steps["tau_w0"], steps["tau_w1"]]
        P = [self.x_hat.copy(), np.zeros(shape), np.zeros(shape)]
        P_bar = [p.copy() for p in P]
        Dl = [np.zeros_like(self.b)] + [np.zeros(shape) for _ in range(6)]
        for _ in range(iterations):
            kp = self.K(*P_bar)
            Dl[0] = np.clip(Dl[0] + sigma[0] * (kp[0] + self.b), -1.0, 1.0)
            for m in range(1, 7):
                Dl[m] = Dl[m] + sigma[m] * kp[m]
            ny = np.maximum(1.0, np.hypot(Dl[1], Dl[2]))
            nz = np.maximum(1.0, np.sqrt(sum(Dl[m] ** 2 for m in range(3, 7))))
            Dl = [Dl[0], Dl[1] / ny, Dl[2] / ny] + [Dl[m] / nz for m in range(3, 7)]
            new = [p - t * g for p, t, g in zip(P, tau, self.KT(*Dl))]
            P_bar = [2.0 * n - p for n, p in zip(new, P)]
            P = new
        return P


# --- discrete search (kernels/search.py) ---------------------------------------------------


def _offset_points(samples, offset):
    """q = p + (u, v) of ``offset`` (components 2, 3) at every pixel p, and the centre
    view's value L(q, 0) there: (qx, qy, centre), float64."""
    offset = np.asarray(offset, np.float64)
    h, w = samples.shape[1:]
    py, px = np.mgrid[0:h, 0:w].astype(np.float64)
    qx, qy = px + offset[..., 2], py + offset[..., 3]
    return qx, qy, bilinear(samples[0], qx, qy)


def disparity_cost(samples, phis, candidates, base, offset) -> np.ndarray:
    """cost[k, p] = the least, over the 8 half-planes of samples (lines through φ = 0 at
    multiples of 45°), mean of |L(q − δ_k φ_s, φ_s) − L(q, 0)| over the samples s ≥ 1 of
    that half; q = p + (u, v) of ``offset`` (h, w, 4), δ_k = candidates[k] + base[p];
    samples whose warped position leaves the image are left out, cost 1 where no half
    has any. (K, h, w)."""
    samples = np.asarray(samples, np.float64)
    phis = np.asarray(phis, np.float64)
    members = half_plane_members(phis)  # (8, S) bool
    n, h, w = samples.shape
    qx, qy, centre = _offset_points(samples, offset)
    out = np.zeros((len(candidates), h, w))
    for k, c in enumerate(np.asarray(candidates, np.float64)):
        d = c + np.asarray(base, np.float64)
        sums = np.zeros((8, h, w))
        cnts = np.zeros((8, h, w))
        for s in range(1, n):
            x, y = qx - d * phis[s, 0], qy - d * phis[s, 1]
            valid = inside((h, w), x, y)
            e = np.where(valid, np.abs(bilinear(samples[s], x, y) - centre), 0.0)
            for m in range(8):
                if members[m, s]:
                    sums[m] += e
                    cnts[m] += valid
        means = np.where(cnts > 0, sums / np.maximum(cnts, 1), np.inf)
        out[k] = np.minimum(means.min(axis=0), 1.0)
    return out


def _box_windows(values, radius: int) -> np.ndarray:
    """The (2r+1)² window around each pixel of each slice of (K, h, w), borders
    replicated: (K, h, w, 2r+1, 2r+1)."""
    values = np.asarray(values, np.float64)
    side = 2 * radius + 1
    padded = np.pad(values, ((0, 0), (radius, radius), (radius, radius)), mode="edge")
    return np.lib.stride_tricks.sliding_window_view(padded, (side, side), axis=(1, 2))


def box_mean(values, radius: int) -> np.ndarray:
    """Mean of each slice of (K, h, w) over (2r+1)² windows, borders replicated."""
    return _box_windows(values, radius).mean(axis=(-2, -1))


def box_min(values, radius: int) -> np.ndarray:
    """Least value of each slice of (K, h, w) over (2r+1)² windows, borders replicated."""
    return _box_windows(values, radius).min(axis=(-2, -1))


def parabola_vertex(cl, c0, cr):
    """Offset (in steps) of the vertex of the parabola through (−1, cl), (0, c0), (1, cr)."""
    return 0.5 * (cl - cr) / (cl - 2.0 * c0 + cr)


def select_disparity(cost, candidates):
    """Winner-take-all over the candidates (K, h, w), ties to the candidate nearest zero
    (then the first), moved to the vertex of the parabola through the minimum and its two
    neighbours (when both exist and the parabola is convex); returns (disparity, winning
    cost) as (h, w) arrays."""
    cost = np.asarray(cost, np.float64)
    cand = np.asarray(candidates, np.float64)
    n = cost.shape[0]
    tied = cost == cost.min(axis=0)
    k = np.argmin(np.where(tied, np.abs(cand)[:, None, None], np.inf), axis=0)
    c0 = np.take_along_axis(cost, k[None], 0)[0]
    d = cand[k]
    interior = (k > 0) & (k < n - 1)
    kl, kr = np.clip(k - 1, 0, n - 1), np.clip(k + 1, 0, n - 1)
    cl = np.take_along_axis(cost, kl[None], 0)[0]
    cr = np.take_along_axis(cost, kr[None], 0)[0]
    curv = cl - 2.0 * c0 + cr
    refine = interior & (curv > 1e-12)
    with np.errstate(invalid="ignore", divide="ignore"):
        step = cand[kr] - cand[k]
        d = np.where(refine, d + parabola_vertex(cl, c0, cr) * step, d)
    return d, c0


def flow_cost(centre1, centre2, candidates, base) -> np.ndarray:
    """cost[k, p] = |I1(p) − I2(p + u_k)|, u_k = candidates[k] + (u, v) of ``base``
    (h, w, 4); 1 where p + u_k leaves the image. (K, h, w)."""
    centre1 = np.asarray(centre1, np.float64)
    base = np.asarray(base, np.float64)
    h, w = centre1.shape
    py, px = np.mgrid[0:h, 0:w].astype(np.float64)
    out = np.zeros((len(candidates), h, w))
    for k, (cu, cv) in enumerate(np.asarray(candidates, np.float64)):
        x, y = px + base[..., 2] + cu, py + base[..., 3] + cv
        out[k] = np.where(inside((h, w), x, y), np.abs(centre1 - bilinear(centre2, x, y)), 1.0)
    return out


def surface_block_cost(centre1, centre2, x, radius: int, tolerance: float) -> np.ndarray:
    """Mean |I1(q) − I2(q + (u, v)(p))| over the window's pixels q (clamped to the image)
    with |δ1(q) − δ1(p)| ≤ tolerance, 1 per term leaving the image
    (kernels/search.py surface_block_cost). Explicit loops."""
    x = np.asarray(x, np.float64)
    h, w = centre1.shape
    out = np.zeros((h, w))
    for i in range(h):
        for j in range(w):
            terms = []
            for ii in range(max(i - radius, 0), min(i + radius + 1, h)):
                for jj in range(max(j - radius, 0), min(j + radius + 1, w)):
                    if abs(x[ii, jj, 0] - x[i, j, 0]) > tolerance:
                        continue
                    qx, qy = jj + x[i, j, 2], ii + x[i, j, 3]
                    inside = 0 <= qx <= w - 1 and 0 <= qy <= h - 1
                    terms.append(abs(centre1[ii, jj] - float(bilinear(np.asarray(centre2, np.float64), np.array(qx), np.array(qy)))) if inside else 1.0)
            out[i, j] = np.mean(terms)
    return out


def gradient_mean(centre) -> np.ndarray:
    """The 3×3 mean of |∇centre| (np.gradient, the edges repeated), as cost_above reads it."""
    gy, gx = np.gradient(np.asarray(centre, np.float64))
    g = np.pad(np.hypot(gx, gy), 1, mode="edge")
    h, w = g.shape[0] - 2, g.shape[1] - 2
    return sum(g[a:a + h, b:b + w] for a in range(3) for b in range(3)) / 9.0


def cost_above(cost, centre, slope: float, above: float, x=None, margin: float = -1.0) -> np.ndarray:
    """1 where cost > slope · :func:`gradient_mean` (centre) + above, else 0; with margin
    ≥ 0 also 0 where p + (u, v) of x lies less than margin inside the outer pixel
    centres (kernels/search.py cost_above)."""
    h, w = cost.shape
    out = cost > slope * gradient_mean(centre) + above
    if margin >= 0:
        qy, qx = np.mgrid[0:h, 0:w]
        qx = qx + np.asarray(x[..., 2], np.float64)
        qy = qy + np.asarray(x[..., 3], np.float64)
        out &= (qx >= margin) & (qy >= margin) & (qx <= w - 1 - margin) & (qy <= h - 1 - margin)
    return out.astype(np.float32)


def flow_grid(half: int) -> np.ndarray:
    """The whole-pixel candidates (dx, dy) of select_flow, k = (dy+n)(2n+1) + (dx+n)."""
    r = np.arange(-half, half + 1)
    dy, dx = np.meshgrid(r, r, indexing="ij")
    return np.stack([dx.ravel(), dy.ravel()], -1)


def select_flow(cost, half: int) -> np.ndarray:
    """Winner-take-all (first minimum) over the (2n+1)² grid (:func:`flow_grid`), each axis
    moved to the vertex of the parabola through the minimum and its two neighbours along
    that axis (when both exist and the parabola is convex). (h, w, 2) = (dx, dy)."""
    cost = np.asarray(cost, np.float64)
    side = 2 * half + 1
    _, h, w = cost.shape
    grid = cost.reshape(side, side, h, w)  # [dy + n, dx + n]
    k = np.argmin(cost, axis=0)
    ky, kx = np.divmod(k, side)
    ii, jj = np.mgrid[0:h, 0:w]
    c0 = grid[ky, kx, ii, jj]
    out = np.stack([kx - half, ky - half], -1).astype(np.float64)
    for axis, (ka, neighbours) in enumerate((
            (kx, lambda d: grid[ky, np.clip(kx + d, 0, side - 1), ii, jj]),
            (ky, lambda d: grid[np.clip(ky + d, 0, side - 1), kx, ii, jj]))):
        cl, cr = neighbours(-1), neighbours(1)
        curv = cl - 2.0 * c0 + cr
        refine = (ka > 0) & (ka < side - 1) & (curv > 1e-12)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[..., axis] += np.where(refine, parabola_vertex(cl, c0, cr), 0.0)
    return out


def flow_runner_up(cost, half: int, distance: int) -> tuple[np.ndarray, np.ndarray]:
    """The runner-up of flow_search over the (2n+1)² grid's costs (K, h, w), taken in
    scan order k = 0 … K − 1: the least cost among shifts at least ``distance`` steps
    (along either axis) from the best so far; the old best becomes it when a new best
    lies that far from it, and it is dropped (3.4e38, k = −1) when a new best lies
    closer to it. Returns (cost, k) as (h, w) arrays."""
    cost = np.asarray(cost, np.float32)
    side = 2 * half + 1

    def apart(k, m):
        return (np.abs(k // side - m // side) >= distance) | (np.abs(k % side - m % side) >= distance)

    best, best_k = cost[0].copy(), np.zeros(cost.shape[1:], int)
    second, second_k = np.full(cost.shape[1:], np.float32(3.4e38)), np.full(cost.shape[1:], -1)
    for k in range(1, cost.shape[0]):
        value = cost[k]
        new_best = value < best
        old_far = new_best & apart(k, best_k)
        dropped = new_best & ~old_far & (second_k >= 0) & ~apart(k, second_k)
        later = ~new_best & (value < second) & apart(k, best_k)
        second = np.where(old_far, best, np.where(dropped, np.float32(3.4e38), np.where(later, value, second)))
        second_k = np.where(old_far, best_k, np.where(dropped, -1, np.where(later, k, second_k)))
        best = np.where(new_best, value, best)
        best_k = np.where(new_best, k, best_k)
    return second, second_k


# --- geometric occlusion at t2 (kernels/occlusion.py) ---------------------------------------


def hidden_at_t2(x, margin, reach, outside=0.0):
    """(h, w) float: 1 where p is hidden at t2 or lies within ``reach`` pixels (a (2r+1)²
    window) of a hidden q with |δ1(q) − δ1(p)| ≤ margin; p is hidden where the pixel
    nearest to p + (u, v) is also the nearest landing pixel of a point whose δ1 exceeds
    δ1(p) + margin, and ``outside`` where that pixel lies outside the image. Explicit
    loops."""
    x = np.asarray(x, np.float32)
    h, w = x.shape[:2]

    def target(i, j):
        return (int(np.floor(np.float32(i) + x[i, j, 3] + np.float32(0.5))),
                int(np.floor(np.float32(j) + x[i, j, 2] + np.float32(0.5))))

    zbuf = np.full((h, w), -np.inf)
    for i in range(h):
        for j in range(w):
            ty, tx = target(i, j)
            if 0 <= ty < h and 0 <= tx < w:
                zbuf[ty, tx] = max(zbuf[ty, tx], x[i, j, 0])
    hidden = np.zeros((h, w))
    for i in range(h):
        for j in range(w):
            ty, tx = target(i, j)
            if not (0 <= ty < h and 0 <= tx < w):
                hidden[i, j] = outside
            elif zbuf[ty, tx] > x[i, j, 0] + margin:
                hidden[i, j] = 1.0
    out = hidden.copy()
    for i in range(h):
        for j in range(w):
            for yy in range(max(i - reach, 0), min(i + reach + 1, h)):
                for xx in range(max(j - reach, 0), min(j + reach + 1, w)):
                    if hidden[yy, xx] and abs(x[yy, xx, 0] - x[i, j, 0]) <= margin:
                        out[i, j] = 1.0
    return out


def fill_hidden_motion(x, hidden, sigma, depth_sigma, radius, flagged=None):
    """x with δ2 = δ1 + D and (u, v) = U where ``hidden`` (kernels/occlusion.py
    fill_hidden_motion): D and U the weighted means of δ2 − δ1 and (u, v) over the
    pixels within ``radius`` (a square window, clamped to the image) that are not
    hidden (for D, nor ``flagged``), weight exp(−(dx² + dy²)/2σ²)·exp(−(δ1(q) −
    δ1(p))²/2σ_d²) (σ_d = 0: no depth weight); D = 0 and the flow unchanged where the
    weights sum to 1e-6 or less. Where flagged but not hidden, δ2 alone. Explicit loops."""
    x = np.asarray(x, np.float64).copy()
    hidden = np.asarray(hidden) > 0.5
    flagged = np.zeros_like(hidden) if flagged is None else np.asarray(flagged) > 0.5
    h, w = hidden.shape
    diff = x[..., 1] - x[..., 0]
    out = x.copy()
    for i in range(h):
        for j in range(w):
            if not (hidden[i, j] or flagged[i, j]):
                continue
            num_d = den_d = 0.0
            num_f = np.zeros(2)
            den_f = 0.0
            for yy in range(max(i - radius, 0), min(i + radius + 1, h)):
                for xx in range(max(j - radius, 0), min(j + radius + 1, w)):
                    if hidden[yy, xx]:
                        continue
                    g = np.exp(-((yy - i) ** 2 + (xx - j) ** 2) / (2.0 * sigma * sigma))
                    if depth_sigma > 0:
                        g *= np.exp(-(x[yy, xx, 0] - x[i, j, 0]) ** 2 / (2.0 * depth_sigma ** 2))
                    num_f += g * x[yy, xx, 2:]
                    den_f += g
                    if not flagged[yy, xx]:
                        num_d += g * diff[yy, xx]
                        den_d += g
            out[i, j, 1] = x[i, j, 0] + (num_d / den_d if den_d > 1e-6 else 0.0)
            if hidden[i, j] and den_f > 1e-6:
                out[i, j, 2:] = num_f / den_f
    return out


def surface_motion_fit(x, untrusted, sigma, depth_sigma, radius, stride, ridge):
    """(δ1, δ1 + D, u, v) at every p from weighted least-squares affine fits of u, v and
    D = δ2 − δ1 in the offset (k, l) over the pixels q = p + stride·(k, l), not
    ``untrusted`` (≤ 0.5),
    |k|, |l| ≤ radius, in the image (kernels/occlusion.py surface_motion_fit): weight
    exp(−(k² + l²)/2σ²)·exp(−(δ1(q) − δ1(p))²/2σ_d²) (σ_d = 0: none), ridge·Σw added to
    the slopes' diagonal; x(p) where Σw ≤ 1e-3. Explicit loops, np.linalg.solve."""
    x = np.asarray(x, np.float64)
    good = np.asarray(untrusted) <= 0.5
    h, w = good.shape
    out = x.copy()
    for i in range(h):
        for j in range(w):
            a = np.zeros((3, 3))
            b = np.zeros((3, 3))  # columns: u, v, D
            for l in range(-radius, radius + 1):
                for k in range(-radius, radius + 1):
                    ii, jj = i + l * stride, j + k * stride
                    if not (0 <= ii < h and 0 <= jj < w) or not good[ii, jj]:
                        continue
                    g = np.exp(-(k * k + l * l) / (2.0 * sigma * sigma))
                    if depth_sigma > 0:
                        g *= np.exp(-(x[ii, jj, 0] - x[i, j, 0]) ** 2 / (2.0 * depth_sigma ** 2))
                    e = np.array([1.0, k, l])
                    a += g * np.outer(e, e)
                    b += g * np.outer(e, [x[ii, jj, 2], x[ii, jj, 3], x[ii, jj, 1] - x[ii, jj, 0]])
            if a[0, 0] <= 1e-3:
                continue
            a[1, 1] += ridge * a[0, 0]
            a[2, 2] += ridge * a[0, 0]
            u, v, d = np.linalg.solve(a, b)[0]
            out[i, j] = (x[i, j, 0], x[i, j, 0] + d, u, v)
    return out


# --- view z-buffers (kernels/occlusion.py splat_views, common.visible) ---------------------------


def splat_views(x, component: int, flow: bool, phis) -> np.ndarray:
    """(S, h, w): zbuf[s, t] = max δ = x[p][component] over the points p whose position in
    view s, q − δφ_s with q = p (+ (u, v) when ``flow``), has t among its bilinear
    neighbours (floor of each coordinate, and floor + 1 where the coordinate is not
    whole); −inf where none. Explicit loops."""
    x = np.asarray(x, np.float32)
    phis = np.asarray(phis, np.float32)
    h, w = x.shape[:2]
    zbuf = np.full((len(phis), h, w), -np.inf)
    for s, (xi, eta) in enumerate(phis):
        for i in range(h):
            for j in range(w):
                d = x[i, j, component]
                px = np.float32(j) - d * xi + (x[i, j, 2] if flow else np.float32(0.0))
                py = np.float32(i) - d * eta + (x[i, j, 3] if flow else np.float32(0.0))
                i0, j0 = int(np.floor(py)), int(np.floor(px))
                for ii in (i0, i0 + 1) if py > i0 else (i0,):
                    for jj in (j0, j0 + 1) if px > j0 else (j0,):
                        if 0 <= ii < h and 0 <= jj < w:
                            zbuf[s, ii, jj] = max(zbuf[s, ii, jj], d)
    return zbuf


#: See kernels/common.py EDGE_JUMP.
EDGE_JUMP = 2.0


def visible(zbuf_s, x, y, disparity, margin) -> np.ndarray:
    """Sample position (x, y) of a view sees the point of disparity δ (kernels/common.py
    visible): the view's z-buffer values at the pixels that (x, y)'s bilinear lookup
    reads with non-zero weight (clamped to the image; a whole coordinate reads one row
    or column) are compared with δ + margin: their largest where they differ by more
    than EDGE_JUMP × margin (a depth edge), else their least."""
    h, w = zbuf_s.shape
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    fx, fy = np.floor(x), np.floor(y)
    i0 = np.clip(fy.astype(int), 0, h - 1)
    j0 = np.clip(fx.astype(int), 0, w - 1)
    i1 = np.clip(fy.astype(int) + (y > fy), 0, h - 1)
    j1 = np.clip(fx.astype(int) + (x > fx), 0, w - 1)
    values = np.stack([zbuf_s[i0, j0], zbuf_s[i0, j1], zbuf_s[i1, j0], zbuf_s[i1, j1]])
    hi, lo = values.max(0), values.min(0)
    with np.errstate(invalid="ignore"):  # −inf − (−inf) where nothing landed: no edge, lo
        covered = np.where(hi - lo > EDGE_JUMP * margin, hi, lo)
    return covered <= np.asarray(disparity) + margin


def disparity_cost_visible(samples, phis, candidates, base, offset, zbuf, margin) -> np.ndarray:
    """cost[k, p] = mean of |L(q − δ_k φ_s, φ_s) − L(q, 0)| over the samples s ≥ 1 whose
    warped position lies in the image and is :func:`visible` by zbuf[s]; q = p + (u, v)
    of ``offset``, δ_k = candidates[k] + base[p]; 1 where no sample is left. (K, h, w)."""
    samples = np.asarray(samples, np.float64)
    phis = np.asarray(phis, np.float64)
    n, h, w = samples.shape
    qx, qy, centre = _offset_points(samples, offset)
    out = np.zeros((len(candidates), h, w))
    for k, c in enumerate(np.asarray(candidates, np.float64)):
        d = c + np.asarray(base, np.float64)
        total = np.zeros((h, w))
        count = np.zeros((h, w))
        for s in range(1, n):
            x, y = qx - d * phis[s, 0], qy - d * phis[s, 1]
            ok = inside((h, w), x, y) & visible(zbuf[s], x, y, d, margin)
            total += np.where(ok, np.abs(bilinear(samples[s], x, y) - centre), 0.0)
            count += ok
        out[k] = np.where(count > 0, total / np.maximum(count, 1), 1.0)
    return out


def shifted(x, dy: int, dx: int) -> np.ndarray:
    """x(p + (dx, dy)) with the edge pixels repeated (kernels/fusion.py shifted)."""
    h, w = x.shape[:2]
    ii = np.clip(np.arange(h) + dy, 0, h - 1)
    jj = np.clip(np.arange(w) + dx, 0, w - 1)
    return x[ii][:, jj]


def depth_nearby(x, component: int, candidate, reach: int, depth: float, keep=None) -> np.ndarray:
    """kernels/fusion.py depth_nearby: 0 where a pixel within ``reach`` (read with the
    edge pixels repeated) holds x[..., component] within ``depth`` of the candidate at p
    and p is not kept (``keep`` > 0.5), else 1."""
    near = np.zeros(candidate.shape, bool)
    for dy in range(-reach, reach + 1):
        for dx in range(-reach, reach + 1):
            near |= np.abs(shifted(x, dy, dx)[..., component] - candidate) < np.float32(depth)
    out = (~near).astype(np.float32)
    if keep is not None:
        out[keep > 0.5] = 1.0
    return out


def states_apart(x, cand, depth_gap, flow_gap) -> np.ndarray:
    """Where the state cand lies apart from x: δ1 and the flow by more than the gaps
    (kernels/fusion.py states_apart)."""
    f32 = np.float32
    du, dv = cand[..., 2] - x[..., 2], cand[..., 3] - x[..., 3]
    return (np.abs(cand[..., 0] - x[..., 0]) > f32(depth_gap)) & (du * du + dv * dv > f32(flow_gap) * f32(flow_gap))


def take_other_surface(x, cand, flow_new, flow_cur, t1_new, t1_cur, seen_new, seen_cur, hidden, floor, margin,
                       depth_gap, flow_gap, best, out, seen_too=True):
    """(best, out) after kernels/fusion.py take_other_surface: the candidate's whole state
    where the pixel is not hidden, its flow residual is above floor and both costs fall
    below margin times the current ones (the t1 cost also below best), with δ1 and the
    flow apart by more than the gaps; with ``seen_too`` a candidate with a lower δ1
    (behind) also needs its visible samples' cost below margin times the current one."""
    f32 = np.float32
    take = (hidden <= 0.5) & (flow_cur > f32(floor))
    take &= (flow_new < f32(margin) * flow_cur) & (t1_new < f32(margin) * t1_cur) & (t1_new < best)
    take &= states_apart(x, cand, depth_gap, flow_gap)
    if seen_too:
        take &= (cand[..., 0] >= x[..., 0]) | (seen_new < f32(margin) * seen_cur)
    best, out = best.copy(), out.copy()
    best[take] = t1_new[take]
    out[take] = cand[take]
    return best, out


def relabel_active(x, hidden, flow_cost, floor, depth_gap, flow_gap, reach) -> np.ndarray:
    """1 where the pixel is not hidden, its flow cost is above floor and a pixel within
    reach (read clamped) has δ1 and flow apart from its own by more than the gaps
    (kernels/search.py relabel_active)."""
    found = np.zeros(x.shape[:2], bool)
    for dy in range(-reach, reach + 1):
        for dx in range(-reach, reach + 1):
            found |= states_apart(x, shifted(x, dy, dx), depth_gap, flow_gap)
    return (found & (hidden <= 0.5) & (flow_cost > np.float32(floor))).astype(np.float32)


def dilated(mask, radius: int) -> np.ndarray:
    """1 where the (2·radius + 1)² window holds a pixel of mask > 0.5 (kernels/search.py dilated)."""
    m = np.pad(mask > 0.5, radius)
    h, w = mask.shape
    out = np.zeros((h, w), bool)
    for a in range(2 * radius + 1):
        for b in range(2 * radius + 1):
            out |= m[a:a + h, b:b + w]
    return out.astype(np.float32)


def remove_speckles(x, radius: int, depth: float, support: int) -> np.ndarray:
    """kernels/median.py remove_speckles: δ1 and δ2 each replaced by the (2r+1)² window's
    median (edge pixels repeated) where fewer than ``support`` window pixels inside the
    image hold a value within ``depth`` of the pixel's; u, v unchanged."""
    h, w = x.shape[:2]
    ii, jj = np.mgrid[0:h, 0:w]
    out = x.copy()
    offsets = [(dy, dx) for dy in range(-radius, radius + 1) for dx in range(-radius, radius + 1)]
    inside = np.stack([(ii + dy >= 0) & (ii + dy < h) & (jj + dx >= 0) & (jj + dx < w) for dy, dx in offsets])
    for k in (0, 1):
        stack = np.stack([shifted(x, dy, dx)[..., k] for dy, dx in offsets])
        near = ((np.abs(stack - x[..., k]) < np.float32(depth)) & inside).sum(0)
        median = np.median(stack, 0).astype(np.float32)
        out[..., k] = np.where(near < support, median, x[..., k])
    return out
