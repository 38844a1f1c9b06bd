"""The linearised L1 data term of the light-field scene-flow model (MODEL.md §3, §5).

For every sample φ_s of the light field and every pixel p, with the warped samples
W1 = L(p − δ̂1 φ, φ, t1), W2 = L(p + û − δ̂2 φ, φ, t2) and J2 = L(p + û, 0, t2):

    ρ1 ≈ A2 − A1 Δδ1                              (stereo at t1, weight λ1)
    ρ2 ≈ A4 − A3 Δδ2 + A8 Δu + A9 Δv              (stereo at t2, weight λ2)
    ρ3 ≈ A7 + A1 Δδ1 − A3 Δδ2 − A5 Δu − A6 Δv     (flow, weight λ3)

with Δx = x − x̂. The unknowns are packed per pixel as vec4 (δ1, δ2, u, v), or as vec2
(u, v) for flow only (:data:`lfsf.kernels.common.UNKNOWNS`).

The row weight w_k is λ_k (divided by the sample count) or 0 where the row is left out (a
warped position leaves the image, an occlusion); σ̃_k = w_k² / ((w_k Σ|row k| + ε) c) is
the dual step of the scaled dual q̃_k = w_k q_k ∈ [−w_k, w_k] (c: the step ratio,
:class:`lfsf.Params` ``step_ratio``), so a left-out row has σ̃_k = 0 and q̃_k = 0.

What a warp stores, once, for the iterations to read, per pixel and sample: A1 … A7
(:data:`COEFFICIENTS`) and the scaled duals q̃1 … q̃3 (:data:`DUALS`); per pixel: ∇J2
(the same for every sample; A8, A9 = ∇J2 − (A5, A6) are rebuilt from it, bit for bit,
one float subtraction either way) and the *row flags*, one bit per sample and row, set
where the row is in (:func:`flag_words` words of 31 bits a row). The dual step computes
σ̃_k from the coefficients and the flag, every iteration: three divisions a sample,
hidden behind the loads of a step bound by memory. Until the twenty-fourth session the
coefficients' kernel stored σ̃1 … σ̃3, 10 values a sample where 7 and the flags now do;
the dual step takes 0.83–0.93× the time without them (640×480, 17 samples, medians of
15–24 alternating launches on random and on a scene's inputs), with the same results
bit for bit (the same float operations on the same values).

The values are stored in *lanes*: a row's pixels in groups of L consecutive ones (L =
:data:`DATA_LANES` on the CPU, :data:`CUDA_LANES` on CUDA), and for each group, sample and value the L
pixels' values side by side, ``coef[i, j // L, (7 s + k) L + j % L]`` (a float array, as
:func:`data_coefficients` writes it; the same memory as L-vectors ``[i, j // L, 7 s + k]``,
as :data:`dual_data_step` reads it), ∇J2 as ``grad_j2[i, j // L, k L + j % L]``, k = 0,
1, and the flags (int32) as ``flags[i, j // L, (k W + s // 31) L + j % L]``, bit s % 31,
for row k = 0, 1, 2 (ρ1, ρ2, ρ3) and W = :func:`flag_words` of the sample count. With
L = 1 this is pixel-major: what one pixel's iteration reads is contiguous. With L = 8 the
iteration works on 8 pixels at once in vector registers (the CPU); with L = 32 a warp of
CUDA threads, a pixel each, reads each value from consecutive addresses.
"""

from typing import Any

import warp as wp

from lfsf.device import is_cpu

from .common import (HALF_PLANES, add_residual, lookup_with_gradient, from_vec4, half_plane_mask, lane_vector,
                     half_plane_normal, in_half_plane, inside, overload_unknowns, store_apart, to_vec4, vec8, visible)

wp.set_module_options({"enable_backward": False})

_FLAG_VECTORS: dict = {}


def flag_vector(lanes: int):
    """The vector type of ``lanes`` int32 row-flag words (one per pixel of a group)."""
    if lanes not in _FLAG_VECTORS:
        _FLAG_VECTORS[lanes] = wp.types.vector(length=lanes, dtype=wp.int32)
    return _FLAG_VECTORS[lanes]


