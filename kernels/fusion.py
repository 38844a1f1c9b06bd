"""The searches' results fused into the estimate on the device (:func:`lfsf.estimate._fuse_flow`,
:func:`lfsf.estimate._fuse_disparities`): per pixel, an unknown keeps its value or takes
the searched one, whichever matches better. The unknowns x = (δ1, δ2, u, v) are vec4
maps; the searched values and the costs float maps. These steps ran in NumPy on the host,
with a round trip per cost: ~0.15 s of a 0.8 s `paper` run on a GPU at 640×480."""

import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.kernel
def unknown_plane(
    row0: int,
    x: wp.array2d(dtype=wp.vec4),
    k: int,
    # outputs
    out: wp.array2d(dtype=float),
):
    """out = component k of x. Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    out[i, j] = x[i, j][k]


@wp.kernel
def with_plane(
    row0: int,
    x: wp.array2d(dtype=wp.vec4),
    k: int,
    plane: wp.array2d(dtype=float),
    # outputs
    out: wp.array2d(dtype=wp.vec4),
):
    """out = x with component k replaced by ``plane`` (``out`` may be ``x``). Launch over
    (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    v = x[i, j]
    v[k] = plane[i, j]
    out[i, j] = v


@wp.kernel
def take_better(
    row0: int,
    candidate: wp.array2d(dtype=wp.vec4),
    new_cost: wp.array2d(dtype=float),
    cost: wp.array2d(dtype=float),
    margin: float,
    hidden: wp.array2d(dtype=float),
    use_hidden: int,
    first: int,
    count: int,
    # outputs
    x: wp.array2d(dtype=wp.vec4),
):
    """Components first … first + count − 1 of x set to the candidate's where it matches
    better, ``new_cost`` < ``margin`` · ``cost``, and (with ``use_hidden``) the pixel is
    not ``hidden`` (> 0.5). Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    if new_cost[i, j] < margin * cost[i, j]:
        if use_hidden != 0:
            if hidden[i, j] > 0.5:
                return
        v = x[i, j]
        c = candidate[i, j]
        for k in range(4):  # (a constant range: unrolled)
            if k >= first and k < first + count:
                v[k] = c[k]
        x[i, j] = v


@wp.kernel
def either_above(
    row0: int,
    a: wp.array2d(dtype=float),
    above_a: float,
    b: wp.array2d(dtype=float),
    above_b: float,
    # outputs
    out: wp.array2d(dtype=float),
):
    """out = 1 where a > ``above_a`` or b > ``above_b``, else 0 (two masks of hidden
    points, one resampled). Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    out[i, j] = wp.where(a[i, j] > above_a or b[i, j] > above_b, 1.0, 0.0)


@wp.kernel
def at_most(
    row0: int,
    a: wp.array2d(dtype=float),
    most: float,
    # outputs
    out: wp.array2d(dtype=float),
):
    """out = 1 where a ≤ ``most``, else 0 (a mask of well-matched points). Launch over
    (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    out[i, j] = wp.where(a[i, j] <= most, 1.0, 0.0)


@wp.kernel
def hidden_or_leaving(
    row0: int,
    hidden: wp.array2d(dtype=float),
    x: wp.array2d(dtype=wp.vec4),
    # outputs
    out: wp.array2d(dtype=float),
):
    """out = 1 where ``hidden`` > 0.5 or the flow (components 2, 3 of x) takes the pixel
    out of the image, p + (u, v) beyond [0, w − 1] × [0, h − 1]; else 0. There the flow's
    cost reads clamped pixels and says nothing of it, and the point has no match in the
    image to find: a block search's value matched better by chance (a pan of 15 px:
    the strip leaving the frame took flows of −11 px). Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    h = x.shape[0]
    w = x.shape[1]
    v = x[i, j]
    xq = float(j) + v[2]
    yq = float(i) + v[3]
    leaves = xq < 0.0 or xq > float(w - 1) or yq < 0.0 or yq > float(h - 1)
    out[i, j] = wp.where(hidden[i, j] > 0.5 or leaves, 1.0, 0.0)


@wp.kernel
def sample_at_flow(
    row0: int,
    image: wp.array2d(dtype=float),
    x: wp.array2d(dtype=wp.vec4),
    # outputs
    out: wp.array2d(dtype=float),
):
    """out(p) = image(p + (u, v)), the flow being components 2, 3 of x: bilinear, the
    position clamped to the image, with the weights and sums in float64 as NumPy takes
    them in :func:`lfsf.estimate._sample_at_flow` (the position itself in float32). The
    estimate is sensitive to the last bit here: δ2's searched candidate at p + (u, v)
    decides, per pixel, whether it is taken, and float32 weights moved `paper`'s flow
    EPE at 160×120 by 7 % (either way over five scenes). Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    h = image.shape[0]
    w = image.shape[1]
    v = x[i, j]
    px = wp.clamp(float(j) + v[2], 0.0, float(w - 1))
    py = wp.clamp(float(i) + v[3], 0.0, float(h - 1))
    x0 = wp.min(int(px), wp.max(w - 2, 0))
    y0 = wp.min(int(py), wp.max(h - 2, 0))
    x1 = wp.min(x0 + 1, w - 1)
    y1 = wp.min(y0 + 1, h - 1)
    fx = wp.float64(px) - wp.float64(x0)
    fy = wp.float64(py) - wp.float64(y0)
    one = wp.float64(1.0)
    top = (one - fx) * wp.float64(image[y0, x0]) + fx * wp.float64(image[y0, x1])
    bottom = (one - fx) * wp.float64(image[y1, x0]) + fx * wp.float64(image[y1, x1])
    out[i, j] = float((one - fy) * top + fy * bottom)


@wp.kernel
def shifted(
    row0: int,
    x: wp.array2d(dtype=wp.vec4),
    dy: int,
    dx: int,
    # outputs
    out: wp.array2d(dtype=wp.vec4),
):
    """out(p) = x(p + (dx, dy)), the pixel read clamped to the image (its edge pixels
    repeated). Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    h = x.shape[0]
    w = x.shape[1]
    out[i, j] = x[wp.clamp(i + dy, 0, h - 1), wp.clamp(j + dx, 0, w - 1)]


