"""Per-view gain fields on the device (:mod:`lfsf.gains`): the views reduced by block
means for the gains' pilot; the fit itself (the views warped to the centre by the pilot's
disparity, the masked sums of each pass, their three-pass box blur, the local ratios);
and the fitted fields, upsampled bilinearly, multiplied into the views that the
sub-aperture sampling reads. All of it used to run in NumPy on the host: on the paper's
setting at 640×480 (81 views) the reduction and the application took about 0.2 s of a
1.4 s run on a GPU, the fit's warps and blurs about 0.1 s of a 0.76 s one."""

import warp as wp

from .common import bilinear

wp.set_module_options({"enable_backward": False})


@wp.kernel
def block_mean(
    row0: int,
    views: wp.array3d(dtype=float),
    factor: int,
    # outputs
    small: wp.array3d(dtype=float),
):
    """small[k, i, j] = the mean of views[k] over the ``factor`` × ``factor`` block whose
    top-left pixel is (factor·i, factor·j); pixels past the last whole block are left
    out. Launch over (n × small rows, small columns)."""
    r, j = wp.tid()
    r = r + row0
    hs = small.shape[1]
    k = r // hs
    i = r - k * hs
    acc = float(0.0)
    for dy in range(factor):
        for dx in range(factor):
            acc += views[k, i * factor + dy, j * factor + dx]
    small[k, i, j] = acc / float(factor * factor)


@wp.func
def upsample_position(x: int, factor: int, small: int):
    """(lower index, fraction) of full-resolution pixel ``x`` between the pixel centres
    of a grid reduced by block means of ``factor`` (``small`` pixels): each block's value
    sits at its centre, clamped at the edges."""
    pos = wp.clamp((float(x) + 0.5) / float(factor) - 0.5, 0.0, float(small - 1))
    lo = wp.min(int(pos), wp.max(small - 2, 0))
    return lo, pos - float(lo)


@wp.kernel
def apply_gains(
    row0: int,
    small: wp.array3d(dtype=float),
    index: wp.array(dtype=wp.int32),
    factor: int,
    # outputs
    views: wp.array3d(dtype=float),
):
    """views[index[m]] ×= the gain field small[index[m]] (fitted on views reduced by
    ``factor``) upsampled bilinearly to the views' size, as :func:`lfsf.gains.full_gains`
    upsamples it. Launch over (len(index) × rows, columns)."""
    r, x = wp.tid()
    r = r + row0
    h = views.shape[1]
    m = r // h
    y = r - m * h
    k = index[m]
    hs = small.shape[1]
    ws = small.shape[2]
    y0, fy = upsample_position(y, factor, hs)
    x0, fx = upsample_position(x, factor, ws)
    y1 = wp.min(y0 + 1, hs - 1)
    x1 = wp.min(x0 + 1, ws - 1)
    top = (1.0 - fx) * small[k, y0, x0] + fx * small[k, y0, x1]
    bottom = (1.0 - fx) * small[k, y1, x0] + fx * small[k, y1, x1]
    views[k, y, x] = views[k, y, x] * ((1.0 - fy) * top + fy * bottom)


@wp.kernel
def warp_to_centre(
    row0: int,
    views: wp.array3d(dtype=float),
    index: wp.array(dtype=wp.int32),
    offsets: wp.array(dtype=wp.vec2),
    disparity: wp.array2d(dtype=float),
    # outputs
    warped: wp.array3d(dtype=float),
):
    """warped[m](p) = views[index[m]](p − δ(p)·(ξ_m, η_m)), the view at angular offset
    (ξ_m, η_m) = offsets[m] (view steps from the grid's centre) seen from the centre
    through the disparity δ: bilinear, the position clamped to the view
    (:func:`lfsf.kernels.common.bilinear`). Launch over (len(index) × rows, columns)."""
    r, x = wp.tid()
    r = r + row0
    h = warped.shape[1]
    m = r // h
    y = r - m * h
    k = index[m]
    d = disparity[y, x]
    o = offsets[m]
    warped[m, y, x] = bilinear(views[k], float(x) - d * o[0], float(y) - d * o[1])


@wp.kernel
def mean_of_views(
    row0: int,
    stack: wp.array3d(dtype=float),
    slots: wp.array(dtype=wp.int32),
    # outputs
    mean: wp.array2d(dtype=float),
):
    """mean = the mean of stack[slots[0]], stack[slots[1]], … (the reference the views
    are matched to: the centre view, or on an even grid those nearest the centre).
    Launch over (rows, columns)."""
    y, x = wp.tid()
    y = y + row0
    acc = float(0.0)
    for i in range(slots.shape[0]):
        acc += stack[slots[i], y, x]
    mean[y, x] = acc / float(slots.shape[0])