#: A sample's coefficients A1 … A9.
vec9 = wp.types.vector(length=9, dtype=wp.float32)
#: Pixels per group of the data term's storage on the CPU (see the module's docstring):
#: the dual step then runs 8 pixels at once in vector registers, 0.69× the time of one
#: pixel at a time (640×480, 17 samples, medians of 8 rounds; bit-identical results).
DATA_LANES = 8
#: … and on CUDA, a warp's worth: a thread per pixel whose loads and stores of a value
#: are consecutive across the warp's threads. With 1 (a pixel's values side by side) a
#: warp's load touched 32 sectors for 4 bytes of each: the dual step ran at 0.09 of the
#: copy bandwidth (H200, 640×480, 17 samples).
CUDA_LANES = 32
#: Values stored per sample: the coefficients A1 … A7 (A8, A9 rebuilt from ∇J2, stored
#: once a pixel; σ̃1 … σ̃3 from the coefficients and the row flags) and the scaled duals.
#: Seven instead of twelve: the dual step, bound by memory since it runs 8 pixels at
#: once, took 0.89× the time with ten (A8, A9 rebuilt), and 0.83–0.93× that with seven.
COEFFICIENTS = 7
DUALS = 3
#: The data rows of a sample (ρ1, ρ2, ρ3), each with its flag bits.
ROWS = wp.constant(3)
#: Row flags per int32 word (the sign bit is left alone).
FLAG_BITS = wp.constant(31)


