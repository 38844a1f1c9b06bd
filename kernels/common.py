"""``@wp.func`` helpers every kernel needs: clamped lookup, bilinear sampling and image
gradients with Neumann boundaries. Pixel (row i, column j) has its centre at image
coordinates (x, y) = (j, i)."""

from typing import Any

import warp as wp

wp.set_module_options({"enable_backward": False})

#: The solver's unknowns per pixel: vec4 (δ1, δ2, u, v), or vec2 (u, v) for flow only
#: (M = 1, where no data row involves δ1 or δ2). Kernels on the unknowns are generic over
#: these two (``dtype=Any``), with an explicit overload for each (:func:`overload_unknowns`).
UNKNOWNS = (wp.vec4, wp.vec2)


def overload_unknowns(kernel, *names: str, values: tuple[str, ...] = ()):
    """Declare ``kernel``'s overloads for each type of :data:`UNKNOWNS`: the arrays named
    (2-D, generic ``dtype``) hold the unknowns, and the arguments named in ``values`` are
    one value per unknown (of the unknowns' vector type). Declaring them at import keeps
    the module the same whichever is launched first (no recompilation on the other's first
    launch)."""
    for vec in UNKNOWNS:
        wp.overload(kernel, {**{name: wp.array2d(dtype=vec) for name in names}, **{name: vec for name in values}})
    return kernel


@wp.func
def at_least(x: float, lo: float):
    """max(x, lo) by one comparison. ``wp.max`` on floats is IEEE fmax (it turns NaN into
    the bound), which costs more in scalar CPU code; a NaN passes through this."""
    return wp.where(x < lo, lo, x)


@wp.func
def at_most(x: float, hi: float):
    """min(x, hi) by one comparison (see :func:`at_least`)."""
    return wp.where(x > hi, hi, x)


_LANE_VECTORS: dict = {}


def lane_vector(lanes: int):
    """The vector type of ``lanes`` floats that the kernels working on groups of pixels
    at once use (the data term's dual step, ROF's lanes steps): one type per length."""
    if lanes not in _LANE_VECTORS:
        _LANE_VECTORS[lanes] = wp.types.vector(length=lanes, dtype=wp.float32)
    return _LANE_VECTORS[lanes]


@wp.func
def float_run(ptr: wp.uint64, offset: wp.int64, n: int):
    """The n floats from float ``offset`` of the memory at ``ptr`` (an array's ``ptr``,
    stored contiguously) as a 1-D array of its own. Its stride is a constant of the code
    (4 bytes), where an array argument's is read at run time: a loop over it reads
    consecutive floats in vector loads where it would otherwise gather them."""
    return wp.array(ptr=ptr + wp.uint64(offset * wp.int64(4)), shape=(n,), dtype=float)


@wp.func_native("""
#if !defined(__CUDA_ARCH__)
asm volatile("" : "+r"(ptr));
#endif
return ptr;
""")
def opaque(ptr: wp.uint64) -> wp.uint64:
    """``ptr`` itself, passed through an empty ``asm`` statement that the CPU compiler
    cannot see through (on CUDA as it is): it no longer knows where the memory lies
    relative to other pointers, so it cannot treat stores through two such pointers as
    neighbours (:func:`store_apart`)."""
    ...


@wp.func
def contiguous_row(a: wp.array3d(dtype=float), s: int, i: int, j: int, n: int):
    """a[s, i, j : j + n] as a 1-D array of constant stride (:func:`float_run`), for an
    ``a`` stored contiguously (C order)."""
    return float_run(a.ptr, (wp.int64(s) * wp.int64(a.shape[1]) + wp.int64(i)) * wp.int64(a.shape[2]) + wp.int64(j), n)


@wp.func
def to_vec4(x: wp.vec4):
    """The unknowns as (δ1, δ2, u, v)."""
    return x


