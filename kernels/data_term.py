"""The linearised L1 data term of the light-field scene-flow model (MODEL.md §3, §5).

For every sample φ_s of the light field and every pixel p, with the warped samples
W1 = L(p − δ̂1 φ, φ, t1), W2 = L(p + û − δ̂2 φ, φ, t2) and J2 = L(p + û, 0, t2):

    ρ1 ≈ A2 − A1 Δδ1                              (stereo at t1, weight λ1)
    ρ2 ≈ A4 − A3 Δδ2 + A8 Δu + A9 Δv              (stereo at t2, weight λ2)
    ρ3 ≈ A7 + A1 Δδ1 − A3 Δδ2 − A5 Δu − A6 Δv     (flow, weight λ3)

with Δx = x − x̂. The unknowns are packed per pixel as vec4 (δ1, δ2, u, v), or as vec2
(u, v) for flow only (:data:`lfsf.kernels.common.UNKNOWNS`). Each sample's
coefficients are stored as ``vec12`` = (A1 … A9, σ̃1, σ̃2, σ̃3), pixel-major (``coef[i, j,
s]``: what one pixel's iteration reads is contiguous). The row weight w_k is λ_k (divided
by the sample count) or 0 where the row is left out (a warped position leaves the image,
an occlusion); σ̃_k = w_k² / ((w_k Σ|row k| + ε) c) is the dual step of the scaled dual
q̃_k = w_k q_k ∈ [−w_k, w_k] (c: the step ratio, :class:`lfsf.Params` ``step_ratio``),
so the iterations divide nothing and a left-out row has σ̃_k = 0 and q̃_k = 0.
"""

from typing import Any

import warp as wp

from .common import (HALF_PLANES, add_residual, bilinear_with_gradient, clip, from_vec4, half_plane_mask,
                     half_plane_normal, in_half_plane, inside, overload_unknowns, to_vec4, vec8, visible)

wp.set_module_options({"enable_backward": False})

vec12 = wp.types.vector(length=12, dtype=wp.float32)
#: An occlusion must also raise the mean residual by this much (intensities in [0, 1]):
#: in weak texture, ratios of tiny residuals are noise.
OCCLUSION_FLOOR = wp.constant(0.01)
#: The centre view at t2 is taken as occluded where it differs from the point's t1
#: appearance by more than this many times the residual of the visible t2 samples.
CENTRE_OCCLUSION_FACTOR = wp.constant(3.0)


@wp.func
def best_half(sums: vec8, counts: vec8, total: float, count: float, ratio: float):
    """Occlusion test of one light field at one pixel, from the residuals |L(q − δφ, φ) −
    c| of its samples s ≥ 1 against the point's appearance c: summed over each half of
    the samples (split by a line through φ = 0 at multiples of 45°; ``sums``,
    ``counts``) and over all (``total``, ``count``). An occluder spoils the samples on
    its side: the best half is taken when its mean is below ``ratio`` times the mean over
    all samples and lower by at least OCCLUSION_FLOOR.

    Returns the best half's index (−1: no occlusion, keep every sample) and the mean
    residual of the samples kept."""
    best = int(-1)
    kept_mean = float(0.0)
    if count > 0.0:
        kept_mean = total / count
    if count > 0.0 and ratio > 0.0:
        mean_all = total / count
        best_mean = mean_all
        for m in range(HALF_PLANES):
            if counts[m] > 0.0:
                mean_m = sums[m] / counts[m]
                if mean_m < best_mean:
                    best_mean = mean_m
                    best = m
        if best_mean >= ratio * mean_all or mean_all - best_mean < OCCLUSION_FLOOR:
            best = -1
        else:
            kept_mean = best_mean
    return best, kept_mean


@wp.func
def keeps(best: int, normal: wp.vec2, phi: wp.vec2):
    """Sample φ is kept by the occlusion test: no occlusion (best < 0), or φ in the best
    half-plane, whose normal (:func:`half_plane_normal` of best) the caller computes once
    per pixel (not per sample: it costs a cosine and a sine)."""
    return best < 0 or in_half_plane(phi, normal)


