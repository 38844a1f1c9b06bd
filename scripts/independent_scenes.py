#!/usr/bin/env python
"""Scenes from a second, independent renderer, for checking that lfsf's accuracy is not
tuned to its own scenes (:mod:`lfsf.synth`): other textures (photographs from
scikit-image, band-limited noise at other scales, sparse dots, blank cards), other motions
(turns in the image plane, looming and receding objects, shear, a camera that moves or
rolls), thin objects and wide disparity ranges. Written apart from lfsf.synth (a
helper's, sixty-first session), checked by its own identities (:func:`self_check`).

The model: piecewise-planar layers in disparity space. A layer has a texture T (bilinear,
mirrored outside), a shape in texture coordinates r, and at each time t an affine pose:
centre-view position p_t(r) = c_t + A_t r and disparity δ_t(r) = d_t + ∇δ_t · (A_t r) (a
3-D plane). In the view at angular offset φ = (ξ, η) the point appears at p_t(r) − δ_t(r) φ
(MODEL.md §1), which is affine in r and inverted exactly per view pixel; the nearest
layer (largest δ) wins, and each pixel averages 2×2 samples. The ground truth at a t1
centre pixel p comes from the same poses: δ1, u = p_2(r) − p, δ2 = δ_2(r) (the t2
disparity of the same point), ``occluded`` where a nearer layer covers p + u at t2 or
p + u leaves the image, and ``valid`` false where a pixel's footprint sees two layers (as
lfsf.synth's; the scores leave those out). Every object is placed 0.27, 0.31 px off the pixel grid, so that
straight outlines do not run through pixel centres (a pixel half on each side has an
arbitrary truth: lfsf's δ1 MSE on such a scene moved 3–15× with it).

Needs scikit-image (the ``peers`` extra) for the photographs. Used by
``scripts/compare_peers.py --independent`` (every scene here, against the peers, with the
project's bars); on its own::

    python scripts/independent_scenes.py --list
    python scripts/independent_scenes.py --check          # the renderer's identities
"""

import argparse
import math
import sys
import zlib
from dataclasses import dataclass

import numpy as np

#: The scene names' prefix in ``scripts/compare_peers.py``.
PREFIX = "indep-"


def rot(deg, s=1.0, shear=(0.0, 0.0), aniso=(1.0, 1.0)):
    """A = s * R(deg) @ [[ax, hx], [hy, ay]]"""
    t = math.radians(deg)
    R = np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]])
    S = np.array([[aniso[0], shear[0]], [shear[1], aniso[1]]])
    return s * R @ S


@dataclass
class Pose:
    c: tuple            # centre-view position (x, y) of the anchor
    A: np.ndarray       # 2x2, texture -> image
    d: float            # disparity at the anchor
    gimg: tuple = (0.0, 0.0)   # d delta / d p (image px), the plane's slant

    @property
    def g(self):
        return np.asarray(self.A).T @ np.asarray(self.gimg, float)


@dataclass
class Layer:
    tex: np.ndarray
    q0: tuple                       # anchor in texture pixel coords (x, y)
    t1: Pose
    t2: Pose
    shape: tuple = ("full",)        # ("rect", hw, hh) | ("disk", r) | ("ring", r0, r1) | ("full",)
    name: str = ""


def inside(shape, rx, ry):
    k = shape[0]
    if k == "full":
        return np.ones(rx.shape, bool)
    if k == "rect":
        return (np.abs(rx) <= shape[1]) & (np.abs(ry) <= shape[2])
    if k == "disk":
        return rx * rx + ry * ry <= shape[1] ** 2
    if k == "ring":
        rr = rx * rx + ry * ry
        return (rr <= shape[2] ** 2) & (rr >= shape[1] ** 2)
    raise ValueError(k)


def sample_tex(tex, qx, qy):
    """Bilinear samples of ``tex`` at (qx, qy), mirrored about its first and last pixels
    outside it (SciPy's ``map_coordinates(order=1, mode="mirror")``, in NumPy)."""
    def fold(q, n):
        period = 2 * (n - 1)
        q = np.abs(np.asarray(q, float)) % period
        return np.where(q > n - 1, period - q, q)

    h, w = tex.shape
    x, y = fold(qx, w), fold(qy, h)
    x0 = np.minimum(np.floor(x).astype(int), w - 2)
    y0 = np.minimum(np.floor(y).astype(int), h - 2)
    fx, fy = x - x0, y - y0
    return ((1 - fy) * ((1 - fx) * tex[y0, x0] + fx * tex[y0, x0 + 1])
            + fy * ((1 - fx) * tex[y0 + 1, x0] + fx * tex[y0 + 1, x0 + 1]))