@wp.func
def to_vec4(x: wp.vec2):
    """Flow only: (0, 0, u, v); δ1 and δ2 have no data rows, and the data coefficients of
    the centre view (φ = 0) do not involve them."""
    return wp.vec4(0.0, 0.0, x[0], x[1])


@wp.func
def from_vec4(v: wp.vec4, like: wp.vec4):
    """(δ1, δ2, u, v) as the type of ``like``: as it is."""
    return v


@wp.func
def from_vec4(v: wp.vec4, like: wp.vec2):
    """(δ1, δ2, u, v) as the type of ``like``: flow only, (u, v)."""
    return wp.vec2(v[2], v[3])


@wp.func
def store_apart(ptr: wp.uint64, at: wp.int64, v: wp.vec4, like: wp.vec4):
    """Element ``at`` of the contiguous array of vec4 at ``ptr`` set to ``from_vec4(v,
    like)``, each component through its own :func:`opaque` pointer. Where a loop sums
    into four lane vectors and then stores each pixel's four sums side by side, the CPU
    compiler otherwise pairs the sums pixel by pixel inside the loop, which costs
    shuffles every iteration (the data term's dual step took 1.4× its time)."""
    base = ptr + wp.uint64(at * wp.int64(16))
    out0 = wp.array(ptr=opaque(base), shape=(1,), dtype=float)
    out1 = wp.array(ptr=opaque(base + wp.uint64(4)), shape=(1,), dtype=float)
    out2 = wp.array(ptr=opaque(base + wp.uint64(8)), shape=(1,), dtype=float)
    out3 = wp.array(ptr=opaque(base + wp.uint64(12)), shape=(1,), dtype=float)
    out0[0] = v[0]
    out1[0] = v[1]
    out2[0] = v[2]
    out3[0] = v[3]


@wp.func
def store_apart(ptr: wp.uint64, at: wp.int64, v: wp.vec4, like: wp.vec2):
    """:func:`store_apart` into an array of vec2 (flow only): (u, v) = v[2], v[3]."""
    base = ptr + wp.uint64(at * wp.int64(8))
    out0 = wp.array(ptr=opaque(base), shape=(1,), dtype=float)
    out1 = wp.array(ptr=opaque(base + wp.uint64(4)), shape=(1,), dtype=float)
    out0[0] = v[2]
    out1[0] = v[3]


@wp.func
def pixel(img: wp.array2d(dtype=float), i: int, j: int):
    """img[i, j] with indices clamped to the image (replicated border)."""
    h = img.shape[0]
    w = img.shape[1]
    return img[wp.clamp(i, 0, h - 1), wp.clamp(j, 0, w - 1)]


@wp.func
def bilinear(img: wp.array2d(dtype=Any), x: float, y: float):
    """Bilinear interpolation of img at (x, y) (x = column), clamped at the borders: of
    a float image, or of the unknowns (vec4 or vec2) component by component."""
    h = img.shape[0]
    w = img.shape[1]
    xc = wp.clamp(x, 0.0, float(w - 1))
    yc = wp.clamp(y, 0.0, float(h - 1))
    j0 = wp.min(int(xc), wp.max(w - 2, 0))
    i0 = wp.min(int(yc), wp.max(h - 2, 0))
    j1 = wp.min(j0 + 1, w - 1)
    i1 = wp.min(i0 + 1, h - 1)
    fx = xc - float(j0)
    fy = yc - float(i0)
    top = (1.0 - fx) * img[i0, j0] + fx * img[i0, j1]
    bottom = (1.0 - fx) * img[i1, j0] + fx * img[i1, j1]
    return (1.0 - fy) * top + fy * bottom


@wp.func
def bilinear_gradient(img: wp.array2d(dtype=float), x: float, y: float):
    """Image gradient (∂x, ∂y) at (x, y): central differences of bilinear samples one
    pixel apart (the interpolated central-difference gradient image)."""
    gx = 0.5 * (bilinear(img, x + 1.0, y) - bilinear(img, x - 1.0, y))
    gy = 0.5 * (bilinear(img, x, y + 1.0) - bilinear(img, x, y - 1.0))
    return wp.vec2(gx, gy)


