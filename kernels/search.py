"""Discrete disparity search (a plane sweep over the light field's samples), used to
start and to rescue the variational disparities where coarse-to-fine warping cannot
reach them: small objects vanish at coarse levels, and a disparity error e moves the
outer samples by R·e pixels, far outside the range of the linearisation.

For a disparity candidate δ the per-pixel matching cost of the samples s ≥ 1 is the mean
absolute difference of the warped samples to the centre view (the stereo residual ρ1,
or ρ2 at p + û); costs are then summed over a small window before the choice.

Two kinds of cost leave occluded samples out. The first needs nothing but the images: the
least mean over the halves of the samples (an occluder spoils the samples on its side).
Where the background has almost no texture it favours the foreground's disparity a few
pixels into the background (every half matches there, and the least of eight means is
lower than the mean of the one half that is free of the occluder). The second
(``*_visible``) asks view z-buffers made from a first estimate
(:func:`lfsf.kernels.occlusion.splat_views`) which samples a nearer point covers, and
takes the mean over the others.
"""

import warp as wp

from lfsf.device import is_cpu

from .common import (HALF_PLANES, bilinear, contiguous_row, float_run, footprint_visible, half_plane_mask,
                     half_plane_residuals, inside, lane_vector, least_half_mean, vec8, visible)
from .fusion import states_apart

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
        cost[k, i, j] = least_half_mean(sums, counts)


@wp.func
def visible_mean(samples: wp.array3d(dtype=float), phis: wp.array(dtype=wp.vec2), zbuf: wp.array3d(dtype=float),
                 qx: float, qy: float, disparity: float, centre: float, margin: float, zx: float, zy: float):
    """Mean |L(q − δφ_s, φ_s) − c| over the samples s ≥ 1 whose warped position lies in
    the image and is not covered by a nearer point (:func:`lfsf.kernels.common.visible`,
    the z-buffers read (``zx``, ``zy``) px further: a map's z-buffers read so are those of
    the map moved as a whole by (−zx, −zy), away from the image's edges); 1 where none is."""
    total = float(0.0)
    count = float(0.0)
    for s in range(1, phis.shape[0]):
        phi = phis[s]
        x = qx - disparity * phi[0]
        y = qy - disparity * phi[1]
        if inside(samples[s], x, y):
            if visible(zbuf, s, x + zx, y + zy, disparity, margin):
                total += wp.abs(bilinear(samples[s], x, y) - centre)
                count += 1.0
    c = float(1.0)
    if count > 0.0:
        c = total / count
    return c


@wp.kernel
def disparity_cost_visible(
    row0: int,
    samples: wp.array3d(dtype=float),
    phis: wp.array(dtype=wp.vec2),
    candidates: wp.array(dtype=float),
    base: wp.array2d(dtype=float),
    offset: wp.array2d(dtype=wp.vec4),
    zbuf: wp.array3d(dtype=float),
    margin: float,
    span: int,
    # outputs
    cost: wp.array3d(dtype=float),
):
    """cost[k, p] = :func:`visible_mean` at q = p + (u, v) of ``offset`` (components 2,
    3) for δ_k = candidates[k] + base[p] and c = L(q, 0): :func:`disparity_cost` with
    the samples a nearer point covers left out, by the view z-buffers ``zbuf`` (S, h, w)
    and ``margin`` instead of the best half. Launch over (candidates × rows, ⌈columns /
    span⌉) (:func:`lfsf.device.row_span`)."""
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
        centre = bilinear(samples[0], qx, qy)
        d = candidates[k] + base[i, j]
        cost[k, i, j] = visible_mean(samples, phis, zbuf, qx, qy, d, centre, margin, 0.0, 0.0)


@wp.kernel
def sample_half_planes(
    row0: int,
    phis: wp.array(dtype=wp.vec2),
    # outputs
    masks: wp.array(dtype=vec8),
):
    """masks[s] = the half-planes that hold φ_s (:func:`lfsf.kernels.common.half_plane_mask`).
    Launch over the samples."""
    s = wp.tid() + row0
    masks[s] = half_plane_mask(phis[s])


#: Columns one thread of the plane-sweep kernels walks on the CPU (:data:`sweep_cost`);
#: on CUDA a thread takes one pixel (:data:`sweep_cost_pixel`).
SWEEP_LANES = 64