@wp.func
def row_steps(c: vec12, lam: wp.vec3, in_1: bool, in_2: bool, in_j: bool, eps: float, step_ratio: float):
    """The row weights w_k of one sample (λ_k where the row is in, else 0) and, in c, the
    dual steps σ̃_k; returns (c, (w1, w2, w3), its part of the column sums Σ|K|)."""
    a1 = wp.abs(c[0])
    a3 = wp.abs(c[2])
    a5 = wp.abs(c[4])
    a6 = wp.abs(c[5])
    a8 = wp.abs(c[7])
    a9 = wp.abs(c[8])
    wt1 = float(0.0)
    wt2 = float(0.0)
    wt3 = float(0.0)
    if in_1:
        wt1 = lam[0]
    if in_2 and in_j:
        wt2 = lam[1]
    if in_1 and in_2:
        wt3 = lam[2]
    c[9] = wt1 * wt1 / ((wt1 * a1 + eps) * step_ratio)
    c[10] = wt2 * wt2 / ((wt2 * (a3 + a8 + a9) + eps) * step_ratio)
    c[11] = wt3 * wt3 / ((wt3 * (a1 + a3 + a5 + a6) + eps) * step_ratio)
    colsum = wp.vec4((wt1 + wt3) * a1, (wt2 + wt3) * a3, wt2 * a8 + wt3 * a5, wt2 * a9 + wt3 * a6)
    return c, wp.vec3(wt1, wt2, wt3), colsum


@wp.func
def keep_duals(q: wp.array3d(dtype=wp.vec3), i: int, j: int, s: int, wt: wp.vec3):
    """The scaled duals of the rows left out (w_k = 0) set to 0, the others kept."""
    qs = q[i, j, s]
    q[i, j, s] = wp.vec3(wp.where(wt[0] > 0.0, qs[0], 0.0), wp.where(wt[1] > 0.0, qs[1], 0.0),
                         wp.where(wt[2] > 0.0, qs[2], 0.0))