@wp.func
def interior(x: float, y: float, h: int, w: int):
    """(x, y) lies a pixel or more inside an h × w image, where
    :func:`bilinear_with_gradient` reads its twelve pixels and :func:`cubic_value` its
    sixteen without clamping."""
    return x >= 1.0 and y >= 1.0 and x < float(w - 2) and y < float(h - 2)


@wp.func
def bilinear_taps(a0: float, a1: float, a2: float, a3: float, b0: float, b1: float, b2: float, b3: float, u0: float,
                  u1: float, d0: float, d1: float, fx: float, fy: float):
    """:func:`bilinear_with_gradient`'s value and gradient (∂x, ∂y) away from the borders,
    at (j + fx, i + fy), from the twelve pixels its five lookups read: rows i and i + 1
    over columns j − 1 … j + 2 (a0 … a3, b0 … b3), rows i − 1 (u0, u1) and i + 2 (d0, d1)
    over j, j + 1."""
    gx = 1.0 - fx
    gy = 1.0 - fy
    top = gx * a1 + fx * a2
    bottom = gx * b1 + fx * b2
    value = gy * top + fy * bottom
    left = gy * (gx * a0 + fx * a1) + fy * (gx * b0 + fx * b1)
    right = gy * (gx * a2 + fx * a3) + fy * (gx * b2 + fx * b3)
    up = gy * (gx * u0 + fx * u1) + fy * top
    down = gy * bottom + fy * (gx * d0 + fx * d1)
    return value, 0.5 * (right - left), 0.5 * (down - up)


@wp.func
def bilinear_with_gradient(img: wp.array2d(dtype=float), x: float, y: float):
    """(:func:`bilinear`, :func:`bilinear_gradient`) at (x, y) in one: away from the
    borders the five lookups share their weights and twelve pixels; within a pixel of
    a border, the two functions as they are (clamped)."""
    h = img.shape[0]
    w = img.shape[1]
    value = float(0.0)
    g = wp.vec2(0.0)
    if interior(x, y, h, w):
        j = int(x)
        i = int(y)
        # rows i and i + 1 over columns j − 1 … j + 2; rows i − 1 and i + 2 over j, j + 1
        value, gx, gy = bilinear_taps(img[i, j - 1], img[i, j], img[i, j + 1], img[i, j + 2], img[i + 1, j - 1],
                                      img[i + 1, j], img[i + 1, j + 1], img[i + 1, j + 2], img[i - 1, j],
                                      img[i - 1, j + 1], img[i + 2, j], img[i + 2, j + 1], x - float(j), y - float(i))
        g = wp.vec2(gx, gy)
    else:
        value = bilinear(img, x, y)
        g = bilinear_gradient(img, x, y)
    return value, g


@wp.func
def cubic_weights(t: float):
    """Catmull–Rom weights of the four pixels j − 1 … j + 2 at j + t (0 ≤ t < 1): the
    cubic through them with central-difference slopes at j and j + 1."""
    t2 = t * t
    t3 = t2 * t
    return wp.vec4(0.5 * (2.0 * t2 - t - t3), 0.5 * (2.0 - 5.0 * t2 + 3.0 * t3), 0.5 * (t + 4.0 * t2 - 3.0 * t3),
                   0.5 * (t3 - t2))


@wp.func
def cubic_value(r0: wp.vec4, r1: wp.vec4, r2: wp.vec4, r3: wp.vec4, fx: float, fy: float):
    """Catmull–Rom interpolation at (j + fx, i + fy) from the 4 × 4 pixels around it:
    rows i − 1 … i + 2 (r0 … r3), each over columns j − 1 … j + 2 (separable: weights
    along x, then along y). It passes through the pixels and reproduces polynomials of
    degree 2 in each coordinate (Keys 1981), where bilinear interpolation reproduces
    only degree 1: on the sampled textures of the synthetic scenes, at the true motion,
    it leaves a residual |I2(p + u) − I1(p)| of a half to a third of bilinear
    interpolation's."""
    wx = cubic_weights(fx)
    wy = cubic_weights(fy)
    return wy[0] * wp.dot(wx, r0) + wy[1] * wp.dot(wx, r1) + wy[2] * wp.dot(wx, r2) + wy[3] * wp.dot(wx, r3)