def layer_at(layer, t, phi, X, Y):
    """r, inside, delta of a layer at view positions (X, Y) of view phi at time t."""
    P = layer.t1 if t == 1 else layer.t2
    A = np.asarray(P.A, float)
    g = P.g
    ph = np.asarray(phi, float)
    B = A - np.outer(ph, g)
    Bi = np.linalg.inv(B)
    bx = X - P.c[0] + P.d * ph[0]
    by = Y - P.c[1] + P.d * ph[1]
    rx = Bi[0, 0] * bx + Bi[0, 1] * by
    ry = Bi[1, 0] * bx + Bi[1, 1] * by
    delta = P.d + g[0] * rx + g[1] * ry
    return rx, ry, inside(layer.shape, rx, ry), delta


def render_points(layers, t, phi, X, Y):
    """Intensity, front delta and front layer index at arbitrary points of a view."""
    best = np.full(X.shape, -np.inf)
    val = np.zeros(X.shape)
    idx = np.full(X.shape, -1)
    for k, L in enumerate(layers):
        rx, ry, m, dl = layer_at(L, t, phi, X, Y)
        win = m & (dl > best)
        if win.any():
            v = sample_tex(L.tex, L.q0[0] + rx[win], L.q0[1] + ry[win])
            val[win] = v
            best[win] = dl[win]
            idx[win] = k
    return val, best, idx


def render(layers, size=(160, 120), grid=9, t=1, ss=2):
    W, H = size
    ac = bc = (grid - 1) / 2
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    offs = [((i + 0.5) / ss - 0.5) for i in range(ss)]
    views = np.zeros((grid, grid, H, W), np.float32)
    for a in range(grid):
        for b in range(grid):
            phi = (b - bc, a - ac)
            acc = np.zeros((H, W))
            for oy in offs:
                for ox in offs:
                    v, _, _ = render_points(layers, t, phi, xx + ox, yy + oy)
                    acc += v
            views[a, b] = acc / (ss * ss)
    return views


def ground_truth(layers, size=(160, 120)):
    W, H = size
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    best = np.full((H, W), -np.inf)
    front = np.full((H, W), -1)
    R = {}
    for k, L in enumerate(layers):
        rx, ry, m, dl = layer_at(L, 1, (0.0, 0.0), xx, yy)
        win = m & (dl > best)
        best[win] = dl[win]
        front[win] = k
        R[k] = (rx, ry)
    assert (front >= 0).all(), "a pixel sees no layer"
    d1 = best
    d2 = np.zeros((H, W))
    u = np.zeros((H, W))
    v = np.zeros((H, W))
    for k, L in enumerate(layers):
        m = front == k
        rx, ry = R[k][0][m], R[k][1][m]
        P = L.t2
        A = np.asarray(P.A, float)
        px = P.c[0] + A[0, 0] * rx + A[0, 1] * ry
        py = P.c[1] + A[1, 0] * rx + A[1, 1] * ry
        g = P.g
        d2[m] = P.d + g[0] * rx + g[1] * ry
        u[m] = px - xx[m]
        v[m] = py - yy[m]
    # occlusion at t2: z-buffer at p + u in the t2 centre view
    X2, Y2 = xx + u, yy + v
    _, best2, _ = render_points(layers, 2, (0.0, 0.0), X2, Y2)
    occ = best2 > d2 + 1e-6
    occ |= (X2 < 0) | (X2 > W - 1) | (Y2 < 0) | (Y2 > H - 1)
    # a pixel whose footprint (its centre and four corners) sees more than one layer
    # straddles an outline: its truth (the centre's layer) is one of two, as lfsf.synth's
    # ``valid`` leaves out too
    straddles = np.zeros((H, W), bool)
    for dx, dy in ((-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5)):
        straddles |= render_points(layers, 1, (0.0, 0.0), xx + dx, yy + dy)[2] != front
    return dict(disp1=d1.astype(np.float32), disp2=d2.astype(np.float32), u=u.astype(np.float32),
                v=v.astype(np.float32), occluded=occ, valid=~straddles)


