"""The data term's coefficients on the CPU, a group of pixels at once
(:data:`data_coefficients_groups`).

:func:`lfsf.kernels.data_term.data_coefficients` runs a thread per pixel. Here a thread
takes the :data:`~lfsf.kernels.data_term.DATA_LANES` pixels of one group of the lane
storage (the data term's module docstring) and computes what each sample's own tests
decide for all of them in loops over the lanes, which the CPU compiler turns into
vector code: the lookups at per-pixel positions as gathers, the coefficients, the row
flags and column sums, and the stores of the group's contiguous values. Each pixel's
arithmetic is the per-pixel kernel's, operation for operation, so the results are the
same bit for bit
(for finite inputs; where a NaN comes out, its sign bit may differ). What needs the
tests of all the samples, the best halves and the centre view at t2, also runs for all
the lanes at once; the second pass, where a pixel needs it, pixel by pixel.

Loops over a constant range stay loops in this module (``max_unroll`` 1): the compiler
vectorises a loop over the lanes, where Warp's unrolled copy of it becomes scalar code.
"""

from typing import Any

import warp as wp

from . import data_term
from .common import (HALF_PLANES, bilinear, bilinear_gradient, bilinear_taps, contiguous_row, cubic_value, float_run,
                     footprint, footprint_visible, from_vec4, half_plane_mask, inside, interior, lane_vector,
                     overload_unknowns, to_vec4)
from .data_term import (CENTRE_OCCLUSION_FACTOR, COEFFICIENTS, DATA_LANES, DUALS, FLAG_BITS, OCCLUSION_FLOOR,
                        flag_vector, pixel_coefficients, second_pass, words_of)

wp.set_module_options({"enable_backward": False, "max_unroll": 1})

#: A value for each pixel of a group.
lanes_f = lane_vector(DATA_LANES)
#: A row-flag word for each pixel of a group.
lanes_words = flag_vector(DATA_LANES)
#: Per-half-plane sums of a group: [half-plane, lane].
half_lanes = wp.types.matrix(shape=(HALF_PLANES, DATA_LANES), dtype=wp.float32)


@wp.func_native("""
#if !defined(__CUDA_ARCH__)
__builtin_prefetch((const char*)ptr + 4 * at, 0, 3);
#endif
""")
def prefetch(ptr: wp.uint64, at: wp.int64):
    """Ask the CPU to bring the float ``at`` of the memory at ``ptr`` into its caches (a
    hint: no fault anywhere, nothing on CUDA, where this module's kernels do not run)."""
    ...


#: How far ahead of a group's lookups (in floats, along the row) :func:`lookup_lanes` and
#: the visibility test ask for the rows they will read (:func:`prefetch`): a thread reads
#: about a hundred rows at once (four for each sample's lookup at t1 and t2, two for each
#: z-buffer), more than the CPU's own prefetchers follow; 1–3 ms of 40 at 640×480.
PREFETCH_AHEAD = wp.constant(32)