def _plane_sweep_kernels(lanes: int):
    """The two plane-sweep cost kernels for threads of at most ``lanes`` consecutive
    columns of one candidate's row. Each sample's bilinear weights are the same for
    every pixel of a sweep, so a thread takes the samples in its outer loop and the
    columns in its inner one, and keeps per-column sums in vectors of ``lanes``: on the
    CPU (64 lanes) this ran 2.5× faster than the sample loop inside the pixel loop
    (640×480, 17 samples, 65 candidates: 1.97 → 0.77 s and 1.55 → 0.76 s). With one
    lane (CUDA) it is a thread per pixel, as before."""
    row = wp.types.vector(length=lanes, dtype=float)
    halves = wp.types.matrix(shape=(HALF_PLANES, lanes), dtype=float)

    @wp.func
    def shifted_residuals(samples: wp.array3d(dtype=float), s: int, i: int, j0: int, n: int, sh: wp.vec4):
        """|L(q + (a, b) + (f, g), φ_s) − L(q, 0)| at the columns j0 … j0 + n − 1 of row
        i, with sh = (a, b, f, g) (see :data:`sweep_cost`), and 1 where the position is
        inside the pixel centres (0 elsewhere, and beyond n)."""
        h = samples.shape[1]
        w = samples.shape[2]
        a = int(sh[0])
        y0 = i + int(sh[1])
        fx = sh[2]
        fy = sh[3]
        gx = 1.0 - fx
        gy = 1.0 - fy
        e = row()
        valid = row()
        if y0 >= 0 and (y0 < h - 1 or (y0 == h - 1 and fy == 0.0)):
            y1 = wp.min(y0 + 1, h - 1)
            lo = wp.max(0, -(j0 + a))
            hi = wp.min(n, w - 1 - (j0 + a))  # x0 ≤ w − 2: x0 + 1 is a column
            if lo == 0 and hi == lanes:
                # every lane inside: the same loop over a constant range, which the
                # compiler turns into vector code
                r0 = contiguous_row(samples, s, y0, j0 + a, lanes + 1)
                r1 = contiguous_row(samples, s, y1, j0 + a, lanes + 1)
                c = contiguous_row(samples, 0, i, j0, lanes)
                for jj in range(lanes):
                    top = gx * r0[jj] + fx * r0[jj + 1]
                    bottom = gx * r1[jj] + fx * r1[jj + 1]
                    e[jj] = wp.abs(gy * top + fy * bottom - c[jj])
                valid = row(1.0)
            else:
                for jj in range(lo, hi):
                    x0 = j0 + jj + a
                    top = gx * samples[s, y0, x0] + fx * samples[s, y0, x0 + 1]
                    bottom = gx * samples[s, y1, x0] + fx * samples[s, y1, x0 + 1]
                    e[jj] = wp.abs(gy * top + fy * bottom - samples[0, i, j0 + jj])
                    valid[jj] = 1.0
            # x0 = w − 1 exactly (no fraction): the last column
            last = w - 1 - (j0 + a)
            if fx == 0.0 and last >= 0 and last < n:
                e[last] = wp.abs(gy * samples[s, y0, w - 1] + fy * samples[s, y1, w - 1] - samples[0, i, j0 + last])
                valid[last] = 1.0
        return e, valid

    @wp.kernel
    def sweep_cost(
        row0: int,
        samples: wp.array3d(dtype=float),
        shifts: wp.array2d(dtype=wp.vec4),
        masks: wp.array(dtype=vec8),
        span: int,
        # outputs
        cost: wp.array3d(dtype=float),
    ):
        """:func:`disparity_cost` of a plane sweep (no base disparity, no flow offset),
        where each sample's warped position moves by a constant: q − δ_k φ_s = q + (a, b)
        + (f, g) with whole (a, b) and fractions (f, g) ∈ [0, 1) given per candidate and
        sample as ``shifts[k, s]`` = (a, b, f, g), and the half-planes holding φ_s as
        ``masks[s]`` (:func:`lfsf.kernels.common.half_plane_mask`). The bilinear weights
        are then the same for every pixel. ``samples`` must be stored contiguously
        (:func:`contiguous_row`). Launch over (candidates × rows, ⌈columns / span⌉),
        span ≤ the kernel's lanes."""
        r, c0 = wp.tid()
        r = r + row0
        h = cost.shape[1]
        w = cost.shape[2]
        k = r // h
        i = r - k * h
        j0 = c0 * span
        n = wp.min(wp.min(span, lanes), w - j0)  # (span ≤ lanes: columns beyond are left alone)
        sums = halves()
        counts = halves()
        for s in range(1, samples.shape[0]):
            e, valid = shifted_residuals(samples, s, i, j0, n, shifts[k, s])
            mask = masks[s]
            for m in range(HALF_PLANES):
                if mask[m] > 0.0:
                    sums[m] = sums[m] + e
                    counts[m] = counts[m] + valid
        # per column, :func:`least_half_mean` of its eight half-plane sums and counts: the
        # half-planes in the outer loop and the columns in the inner one, which the compiler
        # turns into vector code (the same operations per column, in the same order)
        best = row(1.0)
        for m in range(HALF_PLANES):
            sm = sums[m]
            cm = counts[m]
            for jj in range(lanes):
                best[jj] = wp.where(cm[jj] > 0.0, wp.min(best[jj], sm[jj] / cm[jj]), best[jj])
        for jj in range(n):
            cost[k, i, j0 + jj] = best[jj]

    @wp.kernel
    def sweep_cost_visible(
        row0: int,
        samples: wp.array3d(dtype=float),
        shifts: wp.array2d(dtype=wp.vec4),
        candidates: wp.array(dtype=float),
        zbuf: wp.array3d(dtype=float),
        margin: float,
        span: int,
        # outputs
        cost: wp.array3d(dtype=float),
    ):
        """:func:`disparity_cost_visible` of a plane sweep (no base disparity, no flow
        offset), with the constant shifts of :data:`sweep_cost`: the mean residual of the
        samples s ≥ 1 inside the image that no point nearer than δ_k + ``margin`` covers
        (view z-buffers ``zbuf``, :func:`lfsf.kernels.common.visible`: the pixels the
        lookup reads, here at a constant shift too); 1 where none is. ``samples`` and
        ``zbuf`` must be stored contiguously (:func:`contiguous_row`). Launch over
        (candidates × rows, ⌈columns / span⌉), span ≤ the kernel's lanes."""
        r, c0 = wp.tid()
        r = r + row0
        h = cost.shape[1]
        w = cost.shape[2]
        k = r // h
        i = r - k * h
        j0 = c0 * span
        n = wp.min(wp.min(span, lanes), w - j0)  # (span ≤ lanes: columns beyond are left alone)
        d = candidates[k]
        total = row()
        count = row()
        for s in range(1, samples.shape[0]):
            sh = shifts[k, s]
            e, valid = shifted_residuals(samples, s, i, j0, n, sh)
            # the pixels the lookup reads with non-zero weight (visible): rows ya, yb
            ya = wp.clamp(i + int(sh[1]), 0, h - 1)
            yb = wp.clamp(i + int(sh[1]) + wp.where(sh[3] > 0.0, 1, 0), 0, h - 1)
            xa = j0 + int(sh[0])
            xb = xa + wp.where(sh[2] > 0.0, 1, 0)
            # every lane, without a branch (vector code); those past the n columns, whose
            # reads are clamped, are zeroed by ``valid``
            seen = row()
            if xa >= 0 and xb + lanes <= w:
                # no column to clamp: the reads are consecutive in every lane
                za = contiguous_row(zbuf, s, ya, xa, lanes + 1)
                zb = contiguous_row(zbuf, s, yb, xa, lanes + 1)
                dx = xb - xa
                for jj in range(lanes):
                    seen[jj] = wp.where(footprint_visible(za[jj], za[jj + dx], zb[jj], zb[jj + dx], d, margin),
                                        1.0, 0.0)
            else:
                for jj in range(lanes):
                    ca = wp.clamp(xa + jj, 0, w - 1)
                    cb = wp.clamp(xb + jj, 0, w - 1)
                    seen[jj] = wp.where(footprint_visible(zbuf[s, ya, ca], zbuf[s, ya, cb], zbuf[s, yb, ca],
                                                          zbuf[s, yb, cb], d, margin), 1.0, 0.0)
            seen = wp.cw_mul(seen, valid)
            total = total + wp.cw_mul(seen, e)
            count = count + seen
        for jj in range(n):
            c = float(1.0)
            if count[jj] > 0.0:
                c = total[jj] / count[jj]
            cost[k, i, j0 + jj] = c

    return sweep_cost, sweep_cost_visible