# --- textures ---------------------------------------------------------------------------

def _grey(img):
    from lfsf.io import BT601_LUMA

    img = np.asarray(img, float)
    if img.ndim == 3:
        img = img[..., :3] @ np.array(BT601_LUMA)
    return img / 255.0


def gaussian_wrap(img, sigma):
    """``img`` blurred by a Gaussian of ``sigma`` px (truncated at 4σ), wrapped around its
    edges (SciPy's ``gaussian_filter(mode="wrap")``, by FFT)."""
    h, w = img.shape
    r = int(4.0 * sigma + 0.5)
    taps = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    taps /= taps.sum()
    # (separable: the 2-D kernel wrapped onto the image is the outer product of the 1-D ones)
    ky, kx = np.zeros(h), np.zeros(w)
    np.add.at(ky, np.arange(-r, r + 1) % h, taps)
    np.add.at(kx, np.arange(-r, r + 1) % w, taps)
    return np.real(np.fft.ifft2(np.fft.fft2(img) * np.fft.fft2(np.outer(ky, kx))))


def natural(name, contrast=1.0):
    from skimage import data
    img = _grey(getattr(data, name)())
    m = img.mean()
    return np.clip(m + contrast * (img - m), 0, 1)


def noise_tex(sigma, seed, size=600, std=0.18, mean=0.5):
    rng = np.random.default_rng(seed)
    n = gaussian_wrap(rng.standard_normal((size, size)), sigma)
    n = n / n.std()
    return np.clip(mean + std * n, 0, 1)


def dots_tex(n, seed, size=600, radius=2.0, amp=0.35, base=0.5):
    rng = np.random.default_rng(seed)
    img = np.zeros((size, size))
    ys = rng.integers(0, size, n)
    xs = rng.integers(0, size, n)
    img[ys, xs] = rng.choice([-1.0, 1.0], n)
    img = gaussian_wrap(img, radius)
    img = img / np.abs(img).max()
    return np.clip(base + amp * img, 0, 1)


def flat_tex(value=0.5, size=64):
    return np.full((size, size), value)


# --- scenes -----------------------------------------------------------------------------

I = np.eye(2)


def backdrop(tex, d1, d2=None, shift=(0, 0), gimg1=(0, 0), gimg2=None, A1=I, A2=None, size=(160, 120), name="back"):
    W, H = size
    q0 = (tex.shape[1] / 2, tex.shape[0] / 2)
    c = (W / 2, H / 2)
    return Layer(tex, q0, Pose(c, A1, d1, gimg1),
                 Pose((c[0] + shift[0], c[1] + shift[1]), A1 if A2 is None else A2,
                      d1 if d2 is None else d2, gimg1 if gimg2 is None else gimg2), ("full",), name)


#: sub-pixel offset of every object (same at t1 and t2, so flows are unchanged): keeps straight
#: outlines off pixel centres, where a pixel half covered by each side has an arbitrary truth
OFFSET = (0.27, 0.31)


def obj(tex, shape, c1, c2, d1, d2=None, A1=I, A2=None, gimg1=(0, 0), gimg2=None, q0=None, name="obj"):
    c1 = (c1[0] + OFFSET[0], c1[1] + OFFSET[1])
    c2 = (c2[0] + OFFSET[0], c2[1] + OFFSET[1])
    q0 = q0 or (tex.shape[1] / 2, tex.shape[0] / 2)
    # shapes are given in image pixels at t1: convert to texture units by A1's scale
    sc = float(np.sqrt(abs(np.linalg.det(np.asarray(A1, float)))))
    shape = (shape[0],) + tuple(x / sc for x in shape[1:])
    return Layer(tex, q0, Pose(c1, A1, d1, gimg1),
                 Pose(c2, A1 if A2 is None else A2, d1 if d2 is None else d2, gimg1 if gimg2 is None else gimg2),
                 shape, name)


