"""Ray-traced camera-array renderer for synthetic light fields with exact ground truth.

A scene is a list of convex textured primitives (plane patches, spheres, boxes), each
with a rigid pose per time. Views sit on a regular grid of pinhole cameras; the view at
angular offset φ = (ξ, η) has its centre at (ξ·B, η·B, 0) and its sensor shifted by
``s·φ`` pixels, so that a point at depth Z appears at ``p − δ·φ`` with the disparity
δ = f·B/Z − s (``help(lfsf)``, MODEL.md §1). World axes: x right, y down, z forward (away from the
camera). Pixel (row i, column j) has its centre at image coordinates (x, y) = (j, i).

Textures are solid: a function of the hit point in the object's own frame, so they move
with the object. The noise is our own integer-hash value noise, identical on CPU and CUDA.
An object may instead carry an image (a photograph, say) projected along the axis of its
local frame that faces the hit point most, repeated mirrored beyond its edges.
"""

import warp as wp

wp.set_module_options({"enable_backward": False})

KIND_PLANE = wp.constant(0)
KIND_SPHERE = wp.constant(1)
KIND_BOX = wp.constant(2)

NO_HIT = wp.constant(1.0e30)


@wp.struct
class Camera:
    """Pinhole camera array: ``focal`` f (px), principal point (cx, cy) of the centre view,
    ``baseline`` B (world units per view step), ``shift`` s (px per view step)."""

    focal: float
    cx: float
    cy: float
    baseline: float
    shift: float


@wp.struct
class SceneObject:
    """One primitive at one time: local→world rotation ``rot`` and origin ``pos``.

    ``size``: plane patch (half width, half height, unused) in its local z = 0 plane;
    sphere (radius, unused, unused); box (three half extents). Texture: value noise of the
    local point times ``tex_freq`` (features per world unit), ``tex_mean ± tex_contrast``,
    tinted by ``colour``; or, where ``tex_image`` ≥ 0, that image of the render's image
    stack (its top-left ``tex_height`` × ``tex_width`` texels, RGB), ``tex_scale`` texels
    per world unit, its centre at the local origin, tinted by ``colour``.
    """

    kind: int
    rot: wp.mat33
    pos: wp.vec3
    size: wp.vec3
    tex_seed: int
    tex_freq: float
    tex_mean: float
    tex_contrast: float
    colour: wp.vec3
    tex_image: int
    tex_scale: float
    tex_width: int
    tex_height: int


@wp.func
def hash01(x: int, y: int, z: int, seed: int):
    """Integer hash of a lattice point to [0, 1] (same on every device)."""
    h = wp.uint32(x) * wp.uint32(0x27D4EB2F) + wp.uint32(y) * wp.uint32(0x165667B1)
    h = h + wp.uint32(z) * wp.uint32(0x5BD1E995) + wp.uint32(seed) * wp.uint32(0x68E31DA4)
    h = (h ^ (h >> wp.uint32(15))) * wp.uint32(0x2C1B3C6D)
    h = (h ^ (h >> wp.uint32(12))) * wp.uint32(0x297A2D39)
    h = h ^ (h >> wp.uint32(15))
    return float(h) * (1.0 / 4294967295.0)


@wp.func
def fade(t: float):
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


@wp.func
def value_noise(p: wp.vec3, seed: int):
    """Smooth value noise in [−1, 1], one feature per unit (quintic interpolation)."""
    fx = wp.floor(p[0])
    fy = wp.floor(p[1])
    fz = wp.floor(p[2])
    ix = int(fx)
    iy = int(fy)
    iz = int(fz)
    tx = fade(p[0] - fx)
    ty = fade(p[1] - fy)
    tz = fade(p[2] - fz)
    c000 = hash01(ix, iy, iz, seed)
    c100 = hash01(ix + 1, iy, iz, seed)
    c010 = hash01(ix, iy + 1, iz, seed)
    c110 = hash01(ix + 1, iy + 1, iz, seed)
    c001 = hash01(ix, iy, iz + 1, seed)
    c101 = hash01(ix + 1, iy, iz + 1, seed)
    c011 = hash01(ix, iy + 1, iz + 1, seed)
    c111 = hash01(ix + 1, iy + 1, iz + 1, seed)
    x00 = wp.lerp(c000, c100, tx)
    x10 = wp.lerp(c010, c110, tx)
    x01 = wp.lerp(c001, c101, tx)
    x11 = wp.lerp(c011, c111, tx)
    return 2.0 * wp.lerp(wp.lerp(x00, x10, ty), wp.lerp(x01, x11, ty), tz) - 1.0