@wp.func
def lookup_with_gradient(img: wp.array2d(dtype=float), x: float, y: float, cubic: int):
    """A sample's value and gradient at a warped position (x, y), as the data term reads
    them: the value by Catmull–Rom (:func:`cubic_value`) with ``cubic`` (``Params.cubic``)
    where its 4 × 4 pixels lie inside the image (:func:`interior`), else bilinear; the
    gradient always :func:`bilinear_gradient`'s central differences of bilinear samples,
    a derivative that also smooths (the cubic's own derivative amplified the views'
    noise). Within a pixel of a border both are :func:`bilinear_with_gradient`'s
    (clamped)."""
    value, g = bilinear_with_gradient(img, x, y)
    if cubic != 0 and interior(x, y, img.shape[0], img.shape[1]):
        j = int(x)
        i = int(y)
        value = cubic_value(wp.vec4(img[i - 1, j - 1], img[i - 1, j], img[i - 1, j + 1], img[i - 1, j + 2]),
                            wp.vec4(img[i, j - 1], img[i, j], img[i, j + 1], img[i, j + 2]),
                            wp.vec4(img[i + 1, j - 1], img[i + 1, j], img[i + 1, j + 1], img[i + 1, j + 2]),
                            wp.vec4(img[i + 2, j - 1], img[i + 2, j], img[i + 2, j + 1], img[i + 2, j + 2]),
                            x - float(j), y - float(i))
    return value, g


@wp.func
def inside(img: wp.array2d(dtype=float), x: float, y: float):
    """True when (x, y) lies within the image's pixel centres."""
    return x >= 0.0 and y >= 0.0 and x <= float(img.shape[1] - 1) and y <= float(img.shape[0] - 1)


@wp.func
def forward_gradient(img: wp.array2d(dtype=float), i: int, j: int):
    """Forward differences (∂x, ∂y) with Neumann boundary: zero at the last column/row."""
    h = img.shape[0]
    w = img.shape[1]
    v = img[i, j]
    gx = float(0.0)
    gy = float(0.0)
    if j < w - 1:
        gx = img[i, j + 1] - v
    if i < h - 1:
        gy = img[i + 1, j] - v
    return wp.vec2(gx, gy)


vec8 = wp.types.vector(length=8, dtype=wp.float32)

#: Occlusion-aware matching splits the samples by lines through φ = 0 at multiples of
#: 45°: an occluder next to a pixel hides it in the views on one side only.
HALF_PLANES = wp.constant(8)


@wp.func
def half_plane_normal(m: int):
    angle = float(m) * (3.14159265358979 / 4.0)
    return wp.vec2(wp.cos(angle), wp.sin(angle))


@wp.func
def in_half_plane(phi: wp.vec2, normal: wp.vec2):
    """φ lies in the closed half-plane {φ · n ≥ 0} (with a small tolerance)."""
    return wp.dot(phi, normal) >= -1.0e-3 * wp.length(phi)


@wp.func
def half_plane_mask(phi: wp.vec2):
    """1 for each half-plane m (:func:`half_plane_normal`) that contains φ, else 0."""
    mask = vec8()
    for m in range(HALF_PLANES):
        if in_half_plane(phi, half_plane_normal(m)):
            mask[m] = 1.0
    return mask


@wp.func
def least_half_mean(sums: vec8, counts: vec8):
    """The least mean sums[m] / counts[m] over the half-planes that hold a sample; 1
    where none does."""
    c = float(1.0)
    for m in range(HALF_PLANES):
        if counts[m] > 0.0:
            c = wp.min(c, sums[m] / counts[m])
    return c