@wp.func
def lookup_lanes(img: wp.array2d(dtype=float), run: wp.array(dtype=float), x: lanes_f, y: lanes_f, cubic: int):
    """:func:`lfsf.kernels.common.lookup_with_gradient` of ``img`` (its memory as the
    1-D ``run``) at the group's positions: (values, ∂x, ∂y), the values Catmull–Rom's
    with ``cubic``. Every lane takes the interior formula at once (lanes outside the
    interior read at the safe position (1, 1), so the image needs at least 4 rows and 4
    columns), then the lanes within a pixel of a border, if any, the clamped functions.

    Where the group's lookups fall in one row, in consecutive columns (the pixels of a
    group warped by the same whole number of pixels: most groups, as δ and the flow
    vary slowly), each of the twelve taps (sixteen, cubic) is one contiguous load for all
    the lanes instead of a gather, which costs a load per lane (the gathers took most of
    the coefficients' time). The same pixels are read either way."""
    h = img.shape[0]
    w = img.shape[1]
    value = lanes_f()
    gx_out = lanes_f()
    gy_out = lanes_f()
    o = lanes_words()
    fx = lanes_f()
    fy = lanes_f()
    border = int(0)
    for f in range(DATA_LANES):
        inner = interior(x[f], y[f], h, w)
        xf = wp.where(inner, x[f], 1.0)
        yf = wp.where(inner, y[f], 1.0)
        j = int(xf)
        i = int(yf)
        o[f] = i * w + j
        fx[f] = xf - float(j)
        fy[f] = yf - float(i)
        border += wp.where(inner, 0, 1)
    o0 = o[0]
    ahead = wp.int64(o0 + PREFETCH_AHEAD)
    prefetch(run.ptr, ahead - wp.int64(w))
    prefetch(run.ptr, ahead)
    prefetch(run.ptr, ahead + wp.int64(w))
    prefetch(run.ptr, ahead + wp.int64(2 * w))
    apart = int(0)
    for f in range(DATA_LANES):
        apart += wp.where(o[f] == o0 + f, 0, 1)
    if apart == 0:
        # rows i − 1 … i + 2 over the columns the taps need (a lane outside the interior, read
        # at (1, 1) as in the gathers, can only be lane 0 here, and is redone below)
        up = float_run(run.ptr, wp.int64(o0 - w - 1), DATA_LANES + 3)
        mid = float_run(run.ptr, wp.int64(o0 - 1), DATA_LANES + 3)
        low = float_run(run.ptr, wp.int64(o0 + w - 1), DATA_LANES + 3)
        down = float_run(run.ptr, wp.int64(o0 + 2 * w - 1), DATA_LANES + 3)
        for f in range(DATA_LANES):
            v, gx, gy = bilinear_taps(mid[f], mid[f + 1], mid[f + 2], mid[f + 3], low[f], low[f + 1], low[f + 2],
                                      low[f + 3], up[f + 1], up[f + 2], down[f + 1], down[f + 2], fx[f], fy[f])
            value[f] = v
            gx_out[f] = gx
            gy_out[f] = gy
        if cubic != 0:
            for f in range(DATA_LANES):
                value[f] = cubic_value(wp.vec4(up[f], up[f + 1], up[f + 2], up[f + 3]),
                                       wp.vec4(mid[f], mid[f + 1], mid[f + 2], mid[f + 3]),
                                       wp.vec4(low[f], low[f + 1], low[f + 2], low[f + 3]),
                                       wp.vec4(down[f], down[f + 1], down[f + 2], down[f + 3]), fx[f], fy[f])
    else:
        for f in range(DATA_LANES):
            k = o[f]
            v, gx, gy = bilinear_taps(run[k - 1], run[k], run[k + 1], run[k + 2], run[k + w - 1], run[k + w],
                                      run[k + w + 1], run[k + w + 2], run[k - w], run[k - w + 1], run[k + 2 * w],
                                      run[k + 2 * w + 1], fx[f], fy[f])
            value[f] = v
            gx_out[f] = gx
            gy_out[f] = gy
        if cubic != 0:
            for f in range(DATA_LANES):
                k = o[f]
                value[f] = cubic_value(wp.vec4(run[k - w - 1], run[k - w], run[k - w + 1], run[k - w + 2]),
                                       wp.vec4(run[k - 1], run[k], run[k + 1], run[k + 2]),
                                       wp.vec4(run[k + w - 1], run[k + w], run[k + w + 1], run[k + w + 2]),
                                       wp.vec4(run[k + 2 * w - 1], run[k + 2 * w], run[k + 2 * w + 1],
                                               run[k + 2 * w + 2]), fx[f], fy[f])
    if border > 0:
        for f in range(DATA_LANES):
            if not interior(x[f], y[f], h, w):
                value[f] = bilinear(img, x[f], y[f])
                g = bilinear_gradient(img, x[f], y[f])
                gx_out[f] = g[0]
                gy_out[f] = g[1]
    return value, gx_out, gy_out


@wp.func
def store_lanes(ptr: wp.uint64, at: wp.int64, v: lanes_f):
    """The group's values v to floats ``at`` … of the memory at ``ptr``."""
    run = float_run(ptr, at, DATA_LANES)
    for f in range(DATA_LANES):
        run[f] = v[f]


@wp.func
def store_flags(ptr: wp.uint64, at: wp.int64, v: lanes_words):
    """The group's row-flag words v to the int32 ``at`` … of the memory at ``ptr``."""
    run = wp.array(ptr=ptr + wp.uint64(at * wp.int64(4)), shape=(DATA_LANES,), dtype=wp.int32)
    for f in range(DATA_LANES):
        run[f] = v[f]