@wp.kernel
def data_coefficients(
    row0: int,
    samples1: wp.array3d(dtype=float),
    samples2: wp.array3d(dtype=float),
    phis: wp.array(dtype=wp.vec2),
    weights: wp.array(dtype=wp.vec3),
    x_hat: wp.array2d(dtype=Any),
    occlusion_ratio: float,
    hidden2: wp.array2d(dtype=float),
    eps: float,
    step_ratio: float,
    zbuf1: wp.array3d(dtype=float),
    zbuf2: wp.array3d(dtype=float),
    margin: float,
    use_zbuf: int,
    # outputs
    coef: wp.array3d(dtype=vec12),
    data_colsum: wp.array2d(dtype=Any),
    q: wp.array3d(dtype=wp.vec3),
):
    """Coefficients A1…A9 and dual steps σ̃1…σ̃3 of every sample at the linearisation
    point x̂ (``coef[i, j, s]``; σ̃ divided by the step ratio c), and the column sums
    Σ|K| of the data rows for each unknown (the data part of the preconditioner τ). The
    scaled duals q̃ of the rows left out are set to 0 (the others kept):
    :func:`dual_data_step` then needs no row flags, since a row with σ̃ = 0 and q̃ = 0
    stays at 0.

    ``samples1[s]``, ``samples2[s]``: (texture part of) the sub-aperture image at φ_s at
    t1 and t2; sample 0 must be the centre view (φ = 0). ``weights[s]`` = (λ1, λ2, λ3)
    for that sample. Where one side of the samples matches much worse than the other
    (``occlusion_ratio``, see :func:`best_half`; 0 disables), the samples of the worse
    side are left out of that light field's rows: near a depth edge the occluder hides
    the point in the views on its side. Both light fields are tested against the point's
    appearance at t1, I1(p); where the centre view at t2 is itself occluded (|I1 − J2|
    above CENTRE_OCCLUSION_FACTOR times the visible t2 samples' residual, plus the
    floor), every t2 stereo row and the centre's flow row are left out. Where ``hidden2``
    says a nearer point covers the point at t2 (the geometric test of
    :mod:`lfsf.kernels.occlusion`; zeros to skip it), every row involving t2 is left out
    (w2 = w3 = 0 for all samples): its δ2 and flow come from the regulariser alone, which
    measured better than trusting the side views there. With ``use_zbuf`` 1, which side
    views see the point is asked of the view z-buffers instead of the best half:
    ``zbuf1`` of δ̂1 at p, ``zbuf2`` of δ̂2 at p + û (:func:`lfsf.kernels.occlusion.splat_views`);
    a sample is left out where a point nearer by more than ``margin`` covers its warped
    position (:func:`lfsf.kernels.common.visible`). The best halves still give the
    residual of the t2 samples for the test of the centre view at t2. Launch over (rows,
    columns).

    One pass over the samples takes every row that the sample's own tests keep (in the
    image, seen by the z-buffers, not hidden). The best halves and the centre test,
    which need all the samples, can only leave rows out; a second pass, only at the
    pixels where they do, recomputes the steps and column sums from the stored
    coefficients. (Two passes at every pixel took 1.1–1.2× the time, 640×480.)
    """
    i, j = wp.tid()
    i = i + row0
    unknowns = x_hat[i, j]
    xh = to_vec4(unknowns)
    px = float(j)
    py = float(i)
    i1 = samples1[0, i, j]
    xj = px + xh[2]
    yj = py + xh[3]
    centre2 = samples2[0]
    j2, gj = bilinear_with_gradient(centre2, xj, yj)
    in_j0 = inside(centre2, xj, yj)
    hidden = hidden2[i, j] > 0.5
    sums1 = vec8()
    counts1 = vec8()
    sums2 = vec8()
    counts2 = vec8()
    total1 = float(0.0)
    count1 = float(0.0)
    total2 = float(0.0)
    count2 = float(0.0)
    # the t2 halves decide something only through the centre test, |i1 − j2| > 3·kept2 +
    # floor, which needs |i1 − j2| above the floor; t1's only without the view z-buffers
    halves2 = use_zbuf == 0 or (occlusion_ratio > 0.0 and wp.abs(i1 - j2) > OCCLUSION_FLOOR)
    colsum = wp.vec4(0.0)
    for s in range(phis.shape[0]):
        phi = phis[s]
        view1 = samples1[s]
        view2 = samples2[s]
        x1 = px - xh[0] * phi[0]
        y1 = py - xh[0] * phi[1]
        x2 = xj - xh[1] * phi[0]
        y2 = yj - xh[1] * phi[1]
        w1v, g1 = bilinear_with_gradient(view1, x1, y1)
        w2v, g2 = bilinear_with_gradient(view2, x2, y2)
        c = vec12()
        c[0] = -wp.dot(phi, g1)
        c[1] = i1 - w1v
        c[2] = -wp.dot(phi, g2)
        c[3] = j2 - w2v
        c[4] = g2[0]
        c[5] = g2[1]
        c[6] = w1v - w2v
        c[7] = gj[0] - g2[0]
        c[8] = gj[1] - g2[1]
        ins1 = inside(view1, x1, y1)
        ins2 = inside(view2, x2, y2)
        # residuals against the point's appearance at t1, I1(p), summed per half of the
        # samples: the occlusion test of each light field
        if s > 0 and halves2:
            mask = half_plane_mask(phi)
            if use_zbuf == 0 and ins1:
                sums1, counts1, total1, count1 = add_residual(sums1, counts1, total1, count1, wp.abs(w1v - i1), mask)
            if ins2:
                sums2, counts2, total2, count2 = add_residual(sums2, counts2, total2, count2, wp.abs(w2v - i1), mask)
        # the rows that this sample's own tests keep
        seen1 = bool(True)
        seen2 = bool(True)
        if use_zbuf != 0:
            seen1 = visible(zbuf1, s, x1, y1, xh[0], margin)
            seen2 = visible(zbuf2, s, x2, y2, xh[1], margin)
        in_1 = ins1 and seen1
        in_2 = ins2 and seen2 and (s > 0 or in_j0) and not hidden
        c, wt, part = row_steps(c, weights[s], in_1, in_2, in_j0, eps, step_ratio)
        coef[i, j, s] = c
        keep_duals(q, i, j, s, wt)
        colsum += part
    # Both light fields are tested against the point's appearance at t1, I1(p): at t2
    # the centre view itself may be the occluded one (the point moved behind something)
    # while side views still see it; then the stereo rows at t2 (which compare with
    # J2) and the centre's flow row are left out, and the visible side views carry ρ3.
    half1, kept1 = best_half(sums1, counts1, total1, count1, occlusion_ratio)
    half2, kept2 = best_half(sums2, counts2, total2, count2, occlusion_ratio)
    in_j = in_j0
    # (only where side views at t2 give a residual to compare with: flow only, M = 1, has none)
    if occlusion_ratio > 0.0 and count2 > 0.0 and wp.abs(i1 - j2) > CENTRE_OCCLUSION_FACTOR * kept2 + OCCLUSION_FLOOR:
        in_j = False
    # second pass, where the tests of all the samples leave rows out: the rows in, their
    # steps σ̃ and the column sums again
    if (use_zbuf == 0 and (half1 >= 0 or half2 >= 0)) or (in_j0 and not in_j):
        normal1 = half_plane_normal(wp.max(half1, 0))
        normal2 = half_plane_normal(wp.max(half2, 0))
        colsum = wp.vec4(0.0)
        for s in range(phis.shape[0]):
            phi = phis[s]
            x1 = px - xh[0] * phi[0]
            y1 = py - xh[0] * phi[1]
            x2 = xj - xh[1] * phi[0]
            y2 = yj - xh[1] * phi[1]
            seen1 = bool(False)
            seen2 = bool(False)
            if use_zbuf != 0:
                seen1 = visible(zbuf1, s, x1, y1, xh[0], margin)
                seen2 = visible(zbuf2, s, x2, y2, xh[1], margin)
            else:
                seen1 = keeps(half1, normal1, phi)
                seen2 = keeps(half2, normal2, phi)
            in_1 = inside(samples1[s], x1, y1) and seen1
            in_2 = inside(samples2[s], x2, y2) and seen2 and (s > 0 or in_j) and not hidden
            c, wt, part = row_steps(coef[i, j, s], weights[s], in_1, in_2, in_j, eps, step_ratio)
            coef[i, j, s] = c
            keep_duals(q, i, j, s, wt)
            colsum += part
    data_colsum[i, j] = from_vec4(colsum, unknowns)