def flag_words(samples: int) -> int:
    """Words of row flags per pixel and row for ``samples`` samples (in kernels:
    :func:`words_of`)."""
    return -(-int(samples) // FLAG_BITS)


def pixel_flag_words(samples: int) -> int:
    """Words of row flags per pixel, all :data:`ROWS` rows, for ``samples`` samples: the
    flags' lane storage holds this many values a pixel."""
    return ROWS * flag_words(samples)


@wp.func
def words_of(samples: int):
    """:func:`flag_words` in a kernel."""
    return (samples + FLAG_BITS - 1) // FLAG_BITS


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
def row_steps(c: vec9, lam: wp.vec3, in_1: bool, in_2: bool, in_j: bool):
    """The row weights w_k of one sample (λ_k where the row is in, else 0) and their part
    of the column sums Σ|K| (the data part of the preconditioner τ), from the sample's
    coefficients c = (A1 … A9)."""
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
    colsum = wp.vec4((wt1 + wt3) * a1, (wt2 + wt3) * a3, wt2 * a8 + wt3 * a5, wt2 * a9 + wt3 * a6)
    return wp.vec3(wt1, wt2, wt3), colsum


@wp.func
def load_coefficients(coef: wp.array3d(dtype=float), grad_j2: wp.array3d(dtype=float), i: int, g: int, lane: int,
                      lanes: int, s: int):
    """A1 … A9 of sample s at the pixel in lane ``lane`` of group g of row i (column
    g · L + lane; lane storage, module docstring): the seven stored, and A8, A9 = ∇J2 −
    (A5, A6)."""
    at = COEFFICIENTS * s * lanes + lane
    c = vec9()
    for k in range(COEFFICIENTS):
        c[k] = coef[i, g, at + k * lanes]
    c[7] = grad_j2[i, g, lane] - c[4]
    c[8] = grad_j2[i, g, lanes + lane] - c[5]
    return c


@wp.func
def store_coefficients(coef: wp.array3d(dtype=float), i: int, g: int, lane: int, lanes: int, s: int, c: vec9):
    """Store the seven values of sample s at that pixel that are not rebuilt (A1 … A7)."""
    at = COEFFICIENTS * s * lanes + lane
    for k in range(COEFFICIENTS):
        coef[i, g, at + k * lanes] = c[k]


@wp.func
def clear_flags(flags: wp.array3d(dtype=wp.int32), i: int, g: int, lane: int, lanes: int, words: int):
    """Every row flag of the pixel in lane ``lane`` of group g of row i set to 0 (out)."""
    for k in range(ROWS * words):
        flags[i, g, k * lanes + lane] = wp.int32(0)


@wp.func
def set_flags(flags: wp.array3d(dtype=wp.int32), i: int, g: int, lane: int, lanes: int, words: int, s: int,
              wt: wp.vec3):
    """Set the flags of sample s's rows that are in (w_k > 0) at that pixel (after
    :func:`clear_flags`)."""
    bit = wp.int32(1) << wp.int32(s % FLAG_BITS)
    for k in range(ROWS):
        if wt[k] > 0.0:
            at = (k * words + s // FLAG_BITS) * lanes + lane
            flags[i, g, at] = flags[i, g, at] | bit


@wp.func
def keep_duals(q: wp.array3d(dtype=float), i: int, g: int, lane: int, lanes: int, s: int, wt: wp.vec3):
    """The scaled duals of the rows left out (w_k = 0) set to 0, the others kept."""
    at = DUALS * s * lanes + lane
    for k in range(DUALS):
        if wt[k] <= 0.0:
            q[i, g, at + k * lanes] = 0.0


@wp.func
def second_pass(i: int, j: int, g: int, lane: int, lanes: int, xh: wp.vec4, half1: int, half2: int, in_j: bool,
                hidden: bool, samples1: wp.array3d(dtype=float), samples2: wp.array3d(dtype=float),
                phis: wp.array(dtype=wp.vec2), weights: wp.array(dtype=wp.vec3), zbuf1: wp.array3d(dtype=float),
                zbuf2: wp.array3d(dtype=float), margin: float, use_zbuf: int, coef: wp.array3d(dtype=float),
                flags: wp.array3d(dtype=wp.int32), grad_j2: wp.array3d(dtype=float), q: wp.array3d(dtype=float)):
    """The second pass of :func:`data_coefficients` at pixel (i, j), stored in lane
    ``lane`` of group g: the rows that the tests of all the samples keep (the best
    halves ``half1``, ``half2``; the centre view at t2, ``in_j``), their flags again,
    and the duals of the rows left out zeroed. Returns the column sums, again from the
    stored coefficients."""
    px = float(j)
    py = float(i)
    xj = px + xh[2]
    yj = py + xh[3]
    normal1 = half_plane_normal(wp.max(half1, 0))
    normal2 = half_plane_normal(wp.max(half2, 0))
    colsum = wp.vec4(0.0)
    words = words_of(phis.shape[0])
    clear_flags(flags, i, g, lane, lanes, words)
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
        wt, part = row_steps(load_coefficients(coef, grad_j2, i, g, lane, lanes, s), weights[s], in_1, in_2, in_j)
        set_flags(flags, i, g, lane, lanes, words, s, wt)
        keep_duals(q, i, g, lane, lanes, s, wt)
        colsum += part
    return colsum


@wp.func
def pixel_coefficients(
    i: int,
    j: int,
    samples1: wp.array3d(dtype=float),
    samples2: wp.array3d(dtype=float),
    phis: wp.array(dtype=wp.vec2),
    weights: wp.array(dtype=wp.vec3),
    x_hat: Any,
    occlusion_ratio: float,
    hidden2: wp.array2d(dtype=float),
    zbuf1: wp.array3d(dtype=float),
    zbuf2: wp.array3d(dtype=float),
    margin: float,
    use_zbuf: int,
    lanes: int,
    cubic: int,
    coef: wp.array3d(dtype=float),
    flags: wp.array3d(dtype=wp.int32),
    grad_j2: wp.array3d(dtype=float),
    data_colsum: Any,
    q: wp.array3d(dtype=float),
):
    """:func:`data_coefficients` at pixel (i, j)."""
    g = j // lanes  # where the pixel's values are stored
    lane = j - g * lanes
    unknowns = x_hat[i, j]
    xh = to_vec4(unknowns)
    px = float(j)
    py = float(i)
    i1 = samples1[0, i, j]
    xj = px + xh[2]
    yj = py + xh[3]
    centre2 = samples2[0]
    j2, gj = lookup_with_gradient(centre2, xj, yj, cubic)
    grad_j2[i, g, lane] = gj[0]
    grad_j2[i, g, lanes + lane] = gj[1]
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
    words = words_of(phis.shape[0])
    clear_flags(flags, i, g, lane, lanes, words)
    for s in range(phis.shape[0]):
        phi = phis[s]
        view1 = samples1[s]
        view2 = samples2[s]
        x1 = px - xh[0] * phi[0]
        y1 = py - xh[0] * phi[1]
        x2 = xj - xh[1] * phi[0]
        y2 = yj - xh[1] * phi[1]
        w1v, g1 = lookup_with_gradient(view1, x1, y1, cubic)
        w2v, g2 = lookup_with_gradient(view2, x2, y2, cubic)
        c = vec9()
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
        wt, part = row_steps(c, weights[s], in_1, in_2, in_j0)
        store_coefficients(coef, i, g, lane, lanes, s, c)
        set_flags(flags, i, g, lane, lanes, words, s, wt)
        keep_duals(q, i, g, lane, lanes, s, wt)
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
    # second pass, where the tests of all the samples leave rows out: the rows in (their
    # flags) and the column sums again
    if (use_zbuf == 0 and (half1 >= 0 or half2 >= 0)) or (in_j0 and not in_j):
        colsum = second_pass(i, j, g, lane, lanes, xh, half1, half2, in_j, hidden, samples1, samples2, phis, weights,
                             zbuf1, zbuf2, margin, use_zbuf, coef, flags, grad_j2, q)
    data_colsum[i, j] = from_vec4(colsum, unknowns)


#: Registers a CUDA thread of :func:`data_coefficients` may take: left alone it took 254,
#: which let 8 warps run on a multiprocessor (ncu, H200: 12.5 % occupancy, 13 % of the
#: memory throughput); capped at 128 it ran in 385 µs against 509 (0.24 of the copy
#: bandwidth against 0.18; 96: 410 µs), 640×480, 17 samples. The CPU ignores it.
COEFFICIENT_REGISTERS = 128


@wp.kernel(cuda_max_registers=COEFFICIENT_REGISTERS)
def data_coefficients(
    row0: int,
    samples1: wp.array3d(dtype=float),
    samples2: wp.array3d(dtype=float),
    phis: wp.array(dtype=wp.vec2),
    weights: wp.array(dtype=wp.vec3),
    x_hat: wp.array2d(dtype=Any),
    occlusion_ratio: float,
    hidden2: wp.array2d(dtype=float),
    zbuf1: wp.array3d(dtype=float),
    zbuf2: wp.array3d(dtype=float),
    margin: float,
    use_zbuf: int,
    lanes: int,
    cubic: int,
    # outputs
    coef: wp.array3d(dtype=float),
    flags: wp.array3d(dtype=wp.int32),
    grad_j2: wp.array3d(dtype=float),
    data_colsum: wp.array2d(dtype=Any),
    q: wp.array3d(dtype=float),
):
    """Coefficients A1…A9 of every sample at the linearisation point x̂, the rows kept,
    and the column sums Σ|K| of the data rows for each unknown (the data part of the
    preconditioner τ). ``coef``, ``flags``, ``grad_j2`` and ``q`` are lane storage of
    ``lanes`` pixels a group (module docstring): the seven stored values of sample s at
    pixel (i, j) at ``coef[i, j // L, (7 s + k) L + j % L]``, k = 0 … 6 (A1 … A7), ∇J2,
    from which A8 and A9 are rebuilt, and the row flags, bit s % 31 of word k W + s // 31
    set where row k of sample s is in (w_k > 0). The scaled duals q̃ of the rows left out are set to 0 (the others
    kept): :func:`dual_data_step` gives a row left out σ̃ = 0, and with q̃ = 0 it stays
    at 0.

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
    residual of the t2 samples for the test of the centre view at t2. With ``cubic`` 1
    the warped samples' values are Catmull–Rom's, else bilinear
    (:func:`lfsf.kernels.common.lookup_with_gradient`, ``Params.cubic``). Launch over
    (rows, columns).

    One pass over the samples takes every row that the sample's own tests keep (in the
    image, seen by the z-buffers, not hidden). The best halves and the centre test,
    which need all the samples, can only leave rows out; a second pass, only at the
    pixels where they do, recomputes the flags and column sums from the stored
    coefficients. (Two passes at every pixel took 1.1–1.2× the time, 640×480.)

    A thread per pixel: CUDA's kernel. On the CPU
    :data:`lfsf.kernels.data_groups.data_coefficients_groups` gives the same results a
    group of DATA_LANES pixels at once (:func:`lfsf.kernels.data_groups.coefficients_kernel`
    picks one).
    """
    i, j = wp.tid()
    pixel_coefficients(i + row0, j, samples1, samples2, phis, weights, x_hat, occlusion_ratio, hidden2, zbuf1, zbuf2,
                       margin, use_zbuf, lanes, cubic, coef, flags, grad_j2, data_colsum, q)


def _dual_data_kernel(lanes: int):
    """:data:`dual_data_step` for groups of ``lanes`` pixels (the lane storage of the
    module docstring)."""
    row = lane_vector(lanes)
    flag_row = flag_vector(lanes)

    @wp.func
    def step(on: row, lam: float, row_sum: row, eps: float, step_ratio: float):
        """σ̃ = w² / ((w Σ|row| + ε) c) of one row of the L pixels, w = λ where the row is
        in (``on`` 1), else 0 (``on`` 0; then σ̃ = 0)."""
        return wp.cw_mul(on, wp.cw_div(row(lam * lam), (lam * row_sum + row(eps)) * step_ratio))

    @wp.kernel
    def dual_data_step(
        row0: int,
        coef: wp.array3d(dtype=row),
        flags: wp.array3d(dtype=flag_row),
        weights: wp.array(dtype=wp.vec3),
        grad_j2: wp.array3d(dtype=row),
        x_bar: wp.array2d(dtype=Any),
        x_hat: wp.array2d(dtype=Any),
        eps: float,
        step_ratio: float,
        groups: int,
        # outputs
        q: wp.array3d(dtype=row),
        data_grad: wp.array2d(dtype=Any),
    ):
        """Dual ascent on the data rows, fused with the primal gradient Kᵀq of the data term.

        With the scaled duals q̃_k = w_k q_k (``q``):
        q̃_k ← clip(q̃_k + σ̃_k ρ_k(x̄), −w_k, w_k), σ̃_k = w_k σ_k / c and σ_k = 1 / (w_k
        Σ|row k| + ε) the diagonal preconditioner (``eps`` ε, ``step_ratio`` c); then
        ``data_grad`` = Σ_s Kᵀ q for (δ1, δ2, u, v). This is q_k ← clip(q_k + σ_k w_k ρ_k /
        c, −1, 1) of the unscaled duals. w_k is λ_k where the row's flag is set, else 0.
        Rows left out must have q̃_k = 0, as :func:`data_coefficients` leaves them: the
        clip is to ±λ_k, and σ̃_k = 0 keeps them at 0. The clip is vector min/max: a NaN
        (which no valid input leads to) becomes −λ_k rather than passing through.

        ``coef``, ``flags``, ``grad_j2`` and ``q`` are the lane storage (module docstring)
        seen as L-vectors, (rows, groups, 7 S), (rows, groups, 3 W), (rows, groups, 2) and
        (rows, groups, 3 S); A8, A9 = ∇J2 − (A5, A6) are rebuilt per sample. ``data_grad``
        must be stored contiguously. Every operation acts on the L pixels of a group at
        once, each pixel's arithmetic the same as alone. Launch over (rows, ⌈groups per
        row / ``groups``⌉): each thread walks ``groups`` groups of a row."""
        i, c0 = wp.tid()
        i = i + row0
        w = x_bar.shape[1]
        n = weights.shape[0]
        words = words_of(n)
        g0 = c0 * groups
        for g in range(g0, wp.min(coef.shape[1], g0 + groups)):
            # the L pixels' x̄ − x̂ per unknown (pixels past the row's end repeat the last; their
            # coefficients are 0, and their gradient is not stored)
            d0 = row()
            d1 = row()
            d2 = row()
            d3 = row()
            for k in range(lanes):
                j = wp.min(g * lanes + k, w - 1)
                d = to_vec4(x_bar[i, j]) - to_vec4(x_hat[i, j])
                d0[k] = d[0]
                d1[k] = d[1]
                d2[k] = d[2]
                d3[k] = d[3]
            gjx = grad_j2[i, g, 0]
            gjy = grad_j2[i, g, 1]
            s0 = row()
            s1 = row()
            s2 = row()
            s3 = row()
            for word in range(words):
                # the row flags of samples 31 word … 31 word + 30
                f1 = flags[i, g, word]
                f2 = flags[i, g, words + word]
                f3 = flags[i, g, 2 * words + word]
                for s in range(word * FLAG_BITS, wp.min(n, (word + 1) * FLAG_BITS)):
                    bit = s - word * FLAG_BITS
                    # the rows in (1) and out (0)
                    on1 = row()
                    on2 = row()
                    on3 = row()
                    for k in range(lanes):
                        on1[k] = float((f1[k] >> bit) & 1)
                        on2[k] = float((f2[k] >> bit) & 1)
                        on3[k] = float((f3[k] >> bit) & 1)
                    b = COEFFICIENTS * s
                    a1 = coef[i, g, b + 0]
                    a3 = coef[i, g, b + 2]
                    a5 = coef[i, g, b + 4]
                    a6 = coef[i, g, b + 5]
                    a8 = gjx - a5
                    a9 = gjy - a6
                    rho1 = coef[i, g, b + 1] - wp.cw_mul(a1, d0)
                    rho2 = coef[i, g, b + 3] - wp.cw_mul(a3, d1) + wp.cw_mul(a8, d2) + wp.cw_mul(a9, d3)
                    rho3 = (coef[i, g, b + 6] + wp.cw_mul(a1, d0) - wp.cw_mul(a3, d1) - wp.cw_mul(a5, d2)
                            - wp.cw_mul(a6, d3))
                    # the steps σ̃ (the sums of |A| in the order the stored steps had them: the same
                    # bits), 0 where the row is out; clipped to ±λ_k: a row left out has σ̃_k = 0 and
                    # q̃_k = 0 (data_coefficients), so it stays 0
                    lam = weights[s]
                    b1 = wp.abs(a1)
                    b3 = wp.abs(a3)
                    sigma1 = step(on1, lam[0], b1, eps, step_ratio)
                    sigma2 = step(on2, lam[1], b3 + wp.abs(a8) + wp.abs(a9), eps, step_ratio)
                    sigma3 = step(on3, lam[2], b1 + b3 + wp.abs(a5) + wp.abs(a6), eps, step_ratio)
                    top1 = row(lam[0])
                    top2 = row(lam[1])
                    top3 = row(lam[2])
                    e = DUALS * s
                    q1 = wp.min(wp.max(q[i, g, e] + wp.cw_mul(sigma1, rho1), -top1), top1)
                    q2 = wp.min(wp.max(q[i, g, e + 1] + wp.cw_mul(sigma2, rho2), -top2), top2)
                    q3 = wp.min(wp.max(q[i, g, e + 2] + wp.cw_mul(sigma3, rho3), -top3), top3)
                    q[i, g, e] = q1
                    q[i, g, e + 1] = q2
                    q[i, g, e + 2] = q3
                    s0 += wp.cw_mul(q3 - q1, a1)
                    s1 += wp.cw_mul(-(q2 + q3), a3)
                    s2 += wp.cw_mul(q2, a8) - wp.cw_mul(q3, a5)
                    s3 += wp.cw_mul(q2, a9) - wp.cw_mul(q3, a6)
            # (data_grad[i, j] = from_vec4(...), each component stored on its own: see store_apart)
            for k in range(lanes):
                j = g * lanes + k
                if j < w:
                    store_apart(data_grad.ptr, wp.int64(i) * wp.int64(w) + wp.int64(j),
                                wp.vec4(s0[k], s1[k], s2[k], s3[k]), x_hat[i, j])

    return dual_data_step


#: The dual step on groups of :data:`DATA_LANES` pixels (the CPU).
dual_data_step = _dual_data_kernel(DATA_LANES)


@wp.kernel
def dual_data_step_pixel(
    row0: int,
    coef: wp.array3d(dtype=float),
    flags: wp.array3d(dtype=wp.int32),
    weights: wp.array(dtype=wp.vec3),
    grad_j2: wp.array3d(dtype=float),
    x_bar: wp.array2d(dtype=Any),
    x_hat: wp.array2d(dtype=Any),
    eps: float,
    step_ratio: float,
    lanes: int,
    # outputs
    q: wp.array3d(dtype=float),
    data_grad: wp.array2d(dtype=Any),
):
    """:data:`dual_data_step` a pixel per thread (CUDA's kernel), on lane storage of any
    ``lanes`` L seen as the float (and int32) arrays that :func:`data_coefficients` writes:
    value v of sample s at ``coef[i, j // L, (7 s + v) L + j % L]`` (module docstring).
    With L = :data:`CUDA_LANES`, the threads of a warp (consecutive pixels of a row) read
    and write consecutive addresses. The same float operations per pixel as the groups'
    kernel, so the same results. Launch over (rows, width)."""
    i, j = wp.tid()
    i = i + row0
    n = weights.shape[0]
    words = words_of(n)
    g = j // lanes
    lane = j - g * lanes
    d = to_vec4(x_bar[i, j]) - to_vec4(x_hat[i, j])
    gjx = grad_j2[i, g, lane]
    gjy = grad_j2[i, g, lanes + lane]
    s0 = float(0.0)
    s1 = float(0.0)
    s2 = float(0.0)
    s3 = float(0.0)
    for word in range(words):
        # the row flags of samples 31 word … 31 word + 30
        f1 = flags[i, g, word * lanes + lane]
        f2 = flags[i, g, (words + word) * lanes + lane]
        f3 = flags[i, g, (2 * words + word) * lanes + lane]
        for s in range(word * FLAG_BITS, wp.min(n, (word + 1) * FLAG_BITS)):
            bit = s - word * FLAG_BITS
            on1 = float((f1 >> bit) & 1)
            on2 = float((f2 >> bit) & 1)
            on3 = float((f3 >> bit) & 1)
            b = COEFFICIENTS * s * lanes + lane
            a1 = coef[i, g, b]
            a3 = coef[i, g, b + 2 * lanes]
            a5 = coef[i, g, b + 4 * lanes]
            a6 = coef[i, g, b + 5 * lanes]
            a8 = gjx - a5
            a9 = gjy - a6
            rho1 = coef[i, g, b + lanes] - a1 * d[0]
            rho2 = coef[i, g, b + 3 * lanes] - a3 * d[1] + a8 * d[2] + a9 * d[3]
            rho3 = coef[i, g, b + 6 * lanes] + a1 * d[0] - a3 * d[1] - a5 * d[2] - a6 * d[3]
            lam = weights[s]
            b1 = wp.abs(a1)
            b3 = wp.abs(a3)
            sigma1 = on1 * (lam[0] * lam[0] / ((lam[0] * b1 + eps) * step_ratio))
            sigma2 = on2 * (lam[1] * lam[1] / ((lam[1] * (b3 + wp.abs(a8) + wp.abs(a9)) + eps) * step_ratio))
            sigma3 = on3 * (lam[2] * lam[2] / ((lam[2] * (b1 + b3 + wp.abs(a5) + wp.abs(a6)) + eps) * step_ratio))
            e = DUALS * s * lanes + lane
            q1 = wp.min(wp.max(q[i, g, e] + sigma1 * rho1, -lam[0]), lam[0])
            q2 = wp.min(wp.max(q[i, g, e + lanes] + sigma2 * rho2, -lam[1]), lam[1])
            q3 = wp.min(wp.max(q[i, g, e + 2 * lanes] + sigma3 * rho3, -lam[2]), lam[2])
            q[i, g, e] = q1
            q[i, g, e + lanes] = q2
            q[i, g, e + 2 * lanes] = q3
            s0 += (q3 - q1) * a1
            s1 += -(q2 + q3) * a3
            s2 += q2 * a8 - q3 * a5
            s3 += q2 * a9 - q3 * a6
    data_grad[i, j] = from_vec4(wp.vec4(s0, s1, s2, s3), x_hat[i, j])


def data_lanes(device) -> int:
    """Pixels per group of the data term's storage on ``device``: :data:`DATA_LANES` on
    the CPU, :data:`CUDA_LANES` on CUDA."""
    return DATA_LANES if is_cpu(device) else CUDA_LANES


def pixelwise(lanes: int) -> bool:
    """Whether the data term's kernels for storage of ``lanes`` pixels a group take a
    pixel per thread (:func:`data_coefficients`, :func:`dual_data_step_pixel`, reading the
    float arrays) rather than a group per thread in vector registers (the CPU's
    :data:`DATA_LANES`)."""
    return lanes != DATA_LANES


def dual_data_kernel(lanes: int):
    """The dual step for storage of ``lanes`` pixels a group (:func:`pixelwise` says which
    arrays and launch it takes)."""
    return dual_data_step_pixel if pixelwise(lanes) else dual_data_step


# the kernels on the unknowns, for vec4 (δ1, δ2, u, v) and vec2 (u, v; flow only)
overload_unknowns(data_coefficients, "x_hat", "data_colsum")
overload_unknowns(dual_data_step, "x_bar", "x_hat", "data_grad")
overload_unknowns(dual_data_step_pixel, "x_bar", "x_hat", "data_grad")