@wp.kernel
def gain_sums(
    row0: int,
    warped: wp.array3d(dtype=float),
    centre: wp.array2d(dtype=float),
    gains: wp.array3d(dtype=float),
    base: wp.array(dtype=float),
    first: int,
    border: int,
    dark: float,
    match: float,
    # outputs
    sums: wp.array3d(dtype=float),
):
    """One pass of the fit (:func:`lfsf.gains.fit_reduced_gains`): a pixel of view m
    matches where it and the centre C are brighter than ``dark``, it lies ``border`` px or
    more inside, and |g·W − C| < ``match`` (g: the view's global gain base[m] on the
    ``first`` pass, else its fitted field); sums[m], sums[n + m], sums[2n + m] = C·W·M,
    W·W·M and M, M = 1 where it matches, else 0. Launch over (n × rows, columns)."""
    r, x = wp.tid()
    r = r + row0
    n = warped.shape[0]
    h = warped.shape[1]
    w = warped.shape[2]
    m = r // h
    y = r - m * h
    v = warped[m, y, x]
    c = centre[y, x]
    g = base[m]
    if first == 0:
        g = gains[m, y, x]
    on = float(0.0)
    if v > dark and c > dark and y >= border and y < h - border and x >= border and x < w - border:
        if wp.abs(g * v - c) < match:
            on = 1.0
    sums[m, y, x] = c * v * on
    sums[n + m, y, x] = v * v * on
    sums[2 * n + m, y, x] = on


@wp.func
def mirrored(k: int, n: int):
    """Index k into n pixels mirrored at both edges (the edge pixel repeated), as often
    as a wide box needs: …, 1, 0, 0, 1, …, n − 1, n − 1, n − 2, …"""
    period = 2 * n
    k = k % period
    if k < 0:
        k += period
    if k >= n:
        k = period - 1 - k
    return k


@wp.kernel
def box_pass(
    row0: int,
    src: wp.array3d(dtype=float),
    radius: int,
    along_rows: int,
    span: int,
    # outputs
    out: wp.array3d(dtype=float),
):
    """out = the mean of the 2·radius + 1 values of ``src`` around each pixel, along each
    row (``along_rows`` 1) or each column (0), mirrored at the edges: one pass of the
    three-pass box blur of :func:`lfsf.gains.box_blur`. A thread takes ``span``
    consecutive pixels of a line (a row, or a column), the first by its whole box and the
    others by a running sum (the whole line on the CPU: two reads a pixel whatever the
    box; one pixel on CUDA). Launch over (n × lines, ⌈line length / span⌉), the lines
    rows or columns."""
    r, c = wp.tid()
    r = r + row0
    h = src.shape[1]
    w = src.shape[2]
    lines = h
    length = w
    if along_rows == 0:
        lines = w
        length = h
    m = r // lines
    line = r - m * lines
    start = c * span
    stop = wp.min(start + span, length)
    acc = float(0.0)
    for t in range(start - radius, start + radius + 1):
        if along_rows != 0:
            acc += src[m, line, mirrored(t, w)]
        else:
            acc += src[m, mirrored(t, h), line]
    scale = 1.0 / float(2 * radius + 1)
    for i in range(start, stop):
        if i > start:
            # slide the box by one: in comes i + radius, out goes i − radius − 1
            if along_rows != 0:
                acc += src[m, line, mirrored(i + radius, w)] - src[m, line, mirrored(i - radius - 1, w)]
            else:
                acc += src[m, mirrored(i + radius, h), line] - src[m, mirrored(i - radius - 1, h), line]
        if along_rows != 0:
            out[m, line, i] = acc * scale
        else:
            out[m, i, line] = acc * scale


@wp.kernel
def gains_from_sums(
    row0: int,
    sums: wp.array3d(dtype=float),
    base: wp.array(dtype=float),
    support: float,
    max_gain: float,
    # outputs
    gains: wp.array3d(dtype=float),
):
    """The fields of one pass from the blurred sums (:func:`gain_sums`): the local ratio
    G(C·W·M) / G(W·W·M) (base[m] where the denominator is 0), blended towards base[m]
    where the matches' weight G(M) is below ``support`` (linearly, to it at 0), clipped to
    [1 / max_gain, max_gain]. Launch over (n × rows, columns)."""
    r, x = wp.tid()
    r = r + row0
    n = gains.shape[0]
    h = gains.shape[1]
    m = r // h
    y = r - m * h
    b = base[m]
    num = sums[m, y, x]
    den = sums[n + m, y, x]
    ratio = b
    if den > 0.0:
        ratio = num / den
    weight = wp.clamp(sums[2 * n + m, y, x] / support, 0.0, 1.0)
    gains[m, y, x] = wp.clamp(b + (ratio - b) * weight, 1.0 / max_gain, max_gain)