def scene(name, size=(160, 120)):
    """-> (layers, noise sigma, description)"""
    W, H = size
    k = W / 160.0
    cx, cy = W / 2, H / 2
    if name == "v_plane":       # validation: one constant-disparity plane shifted as a whole
        return [backdrop(natural("camera"), 0.7, shift=(3.2 * k, -1.7 * k), size=size)], 0.0, \
            "camera texture, δ=0.7 const, shifted (3.2,-1.7)"
    if name == "v_plane_noise":  # validation 2: smooth band-limited noise plane, slanted δ, shifted
        return [backdrop(noise_tex(2.0, 3), 0.5, shift=(3.2 * k, -1.7 * k), gimg1=(0.005 / k, 0.0), size=size)], 0.0, \
            "noise σ2 texture, δ 0.1…0.9 slanted, shifted (3.2,-1.7)"
    if name == "rot_disk":      # in-plane rotation 12 deg of a disk
        return [backdrop(natural("brick"), -0.6, shift=(1.0 * k, 0.5 * k), size=size),
                obj(natural("astronaut"), ("disk", 40 * k), (cx - 10 * k, cy), (cx - 8 * k, cy + 1 * k), 1.2,
                    A2=rot(12), name="disk")], 0.0, "astronaut disk δ1.2 rotating 12°, brick backdrop"
    if name == "rot_big":       # 25 deg rotation of a square, slanted
        return [backdrop(noise_tex(3, 1), -1.0, shift=(-1.5 * k, 0), gimg1=(0.004 / k, 0), size=size),
                obj(natural("coffee"), ("rect", 30 * k, 25 * k), (cx, cy), (cx + 2 * k, cy - 2 * k), 0.8,
                    A1=rot(0, k * 1.0), A2=rot(25, k * 1.0), name="sq")], 0.0, \
            "coffee square rotating 25° (flow ≤13 px at corners), noise σ3 backdrop"
    if name == "loom":          # looming: scale 1 -> 1.3, δ 0.4 -> 1.3 (δ0 = 2.6)
        return [backdrop(natural("gravel"), -0.8, shift=(0.5 * k, 0.5 * k), size=size),
                obj(natural("coffee"), ("rect", 28 * k, 22 * k), (cx + 5 * k, cy), (cx + 7 * k, cy + 1 * k), 0.4, 1.3,
                    A1=rot(0, k), A2=rot(0, 1.3 * k), name="loomer")], 0.0, \
            "coffee card looming: scale ×1.3, δ 0.4→1.3, gravel backdrop"
    if name == "recede":        # receding: scale 1 -> 0.75, δ 1.6 -> 0.8
        return [backdrop(natural("grass"), -0.5, size=size),
                obj(natural("camera"), ("disk", 38 * k), (cx, cy), (cx - 3 * k, cy + 2 * k), 1.6, 0.8,
                    A1=rot(0, k), A2=rot(5, 0.75 * k), name="receder")], 0.0, \
            "camera disk receding: scale ×0.75 + 5° turn, δ 1.6→0.8, grass backdrop"
    if name == "shear":         # non-rigid: shear + anisotropic stretch, plane tilts
        return [backdrop(natural("grass"), 0.2, shift=(2 * k, -1 * k), A1=I,
                         A2=rot(0, 1, shear=(0.10, 0.0), aniso=(1.04, 0.97)),
                         gimg1=(0.006 / k, 0.0), gimg2=(0.0, 0.008 / k), size=size),
                obj(natural("text"), ("rect", 35 * k, 15 * k), (cx - 20 * k, cy + 25 * k),
                    (cx - 16 * k, cy + 25 * k), 1.5, 1.4,
                    A1=rot(0, k), A2=rot(0, k, shear=(-0.15, 0.05)), name="text")], 0.0, \
            "grass backdrop sheared 10% and re-tilted; text card sheared 15%"
    if name == "cam_trans":     # camera translation by (4, -2) view steps: flow = -δ·(4,-2)
        ph = np.array([4.0, -2.0])
        layers = []
        for (tex, shp, c, d, g) in [(natural("brick"), ("full",), (cx, cy), -1.2, (0.003 / k, 0.002 / k)),
                                    (natural("astronaut"), ("rect", 30 * k, 35 * k), (cx - 35 * k, cy), 0.6, (0, 0)),
                                    (natural("coffee"), ("disk", 22 * k), (cx + 40 * k, cy - 15 * k), 1.8, (0, 0)),
                                    (noise_tex(2, 7), ("rect", 6 * k, 40 * k), (cx + 10 * k, cy + 10 * k), 1.2,
                                        (0, 0))]:
            Lr = obj(tex, shp, c, c, d, A1=rot(0, k), gimg1=g)
            # t2 pose: p2(r) = p1(r) - δ1(r) ph  ->  c2 = c - d ph, A2 = A - ph g^T
            A = Lr.t1.A
            gg = Lr.t1.g
            c0 = Lr.t1.c
            Lr.t2 = Pose((c0[0] - d * ph[0], c0[1] - d * ph[1]), A - np.outer(ph, gg), d, g)
            # δ2(r) = d + gimg·(A2 r) must equal δ1(r) = d + gimg·(A r): keep δ with gimg2 s.t. A2^T gimg2 = g
            Lr.t2.gimg = tuple(np.linalg.solve((A - np.outer(ph, gg)).T, gg))
            layers.append(Lr)
        return layers, 0.0, "camera translated (4,-2) view steps: every point moves -δ·(4,-2), ≤ 8 px"
    if name == "cam_forward":   # camera moves forward: each fronto layer scales about centre by (δ2+δ0)/(δ1+δ0)
        d0 = 3.0
        layers = []
        for (tex, shp, c, d1, d2) in [(natural("moon"), ("full",), (cx, cy), -1.5, -1.3),
                                      (natural("camera"), ("rect", 25 * k, 20 * k), (cx - 35 * k, cy - 20 * k),
                                          0.0, 0.45),
                                      (noise_tex(1.5, 11), ("disk", 18 * k), (cx + 30 * k, cy + 15 * k), 1.0, 1.6)]:
            s = (d2 + d0) / (d1 + d0)
            c2 = (cx + s * (c[0] - cx), cy + s * (c[1] - cy))
            layers.append(obj(tex, shp, c, c2, d1, d2, A1=rot(0, k), A2=rot(0, s * k)))
        return layers, 0.0, "camera moving forward: layers zoom about the centre ×1.13–1.15, δ rises"
    if name == "thin":          # thin bars 2-4 px over a far backdrop
        layers = [backdrop(natural("text", contrast=1.0), -1.0, shift=(-1 * k, 0), size=size)]
        for i, (x, w, dx, dy, tex) in enumerate([(40, 1.5, 5, 3, noise_tex(1.5, 21)), (80, 2.0, 6, -4,
            natural("brick")),
                                                  (120, 1.0, -5, 2, noise_tex(1.0, 22))]):
            layers.append(obj(tex, ("rect", w * k, 45 * k), (x * k, cy), ((x + dx) * k, cy + dy * k), 1.5 + 0.2 * i,
                              A1=rot(10 * (i - 1), k), A2=rot(10 * (i - 1) + 3, k), name=f"bar{i}"))
        return layers, 0.0, "three bars 2–4 px wide at δ 1.5–1.9 moving 5–7 px over a text backdrop"
    if name == "flat":          # large flat regions with sparse dots
        return [backdrop(dots_tex(300, 31), -0.5, shift=(2 * k, 1 * k), size=size),
                obj(flat_tex(0.7), ("rect", 30 * k, 22 * k), (cx - 25 * k, cy), (cx - 20 * k, cy + 3 * k), 0.8,
                    name="flat"),
                obj(natural("camera"), ("disk", 20 * k), (cx + 35 * k, cy - 10 * k), (cx + 30 * k, cy - 12 * k), 1.3,
                    A1=rot(0, k), A2=rot(0, k), name="cam")], 0.0, \
            "sparse dots backdrop (mostly flat), a textureless card, a camera disk"
    if name == "big_flow":      # flows up to ~15 px
        return [backdrop(noise_tex(1.2, 41), -0.4, shift=(-3 * k, 2 * k), size=size),
                obj(natural("astronaut"), ("rect", 26 * k, 24 * k), (cx - 30 * k, cy - 5 * k),
                    (cx - 16 * k, cy - 11 * k), 1.0, 1.1,
                    A1=rot(0, k), A2=rot(4, k), name="fast1"),
                obj(natural("coffee"), ("disk", 18 * k), (cx + 40 * k, cy + 20 * k), (cx + 29 * k, cy + 11 * k), 0.4,
                    A1=rot(0, k), A2=rot(0, k), name="fast2")], 0.0, \
            "fine noise (σ1.2) backdrop, astronaut card moving (14,-6)+4°, coffee disk (-11,-9)"
    if name == "disp_range":    # disparities ±2
        return [backdrop(natural("gravel"), -2.0, -1.8, shift=(1 * k, 0), gimg1=(0.005 / k, 0), size=size),
                obj(natural("brick"), ("rect", 30 * k, 30 * k), (cx + 10 * k, cy), (cx + 18 * k, cy + 3 * k), 2.0, 1.9,
                    A1=rot(0, k), A2=rot(-3, k), gimg1=(0, -0.004 / k), name="near")], 0.0, \
            "backdrop δ −2.0…−1.6 slanted, near card δ 2.0 moving 8 px"
    if name == "fine_noise":    # high-frequency band-limited noise
        return [backdrop(noise_tex(0.8, 51, std=0.2), -0.3, shift=(3 * k, -2 * k), size=size),
                obj(noise_tex(0.8, 52, std=0.2), ("disk", 30 * k), (cx, cy), (cx + 4 * k, cy + 5 * k), 0.9, 1.0,
                    A1=rot(0, k), A2=rot(6, k), name="d")], 0.0, \
            "fine band-limited noise σ0.8 everywhere, disk moving (4,5)+6°"
    if name == "coarse_weak":   # coarse, weak texture
        return [backdrop(noise_tex(12, 61, std=0.05), 0.5, shift=(2 * k, 1 * k), size=size, gimg1=(0, 0.004 / k)),
                obj(noise_tex(9, 62, std=0.06), ("rect", 35 * k, 25 * k), (cx, cy), (cx - 5 * k, cy + 3 * k), 1.5,
                    A1=rot(0, k), A2=rot(-4, k), name="w")], 0.0, \
            "coarse weak noise (σ 9–12, std 0.05), card moving (-5,3)−4°"
    if name == "stack_noisy":   # four layers, mixed motion, natural textures, noise 0.01
        return [backdrop(natural("brick"), -1.0, shift=(1.5 * k, -0.5 * k), size=size),
                obj(natural("text"), ("rect", 40 * k, 18 * k), (cx - 25 * k, cy - 30 * k),
                    (cx - 20 * k, cy - 28 * k), -0.2, name="a"),
                obj(natural("camera"), ("disk", 25 * k), (cx + 20 * k, cy), (cx + 24 * k, cy + 4 * k), 0.7, 0.9,
                    A1=rot(0, k), A2=rot(-8, 1.06 * k), name="b"),
                obj(natural("coffee"), ("rect", 18 * k, 18 * k), (cx - 30 * k, cy + 20 * k),
                    (cx - 22 * k, cy + 14 * k), 1.4,
                    A1=rot(0, k), A2=rot(10, k), name="c")], 0.01, \
            "four layers (brick, text, camera, coffee), translate/rotate/zoom, σ=0.01 noise"
    if name == "roll":          # camera roll 6 deg about the centre + object translation
        return [backdrop(natural("camera"), -0.7, A1=rot(0, 1.0), A2=rot(6, 1.0), size=size),
                obj(natural("coffee"), ("disk", 25 * k), (cx + 20 * k, cy + 10 * k), (cx + 12 * k, cy + 15 * k), 0.9,
                    A1=rot(0, k), A2=rot(6, k), name="o")], 0.0, \
            "whole image rolls 6° (backdrop flow ≤ 10 px at corners), a disk moves too"
    if name == "rot_noisy":
        L, _, d = scene("rot_disk", size)
        return L, 0.01, d + ", σ=0.01 noise"
    if name == "loom_noisy":
        L, _, d = scene("loom", size)
        return L, 0.01, d + ", σ=0.01 noise"
    if name == "rot_big2":     # as rot_big, a well-textured square (noise σ2.5) instead of the coffee crop
        L, n, d = scene("rot_big", size)
        L[1].tex = noise_tex(2.5, 71); L[1].q0 = (300.0, 300.0)
        return L, n, "noise-textured square rotating 25° (flow ≤ 20 px), noise σ3 backdrop"
    if name == "loom2":        # as loom, astronaut texture (2-D structure) instead of the coffee crop
        L, n, d = scene("loom", size)
        L[1].tex = natural("astronaut"); L[1].q0 = (230.0, 150.0)
        return L, n, "astronaut-face card looming: scale ×1.3, δ 0.4→1.3, gravel backdrop"
    if name == "sparse":       # denser dots than flat: a sparse texture with 10-px spacing
        return [backdrop(dots_tex(3500, 81, radius=1.2), -0.5, shift=(2 * k, 1 * k), size=size),
                obj(dots_tex(3500, 82, radius=1.2), ("rect", 30 * k, 22 * k), (cx - 25 * k, cy),
                    (cx - 20 * k, cy + 3 * k), 0.8, name="dots"),
                obj(natural("camera"), ("disk", 20 * k), (cx + 35 * k, cy - 10 * k), (cx + 30 * k, cy - 12 * k), 1.3,
                    A1=rot(0, k), A2=rot(0, k), name="cam")], 0.0, \
            "sparse dot textures (spacing ~10 px) on backdrop and card, camera disk"
    if name == "ring":          # a thin ring rotating & moving
        return [backdrop(natural("grass"), -0.8, shift=(0, 1 * k), size=size),
                obj(natural("astronaut"), ("ring", 28 * k, 34 * k), (cx, cy), (cx + 5 * k, cy - 3 * k), 1.0,
                    A1=rot(0, k), A2=rot(15, k), name="ring")], 0.0, \
            "thin ring (6 px) turning 15° and moving, grass backdrop"
    raise KeyError(name)


