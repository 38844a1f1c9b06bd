"""NumPy reference of the renderer kernels (kernels/render.py), for tiny inputs.

Written from the formulas, not from the kernel code paths: vectorised over rays, float64.
"""

import numpy as np

from lfsf import synth

KINDS = {"plane": 0, "sphere": 1, "box": 2}
NO_HIT = 1.0e30
OCTAVE_ROTATION = np.array([[0.36, 0.48, -0.8], [-0.8, 0.6, 0.0], [0.48, 0.64, 0.6]])


def hash01(x, y, z, seed):
    u = lambda a: np.asarray(a, dtype=np.int64).astype(np.uint32)  # two's-complement wrap
    with np.errstate(over="ignore"):
        h = u(x) * np.uint32(0x27D4EB2F) + u(y) * np.uint32(0x165667B1)
        h = h + u(z) * np.uint32(0x5BD1E995) + u(seed) * np.uint32(0x68E31DA4)
        h = (h ^ (h >> np.uint32(15))) * np.uint32(0x2C1B3C6D)
        h = (h ^ (h >> np.uint32(12))) * np.uint32(0x297A2D39)
        h = h ^ (h >> np.uint32(15))
    return h.astype(np.float64) / 4294967295.0


def value_noise(p, seed):
    f = np.floor(p)
    i = f.astype(np.int64)
    t = p - f
    t = t * t * t * (t * (t * 6 - 15) + 10)
    out = 0.0
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                w = (t[..., 0] if dx else 1 - t[..., 0]) * (t[..., 1] if dy else 1 - t[..., 1]) * (
                    t[..., 2] if dz else 1 - t[..., 2])
                out = out + w * hash01(i[..., 0] + dx, i[..., 1] + dy, i[..., 2] + dz, seed)
    return 2.0 * out - 1.0


def smoothstep(e0, e1, x):
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


def texture(obj, local):
    p = local * obj["freq"]
    s = obj["seed"]
    n = 0.55 * value_noise(p, s)
    p = p @ OCTAVE_ROTATION.T
    n = n + 0.3 * value_noise(p * 2.03, s + 17)
    p = p @ OCTAVE_ROTATION.T
    n = n + 0.15 * value_noise(p * 4.01, s + 31)
    p = p @ OCTAVE_ROTATION.T
    blob = smoothstep(-0.08, 0.08, value_noise(p * 0.61, s + 53)) - 0.5
    return np.clip(obj["mean"] + obj["contrast"] * (n + 0.8 * blob), 0.0, 1.0)


def intersect(obj, origin, direction):
    """Ray parameter of the first hit (NO_HIT if none) and the local hit point, per ray."""
    o = (origin - obj["pos"]) @ obj["rot"]  # rotᵀ·(origin − pos), row vectors
    d = direction @ obj["rot"]
    size = obj["size"]
    with np.errstate(divide="ignore", invalid="ignore"):
        if obj["kind"] == 0:
            t = -o[..., 2] / d[..., 2]
            h = o + t[..., None] * d
            hit = (t > 1e-6) & (np.abs(h[..., 0]) <= size[0]) & (np.abs(h[..., 1]) <= size[1])
        elif obj["kind"] == 1:
            a = np.sum(d * d, -1)
            b = np.sum(o * d, -1)
            c = np.sum(o * o, -1) - size[0] ** 2
            disc = b * b - a * c
            sq = np.sqrt(np.maximum(disc, 0))
            t0, t1 = (-b - sq) / a, (-b + sq) / a
            t = np.where(t0 > 1e-6, t0, t1)
            hit = (disc >= 0) & (t > 1e-6)
        else:
            ta = (-size - o) / d
            tb = (size - o) / d
            tnear = np.max(np.minimum(ta, tb), -1)
            tfar = np.min(np.maximum(ta, tb), -1)
            t = np.where(tnear > 1e-6, tnear, tfar)
            hit = (tnear <= tfar) & (t > 1e-6)
    t = np.where(hit, t, NO_HIT)
    return t, o + np.where(hit, t, 0.0)[..., None] * d