@wp.kernel
def depth_nearby(
    row0: int,
    x: wp.array2d(dtype=wp.vec4),
    component: int,
    candidate: wp.array2d(dtype=float),
    reach: int,
    depth: float,
    keep: wp.array2d(dtype=float),
    use_keep: int,
    # outputs
    out: wp.array2d(dtype=float),
):
    """out = 0 where some pixel q within ``reach`` px of p (|Δi|, |Δj| ≤ ``reach``, read
    clamped to the image) holds a value of the unknown ``component`` of x within
    ``depth`` of ``candidate(p)`` (|x(q)[component] − candidate(p)| < ``depth``), and p
    is not kept (``use_keep`` 0, or ``keep`` ≤ 0.5); else 1: a mask of the pixels that
    keep their value (the ``hidden`` input of :func:`take_better`). A searched depth
    is then taken only where a surface at that depth lies near. Launch over (rows,
    columns)."""
    i, j = wp.tid()
    i = i + row0
    h = x.shape[0]
    w = x.shape[1]
    c = candidate[i, j]
    kept = float(1.0)
    for dy in range(-reach, reach + 1):
        for dx in range(-reach, reach + 1):
            q = x[wp.clamp(i + dy, 0, h - 1), wp.clamp(j + dx, 0, w - 1)]
            if wp.abs(q[component] - c) < depth:
                kept = 0.0
    if use_keep != 0:
        if keep[i, j] > 0.5:
            kept = 1.0
    out[i, j] = kept


@wp.func
def states_apart(v: wp.vec4, c: wp.vec4, depth_gap: float, flow_gap: float):
    """Whether the state c = (δ1, δ2, u, v) lies on another surface than v, as the
    outlines' relabelling tells them apart: δ1 more than ``depth_gap`` and the flow more
    than ``flow_gap`` px apart."""
    apart = False
    if wp.abs(c[0] - v[0]) > depth_gap:
        du = c[2] - v[2]
        dv = c[3] - v[3]
        if du * du + dv * dv > flow_gap * flow_gap:
            apart = True
    return apart


@wp.kernel
def take_other_surface(
    row0: int,
    x: wp.array2d(dtype=wp.vec4),
    candidate: wp.array2d(dtype=wp.vec4),
    flow_new: wp.array2d(dtype=float),
    flow_cur: wp.array2d(dtype=float),
    t1_new: wp.array2d(dtype=float),
    t1_cur: wp.array2d(dtype=float),
    seen_new: wp.array2d(dtype=float),
    seen_cur: wp.array2d(dtype=float),
    hidden: wp.array2d(dtype=float),
    floor: float,
    margin: float,
    depth_gap: float,
    flow_gap: float,
    seen_too: int,
    # outputs
    best: wp.array2d(dtype=float),
    out: wp.array2d(dtype=wp.vec4),
):
    """p takes the whole candidate state (δ1, δ2, u, v), another surface's, where that
    explains both its t1 samples and the centre views better: it lies apart from x's
    (:func:`states_apart`: δ1 by more than ``depth_gap``, the flow by more than
    ``flow_gap`` px); the flow residual ``flow_new`` < ``margin`` · ``flow_cur``, with
    ``flow_cur`` above ``floor`` (a flow that matches leaves the pixel alone); the t1
    cost ``t1_new`` < ``margin`` · ``t1_cur`` and below ``best`` (the lowest t1 cost
    taken so far, which this lowers); with ``seen_too``, where the candidate lies behind
    x (a lower δ1), also the cost over the samples that each map's z-buffers leave
    visible, ``seen_new`` < ``margin`` · ``seen_cur``; and p is not ``hidden`` (> 0.5:
    hidden at t2, where the occluder matches better than the point's own flow). x is
    read, ``out`` written. Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    if hidden[i, j] > 0.5 or flow_cur[i, j] <= floor:
        return
    s = t1_new[i, j]
    if flow_new[i, j] >= margin * flow_cur[i, j] or s >= margin * t1_cur[i, j] or s >= best[i, j]:
        return
    c = candidate[i, j]
    v = x[i, j]
    if not states_apart(v, c, depth_gap, flow_gap):
        return
    if seen_too != 0 and c[0] < v[0] and seen_new[i, j] >= margin * seen_cur[i, j]:
        return
    best[i, j] = s
    out[i, j] = c