#: The plane-sweep costs, walking up to :data:`SWEEP_LANES` columns per thread (CPU).
sweep_cost, sweep_cost_visible = _plane_sweep_kernels(SWEEP_LANES)
#: The same with one column per thread (CUDA).
sweep_cost_pixel, sweep_cost_visible_pixel = _plane_sweep_kernels(1)


def sweep_kernels(device: str):
    """(half-plane kernel, visibility kernel, columns per thread) of the plane sweep for a
    device: :data:`SWEEP_LANES` columns on the CPU, one on CUDA."""
    if is_cpu(device):
        return sweep_cost, sweep_cost_visible, SWEEP_LANES
    return sweep_cost_pixel, sweep_cost_visible_pixel, 1


@wp.func
def window_column(values: wp.array3d(dtype=float), k: int, i: int, j: int):
    """values[k] at rows i − 1, i, i + 1 of column j, clamped to the slice."""
    h = values.shape[1]
    w = values.shape[2]
    jc = wp.clamp(j, 0, w - 1)
    return wp.vec3(values[k, wp.max(i - 1, 0), jc], values[k, i, jc], values[k, wp.min(i + 1, h - 1), jc])


#: Columns the window filters take at once where the window needs no clamped column: the
#: same sums in the same order over a constant range, which the compiler turns into
#: vector code (the rows must be stored contiguously, :func:`contiguous_row`).
BOX_LANES = 32
box_row = lane_vector(BOX_LANES)


@wp.func
def window_runs(values: wp.array3d(dtype=float), k: int, i: int, j: int):
    """Rows i − 1, i, i + 1 of slice k (clamped to the slice) from column j − 1, BOX_LANES
    + 2 floats each (:func:`contiguous_row`)."""
    n = BOX_LANES + 2
    return (contiguous_row(values, k, wp.max(i - 1, 0), j - 1, n), contiguous_row(values, k, i, j - 1, n),
            contiguous_row(values, k, wp.min(i + 1, values.shape[1] - 1), j - 1, n))


@wp.func
def box_run_fits(j: int, end: int, w: int):
    """BOX_LANES columns from column j lie before ``end`` (the thread's span) and no column
    of their 3×3 windows is clamped."""
    return j >= 1 and j + BOX_LANES <= end and j + BOX_LANES <= w - 1


@wp.func
def window_columns(values: wp.array3d(dtype=float), k: int, i: int, j: int):
    """:func:`window_column` at columns j − 1, j and j + 1."""
    return window_column(values, k, i, j - 1), window_column(values, k, i, j), window_column(values, k, i, j + 1)


@wp.func
def store_box_row(out: wp.array3d(dtype=float), k: int, i: int, j: int, v: box_row):
    run = contiguous_row(out, k, i, j, BOX_LANES)
    for jj in range(BOX_LANES):
        run[jj] = v[jj]