@wp.func
def zero_left_out(ptr: wp.uint64, at: wp.int64, wt: lanes_f):
    """The scaled duals at floats ``at`` … set to 0 where the row weight w_k is 0."""
    run = float_run(ptr, at, DATA_LANES)
    for f in range(DATA_LANES):
        run[f] = wp.where(wt[f] <= 0.0, 0.0, run[f])


@wp.func
def visible_run(zbuf: wp.array(dtype=float), h: int, w: int, x: float, y: float, disparity: float, margin: float):
    """:func:`lfsf.kernels.common.visible` on one view z-buffer of h × w, stored as the
    1-D ``zbuf``."""
    i0, j0, i1, j1 = footprint(x, y, h, w)
    return footprint_visible(zbuf[i0 * w + j0], zbuf[i0 * w + j1], zbuf[i1 * w + j0], zbuf[i1 * w + j1], disparity,
                             margin)


@wp.func
def best_half_lanes(sums: half_lanes, counts: half_lanes, total: lanes_f, count: lanes_f, ratio: float):
    """:func:`lfsf.kernels.data_term.best_half` of every lane, operation for operation:
    (the best half's index as a float, −1 for none; the mean residual kept)."""
    best = lanes_f()
    best_mean = lanes_f()
    mean_all = lanes_f()
    for f in range(DATA_LANES):
        mean_all[f] = wp.where(count[f] > 0.0, total[f] / count[f], 0.0)
        best_mean[f] = mean_all[f]
        best[f] = -1.0
    for m in range(HALF_PLANES):
        for f in range(DATA_LANES):
            mean_m = sums[m, f] / counts[m, f]
            better = counts[m, f] > 0.0 and mean_m < best_mean[f]
            best_mean[f] = wp.where(better, mean_m, best_mean[f])
            best[f] = wp.where(better, float(m), best[f])
    kept = lanes_f()
    for f in range(DATA_LANES):
        tested = count[f] > 0.0 and ratio > 0.0
        rejected = best_mean[f] >= ratio * mean_all[f] or mean_all[f] - best_mean[f] < OCCLUSION_FLOOR
        found = tested and not rejected
        best[f] = wp.where(found, best[f], -1.0)
        kept[f] = wp.where(found, best_mean[f], mean_all[f])
    return best, kept