@wp.func
def texture_value(obj: SceneObject, local: wp.vec3):
    """Grey value in [0, 1] of the object's solid texture at a local point: three octaves
    of value noise plus a layer of soft-edged blobs (edges inside the texture)."""
    # Each octave sees the point through a fixed rotation, which hides the lattice axes.
    rot = wp.mat33(0.36, 0.48, -0.8, -0.8, 0.6, 0.0, 0.48, 0.64, 0.6)
    p = local * obj.tex_freq
    n = 0.55 * value_noise(p, obj.tex_seed)
    p = rot * p
    n = n + 0.3 * value_noise(p * 2.03, obj.tex_seed + 17)
    p = rot * p
    n = n + 0.15 * value_noise(p * 4.01, obj.tex_seed + 31)
    p = rot * p
    blob = wp.smoothstep(-0.08, 0.08, value_noise(p * 0.61, obj.tex_seed + 53)) - 0.5
    return wp.clamp(obj.tex_mean + obj.tex_contrast * (n + 0.8 * blob), 0.0, 1.0)


@wp.func
def mirror(x: float, n: int):
    """Texel coordinate ``x`` of an image n texels wide (texel k covers [k − ½, k + ½])
    folded back into it by mirrored repetition, each edge texel repeated as in a mirror
    (period 2n), then clamped to the texel centres [0, n − 1] for a bilinear lookup."""
    period = 2.0 * float(n)
    t = x + 0.5
    t = t - period * wp.floor(t / period)
    t = wp.where(t > float(n), period - t, t)
    return wp.clamp(t - 0.5, 0.0, float(n - 1))


@wp.func
def image_value(images: wp.array4d(dtype=float), obj: SceneObject, local: wp.vec3):
    """RGB of the object's image texture at a local point: the image lies in the plane of
    the two local axes other than the one along which the point lies furthest out
    (relative to a box's half extents; a plane patch's own z), its centre at the local
    origin, ``tex_scale`` texels per world unit, bilinear, repeated mirrored."""
    a = int(0)
    b = int(1)
    if obj.kind != KIND_PLANE:
        q = local
        if obj.kind == KIND_BOX:
            q = wp.cw_div(local, obj.size)
        qx = wp.abs(q[0])
        qy = wp.abs(q[1])
        qz = wp.abs(q[2])
        if qx >= qy and qx >= qz:
            a = 1
            b = 2
        elif qy >= qz:
            a = 0
            b = 2
    w = obj.tex_width
    h = obj.tex_height
    x = mirror(local[a] * obj.tex_scale + 0.5 * float(w) - 0.5, w)
    y = mirror(local[b] * obj.tex_scale + 0.5 * float(h) - 0.5, h)
    j0 = wp.min(int(x), w - 2)
    i0 = wp.min(int(y), h - 2)
    fx = x - float(j0)
    fy = y - float(i0)
    k = obj.tex_image
    out = wp.vec3(0.0)
    for c in range(3):
        top = (1.0 - fx) * images[k, i0, j0, c] + fx * images[k, i0, j0 + 1, c]
        bottom = (1.0 - fx) * images[k, i0 + 1, j0, c] + fx * images[k, i0 + 1, j0 + 1, c]
        out[c] = (1.0 - fy) * top + fy * bottom
    return out