def _box_kernels(vector: bool):
    """:data:`box_sum` and :data:`box_min`, with the runs of BOX_LANES columns as vector
    code (``vector``: the CPU's, where a thread walks a row) or pixel by pixel only (CUDA,
    a thread per pixel, where the runs never fit but their code would take registers)."""

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
        (slices × rows, ⌈columns / span⌉) (:func:`lfsf.device.row_span`). For r = 1 (the
        default search radius) a thread takes BOX_LANES columns at once where no column of
        their windows is clamped (vector code; ``values`` and ``out`` must be stored
        contiguously, with the same shape), the sum in the same order as pixel by pixel."""
        r, c = wp.tid()
        r = r + row0
        h = values.shape[1]
        w = values.shape[2]
        k = r // h
        i = r - k * h
        side = float(2 * radius + 1)
        j0 = c * span
        if radius == 1:
            end = wp.min(w, j0 + span)
            j = j0
            while j < end:
                if wp.static(vector) and box_run_fits(j, end, w):
                    # BOX_LANES columns at once, as vectors: the same sums in the same order
                    a, b, d = window_runs(values, k, i, j)
                    v = box_row()
                    for jj in range(BOX_LANES):
                        v[jj] = (a[jj] + a[jj + 1] + a[jj + 2] + b[jj] + b[jj + 1] + b[jj + 2] + d[jj] + d[jj + 1]
                                 + d[jj + 2]) / 9.0
                    store_box_row(out, k, i, j, v)
                    j += BOX_LANES
                else:
                    left, mid, right = window_columns(values, k, i, j)
                    acc = left[0] + mid[0] + right[0] + left[1] + mid[1] + right[1] + left[2] + mid[2] + right[2]
                    out[k, i, j] = acc / 9.0
                    j += 1
        else:
            for j in range(j0, wp.min(w, j0 + span)):
                acc = float(0.0)
                for dy in range(-radius, radius + 1):
                    for dx in range(-radius, radius + 1):
                        acc += values[k, wp.clamp(i + dy, 0, h - 1), wp.clamp(j + dx, 0, w - 1)]
                out[k, i, j] = acc / (side * side)


    @wp.kernel
    def box_min(
        row0: int,
        values: wp.array3d(dtype=float),
        radius: int,
        span: int,
        # outputs
        out: wp.array3d(dtype=float),
    ):
        """Least value of each slice over a (2r+1)² window, clamped at the borders: after
        :func:`box_sum`, the cost of the best of the windows that hold the pixel (shiftable
        windows). Launch over (slices × rows, ⌈columns / span⌉). For r = 1, BOX_LANES
        columns at once where they fit, as in :func:`box_sum`: ``values`` and ``out`` must be
        stored contiguously, with the same shape."""
        r, c = wp.tid()
        r = r + row0
        h = values.shape[1]
        w = values.shape[2]
        k = r // h
        i = r - k * h
        j0 = c * span
        if radius == 1:
            end = wp.min(w, j0 + span)
            j = j0
            while j < end:
                if wp.static(vector) and box_run_fits(j, end, w):
                    # BOX_LANES columns at once, as vectors: the same minima in the same order
                    a, b, d = window_runs(values, k, i, j)
                    v = box_row()
                    for jj in range(BOX_LANES):
                        v[jj] = wp.min(wp.min(wp.min(wp.vec3(a[jj], b[jj], d[jj])), wp.min(wp.vec3(a[jj + 1], b[jj + 1],
                                                                                                  d[jj + 1]))),
                                       wp.min(wp.vec3(a[jj + 2], b[jj + 2], d[jj + 2])))
                    store_box_row(out, k, i, j, v)
                    j += BOX_LANES
                else:
                    left, mid, right = window_columns(values, k, i, j)
                    out[k, i, j] = wp.min(wp.min(wp.min(left), wp.min(mid)), wp.min(right))
                    j += 1
        else:
            for j in range(j0, wp.min(w, j0 + span)):
                m = values[k, i, j]
                for dy in range(-radius, radius + 1):
                    for dx in range(-radius, radius + 1):
                        m = wp.min(m, values[k, wp.clamp(i + dy, 0, h - 1), wp.clamp(j + dx, 0, w - 1)])
                out[k, i, j] = m

    return box_sum, box_min


#: The window filters with their vector runs (the CPU) …
box_sum, box_min = _box_kernels(True)
#: … and pixel by pixel only (CUDA).
box_sum_pixel, box_min_pixel = _box_kernels(False)


def box_kernels(device: str):
    """(:data:`box_sum`, :data:`box_min`) for a device: with vector runs on the CPU, pixel
    by pixel on CUDA."""
    if is_cpu(device):
        return box_sum, box_min
    return box_sum_pixel, box_min_pixel


@wp.func
def parabola_vertex(left: float, centre: float, right: float):
    """The vertex of the parabola through (−1, left), (0, centre), (1, right), in steps
    from the middle sample; 0 where the parabola is not convex."""
    curv = left - 2.0 * centre + right
    offset = float(0.0)
    if curv > 1.0e-12:
        offset = 0.5 * (left - right) / curv
    return offset


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
    and its neighbours (candidates evenly spaced). Ties go to the candidate nearest
    zero (then the first): on an exactly flat region every candidate ties, and the first
    had made the searched disparity there −range (a textureless half-image rendered
    without noise, `paper` preset at 160×120: δ1 MSE 0.388, now 0.069; 0.051 with noise
    of 10⁻⁶, where no two costs tie). Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    n = cost.shape[0]
    kmin = int(0)
    cmin = cost[0, i, j]
    for k in range(1, n):
        c = cost[k, i, j]
        if c < cmin or (c == cmin and wp.abs(candidates[k]) < wp.abs(candidates[kmin])):
            cmin = c
            kmin = k
    d = candidates[kmin]
    if kmin > 0 and kmin < n - 1:
        step = candidates[kmin + 1] - candidates[kmin]
        d = d + parabola_vertex(cost[kmin - 1, i, j], cmin, cost[kmin + 1, i, j]) * step
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
def surface_block_cost(
    row0: int,
    centre1: wp.array2d(dtype=float),
    centre2: wp.array2d(dtype=float),
    x: wp.array2d(dtype=wp.vec4),
    radius: int,
    tolerance: float,
    # outputs
    cost: wp.array2d(dtype=float),
):
    """cost(p) = the mean of |I1(q) − I2(q + (u, v)(p))| over the pixels q of the
    (2r+1)² window at p (clamped to the image) on p's surface, |δ1(q) − δ1(p)| ≤
    ``tolerance`` (δ1, u, v: components 0, 2, 3 of x), each term 1 where q + (u, v)
    leaves the image: how well p's flow, moved as a block, explains its own surface
    around it. The window's pixels of another surface are left out, so a rim is judged
    by its own texture. Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    h = x.shape[0]
    w = x.shape[1]
    v = x[i, j]
    acc = float(0.0)
    n = float(0.0)
    for ii in range(wp.max(i - radius, 0), wp.min(i + radius + 1, h)):
        for jj in range(wp.max(j - radius, 0), wp.min(j + radius + 1, w)):
            if wp.abs(x[ii, jj][0] - v[0]) <= tolerance:
                qx = float(jj) + v[2]
                qy = float(ii) + v[3]
                value = float(1.0)
                if inside(centre2, qx, qy):
                    value = wp.abs(centre1[ii, jj] - bilinear(centre2, qx, qy))
                acc += value
                n += 1.0
    cost[i, j] = acc / n


