"""Per-view gain fields on the device (:mod:`lfsf.gains`): the views reduced by block
means for the gains' pilot, and the fitted fields, upsampled bilinearly, multiplied into
the views that the sub-aperture sampling reads. Both used to run in NumPy on the host:
on the paper's setting at 640×480 (81 views) they took about 0.2 s of a 1.4 s run on a
GPU."""

import warp as wp

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