@wp.func
def intersect(obj: SceneObject, origin: wp.vec3, direction: wp.vec3):
    """Ray parameter t of the first hit (``NO_HIT`` if none) and the hit point in the
    object's local frame. The ray is ``origin + t·direction``, t > 0."""
    rt = wp.transpose(obj.rot)
    o = rt * (origin - obj.pos)
    d = rt * direction
    t = NO_HIT
    if obj.kind == KIND_PLANE:
        if wp.abs(d[2]) > 1.0e-12:
            tp = -o[2] / d[2]
            if tp > 1.0e-6:
                h = o + tp * d
                if wp.abs(h[0]) <= obj.size[0] and wp.abs(h[1]) <= obj.size[1]:
                    t = tp
    elif obj.kind == KIND_SPHERE:
        r = obj.size[0]
        a = wp.dot(d, d)
        b = wp.dot(o, d)
        c = wp.dot(o, o) - r * r
        disc = b * b - a * c
        if disc >= 0.0:
            sq = wp.sqrt(disc)
            t0 = (-b - sq) / a
            t1 = (-b + sq) / a
            if t0 > 1.0e-6:
                t = t0
            elif t1 > 1.0e-6:
                t = t1
    else:
        tnear = -NO_HIT
        tfar = NO_HIT
        for k in range(3):
            if wp.abs(d[k]) < 1.0e-12:
                if wp.abs(o[k]) > obj.size[k]:
                    tfar = -NO_HIT
            else:
                ta = (-obj.size[k] - o[k]) / d[k]
                tb = (obj.size[k] - o[k]) / d[k]
                tnear = wp.max(tnear, wp.min(ta, tb))
                tfar = wp.min(tfar, wp.max(ta, tb))
        if tnear <= tfar:
            if tnear > 1.0e-6:
                t = tnear
            elif tfar > 1.0e-6:
                t = tfar
    return t, o + t * d


@wp.func
def trace(objects: wp.array(dtype=SceneObject), origin: wp.vec3, direction: wp.vec3):
    """Nearest object hit along a ray: (object index or −1, ray parameter, local hit point)."""
    best = int(-1)
    best_t = float(NO_HIT)
    best_local = wp.vec3(0.0)
    for k in range(objects.shape[0]):
        t, local = intersect(objects[k], origin, direction)
        if t < best_t:
            best = k
            best_t = t
            best_local = local
    return best, best_t, best_local


@wp.func
def view_ray(cam: Camera, xi: float, eta: float, x: float, y: float):
    """Origin and direction of the ray through image point (x, y) of the view at φ = (ξ, η)."""
    origin = wp.vec3(xi * cam.baseline, eta * cam.baseline, 0.0)
    direction = wp.vec3(
        (x - cam.cx - xi * cam.shift) / cam.focal, (y - cam.cy - eta * cam.shift) / cam.focal, 1.0
    )
    return origin, direction


@wp.kernel
def render_views(
    row0: int,
    cam: Camera,
    objects: wp.array(dtype=SceneObject),
    grid_cols: int,
    centre_row: float,
    centre_col: float,
    supersample: int,
    images: wp.array4d(dtype=float),
    # outputs
    views: wp.array4d(dtype=float),
):
    """Render every view of the light field, ``supersample²`` rays per pixel (box filter).

    Launch over (views × rows, columns); ``views`` is [view, y, x, channel] with view =
    a·cols + b; one channel writes the BT.601 luma of the colour, three write RGB.
    ``images`` [image, y, x, RGB] holds the objects' image textures (any array of that
    rank where no object has one).
    """
    i, x = wp.tid()
    i = i + row0
    height = views.shape[1]
    view = i // height
    y = i - view * height
    a = view // grid_cols
    b = view - a * grid_cols
    xi = float(b) - centre_col
    eta = float(a) - centre_row
    inv = 1.0 / float(supersample)
    acc = wp.vec3(0.0)
    for sy in range(supersample):
        for sx in range(supersample):
            px = float(x) + (float(sx) + 0.5) * inv - 0.5
            py = float(y) + (float(sy) + 0.5) * inv - 0.5
            origin, direction = view_ray(cam, xi, eta, px, py)
            k, t, local = trace(objects, origin, direction)
            if k >= 0:
                obj = objects[k]
                if obj.tex_image >= 0:
                    acc = acc + wp.cw_mul(image_value(images, obj, local), obj.colour)
                else:
                    acc = acc + texture_value(obj, local) * obj.colour
            else:
                acc = acc + wp.vec3(0.5)
    colour = acc * (inv * inv)
    if views.shape[3] == 1:
        views[view, y, x, 0] = 0.299 * colour[0] + 0.587 * colour[1] + 0.114 * colour[2]
    else:
        for c in range(3):
            views[view, y, x, c] = colour[c]