@wp.func
def gradient_norm(image: wp.array2d(dtype=float), i: int, j: int):
    """|∇I| at pixel (i, j): central differences, one-sided on the border (NumPy's
    ``gradient``)."""
    h = image.shape[0]
    w = image.shape[1]
    j0 = wp.max(j - 1, 0)
    j1 = wp.min(j + 1, w - 1)
    i0 = wp.max(i - 1, 0)
    i1 = wp.min(i + 1, h - 1)
    gx = float(0.0)
    gy = float(0.0)
    if j1 > j0:
        gx = (image[i, j1] - image[i, j0]) / float(j1 - j0)
    if i1 > i0:
        gy = (image[i1, j] - image[i0, j]) / float(i1 - i0)
    return wp.sqrt(gx * gx + gy * gy)


@wp.kernel
def cost_above(
    row0: int,
    cost: wp.array2d(dtype=float),
    centre: wp.array2d(dtype=float),
    slope: float,
    above: float,
    x: wp.array2d(dtype=wp.vec4),
    margin: float,
    # outputs
    out: wp.array2d(dtype=float),
):
    """out = 1 where cost(p) > ``slope`` · ḡ(p) + ``above``, else 0; ḡ the mean of
    |∇I| (:func:`gradient_norm`) of ``centre`` over the 3 × 3 pixels at p (clamped to
    the image). A block residual that a flow ``slope`` px off would leave grows with
    the texture's gradient; above it, the flow is further off, or matches nothing.
    With ``margin`` ≥ 0, 0 also where p + (u, v) of x (components 2, 3) lies less than
    ``margin`` px inside the image's outer pixel centres, or outside: there the block
    residual holds terms that leave the image. Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    h = cost.shape[0]
    w = cost.shape[1]
    limit = above
    if slope != 0.0:
        g = float(0.0)
        for di in range(-1, 2):
            for dj in range(-1, 2):
                g += gradient_norm(centre, wp.clamp(i + di, 0, h - 1), wp.clamp(j + dj, 0, w - 1))
        limit += slope * g / 9.0
    flag = cost[i, j] > limit
    if margin >= 0.0:
        v = x[i, j]
        qx = float(j) + v[2]
        qy = float(i) + v[3]
        if qx < margin or qy < margin or qx > float(w - 1) - margin or qy > float(h - 1) - margin:
            flag = False
    out[i, j] = wp.where(flag, 1.0, 0.0)


#: The largest window radius of :func:`flow_search` (its ring buffer of column sums).
MAX_SEARCH_RADIUS = wp.constant(5)
vec11 = wp.types.vector(length=11, dtype=wp.float32)
#: :func:`flow_search`'s runner-up cost where it has none (float32's largest finite value).
NO_COST = wp.constant(3.4e38)


@wp.func
def grid_apart(k: int, m: int, side: int, distance: int):
    """Whether shifts k and m of a side × side grid (k = row·side + column) lie at least
    ``distance`` steps apart along either axis."""
    ky = k // side
    my = m // side
    return wp.abs(ky - my) >= distance or wp.abs((k - ky * side) - (m - my * side)) >= distance


@wp.func
def shifted_cost(centre1: wp.array2d(dtype=float), centre2: wp.array2d(dtype=float), i: int, j: int, dx: int,
                 dy: int):
    """|I1(p) − I2(p + (dx, dy))| at pixel p = (i, j) for a whole-pixel shift; 1 where
    p + (dx, dy) leaves the image (as :func:`flow_cost`)."""
    y = i + dy
    x = j + dx
    value = float(1.0)
    if x >= 0 and y >= 0 and x < centre2.shape[1] and y < centre2.shape[0]:
        value = wp.abs(centre1[i, j] - centre2[y, x])
    return value


@wp.func
def column_cost(centre1: wp.array2d(dtype=float), centre2: wp.array2d(dtype=float), i: int, j: int, dx: int,
                dy: int, radius: int):
    """Σ over the window's column at (clamped) column j: Σ_t cost(clamp(i + t), j)."""
    h = centre1.shape[0]
    w = centre1.shape[1]
    jc = wp.clamp(j, 0, w - 1)
    acc = float(0.0)
    for t in range(-radius, radius + 1):
        acc += shifted_cost(centre1, centre2, wp.clamp(i + t, 0, h - 1), jc, dx, dy)
    return acc