#: Every scene, in the order of the tables.
ALL = ["v_plane", "v_plane_noise", "rot_disk", "rot_big", "rot_big2", "loom", "loom2", "loom_noisy", "recede", "shear",
       "cam_trans", "cam_forward", "thin", "flat", "sparse", "big_flow", "disp_range", "fine_noise", "coarse_weak",
       "stack_noisy", "roll", "rot_noisy", "ring"]


def render_scene(name: str, size=(160, 120), grid: int = 9):
    """Scene ``name`` (one of :data:`ALL`, with or without :data:`PREFIX`) rendered at
    ``size`` (W, H; its layout scales with W / 160) on a ``grid``×``grid`` view grid: the
    light fields at t1 and t2 (:class:`lfsf.LightField`, float32 in [0, 1]) and the ground
    truth (``disp1``, ``disp2``, ``u``, ``v``, ``valid``: false where a pixel straddles an
    outline, ``occluded``), as :func:`lfsf.synth.render_scene` gives them. Scenes with noise draw it from a seed of
    the scene's name."""
    from lfsf.io import LightField

    name = name[len(PREFIX):] if name.startswith(PREFIX) else name
    if name not in ALL:
        raise ValueError(f"unknown independent scene {name!r}; known: {ALL}")
    size = (int(size[0]), int(size[1]))
    layers, noise, description = scene(name, size)
    views = [render(layers, size, grid, t=t) for t in (1, 2)]
    if noise > 0:
        rng = np.random.default_rng(zlib.crc32(name.encode()))
        views = [np.clip(v + rng.normal(0.0, noise, v.shape), 0.0, 1.0).astype(np.float32) for v in views]
    gt = ground_truth(layers, size)
    source = f"independent scene {name!r} ({description})"
    return LightField(views[0], source=source + " at t1"), LightField(views[1], source=source + " at t2"), gt