@wp.func
def disparity_of_depth(cam: Camera, z: float):
    return cam.focal * cam.baseline / z - cam.shift


@wp.kernel
def ground_truth(
    row0: int,
    cam: Camera,
    objects1: wp.array(dtype=SceneObject),
    objects2: wp.array(dtype=SceneObject),
    width: int,
    height: int,
    # outputs
    disp1: wp.array2d(dtype=float),
    disp2: wp.array2d(dtype=float),
    flow_u: wp.array2d(dtype=float),
    flow_v: wp.array2d(dtype=float),
    valid: wp.array2d(dtype=wp.uint8),
    occluded: wp.array2d(dtype=wp.uint8),
):
    """Exact scene flow of the centre view (φ = 0) at each pixel centre.

    δ1: disparity at t1 of the point seen at p; the same point, moved rigidly with its
    object, gives δ2 (its disparity at t2) and the flow u = p2 − p (``help(lfsf)``, MODEL.md §1).
    ``valid`` is 0 where the pixel's footprint (centre and corners) sees more than one
    object (a depth edge); ``occluded`` is 1 where the point is hidden or out of the
    image at t2. Launch over (height, width).
    """
    i, j = wp.tid()
    i = i + row0
    origin, direction = view_ray(cam, 0.0, 0.0, float(j), float(i))
    k, t, local = trace(objects1, origin, direction)
    if k < 0:
        disp1[i, j] = wp.nan
        disp2[i, j] = wp.nan
        flow_u[i, j] = wp.nan
        flow_v[i, j] = wp.nan
        valid[i, j] = wp.uint8(0)
        occluded[i, j] = wp.uint8(1)
        return
    disp1[i, j] = disparity_of_depth(cam, t)  # direction has unit z, so t is the depth Z1

    same = int(1)
    for c in range(4):
        ox = 0.5 * float(2 * (c % 2) - 1)
        oy = 0.5 * float(2 * (c // 2) - 1)
        o2, d2 = view_ray(cam, 0.0, 0.0, float(j) + ox, float(i) + oy)
        kc, tc, lc = trace(objects1, o2, d2)
        if kc != k:
            same = 0
    valid[i, j] = wp.uint8(same)

    moved = objects2[k]
    world2 = moved.rot * local + moved.pos
    z2 = world2[2]
    x2 = cam.focal * world2[0] / z2 + cam.cx
    y2 = cam.focal * world2[1] / z2 + cam.cy
    disp2[i, j] = disparity_of_depth(cam, z2)
    flow_u[i, j] = x2 - float(j)
    flow_v[i, j] = y2 - float(i)

    hidden = int(0)
    if x2 < -0.5 or y2 < -0.5 or x2 > float(width) - 0.5 or y2 > float(height) - 0.5 or z2 <= 0.0:
        hidden = 1
    else:
        o3, d3 = view_ray(cam, 0.0, 0.0, x2, y2)
        k3, t3, l3 = trace(objects2, o3, d3)
        if k3 != k or wp.abs(t3 - z2) > 1.0e-4 * z2:
            hidden = 1
    occluded[i, j] = wp.uint8(hidden)