@wp.func
def window_shift_cost(centre1: wp.array2d(dtype=float), centre2: wp.array2d(dtype=float), i: int, j: int,
                      dx: int, dy: int, radius: int):
    """The mean of :func:`shifted_cost` over the (2r+1)² window at p, clamped at the
    borders (as :func:`box_sum` of :func:`flow_cost`), summed column by column."""
    acc = float(0.0)
    for t in range(-radius, radius + 1):
        acc += column_cost(centre1, centre2, i, j + t, dx, dy, radius)
    n = float(2 * radius + 1)
    return acc / (n * n)


@wp.func
def keep_best(k: int, value: float, i: int, j: int, side: int, distance: int, best_cost: wp.array2d(dtype=float),
              best_k: wp.array2d(dtype=int), second_cost: wp.array2d(dtype=float), second_k: wp.array2d(dtype=int)):
    """The update of the best shift and the runner-up (one ``distance`` or more apart on
    the grid of shifts) at (i, j) by shift k's ``value`` (:func:`flow_search`,
    :func:`flow_search_rows`)."""
    if k == 0:
        best_cost[i, j] = value
        best_k[i, j] = k
        second_cost[i, j] = NO_COST
        second_k[i, j] = -1
    elif value < best_cost[i, j]:
        kb = best_k[i, j]
        if grid_apart(k, kb, side, distance):
            second_cost[i, j] = best_cost[i, j]
            second_k[i, j] = kb
        elif second_k[i, j] >= 0 and not grid_apart(k, second_k[i, j], side, distance):
            second_cost[i, j] = NO_COST
            second_k[i, j] = -1
        best_cost[i, j] = value
        best_k[i, j] = k
    elif value < second_cost[i, j] and grid_apart(k, best_k[i, j], side, distance):
        second_cost[i, j] = value
        second_k[i, j] = k


@wp.func
def refined_shift(centre1: wp.array2d(dtype=float), centre2: wp.array2d(dtype=float), i: int, j: int, kmin: int,
                  cmin: float, half: int, radius: int):
    """The best shift k (of cost ``cmin``) at (i, j) as (dx, dy), each refined by the
    parabola through its neighbours' costs where it has both (:func:`flow_search`)."""
    side = 2 * half + 1
    ky = kmin // side
    kx = kmin - ky * side
    dx = float(kx - half)
    dy = float(ky - half)
    if kx > 0 and kx < side - 1:
        dx = dx + parabola_vertex(window_shift_cost(centre1, centre2, i, j, kx - 1 - half, ky - half, radius), cmin,
                                  window_shift_cost(centre1, centre2, i, j, kx + 1 - half, ky - half, radius))
    if ky > 0 and ky < side - 1:
        dy = dy + parabola_vertex(window_shift_cost(centre1, centre2, i, j, kx - half, ky - 1 - half, radius), cmin,
                                  window_shift_cost(centre1, centre2, i, j, kx - half, ky + 1 - half, radius))
    return wp.vec2(dx, dy)