def plane_shift_error(delta: float, size=(160, 120), grid: int = 9) -> float:
    """The largest difference between a view and the centre view shifted by δφ, over the
    views of a fronto-parallel plane at ``delta`` whose shift is a whole number of pixels
    (exactly 0 for a right renderer)."""
    W, H = size
    c = (grid - 1) // 2
    views = render([backdrop(noise_tex(1.5, 5), delta, size=size)], size, grid, t=1)
    worst = 0.0
    for a in range(grid):
        for b in range(grid):
            sx, sy = delta * (b - c), delta * (a - c)
            if sx != int(sx) or sy != int(sy):
                continue
            sx, sy = int(sx), int(sy)
            view = views[a, b][max(0, -sy):H - max(0, sy), max(0, -sx):W - max(0, sx)]
            centre = views[c, c][max(0, sy):H + min(0, sy), max(0, sx):W + min(0, sx)]
            worst = max(worst, float(np.abs(view - centre).max()))
    return worst


def inverse_error(layers, seed: int = 0) -> float:
    """Points of every layer pushed forward into views (p(r) − δ(r) φ), at t1 and t2: the
    largest error of the r and δ that the inverse mapping finds for them."""
    rng = np.random.default_rng(seed)
    worst = 0.0
    for t in (1, 2):
        for phi in ((-4, -4), (4, -3), (2, 4), (0.5, -2.25)):
            for layer in layers:
                pose = layer.t1 if t == 1 else layer.t2
                rx, ry = rng.uniform(-30, 30, (2, 500))
                A, g = np.asarray(pose.A, float), pose.g
                delta = pose.d + g[0] * rx + g[1] * ry
                x = pose.c[0] + A[0, 0] * rx + A[0, 1] * ry - delta * phi[0]
                y = pose.c[1] + A[1, 0] * rx + A[1, 1] * ry - delta * phi[1]
                rx2, ry2, _, delta2 = layer_at(layer, t, phi, x, y)
                worst = max(worst, float(np.abs(rx2 - rx).max()), float(np.abs(ry2 - ry).max()),
                            float(np.abs(delta2 - delta).max()))
    return worst