def trace(objects, origin, direction):
    best = np.full(direction.shape[:-1], -1)
    best_t = np.full(direction.shape[:-1], NO_HIT)
    best_local = np.zeros(direction.shape)
    for k, obj in enumerate(objects):
        t, local = intersect(obj, origin, direction)
        closer = t < best_t
        best = np.where(closer, k, best)
        best_t = np.where(closer, t, best_t)
        best_local = np.where(closer[..., None], local, best_local)
    return best, best_t, best_local


def image_texture(obj, local):
    """RGB of an image texture: the image (w × h texels, texel k covering [k − ½, k + ½])
    in the plane of the two local axes other than the one along which the point lies
    furthest out (in units of a box's half extents), centred on the local origin,
    obj["scale"] texels per world unit, repeated mirrored with period 2w (each edge
    texel doubled), bilinear between texel centres."""
    img = obj["image"]
    h, w = img.shape[:2]
    if obj["kind"] == 0:
        axis = np.full(local.shape[:-1], 2)
    else:
        q = local / obj["size"] if obj["kind"] == 2 else local
        axis = np.argmax(np.abs(q), -1)  # (ties: x, then y, as the kernel)
    others = np.array([[1, 2], [0, 2], [0, 1]])[axis]
    a = np.take_along_axis(local, others[..., :1], -1)[..., 0]
    b = np.take_along_axis(local, others[..., 1:], -1)[..., 0]

    def fold(t, n):
        """Texel coordinate folded into the image: its position from the image's left
        edge, t + ½, modulo 2n, reflected from the far half, clamped to the centres."""
        e = np.mod(t + 0.5, 2.0 * n)
        e = np.where(e > n, 2.0 * n - e, e)
        return np.clip(e - 0.5, 0.0, n - 1.0)

    x = fold(a * obj["scale"] + (w - 1) / 2, w)
    y = fold(b * obj["scale"] + (h - 1) / 2, h)
    j0 = np.minimum(np.floor(x).astype(int), w - 2)
    i0 = np.minimum(np.floor(y).astype(int), h - 2)
    fx, fy = (x - j0)[..., None], (y - i0)[..., None]
    return ((1 - fy) * ((1 - fx) * img[i0, j0] + fx * img[i0, j0 + 1])
            + fy * ((1 - fx) * img[i0 + 1, j0] + fx * img[i0 + 1, j0 + 1]))