@wp.func
def dual_data_pixel(
    coef: wp.array3d(dtype=vec12),
    weights: wp.array(dtype=wp.vec3),
    x_bar: wp.array2d(dtype=Any),
    x_hat: wp.array2d(dtype=Any),
    q: wp.array3d(dtype=wp.vec3),
    data_grad: wp.array2d(dtype=Any),
    i: int,
    j: int,
):
    """The dual data step at pixel (i, j) (see :func:`dual_data_step`)."""
    unknowns = x_hat[i, j]
    d = to_vec4(x_bar[i, j]) - to_vec4(unknowns)
    g = wp.vec4(0.0)
    for s in range(coef.shape[2]):
        c = coef[i, j, s]
        lam = weights[s]
        a1 = c[0]
        a3 = c[2]
        a5 = c[4]
        a6 = c[5]
        a8 = c[7]
        a9 = c[8]
        rho1 = c[1] - a1 * d[0]
        rho2 = c[3] - a3 * d[1] + a8 * d[2] + a9 * d[3]
        rho3 = c[6] + a1 * d[0] - a3 * d[1] - a5 * d[2] - a6 * d[3]
        # clipped to ±λ_k: a row left out has σ̃_k = 0 and q̃_k = 0 (data_coefficients), so
        # it stays 0 without a test of its flag
        qs = q[i, j, s]
        q1 = clip(qs[0] + c[9] * rho1, -lam[0], lam[0])
        q2 = clip(qs[1] + c[10] * rho2, -lam[1], lam[1])
        q3 = clip(qs[2] + c[11] * rho3, -lam[2], lam[2])
        q[i, j, s] = wp.vec3(q1, q2, q3)
        g += wp.vec4((q3 - q1) * a1, -(q2 + q3) * a3, q2 * a8 - q3 * a5, q2 * a9 - q3 * a6)
    data_grad[i, j] = from_vec4(g, unknowns)


@wp.kernel
def dual_data_step(
    row0: int,
    coef: wp.array3d(dtype=vec12),
    weights: wp.array(dtype=wp.vec3),
    x_bar: wp.array2d(dtype=Any),
    x_hat: wp.array2d(dtype=Any),
    span: int,
    # outputs
    q: wp.array3d(dtype=wp.vec3),
    data_grad: wp.array2d(dtype=Any),
):
    """Dual ascent on the data rows, fused with the primal gradient Kᵀq of the data term.

    With the scaled duals q̃_k = w_k q_k (``q[i, j, s]``):
    q̃_k ← clip(q̃_k + σ̃_k ρ_k(x̄), −w_k, w_k), σ̃_k = w_k σ_k and σ_k = 1 / (w_k Σ|row k| + ε)
    the diagonal preconditioner; then ``data_grad`` = Σ_s Kᵀ q for (δ1, δ2, u, v). This
    is q_k ← clip(q_k + σ_k w_k ρ_k, −1, 1) of the unscaled duals, without a division.
    Rows left out (w_k = 0) must have q̃_k = 0, as :func:`data_coefficients` leaves them:
    the clip is to ±λ_k, and σ̃_k = 0 keeps them at 0. Launch over (rows, ⌈columns /
    span⌉): each thread walks ``span`` pixels of a row (:func:`lfsf.device.row_span`).
    """
    i, c0 = wp.tid()
    i = i + row0
    j0 = c0 * span
    for j in range(j0, wp.min(x_bar.shape[1], j0 + span)):
        dual_data_pixel(coef, weights, x_bar, x_hat, q, data_grad, i, j)


# the kernels on the unknowns, for vec4 (δ1, δ2, u, v) and vec2 (u, v; flow only)
overload_unknowns(data_coefficients, "x_hat", "data_colsum")
overload_unknowns(dual_data_step, "x_bar", "x_hat", "data_grad")