@wp.kernel
def flow_search(
    row0: int,
    centre1: wp.array2d(dtype=float),
    centre2: wp.array2d(dtype=float),
    half: int,
    radius: int,
    distance: int,
    span: int,
    # outputs
    best_cost: wp.array2d(dtype=float),
    best_k: wp.array2d(dtype=int),
    best: wp.array2d(dtype=wp.vec2),
    second_cost: wp.array2d(dtype=float),
    second_k: wp.array2d(dtype=int),
):
    """Whole-pixel block matching without a cost volume: for every shift of the
    (2n+1)² grid (k = (dy+n)(2n+1) + (dx+n), n = ``half``) the windowed mean of
    |I1(p) − I2(p + (dx, dy))| over (2r+1)² (r = ``radius`` ≤ MAX_SEARCH_RADIUS, clamped
    at the borders), the first minimum kept per pixel, then each axis refined by the
    parabola through the minimum and its two neighbours: the same as :func:`flow_cost`,
    :func:`box_sum` and :func:`select_flow` in turn. Each thread walks ``span`` pixels
    of a row, the window's column sums kept in a ring so that each is computed once
    per shift. Launch over (rows, ⌈columns / span⌉) (:func:`lfsf.device.row_span`).

    Alongside, in the same pass, the runner-up of another place: the least cost (and its
    k) among the shifts at least ``distance`` steps (along either axis) from the best so
    far. When a new best arrives, the old one becomes the runner-up if it lies that far
    away; a runner-up that the new best lies closer to than ``distance`` is dropped (3.4e38
    and k = −1 until another comes), so the value may be higher than the least over all
    the far shifts of the final best, never lower. A runner-up close to the best marks a
    match that is not unique (a periodic texture, a flat region; ``lfsf.estimate``)."""
    i, c = wp.tid()
    i = i + row0
    w = centre1.shape[1]
    side = 2 * half + 1
    n = 2 * radius + 1
    area = float(n * n)
    j0 = c * span
    j1 = wp.min(w, j0 + span)
    for k in range(side * side):
        sy = k // side - half
        sx = k - (k // side) * side - half
        ring = vec11()
        # the ring holds the column sums of columns j − r … j + r at slot (column + r) mod n;
        # the slots stepped on, not taken mod n (an integer division each: 6 of them per
        # pixel and shift had been most of the kernel's time)
        slot = (j0 + n) % n  # column j0 − r's
        for t in range(-radius, radius):
            ring[slot] = column_cost(centre1, centre2, i, j0 + t, sx, sy, radius)
            slot = wp.where(slot == n - 1, 0, slot + 1)
        first = j0 % n  # the slot of column j − r, the window's first
        for j in range(j0, j1):
            ring[slot] = column_cost(centre1, centre2, i, j + radius, sx, sy, radius)
            slot = wp.where(slot == n - 1, 0, slot + 1)
            acc = float(0.0)
            at = first
            for t in range(n):
                acc += ring[at]
                at = wp.where(at == n - 1, 0, at + 1)
            first = wp.where(first == n - 1, 0, first + 1)
            keep_best(k, acc / area, i, j, side, distance, best_cost, best_k, second_cost, second_k)
    for j in range(j0, j1):
        best[i, j] = refined_shift(centre1, centre2, i, j, best_k[i, j], best_cost[i, j], half, radius)


#: Columns :func:`flow_search_rows` takes at once (constant-length loops: vector code).
SEARCH_CHUNK = wp.constant(16)
vec16 = wp.types.vector(length=16, dtype=wp.float32)


@wp.func
def add_shifted_column(centre1: wp.array2d(dtype=float), centre2: wp.array2d(dtype=float), out: wp.array(dtype=float),
                       q: int, yc: int, y: int, jj: int, sx: int, h: int, w: int):
    """out[q] += :func:`shifted_cost` at row ``yc`` (its t2 row ``y``) of the clamped column ``jj``."""
    jc = wp.clamp(jj, 0, w - 1)
    x = jc + sx
    v = float(1.0)
    if x >= 0 and y >= 0 and x < w and y < h:
        v = wp.abs(centre1[yc, jc] - centre2[y, x])
    out[q] = out[q] + v


@wp.func
def row_column_costs(centre1: wp.array2d(dtype=float), centre2: wp.array2d(dtype=float), colc: wp.array2d(dtype=float),
                     i: int, sx: int, sy: int, radius: int):
    """colc[i, jj + r] = :func:`column_cost` (i, jj, sx, sy, r) of every column jj of
    −r … w − 1 + r: the same terms added in the same order (t = −r … r), the columns whose
    t2 pixel lies inside without clamping in chunks of SEARCH_CHUNK."""
    h = centre1.shape[0]
    w = centre1.shape[1]
    r = radius
    cw = w + 2 * r
    base = wp.int64(i) * wp.int64(colc.shape[1])
    out = float_run(colc.ptr, base, cw)
    for q in range(cw):
        out[q] = 0.0
    # columns lo … hi − 1: unclamped, their t2 pixel inside; none where |sx| ≥ w (a shift
    # of more than the width, on views taller than wide: lo had passed w, and the clamped
    # columns' loop written past the row's end)
    lo = wp.min(wp.max(0, -sx), w)
    hi = wp.min(w, w - sx)
    if hi < lo:
        hi = lo
    for t in range(-r, r + 1):
        yc = wp.clamp(i + t, 0, h - 1)
        y = yc + sy
        if y < 0 or y >= h:
            for q in range(cw):
                out[q] = out[q] + 1.0
        else:
            for q in range(0, lo + r):
                add_shifted_column(centre1, centre2, out, q, yc, y, q - r, sx, h, w)
            for q in range(hi + r, cw):
                add_shifted_column(centre1, centre2, out, q, yc, y, q - r, sx, h, w)
            m = hi - lo
            chunks = m // SEARCH_CHUNK
            a_at = wp.int64(yc) * wp.int64(w) + wp.int64(lo)
            b_at = wp.int64(y) * wp.int64(w) + wp.int64(lo + sx)
            o_at = base + wp.int64(lo + r)
            for c in range(chunks):
                at = wp.int64(c * SEARCH_CHUNK)
                ca = float_run(centre1.ptr, a_at + at, SEARCH_CHUNK)
                cb = float_run(centre2.ptr, b_at + at, SEARCH_CHUNK)
                co = float_run(colc.ptr, o_at + at, SEARCH_CHUNK)
                for x in range(SEARCH_CHUNK):
                    co[x] = co[x] + wp.abs(ca[x] - cb[x])
            for jj in range(lo + chunks * SEARCH_CHUNK, hi):
                add_shifted_column(centre1, centre2, out, jj + r, yc, y, jj, sx, h, w)


@wp.kernel
def flow_search_rows(
    row0: int,
    centre1: wp.array2d(dtype=float),
    centre2: wp.array2d(dtype=float),
    half: int,
    radius: int,
    distance: int,
    colc: wp.array2d(dtype=float),
    # outputs
    best_cost: wp.array2d(dtype=float),
    best_k: wp.array2d(dtype=int),
    best: wp.array2d(dtype=wp.vec2),
    second_cost: wp.array2d(dtype=float),
    second_k: wp.array2d(dtype=int),
):
    """:func:`flow_search` with a thread per row (the CPU's): per shift, the row's column
    sums (:func:`row_column_costs`, into ``colc``, (rows, columns + 2r) scratch stored
    contiguously, ``centre1`` and ``centre2`` too), then each window's mean as the ring's
    sum (columns j − r … j + r in turn, from 0), SEARCH_CHUNK windows at once; the same
    values, bests and runner-ups. Launch over (rows, 1)."""
    i, c = wp.tid()
    i = i + row0
    w = centre1.shape[1]
    side = 2 * half + 1
    n = 2 * radius + 1
    area = float(n * n)
    base = wp.int64(i) * wp.int64(colc.shape[1])
    row_at = wp.int64(i) * wp.int64(w)
    chunks = w // SEARCH_CHUNK
    for k in range(side * side):
        sy = k // side - half
        sx = k - (k // side) * side - half
        row_column_costs(centre1, centre2, colc, i, sx, sy, radius)
        for g in range(chunks):
            j0 = g * SEARCH_CHUNK
            acc = vec16()
            for t in range(n):
                cr = float_run(colc.ptr, base + wp.int64(j0 + t), SEARCH_CHUNK)
                for x in range(SEARCH_CHUNK):
                    acc[x] = acc[x] + cr[x]
            value = acc / area
            # the chunk's windows all at least their best and their runner-up so far change nothing:
            # one test of the 16 in vector code, most shifts
            bc = float_run(best_cost.ptr, row_at + wp.int64(j0), SEARCH_CHUNK)
            sc = float_run(second_cost.ptr, row_at + wp.int64(j0), SEARCH_CHUNK)
            lower = int(0)
            for x in range(SEARCH_CHUNK):
                lower = lower | wp.where(value[x] < wp.max(bc[x], sc[x]), 1, 0)
            if k == 0 or lower != 0:
                for x in range(SEARCH_CHUNK):
                    keep_best(k, value[x], i, j0 + x, side, distance, best_cost, best_k, second_cost, second_k)
        for j in range(chunks * SEARCH_CHUNK, w):
            acc1 = float(0.0)
            for t in range(n):
                acc1 += colc[i, j + t]
            keep_best(k, acc1 / area, i, j, side, distance, best_cost, best_k, second_cost, second_k)
    for j in range(w):
        best[i, j] = refined_shift(centre1, centre2, i, j, best_k[i, j], best_cost[i, j], half, radius)


@wp.kernel
def relabel_active(
    row0: int,
    x: wp.array2d(dtype=wp.vec4),
    hidden: wp.array2d(dtype=float),
    flow_cost: wp.array2d(dtype=float),
    floor: float,
    depth_gap: float,
    flow_gap: float,
    reach: int,
    # outputs
    out: wp.array2d(dtype=float),
):
    """1 where p may take a neighbour's state (:func:`lfsf.kernels.fusion.take_other_surface`):
    p is not ``hidden`` (> 0.5), its ``flow_cost`` is above ``floor``, and a pixel within
    ``reach`` (read clamped to the image, as the shifted candidates are) lies apart from
    p's state by the same test (:func:`lfsf.kernels.fusion.states_apart`); else 0.
    Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    h = x.shape[0]
    w = x.shape[1]
    active = float(0.0)
    if hidden[i, j] <= 0.5 and flow_cost[i, j] > floor:
        v = x[i, j]
        for dy in range(-reach, reach + 1):
            for dx in range(-reach, reach + 1):
                c = x[wp.clamp(i + dy, 0, h - 1), wp.clamp(j + dx, 0, w - 1)]
                if states_apart(v, c, depth_gap, flow_gap):
                    active = 1.0
    out[i, j] = active


@wp.kernel
def dilated(
    row0: int,
    mask: wp.array2d(dtype=float),
    radius: int,
    # outputs
    out: wp.array2d(dtype=float),
):
    """1 where ``mask`` (> 0.5) holds a pixel of the (2·radius + 1)² window, else 0.
    Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    h = mask.shape[0]
    w = mask.shape[1]
    found = float(0.0)
    for ii in range(wp.max(i - radius, 0), wp.min(i + radius + 1, h)):
        for jj in range(wp.max(j - radius, 0), wp.min(j + radius + 1, w)):
            if mask[ii, jj] > 0.5:
                found = 1.0
    out[i, j] = found


@wp.kernel
def state_costs(
    row0: int,
    samples: wp.array3d(dtype=float),
    phis: wp.array(dtype=wp.vec2),
    centre1: wp.array2d(dtype=float),
    centre2: wp.array2d(dtype=float),
    x: wp.array2d(dtype=wp.vec4),
    active: wp.array2d(dtype=float),
    zbuf: wp.array3d(dtype=float),
    dy: int,
    dx: int,
    margin: float,
    seen_too: int,
    # outputs
    cost: wp.array3d(dtype=float),
):
    """Per pixel p where ``active`` (> 0.5), the three costs of the state x(p):
    cost[0, p] = the t1 samples' best-half cost of δ1 (:func:`disparity_cost` with no
    flow and δ = δ1(p)), cost[1, p] = the flow residual |I1(p) − I2(p + (u, v))|
    (:func:`flow_cost`), the same values as those kernels give, and cost[2, p] = the
    mean over the t1 samples that the view z-buffers ``zbuf`` (S, h, w) leave visible
    (:func:`visible_mean` with ``margin``, as :func:`disparity_cost_visible`), read
    (``dx``, ``dy``) px further: for an x that is a map moved as a whole by (−dx, −dy),
    ``zbuf`` may be that map's (exact away from the image's edges, where the moved map
    repeats its edge pixels; 0 without ``seen_too``, and ``zbuf`` is not read); 0
    elsewhere (the outlines' relabelling reads them only where the windows hold active
    pixels alone). Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    t1 = float(0.0)
    flow = float(0.0)
    seen = float(0.0)
    if active[i, j] > 0.5:
        v = x[i, j]
        qx = float(j)
        qy = float(i)
        centre = bilinear(samples[0], qx, qy)
        sums, counts, total, count = half_plane_residuals(samples, phis, qx, qy, v[0], centre)
        t1 = least_half_mean(sums, counts)
        if seen_too != 0:
            seen = visible_mean(samples, phis, zbuf, qx, qy, v[0], centre, margin, float(dx), float(dy))
        fx = float(j) + v[2]
        fy = float(i) + v[3]
        flow = float(1.0)
        if inside(centre2, fx, fy):
            flow = wp.abs(centre1[i, j] - bilinear(centre2, fx, fy))
    cost[0, i, j] = t1
    cost[1, i, j] = flow
    cost[2, i, j] = seen