def prefiltered(img, shrink):
    """An image seen `shrink` texels per pixel, as the renderer should sample it: k × k
    block means for k = ⌊shrink/2⌋ when shrink ≥ 4 (cut about the centre to whole blocks),
    then a Gaussian that makes the total blur σ = shrink/2 original texels (a k-box
    counting k²/12 of variance), edges mirrored with the edge texel repeated.
    Returns (image, k)."""
    img = np.asarray(img, np.float64)
    k = max(1, min(int(shrink // 2) if shrink >= 4 else 1, min(img.shape[:2]) // 2))
    var = (shrink / 2) ** 2 if shrink > 1 else 0.0
    if k > 1:
        h, w = img.shape[0] // k * k, img.shape[1] // k * k
        i0, j0 = (img.shape[0] - h) // 2, (img.shape[1] - w) // 2
        img = img[i0:i0 + h, j0:j0 + w].reshape(h // k, k, w // k, k, -1).mean((1, 3))
        var = max(0.0, var - k * k / 12) / k ** 2
    if var > 0:
        sigma = np.sqrt(var)
        r = max(1, int(np.ceil(3 * sigma)))
        g = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
        g /= g.sum()
        for axis in (0, 1):
            n = img.shape[axis]
            idx = np.arange(-r, n + r)
            idx = np.where(idx < 0, -idx - 1, idx)          # mirrored, the edge texel repeated
            idx = np.where(idx >= n, 2 * n - 1 - idx, idx)  # (r < n here)
            padded = np.take(img, idx, axis=axis)
            img = sum(g[i] * np.take(padded, np.arange(i, i + n), axis=axis) for i in range(2 * r + 1))
    return img, k


def scene_objects(scene, cam, stack=None):
    """Per time, a list of dicts describing each primitive (from synth's own geometry);
    an object with an image texture takes the next image of ``stack`` (float (h, w, 3),
    one per such object in the scene's order, as given, before any prefilter)."""
    times = ([], [])
    images = iter(stack or ())
    for prim in synth.get_scene(scene).objects:
        (p1, p2), size, freq = synth._object_poses(prim, cam)
        extra = {}
        if prim.texture.image >= 0:
            img = np.asarray(next(images), np.float64)
            span = prim.texture.image_span * cam.width / synth.REFERENCE_WIDTH  # px at the object's depth
            seen, k = prefiltered(img, img.shape[1] / span)
            extra = dict(image=seen, scale=img.shape[1] / (k * span * prim.depth / cam.focal))
        for (rot, pos), out in zip((p1, p2), times):
            out.append(dict(kind=KINDS[prim.kind], rot=rot, pos=pos, size=size, freq=freq,
                            seed=prim.texture.seed, mean=prim.texture.mean,
                            contrast=prim.texture.contrast, colour=np.asarray(prim.texture.colour), **extra))
    return times


def rays(cam, xi, eta, x, y):
    origin = np.array([xi * cam.baseline, eta * cam.baseline, 0.0])
    d = np.stack([(x - cam.cx - xi * cam.shift) / cam.focal, (y - cam.cy - eta * cam.shift) / cam.focal,
                  np.ones_like(x)], -1)
    return np.broadcast_to(origin, d.shape), d


def render(scene, size, grid, supersample, stack=None):
    """Grey views [t][a, b, y, x] of both times (``stack``: as :func:`scene_objects`)."""
    width, height = size
    cam = synth.CameraArray.for_size(width, height)
    out = []
    for objects in scene_objects(scene, cam, stack):
        views = np.zeros((grid, grid, height, width))
        for a in range(grid):
            for b in range(grid):
                xi, eta = b - (grid - 1) / 2, a - (grid - 1) / 2
                acc = np.zeros((height, width, 3))
                for sy in range(supersample):
                    for sx in range(supersample):
                        y, x = np.mgrid[0:height, 0:width].astype(np.float64)
                        x = x + (sx + 0.5) / supersample - 0.5
                        y = y + (sy + 0.5) / supersample - 0.5
                        k, t, local = trace(objects, *rays(cam, xi, eta, x, y))
                        for idx, obj in enumerate(objects):
                            m = k == idx
                            if "image" in obj:
                                acc[m] += image_texture(obj, local[m]) * obj["colour"]
                            else:
                                acc[m] += texture(obj, local[m])[:, None] * obj["colour"]
                        acc[k < 0] += 0.5
                rgb = acc / supersample**2
                views[a, b] = rgb @ np.array([0.299, 0.587, 0.114])
        out.append(views)
    return out


def ground_truth(scene, size):
    width, height = size
    cam = synth.CameraArray.for_size(width, height)
    obj1, obj2 = scene_objects(scene, cam)
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    k, t, local = trace(obj1, *rays(cam, 0.0, 0.0, x, y))
    same = np.ones_like(k, dtype=bool)
    for ox in (-0.5, 0.5):
        for oy in (-0.5, 0.5):
            same &= trace(obj1, *rays(cam, 0.0, 0.0, x + ox, y + oy))[0] == k
    world2 = np.zeros(local.shape)
    for idx, obj in enumerate(obj2):
        m = k == idx
        world2[m] = local[m] @ obj["rot"].T + obj["pos"]
    z2 = world2[..., 2]
    x2 = cam.focal * world2[..., 0] / z2 + cam.cx
    y2 = cam.focal * world2[..., 1] / z2 + cam.cy
    k3, t3, _ = trace(obj2, *rays(cam, 0.0, 0.0, x2, y2))
    outside = (x2 < -0.5) | (y2 < -0.5) | (x2 > width - 0.5) | (y2 > height - 0.5)
    occluded = outside | (k3 != k) | (np.abs(t3 - z2) > 1e-4 * z2)
    return dict(disp1=cam.disparity(t), disp2=cam.disparity(z2), u=x2 - x, v=y2 - y, valid=same,
                occluded=occluded)