@wp.func
def add_residual(sums: vec8, counts: vec8, total: float, count: float, e: float, mask: vec8):
    """One sample's residual e added to per-half-plane sums: to each half that holds the
    sample (``mask``, :func:`half_plane_mask`) and to the total."""
    return sums + e * mask, counts + mask, total + e, count + 1.0


#: A view z-buffer's values under one bilinear lookup that differ by more than this many
#: times the occlusion margin mark a depth edge through the lookup (:func:`visible`).
EDGE_JUMP = wp.constant(2.0)


@wp.func
def footprint(x: float, y: float, h: int, w: int):
    """The rows i0, i1 and columns j0, j1 of the pixels that a bilinear lookup at (x, y) of
    an h × w image reads with non-zero weight, clamped to the image (a whole coordinate
    reads one row or column: i1 = i0, j1 = j0)."""
    fy = wp.floor(y)
    fx = wp.floor(x)
    i0 = wp.clamp(int(fy), 0, h - 1)
    j0 = wp.clamp(int(fx), 0, w - 1)
    i1 = wp.clamp(int(fy) + wp.where(y > fy, 1, 0), 0, h - 1)
    j1 = wp.clamp(int(fx) + wp.where(x > fx, 1, 0), 0, w - 1)
    return i0, j0, i1, j1


@wp.func
def visible(zbuf: wp.array3d(dtype=float), s: int, x: float, y: float, disparity: float, margin: float):
    """Sample s at (x, y) of its view sees the point of disparity δ = ``disparity``, by the
    view z-buffer ``zbuf[s]`` (:func:`lfsf.kernels.occlusion.splat_views`) at the pixels
    that the bilinear lookup at (x, y) reads with non-zero weight (clamped to the image;
    a whole coordinate reads one row or column): :func:`footprint_visible`."""
    i0, j0, i1, j1 = footprint(x, y, zbuf.shape[1], zbuf.shape[2])
    return footprint_visible(zbuf[s, i0, j0], zbuf[s, i0, j1], zbuf[s, i1, j0], zbuf[s, i1, j1], disparity, margin)


@wp.func
def footprint_visible(a: float, b: float, c: float, d: float, disparity: float, margin: float):
    """The decision of :func:`visible` from the z-buffer values a … d under a lookup.
    Where they differ by more than EDGE_JUMP × margin, a depth edge runs through the
    lookup: the sample is left out if any of them holds a point nearer than δ + margin
    (a lookup that mixes in the nearer surface's pixels pulls the background's
    disparity towards the foreground's). Elsewhere (one surface, perhaps slanted, whose
    own neighbours are a little nearer) only if all of them do."""
    # (by comparisons, :func:`at_least`: data_coefficients 6 % faster than with wp.max)
    hi = at_least(at_least(a, b), at_least(c, d))
    lo = at_most(at_most(a, b), at_most(c, d))
    covered = wp.where(hi - lo > EDGE_JUMP * margin, hi, lo)
    return covered <= disparity + margin


@wp.func
def half_plane_residuals(samples: wp.array3d(dtype=float), phis: wp.array(dtype=wp.vec2), qx: float, qy: float,
                         disparity: float, centre: float):
    """Residuals |L(q − δφ_s, φ_s) − c| of the samples s ≥ 1 whose warped position lies in
    the image, summed per half-plane of samples and over all of them: returns (sums,
    counts) per half-plane (vec8) and (total, count)."""
    sums = vec8()
    counts = vec8()
    total = float(0.0)
    count = float(0.0)
    for s in range(1, phis.shape[0]):
        phi = phis[s]
        x = qx - disparity * phi[0]
        y = qy - disparity * phi[1]
        if inside(samples[s], x, y):
            e = wp.abs(bilinear(samples[s], x, y) - centre)
            sums, counts, total, count = add_residual(sums, counts, total, count, e, half_plane_mask(phi))
    return sums, counts, total, count
