"""Decoding a raw lenslet image into sub-aperture views (``lfsf decode``).

Conventions (those of :mod:`lfsf.decode`): sensor pixel (row i, column j) has its centre
at sensor coordinates (x, y) = (j, i). Micro-lens (i, j) of the fitted lattice sits at

    c(i, j) = origin + (j + s·(i mod 2))·e1 + i·e2

with ``s = 0.5`` on a hexagonal lattice and ``s = 0`` on a rectangular one; ``e1`` is the
step from lens (i, j) to (i, j + 1) and ``e2`` the step from row i to row i + 1, both in
sensor pixels. In lattice-plane coordinates (u, v), measured in lens pitches along the
lattice's own axes, lens (i, j) sits at (j + s·(i mod 2), i·h) with h = √3/2 (hexagonal)
or 1 (rectangular).
"""

import warp as wp

from .common import bilinear

wp.set_module_options({"enable_backward": False})


@wp.func
def parity(i: int):
    """i mod 2 in {0, 1}, also for negative i (Warp's % keeps the dividend's sign)."""
    return ((i % 2) + 2) % 2


@wp.kernel
def devignette(
    row0: int,
    raw: wp.array2d(dtype=float),
    white: wp.array2d(dtype=float),
    floor: float,
    level: float,
    # outputs
    out: wp.array2d(dtype=float),
):
    """out = level · raw / max(white, floor): the raw image divided by the white image of
    the same camera taken relative to its bright ``level``, which removes the micro-lens
    and main-lens vignetting (and, photosite by photosite, the colour filters' gains)
    whatever exposure the white was taken at. Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    out[i, j] = level * raw[i, j] / wp.max(white[i, j], floor)


@wp.kernel
def demosaic_bilinear(
    row0: int,
    mosaic: wp.array2d(dtype=float),
    pattern: wp.vec4i,
    channel: int,
    # outputs
    out: wp.array2d(dtype=float),
):
    """One colour plane of a Bayer mosaic by bilinear interpolation.

    ``pattern`` gives the colour (0 = R, 1 = G, 2 = B) of the photosites at (row, column)
    parity (0, 0), (0, 1), (1, 0), (1, 1). A photosite of colour ``channel`` keeps its
    value; any other takes the mean of the nearest photosites of that colour in its 3×3
    neighbourhood, weighted (2 − |di|)(2 − |dj|): the two or four edge neighbours, or the
    four diagonal ones. Borders are replicated. Launch over (rows, columns)."""
    i, j = wp.tid()
    i = i + row0
    h = mosaic.shape[0]
    w = mosaic.shape[1]
    if pattern[2 * (i % 2) + (j % 2)] == channel:
        out[i, j] = mosaic[i, j]
        return
    total = float(0.0)
    weight = float(0.0)
    for di in range(-1, 2):
        for dj in range(-1, 2):
            ii = wp.clamp(i + di, 0, h - 1)
            jj = wp.clamp(j + dj, 0, w - 1)
            if pattern[2 * (ii % 2) + (jj % 2)] == channel:
                k = float((2 - wp.abs(di)) * (2 - wp.abs(dj)))
                total += k * mosaic[ii, jj]
                weight += k
    value = float(0.0)
    if weight > 0.0:
        value = total / weight
    out[i, j] = value


@wp.kernel
def sample_micro_images(
    row0: int,
    image: wp.array2d(dtype=float),
    origin: wp.vec2,
    e1: wp.vec2,
    e2: wp.vec2,
    row_shift: float,
    first_row: int,
    first_col: int,
    offsets: wp.array(dtype=wp.vec2),
    # outputs
    lens_values: wp.array3d(dtype=float),
):
    """lens_values[v, r, k] = image(c(first_row + r, first_col + k) + offsets[v]): every
    lens's micro-image sampled (bilinearly, clamped to the sensor) at the sensor offset
    of view v from the lens centre. Launch over (views × lens rows, lens columns)."""
    t, k = wp.tid()
    t = t + row0
    rows = lens_values.shape[1]
    v = t // rows
    r = t - v * rows
    i = first_row + r
    j = first_col + k
    centre = origin + (float(j) + row_shift * float(parity(i))) * e1 + float(i) * e2
    p = centre + offsets[v]
    lens_values[v, r, k] = bilinear(image, p[0], p[1])


@wp.func
def lens_value(lens_values: wp.array3d(dtype=float), v: int, i: int, j: int):
    """lens_values[v, i, j] with lens indices clamped to the array."""
    rows = lens_values.shape[1]
    cols = lens_values.shape[2]
    return lens_values[v, wp.clamp(i, 0, rows - 1), wp.clamp(j, 0, cols - 1)]


@wp.kernel
def resample_lattice(
    row0: int,
    lens_values: wp.array3d(dtype=float),
    row_shift: float,
    row_height: float,
    first_row: int,
    first_col: int,
    u0: float,
    v0: float,
    # outputs
    views: wp.array3d(dtype=float),
):
    """views[v, y, x] = the lens values of view v interpolated at lattice-plane position
    (u, v) = (u0 + x, v0 + y) lens pitches: a rectangular grid of square pixels one pitch
    wide.

    A rectangular lattice (``row_shift = 0``) is interpolated bilinearly. On a hexagonal
    one (``row_shift = 0.5``, ``row_height = √3/2``) the point is located in the strip
    between lens rows i0 and i0 + 1; in the oblique coordinates (α, β) = (u − s0 − (s1 −
    s0)·β, (v − i0·h)/h), with s0, s1 the two rows' shifts, the lenses are the integer
    points, and the unit cell splits along its short diagonal into two of the lattice's
    equilateral triangles; the value is the barycentric interpolation over the triangle
    holding the point (barycentric weights are affine invariant, so they can be computed
    in the oblique frame). Launch over (views × rows, columns)."""
    t, x = wp.tid()
    t = t + row0
    height = views.shape[1]
    v = t // height
    y = t - v * height
    pu = u0 + float(x)
    pv = v0 + float(y)
    rt = pv / row_height
    i0 = int(wp.floor(rt))
    fb = rt - float(i0)
    s0 = row_shift * float(parity(i0))
    s1 = row_shift * float(parity(i0 + 1))
    d = s1 - s0
    alpha = pu - s0 - d * fb
    j0 = int(wp.floor(alpha))
    fa = alpha - float(j0)
    r = i0 - first_row
    c = j0 - first_col
    q00 = lens_value(lens_values, v, r, c)
    q10 = lens_value(lens_values, v, r, c + 1)
    q01 = lens_value(lens_values, v, r + 1, c)
    q11 = lens_value(lens_values, v, r + 1, c + 1)
    value = float(0.0)
    if d == 0.0:
        value = (1.0 - fb) * ((1.0 - fa) * q00 + fa * q10) + fb * ((1.0 - fa) * q01 + fa * q11)
    elif d > 0.0:
        # short diagonal from lens (i0, j0 + 1) to (i0 + 1, j0)
        if fa + fb <= 1.0:
            value = (1.0 - fa - fb) * q00 + fa * q10 + fb * q01
        else:
            value = (fa + fb - 1.0) * q11 + (1.0 - fb) * q10 + (1.0 - fa) * q01
    else:
        # short diagonal from lens (i0, j0) to (i0 + 1, j0 + 1)
        if fa >= fb:
            value = (1.0 - fa) * q00 + (fa - fb) * q10 + fb * q11
        else:
            value = (1.0 - fb) * q00 + (fb - fa) * q01 + fa * q11
    views[v, y, x] = value