def ground_truth_error(layers, size=(160, 120)) -> tuple[float, int]:
    """The ground truth against the renderer: the largest difference between the t1 view φ
    at p − δ1 φ and the t2 view φ at p + u − δ2 φ (texture values, sampled at points) where
    the point is in front in both, and how many such samples there were."""
    W, H = size
    gt = ground_truth(layers, size)
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    worst, seen = 0.0, 0
    for phi in ((0, 0), (4, 4), (-4, 2), (1, -3)):
        v1, front1, _ = render_points(layers, 1, phi, xx - gt["disp1"] * phi[0], yy - gt["disp1"] * phi[1])
        v2, front2, _ = render_points(layers, 2, phi, xx + gt["u"] - gt["disp2"] * phi[0],
                                      yy + gt["v"] - gt["disp2"] * phi[1])
        both = (np.abs(front1 - gt["disp1"]) < 1e-4) & (np.abs(front2 - gt["disp2"]) < 1e-4)
        worst = max(worst, float(np.abs(v1 - v2)[both].max()))
        seen += int(both.sum())
    return worst, seen


def self_check(size=(160, 120)) -> list[str]:
    """The renderer's identities on the scenes, each a line; AssertionError where one
    fails: :func:`plane_shift_error` (0), :func:`inverse_error` (below 1e-9) and
    :func:`ground_truth_error` (below 1e-5: float32 views)."""
    lines = []
    for delta in (1.0, 0.5, -1.0):
        worst = plane_shift_error(delta, size)
        assert worst == 0.0, f"plane at δ = {delta}: a whole-pixel view differs by {worst}"
        lines.append(f"plane at δ = {delta:+.1f}: whole-pixel views equal the shifted centre view exactly")
    for name in ("rot_big2", "shear", "cam_trans", "disp_range"):
        worst = inverse_error(scene(name, size)[0])
        assert worst < 1e-9, f"{name}: a point maps back {worst} off"
        lines.append(f"{name}: points map back to their r and δ within {worst:.1e}")
    for name in ("rot_disk", "loom", "cam_trans", "cam_forward", "thin", "shear"):
        worst, seen = ground_truth_error(scene(name, size)[0], size)
        assert worst < 1e-5, f"{name}: the ground truth's t1 and t2 samples differ by {worst}"
        lines.append(f"{name}: t1 and t2 samples of the ground truth agree within {worst:.1e} ({seen} samples)")
    return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--list", action="store_true", help="list the scenes with what each holds")
    parser.add_argument("--check", action="store_true", help="check the renderer's identities")
    parser.add_argument("--size", nargs=2, type=int, default=[160, 120], metavar=("W", "H"))
    args = parser.parse_args(argv)
    if not (args.list or args.check):
        parser.print_help()
        return 2
    if args.list:
        for name in ALL:
            print(f"{PREFIX}{name}: {scene(name, tuple(args.size))[2]}")
    if args.check:
        for line in self_check(tuple(args.size)):
            print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