@wp.func
def group_coefficients(
    i: int,
    g: int,
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
    cubic: int,
    coef: wp.array3d(dtype=float),
    flags: wp.array3d(dtype=wp.int32),
    grad_j2: wp.array3d(dtype=float),
    data_colsum: Any,
    q: wp.array3d(dtype=float),
):
    """:func:`lfsf.kernels.data_term.data_coefficients` at the DATA_LANES pixels of group
    g of row i, all inside the row (the storage's lanes = DATA_LANES)."""
    lanes = DATA_LANES
    h = samples1.shape[1]
    w = samples1.shape[2]
    plane = wp.int64(h) * wp.int64(w)
    j0 = g * lanes
    d1 = lanes_f()
    d2 = lanes_f()
    px = lanes_f()
    py = lanes_f()
    xj = lanes_f()
    yj = lanes_f()
    hid = lanes_f()
    i1_run = contiguous_row(samples1, 0, i, j0, lanes)
    i1 = lanes_f()
    for f in range(DATA_LANES):
        xh = to_vec4(x_hat[i, j0 + f])
        d1[f] = xh[0]
        d2[f] = xh[1]
        px[f] = float(j0 + f)
        py[f] = float(i)
        xj[f] = px[f] + xh[2]
        yj[f] = py[f] + xh[3]
        i1[f] = i1_run[f]
        hid[f] = wp.where(hidden2[i, j0 + f] > 0.5, 1.0, 0.0)
    centre2 = samples2[0]
    j2, gjx, gjy = lookup_lanes(centre2, float_run(samples2.ptr, wp.int64(0), h * w), xj, yj, cubic)
    grad_run = float_run(grad_j2.ptr, (wp.int64(i) * wp.int64(grad_j2.shape[1]) + wp.int64(g))
                         * wp.int64(grad_j2.shape[2]), 2 * lanes)
    in_j0 = lanes_f()
    halves2 = lanes_f()
    any_halves = int(0)
    for f in range(DATA_LANES):
        grad_run[f] = gjx[f]
        grad_run[lanes + f] = gjy[f]
        in_j0[f] = wp.where(inside(centre2, xj[f], yj[f]), 1.0, 0.0)
        # (as the per-pixel kernel: the t2 halves decide something only through the centre test)
        halves = use_zbuf == 0 or (occlusion_ratio > 0.0 and wp.abs(i1[f] - j2[f]) > OCCLUSION_FLOOR)
        halves2[f] = wp.where(halves, 1.0, 0.0)
        any_halves += wp.where(halves, 1, 0)
    sums1 = half_lanes()
    counts1 = half_lanes()
    sums2 = half_lanes()
    counts2 = half_lanes()
    total1 = lanes_f()
    count1 = lanes_f()
    total2 = lanes_f()
    count2 = lanes_f()
    cs0 = lanes_f()
    cs1 = lanes_f()
    cs2 = lanes_f()
    cs3 = lanes_f()
    keep1 = lanes_f()
    keep2 = lanes_f()
    coef_at = (wp.int64(i) * wp.int64(coef.shape[1]) + wp.int64(g)) * wp.int64(coef.shape[2])
    q_at = (wp.int64(i) * wp.int64(q.shape[1]) + wp.int64(g)) * wp.int64(q.shape[2])
    flags_at = (wp.int64(i) * wp.int64(flags.shape[1]) + wp.int64(g)) * wp.int64(flags.shape[2])
    n = phis.shape[0]
    words = words_of(n)
    flag1 = lanes_words()
    flag2 = lanes_words()
    flag3 = lanes_words()
    for s in range(n):
        phi = phis[s]
        lam = weights[s]
        view1 = samples1[s]
        view2 = samples2[s]
        x1 = px - d1 * phi[0]
        y1 = py - d1 * phi[1]
        x2 = xj - d2 * phi[0]
        y2 = yj - d2 * phi[1]
        w1v, g1x, g1y = lookup_lanes(view1, float_run(samples1.ptr, wp.int64(s) * plane, h * w), x1, y1, cubic)
        w2v, g2x, g2y = lookup_lanes(view2, float_run(samples2.ptr, wp.int64(s) * plane, h * w), x2, y2, cubic)
        # residuals against the point's appearance at t1, per half of the samples (where needed)
        if s > 0 and any_halves > 0:
            mask = half_plane_mask(phi)
            for f in range(DATA_LANES):
                if halves2[f] > 0.0:
                    # (common.add_residual, in place)
                    if use_zbuf == 0 and inside(view1, x1[f], y1[f]):
                        e = wp.abs(w1v[f] - i1[f])
                        for k in range(HALF_PLANES):
                            sums1[k, f] = sums1[k, f] + e * mask[k]
                            counts1[k, f] = counts1[k, f] + mask[k]
                        total1[f] = total1[f] + e
                        count1[f] = count1[f] + 1.0
                    if inside(view2, x2[f], y2[f]):
                        e = wp.abs(w2v[f] - i1[f])
                        for k in range(HALF_PLANES):
                            sums2[k, f] = sums2[k, f] + e * mask[k]
                            counts2[k, f] = counts2[k, f] + mask[k]
                        total2[f] = total2[f] + e
                        count2[f] = count2[f] + 1.0
        # the rows that this sample's own tests keep: in the view and, with the view
        # z-buffers, seen (as common.visible, on the sample's z-buffers as 1-D runs)
        zrun1 = float_run(zbuf1.ptr, wp.int64(s) * plane, h * w)
        zrun2 = float_run(zbuf2.ptr, wp.int64(s) * plane, h * w)
        if use_zbuf != 0:  # (the rows of the z-buffer lookups below, ahead, as lookup_lanes does)
            z1 = wp.int64(int(y1[0]) * w + int(x1[0]) + PREFETCH_AHEAD)
            z2 = wp.int64(int(y2[0]) * w + int(x2[0]) + PREFETCH_AHEAD)
            prefetch(zrun1.ptr, z1)
            prefetch(zrun1.ptr, z1 + wp.int64(w))
            prefetch(zrun2.ptr, z2)
            prefetch(zrun2.ptr, z2 + wp.int64(w))
        for f in range(DATA_LANES):
            seen1 = bool(True)
            seen2 = bool(True)
            if use_zbuf != 0:
                seen1 = visible_run(zrun1, h, w, x1[f], y1[f], d1[f], margin)
                seen2 = visible_run(zrun2, h, w, x2[f], y2[f], d2[f], margin)
            in_1 = inside(view1, x1[f], y1[f]) and seen1
            in_2 = inside(view2, x2[f], y2[f]) and seen2 and (s > 0 or in_j0[f] > 0.0) and hid[f] == 0.0
            keep1[f] = wp.where(in_1, 1.0, 0.0)
            keep2[f] = wp.where(in_2, 1.0, 0.0)
        # the coefficients, the row weights and column sums (data_term.row_steps, operation
        # for operation), the stored values, the row flags and the duals of the rows left
        # out. (Stores in loops of their own: the compiler vectorises a loop that writes to
        # one run.)
        c0 = lanes_f()
        c2 = lanes_f()
        bit = wp.int32(1) << wp.int32(s % FLAG_BITS)
        wt1_f = lanes_f()
        wt2_f = lanes_f()
        wt3_f = lanes_f()
        for f in range(DATA_LANES):
            c0[f] = -(phi[0] * g1x[f] + phi[1] * g1y[f])
            c2[f] = -(phi[0] * g2x[f] + phi[1] * g2y[f])
            a1 = wp.abs(c0[f])
            a3 = wp.abs(c2[f])
            a5 = wp.abs(g2x[f])
            a6 = wp.abs(g2y[f])
            a8 = wp.abs(gjx[f] - g2x[f])
            a9 = wp.abs(gjy[f] - g2y[f])
            in_1 = keep1[f] > 0.0
            in_2 = keep2[f] > 0.0
            wt1 = wp.where(in_1, lam[0], 0.0)
            wt2 = wp.where(in_2 and in_j0[f] > 0.0, lam[1], 0.0)
            wt3 = wp.where(in_1 and in_2, lam[2], 0.0)
            flag1[f] = flag1[f] | wp.where(wt1 > 0.0, bit, wp.int32(0))
            flag2[f] = flag2[f] | wp.where(wt2 > 0.0, bit, wp.int32(0))
            flag3[f] = flag3[f] | wp.where(wt3 > 0.0, bit, wp.int32(0))
            cs0[f] = cs0[f] + (wt1 + wt3) * a1
            cs1[f] = cs1[f] + (wt2 + wt3) * a3
            cs2[f] = cs2[f] + (wt2 * a8 + wt3 * a5)
            cs3[f] = cs3[f] + (wt2 * a9 + wt3 * a6)
            wt1_f[f] = wt1
            wt2_f[f] = wt2
            wt3_f[f] = wt3
        at = coef_at + wp.int64(COEFFICIENTS * s * lanes)
        store_lanes(coef.ptr, at, c0)
        store_lanes(coef.ptr, at + wp.int64(lanes), i1 - w1v)
        store_lanes(coef.ptr, at + wp.int64(2 * lanes), c2)
        store_lanes(coef.ptr, at + wp.int64(3 * lanes), j2 - w2v)
        store_lanes(coef.ptr, at + wp.int64(4 * lanes), g2x)
        store_lanes(coef.ptr, at + wp.int64(5 * lanes), g2y)
        store_lanes(coef.ptr, at + wp.int64(6 * lanes), w1v - w2v)
        if s % FLAG_BITS == FLAG_BITS - 1 or s == n - 1:
            # a word of flags complete: stored, and the next one started
            word = wp.int64(s // FLAG_BITS)
            store_flags(flags.ptr, flags_at + word * wp.int64(lanes), flag1)
            store_flags(flags.ptr, flags_at + (wp.int64(words) + word) * wp.int64(lanes), flag2)
            store_flags(flags.ptr, flags_at + (wp.int64(2 * words) + word) * wp.int64(lanes), flag3)
            flag1 = lanes_words()
            flag2 = lanes_words()
            flag3 = lanes_words()
        qa = q_at + wp.int64(DUALS * s * lanes)
        zero_left_out(q.ptr, qa, wt1_f)
        zero_left_out(q.ptr, qa + wp.int64(lanes), wt2_f)
        zero_left_out(q.ptr, qa + wp.int64(2 * lanes), wt3_f)
    # the tests of all the samples (data_term.pixel_coefficients): the best halves and the
    # centre view at t2, for every lane at once; the second pass, where needed, pixel by pixel
    half1, kept1 = best_half_lanes(sums1, counts1, total1, count1, occlusion_ratio)
    half2, kept2 = best_half_lanes(sums2, counts2, total2, count2, occlusion_ratio)
    in_j = lanes_f()
    again = lanes_f()
    any_again = int(0)
    for f in range(DATA_LANES):
        centre_hidden = (occlusion_ratio > 0.0 and count2[f] > 0.0
                         and wp.abs(i1[f] - j2[f]) > CENTRE_OCCLUSION_FACTOR * kept2[f] + OCCLUSION_FLOOR)
        in_j[f] = wp.where(centre_hidden, 0.0, in_j0[f])
        second = (use_zbuf == 0 and (half1[f] >= 0.0 or half2[f] >= 0.0)) or (in_j0[f] > 0.0 and centre_hidden)
        again[f] = wp.where(second, 1.0, 0.0)
        any_again += wp.where(second, 1, 0)
    if any_again > 0:
        for f in range(DATA_LANES):
            if again[f] > 0.0:
                colsum = second_pass(i, j0 + f, g, f, lanes, to_vec4(x_hat[i, j0 + f]), int(half1[f]), int(half2[f]),
                                     in_j[f] > 0.0, hid[f] > 0.0, samples1, samples2, phis, weights, zbuf1, zbuf2,
                                     margin, use_zbuf, coef, flags, grad_j2, q)
                cs0[f] = colsum[0]
                cs1[f] = colsum[1]
                cs2[f] = colsum[2]
                cs3[f] = colsum[3]
    for f in range(DATA_LANES):
        j = j0 + f
        data_colsum[i, j] = from_vec4(wp.vec4(cs0[f], cs1[f], cs2[f], cs3[f]), x_hat[i, j])


@wp.kernel
def data_coefficients_groups(
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
    """:func:`lfsf.kernels.data_term.data_coefficients` (same arguments, same results bit
    for bit), a thread per group of ``lanes`` pixels: launch over (rows, ⌈columns /
    lanes⌉). A group of DATA_LANES pixels inside the row, on views of at least 4 rows,
    runs as vector code (:func:`group_coefficients`); other groups pixel by pixel. The
    sample stacks, the view z-buffers (when ``use_zbuf``) and the lane storage must be
    stored contiguously, and the z-buffers must have the sample stacks' shape."""
    i, g = wp.tid()
    i = i + row0
    h = samples1.shape[1]
    w = samples1.shape[2]
    j0 = g * lanes
    if lanes == DATA_LANES and j0 + lanes <= w and h >= 4:
        group_coefficients(i, g, samples1, samples2, phis, weights, x_hat, occlusion_ratio, hidden2, zbuf1, zbuf2,
                           margin, use_zbuf, cubic, coef, flags, grad_j2, data_colsum, q)
    else:
        for j in range(j0, wp.min(j0 + lanes, w)):
            pixel_coefficients(i, j, samples1, samples2, phis, weights, x_hat, occlusion_ratio, hidden2, zbuf1, zbuf2,
                               margin, use_zbuf, lanes, cubic, coef, flags, grad_j2, data_colsum, q)


overload_unknowns(data_coefficients_groups, "x_hat", "data_colsum")


def coefficients_kernel(width: int, lanes: int):
    """The data coefficients' kernel for lane storage of ``lanes`` pixels a group
    (:func:`lfsf.kernels.data_term.data_lanes` of the device) and the columns to launch it
    over, (kernel, columns), with rows as the first dimension: for groups (the CPU's
    storage, DATA_LANES) :data:`data_coefficients_groups` over ⌈width / lanes⌉ groups;
    for any other (CUDA's, :data:`lfsf.kernels.data_term.CUDA_LANES`) the per-pixel :func:`lfsf.kernels.data_term.data_coefficients` over
    ``width``, a thread per pixel, where the vector code would only take registers. Same
    arguments, same results."""
    if not data_term.pixelwise(lanes):
        return data_coefficients_groups, -(-int(width) // int(lanes))
    return data_term.data_coefficients, int(width)
