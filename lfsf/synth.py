"""Synthetic light-field pairs with exact ground truth.

Scenes are textured convex primitives, each with its own rigid motion between t1 and t2,
seen by a regular grid of pinhole cameras (a camera array, or a plenoptic camera's views).
Geometry is fixed in the world; the focal length scales with the image width, so a scene
looks the same at every size. Two things are kept the same *in pixels* at every size,
because they are what an estimator's difficulty depends on: the disparity range (the
baseline scales as 1/width, as the angular sampling of a plenoptic camera would) and the
translational image motion of each object (``shift``, in pixels). Rotations are angles.

The ground truth follows the conventions of ``help(lfsf)`` (MODEL.md §1): ``disp1`` is the disparity δ1 (px per view step) of
the point seen at each centre pixel at t1, ``u, v`` its flow to the centre view at t2,
``disp2`` its disparity at t2 (indexed by its t1 pixel), ``valid`` is false where a pixel
straddles a depth edge, ``occluded`` is true where the point is hidden (or leaves the
image) at t2.

>>> lf1, lf2, gt = render_scene("paper", size=(160, 120), grid=9)   # doctest: +SKIP
"""

from __future__ import annotations

import math
import os
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from lfsf import device as _device
from lfsf._errors import LfsfWarning

if TYPE_CHECKING:
    from lfsf.io import LightField

#: Depth (world units) seen with zero disparity, and f·B (px · world units): a point at
#: depth Z has disparity δ = f·B/Z − f·B/Z0, so Z = 4 gives +2 and Z = 12 gives −2.
ZERO_DISPARITY_DEPTH = 6.0
FOCAL_BASELINE = 24.0
#: Focal length in units of the image width (a horizontal field of view of about 53°).
FOCAL_PER_WIDTH = 1.0
#: Image width at which texture periods are given; textures scale with the image but
#: never get finer than MIN_TEXTURE_PERIOD pixels, so that the finest octave (a quarter
#: of the period) stays above the Nyquist limit at small sizes.
REFERENCE_WIDTH = 640
MIN_TEXTURE_PERIOD = 10.0


@dataclass(frozen=True)
class Texture:
    """Solid value-noise texture: feature ``period`` in pixels (at the object's depth in a
    640-pixel-wide image), grey level ``mean ± contrast``, RGB tint ``colour``.

    With ``image`` ≥ 0 the object shows instead that image of the ``images`` given to
    :func:`render_scene` (a photograph, say; :func:`with_images`), tinted by ``colour``:
    its width spans ``image_span`` pixels of a 640-pixel-wide image at the object's depth,
    and it repeats mirrored beyond its edges. ``period``, ``mean``, ``contrast`` and
    ``seed`` are then unused."""

    period: float = 16.0
    mean: float = 0.5
    contrast: float = 0.45
    colour: tuple[float, float, float] = (1.0, 1.0, 1.0)
    seed: int = 0
    image: int = -1
    image_span: float = 320.0


@dataclass(frozen=True)
class Primitive:
    """A textured primitive and its motion from t1 to t2.

    Parameters
    ----------
    kind : "plane", "sphere" or "box"
    at : centre position at t1, as fractions (x, y) of the image width and height
    depth : depth Z of the centre at t1 (world units; see ZERO_DISPARITY_DEPTH)
    size : plane (half width, half height), sphere (radius,), box (three half extents),
        as fractions of the image width at the object's depth
    tilt : orientation at t1, degrees of rotation about x, then y, then z
    shift : image motion (px) of the centre from t1 to t2
    approach : change of the centre's depth from t1 to t2 (negative: towards the camera)
    spin : rotation from t1 to t2 about the centre, degrees about x, y, z
    """

    kind: str
    at: tuple[float, float]
    depth: float
    size: tuple[float, ...]
    texture: Texture = field(default_factory=Texture)
    tilt: tuple[float, float, float] = (0.0, 0.0, 0.0)
    shift: tuple[float, float] = (0.0, 0.0)
    approach: float = 0.0
    spin: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Scene:
    name: str
    description: str
    objects: tuple[Primitive, ...]


def _backdrop(depth, texture, tilt=(0.0, 0.0, 0.0), shift=(0.0, 0.0)):
    return Primitive("plane", (0.5, 0.5), depth, (3.0, 3.0), texture, tilt=tilt, shift=shift)


SCENES: dict[str, Scene] = {
    s.name: s
    for s in (
        Scene(
            "paper",
            "several objects at different depths moving independently (like the paper's "
            "rendered scenes): a slanted backdrop, a tilted card, a spinning box that comes "
            "closer, two spheres",
            (
                _backdrop(11.0, Texture(22, 0.5, 0.4, (0.9, 0.95, 1.0), 1), tilt=(0, 12, 0), shift=(1.5, 0.5)),
                Primitive("plane", (0.24, 0.3), 8.0, (0.13, 0.1), Texture(14, 0.55, 0.45, (1.0, 0.9, 0.7), 2),
                          tilt=(0, 0, 12), shift=(-3.0, 1.5), spin=(0, 0, 3)),
                Primitive("box", (0.7, 0.33), 6.5, (0.08, 0.08, 0.08), Texture(12, 0.5, 0.45, (0.8, 1.0, 0.8), 3),
                          tilt=(25, 35, 0), shift=(2.0, 2.5), approach=-0.6, spin=(0, 8, 0)),
                Primitive("sphere", (0.42, 0.64), 4.2, (0.1,), Texture(12, 0.5, 0.5, (1.0, 0.8, 0.8), 4),
                          shift=(4.5, -2.5), spin=(0, 15, 0)),
                Primitive("sphere", (0.82, 0.76), 5.2, (0.06,), Texture(10, 0.45, 0.45, (0.8, 0.85, 1.0), 5),
                          shift=(-2.0, -3.0), approach=0.4),
            ),
        ),
        Scene(
            "slanted",
            "slanted planar surfaces only: piecewise-linear disparity on a tilted backdrop",
            (
                _backdrop(10.0, Texture(20, 0.5, 0.4, (1.0, 1.0, 0.9), 11), tilt=(10, 28, 0), shift=(1.0, -0.5)),
                Primitive("plane", (0.3, 0.45), 6.0, (0.14, 0.24), Texture(14, 0.5, 0.45, (0.9, 1.0, 1.0), 12),
                          tilt=(0, -42, 0), shift=(2.0, 1.0), spin=(0, 4, 0)),
                Primitive("plane", (0.72, 0.55), 4.8, (0.13, 0.13), Texture(12, 0.5, 0.45, (1.0, 0.9, 0.9), 13),
                          tilt=(38, 22, 10), shift=(-2.5, 1.5), spin=(-3, 0, 4)),
                Primitive("plane", (0.55, 0.2), 8.0, (0.18, 0.06), Texture(16, 0.5, 0.4, (0.9, 0.9, 1.0), 14),
                          tilt=(-50, 0, 0), shift=(0.5, 2.0)),
            ),
        ),
        Scene(
            "large_motion",
            "large displacements: objects move 12-18 px between the two times, over a "
            "moving backdrop",
            (
                _backdrop(10.0, Texture(20, 0.5, 0.4, (1.0, 0.95, 0.9), 21), shift=(3.0, 1.0)),
                Primitive("sphere", (0.3, 0.48), 5.0, (0.1,), Texture(12, 0.5, 0.5, (0.9, 1.0, 0.9), 22),
                          shift=(14.0, 6.0), spin=(0, 10, 0)),
                Primitive("box", (0.7, 0.38), 7.0, (0.08, 0.07, 0.08), Texture(12, 0.5, 0.45, (1.0, 0.85, 0.85), 23),
                          tilt=(15, 25, 5), shift=(-12.0, 9.0), spin=(0, 0, 6)),
                Primitive("plane", (0.52, 0.76), 4.2, (0.12, 0.08), Texture(12, 0.5, 0.45, (0.85, 0.9, 1.0), 24),
                          tilt=(0, 0, -8), shift=(8.0, -11.0), approach=-0.3),
            ),
        ),
        Scene(
            "weak_texture",
            "weakly textured, low-contrast surfaces with coarse features: the regulariser "
            "has to fill in where the data term says little",
            (
                _backdrop(10.0, Texture(44, 0.5, 0.07, (1.0, 1.0, 1.0), 31), tilt=(0, 8, 0), shift=(1.0, 0.5)),
                Primitive("sphere", (0.35, 0.5), 5.0, (0.12,), Texture(36, 0.55, 0.1, (1.0, 1.0, 1.0), 32),
                          shift=(3.0, 1.0), spin=(0, 8, 0)),
                Primitive("box", (0.7, 0.45), 6.5, (0.09, 0.09, 0.09), Texture(40, 0.45, 0.1, (1.0, 1.0, 1.0), 33),
                          tilt=(20, 30, 0), shift=(-2.5, 2.0), approach=-0.4),
            ),
        ),
    )
}


def list_scenes() -> dict[str, str]:
    """Names of the built-in scenes and a line describing each (``random-N`` scenes, any
    N ≥ 0, are accepted as well: :func:`random_scene`)."""
    return {name: scene.description for name, scene in SCENES.items()}


#: Prefix of the names of generated scenes: ``random-N`` is :func:`random_scene` (N).
RANDOM_PREFIX = "random-"


def random_scene(seed: int) -> Scene:
    """A scene drawn at random, reproducibly from ``seed`` (≥ 0), for measuring accuracy
    on scenes no default was tuned on. Its draws span what the estimator is meant to
    reach: a tilted, moving backdrop behind two to four planes, spheres and boxes at
    disparities of about ±2.5 px per view step, each moving up to 12 px (and
    towards or away from the camera, and turning), textured with features of 10 to 40 px
    at contrasts from weak (0.08) to strong (0.5)."""
    seed = _whole("a random scene's seed", seed, -2 ** 63, 2 ** 63 - 1)     # (1.5 was read as 1)
    if seed < 0:
        raise ValueError(f"a random scene's seed must be ≥ 0, got {seed}")
    rng = np.random.default_rng([0x5CE7E, seed])

    def texture(k: int) -> Texture:
        return Texture(period=float(rng.uniform(10.0, 40.0)), mean=float(rng.uniform(0.35, 0.65)),
                       contrast=float(np.exp(rng.uniform(np.log(0.08), np.log(0.5)))),
                       colour=tuple(float(c) for c in rng.uniform(0.75, 1.0, 3)), seed=1000 * seed + k)

    def motion(largest: float) -> tuple[float, float]:
        angle, length = rng.uniform(0.0, 2.0 * math.pi), rng.uniform(0.0, largest)
        return (float(length * math.cos(angle)), float(length * math.sin(angle)))

    objects = [_backdrop(float(rng.uniform(9.0, 14.0)), texture(0),
                         tilt=(float(rng.uniform(-15, 15)), float(rng.uniform(-25, 25)), 0.0), shift=motion(3.0))]
    for k in range(1, int(rng.integers(2, 5)) + 1):
        kind = str(rng.choice(["plane", "sphere", "box"]))
        size = {"plane": (float(rng.uniform(0.06, 0.16)), float(rng.uniform(0.05, 0.14))),
                "sphere": (float(rng.uniform(0.05, 0.12)),),
                "box": tuple(float(x) for x in rng.uniform(0.05, 0.09, 3))}[kind]
        objects.append(Primitive(
            kind, (float(rng.uniform(0.15, 0.85)), float(rng.uniform(0.2, 0.8))), float(rng.uniform(3.8, 9.0)),
            size, texture(k), tilt=tuple(float(x) for x in rng.uniform(-40, 40, 3)), shift=motion(12.0),
            approach=float(rng.uniform(-0.5, 0.5)), spin=tuple(float(x) for x in rng.uniform(-8, 8, 3))))
    return Scene(f"{RANDOM_PREFIX}{seed}", f"random scene {seed}: {len(objects) - 1} objects over a backdrop",
                 tuple(objects))


def with_images(scene: str | Scene, count: int, seed: int = 0, span=(200.0, 800.0),
                backdrop_span=(800.0, 1600.0)) -> Scene:
    """``scene`` with every object showing one of ``count`` images instead of its solid
    texture (:class:`Texture`; give the images to :func:`render_scene`): the image and the
    width it spans (uniform in ``span``, pixels of a 640-pixel-wide image at the object's
    depth; in ``backdrop_span`` for a plane as wide as the image or wider) drawn
    reproducibly from ``seed``, the objects untinted. The geometry, the motion and so the
    ground truth are the scene's."""
    sc = get_scene(scene)
    count = _whole("with_images: the count of images", count, -2 ** 31, 2 ** 31)
    if count < 1:
        raise ValueError(f"with_images needs at least one image, got {count}")
    seed = _whole("with_images: the seed", seed, -2 ** 63, 2 ** 63 - 1)
    if seed < 0:
        raise ValueError(f"with_images: the seed must be ≥ 0, got {seed}")
    for name, (low, high) in (("span", _pair("span", span, "(least, most)")),
                              ("backdrop_span", _pair("backdrop_span", backdrop_span, "(least, most)"))):
        # an image spans a width in pixels: 1e-300 made the prefilter's blur overflow
        if not all(_is_number(x) and 1.0 <= x <= 1e6 for x in (low, high)) or low > high:
            raise ValueError(f"with_images: {name} must be (least, most) widths in 1…1e6 px, got {(low, high)!r}")
    rng = np.random.default_rng([0x1A6E5, seed])
    objects = []
    for prim in sc.objects:
        backdrop = prim.kind == "plane" and prim.size[0] >= 0.5
        texture = Texture(colour=(1.0, 1.0, 1.0), image=int(rng.integers(0, int(count))),
                          image_span=float(rng.uniform(*(backdrop_span if backdrop else span))))
        objects.append(Primitive(prim.kind, prim.at, prim.depth, prim.size, texture, tilt=prim.tilt,
                                 shift=prim.shift, approach=prim.approach, spin=prim.spin))
    return Scene(f"{sc.name}+images", f"{sc.description}, showing images", tuple(objects))


def with_images_of_name(name: str, count: int) -> Scene:
    """:func:`with_images` of the scene ``name`` with the seed drawn from the name (its
    CRC-32): each scene shows the same photographs wherever it is rendered with the same
    ``count`` images (``scripts/compare_peers.py --images``, ``scripts/sweep.py
    --images``)."""
    return with_images(name, count, seed=zlib.crc32(str(name).encode()))


#: File suffixes that :func:`load_images` reads from a folder.
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff")


def load_images(folder: str | os.PathLike) -> list[np.ndarray]:
    """The images of a folder (PNG, JPEG, TIFF; sorted by name) as float32 (h, w, 3)
    arrays in [0, 1] (grey repeated, alpha dropped), for :func:`with_images`.
    FileNotFoundError or ValueError names a missing folder, a folder without images or
    a file that is not one."""
    from lfsf.io import read_image

    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"{folder}: not a folder; give the folder that holds the images")
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such folder of images")
    files = sorted(f for f in folder.iterdir() if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise ValueError(f"{folder}: no images ({', '.join(IMAGE_SUFFIXES)}) in the folder")
    return [_as_rgb(read_image(f), str(f)) for f in files]


#: scikit-image's sample photographs and textures that :func:`photographs` gives for
#: ``"skimage"``.
SKIMAGE_IMAGES = ("astronaut", "coffee", "chelsea", "rocket", "camera", "brick", "grass", "gravel", "coins",
                  "moon")


def photographs(source: str | os.PathLike) -> list[np.ndarray]:
    """Images for :func:`with_images`: scikit-image's samples for ``"skimage"``
    (:data:`SKIMAGE_IMAGES`, as they come; the renderer scales integers to [0, 1]; needs
    the ``peers`` extra), else the images of a folder (:func:`load_images`, whose errors
    name the folder or file)."""
    if str(source) != "skimage":
        return load_images(source)
    try:
        import skimage.data
    except ImportError:
        raise ValueError("images from 'skimage' need scikit-image: pip install scikit-image") from None
    return [np.asarray(getattr(skimage.data, name)()) for name in SKIMAGE_IMAGES]


def _rotation(degrees) -> np.ndarray:
    """Rotation matrix of successive rotations about x, y, z (degrees)."""
    ax, ay, az = np.deg2rad(np.asarray(degrees, dtype=np.float64))
    rx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
    ry = np.array([[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]])
    rz = np.array([[math.cos(az), -math.sin(az), 0], [math.sin(az), math.cos(az), 0], [0, 0, 1]])
    return rz @ ry @ rx


@dataclass(frozen=True)
class CameraArray:
    """The camera array at a given image size: focal length f (px), principal point,
    baseline B between neighbouring views and sensor shift s (px per view step)."""

    width: int
    height: int
    focal: float
    baseline: float
    shift: float

    @classmethod
    def for_size(cls, width: int, height: int) -> "CameraArray":
        focal = FOCAL_PER_WIDTH * width
        return cls(width, height, focal, FOCAL_BASELINE / focal, FOCAL_BASELINE / ZERO_DISPARITY_DEPTH)

    @property
    def cx(self) -> float:
        return (self.width - 1) / 2.0

    @property
    def cy(self) -> float:
        return (self.height - 1) / 2.0

    def disparity(self, depth):
        """δ = f·B/Z − s, px per view step."""
        return self.focal * self.baseline / np.asarray(depth) - self.shift

    def back_project(self, x, y, depth) -> np.ndarray:
        """World point seen by the centre view at image point (x, y) and depth Z."""
        return np.array([(x - self.cx) * depth / self.focal, (y - self.cy) * depth / self.focal, depth])


def _object_poses(prim: Primitive, cam: CameraArray, times=(0, 1)):
    """World poses (rotation, centre) at each frame of ``times``, world size and texture
    frequency.

    Frame 0 is t1 and frame 1 is t2. The motion repeats at a constant rate: at frame k the
    centre has moved k·``shift`` px in the centre view and k·``approach`` in depth, and the
    object has turned by ``spin`` k times. Frames 0 and 1 are the pair of the scene itself.
    """
    x1 = prim.at[0] * (cam.width - 1)
    y1 = prim.at[1] * (cam.height - 1)
    r1 = _rotation(prim.tilt)
    spin = _rotation(prim.spin)
    poses = []
    for k in times:
        z = prim.depth + k * prim.approach
        if z <= 0:
            raise ValueError(f"object moves behind the camera at frame {k} "
                             f"(depth {prim.depth} + {k} × approach {prim.approach})")
        centre = cam.back_project(x1 + k * prim.shift[0], y1 + k * prim.shift[1], z)
        poses.append((np.linalg.matrix_power(spin, int(k)) @ r1, centre))
    # sizes are fractions of the image width at the object's depth at frame 0
    world_per_px = prim.depth / cam.focal
    size = np.zeros(3)
    size[: len(prim.size)] = np.asarray(prim.size, dtype=np.float64) * cam.width * world_per_px
    period_px = max(prim.texture.period * cam.width / REFERENCE_WIDTH, MIN_TEXTURE_PERIOD)
    tex_freq = 1.0 / (period_px * world_per_px)
    return poses, size, tex_freq


_KINDS = {"plane": 0, "sphere": 1, "box": 2}


def _scene_arrays(scene: Scene, cam: CameraArray, device: str, times=(0, 1), textures=None):
    """Warp arrays of SceneObject, one per frame of ``times`` (default t1 and t2);
    ``textures``: the image textures' (width, height, texels per world unit) in the
    scene's order, as :func:`_image_stack` returns them."""
    import warp as wp

    from lfsf.kernels import render

    textures = list(textures or ())
    slot = 0
    per_time = tuple([] for _ in times)
    for prim in scene.objects:
        if prim.kind not in _KINDS:
            raise ValueError(f"scene {scene.name!r}: unknown primitive kind {prim.kind!r}")
        poses, size, tex_freq = _object_poses(prim, cam, times)
        for (rot, centre), out in zip(poses, per_time):
            obj = render.SceneObject()
            obj.kind = _KINDS[prim.kind]
            obj.rot = wp.mat33(*rot.astype(np.float32).ravel())
            obj.pos = wp.vec3(*centre.astype(np.float32))
            obj.size = wp.vec3(*size.astype(np.float32))
            obj.tex_seed = int(prim.texture.seed)
            obj.tex_freq = float(tex_freq)
            obj.tex_mean = float(prim.texture.mean)
            obj.tex_contrast = float(prim.texture.contrast)
            obj.colour = wp.vec3(*prim.texture.colour)
            obj.tex_image = -1
            obj.tex_scale = 0.0
            obj.tex_width = 0
            obj.tex_height = 0
            out.append(obj)
        if prim.texture.image >= 0:  # its own slot of the image stack (_image_stack, same order)
            if slot >= len(textures):
                raise ValueError(f"scene {scene.name!r}: a {prim.kind} shows an image, but no image stack was made")
            w, h, scale = textures[slot]
            for objs in per_time:
                objs[-1].tex_image = slot
                objs[-1].tex_scale = float(scale)
                objs[-1].tex_width = int(w)
                objs[-1].tex_height = int(h)
            slot += 1
    return tuple(wp.array(objs, dtype=render.SceneObject, device=device) for objs in per_time)


def _image_span_px(texture: Texture, cam: CameraArray) -> float:
    """The pixels that an image texture's width spans at the object's depth at t1."""
    return texture.image_span * cam.width / REFERENCE_WIDTH


def _as_rgb(image, name: str) -> np.ndarray:
    """An image as float32 (h, w, 3) in [0, 1]: integers scaled by their type's maximum,
    booleans as 0 and 1, grey repeated, alpha dropped. ValueError names ``name`` and the
    problem."""
    from lfsf.io import _to_unit_float32, refuse_wide_integers

    a = np.asarray(image)
    if a.dtype.kind not in "biuf":
        raise ValueError(f"{name}: not an image of numbers ({a.dtype})")
    refuse_wide_integers(a, name, "pixels", fix="give an image of 8 or 16 bits (uint8 or uint16; a file saved so) "
                         "or of floats in [0, 1]")
    a = _to_unit_float32(a)
    if a.ndim == 3 and a.shape[2] in (1, 2):  # grey, grey + alpha
        a = a[..., 0]
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] not in (3, 4) or min(a.shape[:2]) < 2:
        raise ValueError(f"{name}: an image texture must be (h, w) or (h, w, 1…4) with h, w ≥ 2, "
                         f"got shape {np.shape(image)}")
    a = a[..., :3]
    if not np.all(np.isfinite(a)) or a.min() < 0.0 or a.max() > 1.0:
        raise ValueError(f"{name}: an image texture's values must be finite and in [0, 1]")
    return np.ascontiguousarray(a)


def _check_images(scene: Scene, images) -> list[np.ndarray]:
    """The images as float32 (h, w, 3) arrays in [0, 1] (:func:`_as_rgb`), checked
    against the scene's image textures."""
    if isinstance(images, np.ndarray):      # (one array: its truth value was 'ambiguous')
        raise ValueError(f"images must be a list of images (arrays), got one array of shape {images.shape}")
    out = [_as_rgb(img, f"image {k}") for k, img in enumerate(images or ())]
    for prim in scene.objects:
        if prim.texture.image >= len(out):
            raise ValueError(f"scene {scene.name!r}: a {prim.kind} shows image {prim.texture.image}, but "
                             f"{len(out)} image(s) were given")
        span = prim.texture.image_span
        if prim.texture.image >= 0 and not (math.isfinite(span) and span > 0):
            raise ValueError(f"scene {scene.name!r}: a {prim.kind}'s image_span must be a number > 0, got {span}")
    return out


def _prefiltered(image: np.ndarray, shrink: float) -> tuple[np.ndarray, int]:
    """An image seen ``shrink`` texels per rendered pixel, made fit to be sampled there:
    (image, k). Where shrink ≥ 4, the means of k × k blocks, k = ⌊shrink / 2⌋ (the image
    first cut, about its centre, to whole blocks); then a Gaussian that brings the
    blur to σ = shrink / 2 texels in all, where shrink > 1. Edges mirrored as the
    renderer repeats the image."""
    from lfsf._filters import gaussian_blur

    k = max(1, min(int(shrink // 2) if shrink >= 4 else 1, min(image.shape[:2]) // 2))  # (2 texels at least)
    sigma = 0.5 * shrink if shrink > 1 else 0.0
    if k > 1:
        h, w = (image.shape[0] // k) * k, (image.shape[1] // k) * k
        i0, j0 = (image.shape[0] - h) // 2, (image.shape[1] - w) // 2
        image = image[i0:i0 + h, j0:j0 + w].reshape(h // k, k, w // k, k, 3).mean((1, 3))
        sigma = math.sqrt(max(0.0, sigma * sigma - k * k / 12.0)) / k  # (a k-box's variance is k²/12)
    if sigma > 0:
        image = np.stack([gaussian_blur(image[..., c], sigma) for c in range(3)], axis=-1)
    return image.astype(np.float32), k


def _image_stack(scene: Scene, cam: CameraArray, images: list[np.ndarray], device: str):
    """The render's image stack [slot, y, x, RGB] and each slot's (width, height, texels
    per world unit): for each object with an image texture, in the scene's order, its
    image made fit to be seen at the object's depth at t1 (:func:`_prefiltered`; a plane
    seen at a slant, or an object moving away in a long sequence, is seen shrunk more
    than that and may alias); a 1×1×1×3 array where no object has one."""
    wp = _device.warp()
    chosen, textures = [], []
    for prim in scene.objects:
        if prim.texture.image >= 0:
            img = images[prim.texture.image]
            span = _image_span_px(prim.texture, cam)
            img_k, k = _prefiltered(img, img.shape[1] / span)
            chosen.append(img_k)
            # a texel is k of the image's own, which spans `span` px at the object's depth
            textures.append((img_k.shape[1], img_k.shape[0], img.shape[1] / (k * span * prim.depth / cam.focal)))
    if not chosen:
        return wp.zeros((1, 1, 1, 3), dtype=float, device=device), textures
    h = max(a.shape[0] for a in chosen)
    w = max(a.shape[1] for a in chosen)
    stack = np.zeros((len(chosen), h, w, 3), np.float32)
    for k, a in enumerate(chosen):
        stack[k, :a.shape[0], :a.shape[1]] = a
    return wp.array(stack, dtype=float, device=device), textures


def _warp_camera(cam: CameraArray):
    from lfsf.kernels import render

    c = render.Camera()
    c.focal = float(cam.focal)
    c.cx = float(cam.cx)
    c.cy = float(cam.cy)
    c.baseline = float(cam.baseline)
    c.shift = float(cam.shift)
    return c


#: Upper bounds on what a render may ask for, checked before any work: a view's side in
#: pixels, views per side of the grid, rays per pixel side, and float32 values in all the
#: frames' light fields together (2³¹, 8 GiB: more than the estimator could hold anyway).
MAX_VIEW_SIDE = 8192
MAX_GRID = 33
MAX_SUPERSAMPLE = 16
MAX_RENDER_VALUES = 2 ** 31


def _is_number(value) -> bool:
    """An int or a float (numpy's too), not a bool: what a numeric argument may be."""
    return isinstance(value, (int, np.integer, float, np.floating)) and not isinstance(value, (bool, np.bool_))


def _whole(name: str, value, least: int, most: int) -> int:
    """``value`` as an int in [least, most], or a ValueError naming ``name``: a bool or a
    fraction is an error, not truncated."""
    if not _is_number(value) or not (isinstance(value, (int, np.integer)) or float(value).is_integer()):
        raise ValueError(f"{name} must be a whole number, got {value!r}")
    value = int(value)  # (an int as it is: float() of one past float's range overflows)
    if not least <= value <= most:
        raise ValueError(f"{name} must be in {least}…{most}, got {value}")
    return value


def _pair(name: str, value, what: str) -> tuple:
    """A scalar as (value, value), or a 2-sequence as a tuple; anything else names ``name``."""
    if np.isscalar(value):
        return value, value
    try:
        first, second = value
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be {what}, got {value!r}") from None
    return first, second


def _grid(grid) -> tuple[int, int]:
    rows, cols = _pair("grid", grid, "a number of views per side or (rows, cols)")
    return (_whole("grid rows", rows, 1, MAX_GRID), _whole("grid columns", cols, 1, MAX_GRID))


def _check_size(size) -> tuple[int, int]:
    if np.isscalar(size):
        raise ValueError(f"size must be (width, height), got {size!r}")
    width, height = _pair("size", size, "(width, height)")
    return (_whole("image width", width, 8, MAX_VIEW_SIDE), _whole("image height", height, 8, MAX_VIEW_SIDE))


def check_render(size, grid, supersample=2, frames=2, colour=False, noise=0.0) -> dict:
    """The settings of a render checked and normalised, before any work: ``size`` (width,
    height), ``grid`` (rows, cols), ``supersample``, ``frames`` and ``noise`` as
    :func:`render_sequence` and :func:`write_scene` take them. Any of them out of range,
    or light fields too large together (more than :data:`MAX_RENDER_VALUES` values), is a
    ``ValueError`` naming it."""
    width, height = _check_size(size)
    rows, cols = _grid(grid)
    if not isinstance(colour, (bool, np.bool_)):  # ("no" would be true)
        raise ValueError(f"colour must be True or False, got {colour!r}")
    supersample = _whole("supersample", supersample, 1, MAX_SUPERSAMPLE)
    frames = _whole("frames (a sequence needs at least 2)", frames, 2, MAX_RENDER_VALUES)
    values = frames * rows * cols * height * width * (3 if colour else 1)
    if values > MAX_RENDER_VALUES:
        raise ValueError(f"{frames} light fields of {rows}×{cols} views of {width}×{height}"
                         f"{' RGB' if colour else ''} pixels hold {values:,} values, more than the "
                         f"{MAX_RENDER_VALUES:,} a render may (8 GiB): use a smaller size, grid or "
                         "number of frames")
    return {"size": (width, height), "grid": (rows, cols), "supersample": supersample, "frames": frames,
            "noise": _noise_sigma(noise)}


def get_scene(scene: str | Scene) -> Scene:
    """The :class:`Scene` of a built-in name, of ``random-N`` (:func:`random_scene`), or
    the scene itself."""
    if isinstance(scene, Scene):
        return scene
    if isinstance(scene, str) and scene.startswith(RANDOM_PREFIX) and scene[len(RANDOM_PREFIX):].isdecimal():
        return random_scene(int(scene[len(RANDOM_PREFIX):]))
    if not isinstance(scene, str) or scene not in SCENES:
        raise ValueError(f"unknown scene {scene!r}: the scenes are {', '.join(SCENES)} "
                         f"and {RANDOM_PREFIX}N (N = 0, 1, …)")
    return SCENES[scene]


def render_scene(
    scene: str | Scene,
    *,
    size: tuple[int, int] = (640, 480),
    grid: int | tuple[int, int] = 9,
    supersample: int = 2,
    colour: bool = False,
    device: str | None = None,
    images: Sequence[ArrayLike] | None = None,
) -> tuple[LightField, LightField, dict[str, Any]]:
    """Render a light-field pair of a scene and its exact ground truth.

    Parameters
    ----------
    scene : name of a built-in scene (see :func:`list_scenes`) or a :class:`Scene`
    size : (width, height) of each view in pixels
    grid : views per side (or (rows, cols)); the angular centre is the grid's centre
    supersample : rays per pixel along each axis (box-filtered)
    colour : RGB views if true, else grey (BT.601 luma of the same colours)
    device : Warp device (default as :func:`lfsf.device.resolve_device`)
    images : the images that the scene's image textures name (:class:`Texture`), each
        (h, w) or (h, w, 1…4) (alpha dropped), floats in [0, 1] or integers (scaled by
        their type's maximum)

    Returns
    -------
    lf1, lf2 : :class:`lfsf.io.LightField` at t1 and t2
    gt : dict of float32 (H, W) ``disp1``, ``disp2``, ``u``, ``v`` and bool ``valid``,
        ``occluded`` (the conventions of ``help(lfsf)``, MODEL.md §1), plus the camera as scalars
        (``focal``, ``baseline``, ``shift``)
    """
    lfs, gts = render_sequence(scene, 2, size=size, grid=grid, supersample=supersample, colour=colour,
                               device=device, images=images)
    return lfs[0], lfs[1], gts[0]


def _as_lightfield(lf):
    """A LightField as it is, views (an array) as a LightField, with intensities in
    [0, 1] (what the camera effects here clip to); anything else a ValueError."""
    from lfsf.io import LightField

    lf = lf if isinstance(lf, LightField) else LightField(lf, source="views")
    high = float(lf.views.max())
    if high > 1.0 + 1e-6:         # counts as floats would all be clipped to 1
        raise ValueError(f"{lf.source}: intensities up to {high:g}; noise and vignetting are added to "
                         "intensities in [0, 1] (scale counts by their maximum first)")
    return lf


def _noise_sigma(sigma) -> float:
    """A noise level as a float, or a ValueError naming the problem."""
    if not _is_number(sigma):
        raise ValueError(f"noise sigma must be a finite number ≥ 0, got {sigma!r}")
    sigma = float(sigma)
    if not math.isfinite(sigma) or not 0 <= sigma <= MAX_NOISE:
        raise ValueError(f"noise sigma must be a number from 0 to {MAX_NOISE:g} (intensities in [0, 1]), got {sigma:g}")
    return sigma


#: The most noise :func:`add_noise` takes: at σ = 1 every value is clipped noise, of
#: which nothing of the scene is left to see (σ = 1000 was taken).
MAX_NOISE = 1.0


def add_noise(lf, sigma: float, seed: int = 0):
    """``lf`` with independent Gaussian noise of standard deviation ``sigma`` (intensities
    in [0, 1]) on every pixel of every view, clipped to [0, 1]: a camera's sensor noise,
    reproducible from ``seed``. Give the two times different seeds: their noise is
    independent. ``sigma`` 0 returns ``lf`` itself."""
    from lfsf.io import LightField

    lf = _as_lightfield(lf)
    sigma = _noise_sigma(sigma)
    seed = _whole("seed", seed, 0, 2 ** 63 - 1)
    if sigma == 0:
        return lf
    rng = np.random.default_rng(seed)
    views = lf.views + rng.normal(0.0, sigma, lf.views.shape).astype(np.float32)
    return LightField(np.clip(views, 0.0, 1.0), source=f"{lf.source} + noise σ={sigma:g}",
                      meta={**lf.meta, "noise_sigma": sigma})


def vignetting_gains(grid: tuple[int, int], size: tuple[int, int], strength: float) -> np.ndarray:
    """Gains (a, b, h, w) of :func:`add_vignetting`: with the view offsets ξ̃, η̃ and the
    pixel position x̃, ỹ each scaled to [−1, 1] (0 at the centre view and the image
    centre), ρ² = (ξ̃² + η̃²)/2 and r² = (x̃² + ỹ²)/2,

        g = 1 − k · ρ² · (1 + r² + x̃ξ̃ + ỹη̃) / 2.

    The centre view keeps g = 1; the further a view lies from it, the darker it is,
    most on the side of the image its offset points to (a corner view at that image
    corner: 1 − 2k) and not at all at the opposite corner (g ≤ 1 everywhere). Smooth,
    low-frequency and different in every view, as a lens's vignetting or a surface's
    view-dependent shading is."""
    if not _is_number(strength):
        raise ValueError(f"vignetting strength must be a number in [0, 0.5), got {strength!r}")
    strength = float(strength)
    if not math.isfinite(strength) or not 0 <= strength < 0.5:
        raise ValueError(f"vignetting strength must be in [0, 0.5), got {strength}")
    rows, cols = grid
    width, height = size
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float64)
    xs = (xx - (width - 1) / 2) / max((width - 1) / 2, 1.0)
    ys = (yy - (height - 1) / 2) / max((height - 1) / 2, 1.0)
    gains = np.empty((rows, cols, height, width), np.float32)
    for a in range(rows):
        for b in range(cols):
            eta = (a - (rows - 1) / 2) / max((rows - 1) / 2, 1.0)
            xi = (b - (cols - 1) / 2) / max((cols - 1) / 2, 1.0)
            rho2 = (xi * xi + eta * eta) / 2
            gains[a, b] = 1.0 - strength * rho2 * (1.0 + (xs * xs + ys * ys) / 2 + xs * xi + ys * eta) / 2
    return gains


def add_vignetting(lf, strength: float):
    """``lf`` with every view multiplied by a smooth gain field of its own
    (:func:`vignetting_gains`, ``strength`` k in [0, 0.5)), clipped to [0, 1]: the
    brightness differences between views that a real camera's vignetting or a
    surface's view-dependent shading leaves, which the renderer's Lambertian scenes
    lack. Give both times the same strength: the camera is the same. ``strength`` 0
    returns ``lf`` itself."""
    from lfsf.io import LightField

    lf = _as_lightfield(lf)
    gains = vignetting_gains(lf.grid, (lf.width, lf.height), strength)
    if strength == 0:
        return lf
    views = lf.views * gains.reshape(gains.shape + (1,) * (lf.views.ndim - 4))
    return LightField(np.clip(views, 0.0, 1.0).astype(np.float32), source=f"{lf.source} + vignetting {strength:g}",
                      meta={**lf.meta, "vignetting": float(strength)})


def render_sequence(
    scene: str | Scene,
    frames: int,
    *,
    size: tuple[int, int] = (640, 480),
    grid: int | tuple[int, int] = 9,
    supersample: int = 2,
    colour: bool = False,
    device: str | None = None,
    images: Sequence[ArrayLike] | None = None,
) -> tuple[list[LightField], list[dict[str, Any]]]:
    """Render ``frames`` light fields of a scene moving at a constant rate, and the exact
    ground truth of each consecutive pair.

    Frame k shows every object after k times its motion from t1 to t2 (see
    :func:`_object_poses`), so frames 0 and 1 are :func:`render_scene`'s pair and every
    later pair moves the same way again. Parameters are those of :func:`render_scene`.

    Returns
    -------
    lfs : list of ``frames`` :class:`lfsf.io.LightField`
    gts : list of ``frames − 1`` ground-truth dicts as :func:`render_scene`'s, pair k
        going from frame k to frame k + 1
    """
    from lfsf.io import LightField
    from lfsf.kernels import render

    wp = _device.warp()
    sc = get_scene(scene)
    checked = check_render(size, grid, supersample, frames, colour)
    (width, height), (rows, cols) = checked["size"], checked["grid"]
    supersample, frames = checked["supersample"], checked["frames"]
    dev = _device.resolve_device(device)
    cam = CameraArray.for_size(width, height)
    wcam = _warp_camera(cam)
    image_stack, textures = _image_stack(sc, cam, _check_images(sc, images), dev)
    objects = _scene_arrays(sc, cam, dev, times=range(int(frames)), textures=textures)
    channels = 3 if colour else 1

    lfs = []
    for t, objs in enumerate(objects):
        views = wp.empty((rows * cols, height, width, channels), dtype=float, device=dev)
        _device.launch_rows(
            render.render_views,
            dim=(rows * cols * height, width),
            inputs=[wcam, objs, cols, (rows - 1) / 2.0, (cols - 1) / 2.0, int(supersample), image_stack],
            outputs=[views],
            device=dev,
        )
        arr = views.numpy().reshape(rows, cols, height, width, channels)
        if channels == 1:
            arr = arr[..., 0]
        name = f"t{t + 1}" if frames == 2 else f"frame {t}"
        lfs.append(LightField(arr, source=f"synthetic scene '{sc.name}' at {name}"))

    gts = []
    for t in range(int(frames) - 1):
        out = {k: wp.empty((height, width), dtype=float, device=dev) for k in ("disp1", "disp2", "u", "v")}
        masks = {k: wp.empty((height, width), dtype=wp.uint8, device=dev) for k in ("valid", "occluded")}
        _device.launch_rows(
            render.ground_truth,
            dim=(height, width),
            inputs=[wcam, objects[t], objects[t + 1], width, height],
            outputs=[out["disp1"], out["disp2"], out["u"], out["v"], masks["valid"], masks["occluded"]],
            device=dev,
        )
        gt = {k: a.numpy().astype(np.float32) for k, a in out.items()}
        gt.update({k: a.numpy().astype(bool) for k, a in masks.items()})
        gt.update(focal=np.float32(cam.focal), baseline=np.float32(cam.baseline), shift=np.float32(cam.shift))
        gts.append(gt)
    return lfs, gts


def write_scene(
    scene: str | Scene,
    out: str | os.PathLike,
    *,
    size: tuple[int, int] = (640, 480),
    grid: int | tuple[int, int] = 9,
    supersample: int = 2,
    colour: bool = False,
    device: str | None = None,
    noise: float = 0.0,
    images=None,
    preview: bool = False,
) -> dict[str, Path]:
    """Render a scene and write ``lf1.npz``, ``lf2.npz`` and ``gt.npz`` into ``out``.

    ``noise`` > 0 adds sensor noise of that standard deviation to every view
    (:func:`add_noise`, independent at t1 and t2, seeds 0 and 1); the ground truth is the
    scene's. ``preview``: also ``preview.png``, the ground truth drawn as
    :func:`lfsf.viz.overview_figure` draws an estimate's; without it an earlier render's
    ``preview.png`` is removed. The files are written into a temporary folder and moved
    into place together, so an interrupted write leaves none of them (and no mix with
    an earlier render's). Returns the paths written.
    """
    from lfsf._files import file_set, output_folder, savez_atomic
    from lfsf.io import write_lightfield

    noise = _noise_sigma(noise)  # a bad sigma: an error before any rendering
    # and an output that cannot be written
    output_folder(out, create=False, names=list(SCENE_FILES) + [PREVIEW_NAME] * bool(preview))
    lf1, lf2, gt = render_scene(scene, size=size, grid=grid, supersample=supersample, colour=colour, device=device,
                                images=images)
    lf1, lf2 = add_noise(lf1, noise, seed=0), add_noise(lf2, noise, seed=1)
    out = Path(out)
    names = dict(zip(("lf1", "lf2", "gt"), SCENE_FILES))
    if preview:
        names["preview"] = PREVIEW_NAME
    name = get_scene(scene).name
    with file_set(out, list(names.values()), stale=() if preview else earlier_preview(out)) as tmp:
        write_lightfield(lf1, tmp / names["lf1"])
        write_lightfield(lf2, tmp / names["lf2"])
        savez_atomic(tmp / names["gt"], compressed=True, scene=np.str_(name), **gt)
        if preview:
            from lfsf.viz import overview_figure

            overview_figure(lf1.centre, lf2.centre, gt["disp1"], gt["disp2"], gt["u"], gt["v"],
                            path=tmp / PREVIEW_NAME, title=f"{name}: ground truth", label="ground truth",
                            occluded=gt["occluded"].astype(bool))
    return {key: out / name for key, name in names.items()}


def earlier_preview(out) -> tuple[str, ...]:
    """``(PREVIEW_NAME,)`` where ``out`` holds an earlier render's picture (a preview.png
    beside a gt.npz), which a render without ``preview`` removes with the rest of the set
    it replaces; () otherwise: a preview.png of the user's own stays."""
    from lfsf._files import stale_picture

    return stale_picture(out, PREVIEW_NAME, SCENE_FILES[2])


#: The files :func:`write_scene` writes: the light fields at t1 and t2, the ground truth.
SCENE_FILES = ("lf1.npz", "lf2.npz", "gt.npz")
#: The picture of a rendered pair's ground truth (:func:`write_scene`'s ``preview``).
PREVIEW_NAME = "preview.png"


def _warn_beyond_ranges(gts: list, out) -> None:
    """Warn where a sequence's ground truth goes beyond what the estimator reaches with its
    defaults (``Params.disparity_range``, and the flow search's range for views of its
    size, ``lfsf.estimate.searched_flow_range``): a long sequence of a moving
    scene runs on into disparities no preset can follow (a helper's 10 frames of `paper`
    reached δ2 = 34 px per view step, and the batch's last pairs were garbage, silently)."""
    import warnings

    from lfsf.estimate import pyramid_sizes, searched_flow_range
    from lfsf.params import Params

    defaults = Params()
    for k, gt in enumerate(gts):
        valid = np.asarray(gt.get("valid", np.ones_like(gt["disp1"], bool)), bool)
        if not valid.any():
            continue
        disparity = max(float(np.abs(gt[key][valid]).max()) for key in ("disp1", "disp2"))
        flow = float(np.hypot(gt["u"], gt["v"])[valid].max())
        flow_range = searched_flow_range(defaults, pyramid_sizes(*valid.shape, defaults))
        if disparity > defaults.disparity_range or flow > flow_range:
            warnings.warn(f"{out}: from pair f{k:03d} on, the ground truth reaches |δ| = {disparity:.1f} px per view "
                          f"step and flows of {flow:.1f} px, beyond the estimator's defaults (disparity_range "
                          f"{defaults.disparity_range:g}, flow search ±{flow_range:g} px); fewer --frames keep "
                          "within them", LfsfWarning, stacklevel=3)
            return


def write_sequence(
    scene: str | Scene,
    out: str | os.PathLike,
    frames: int,
    *,
    size: tuple[int, int] = (640, 480),
    grid: int | tuple[int, int] = 9,
    supersample: int = 2,
    colour: bool = False,
    device: str | None = None,
    noise: float = 0.0,
    images=None,
) -> dict[str, list[Path]]:
    """Render :func:`render_sequence` and write the frames ``out/frames/f000.npz``, … (a
    folder ``lfsf batch`` reads as consecutive pairs) and each pair's ground truth
    ``out/gt/f000.npz``, … (named after the pair's first frame), all moved into place
    together once written.
    ``noise`` > 0: sensor noise on every view, independent per frame (seed = frame)."""
    from lfsf._files import file_set, output_folder, savez_atomic
    from lfsf.io import write_lightfield

    noise = _noise_sigma(noise)  # a bad sigma: an error before any rendering
    frames = check_render(size, grid, supersample, frames, colour)["frames"]  # (and the rest: before the names)
    output_folder(out, create=False)  # and an output that cannot be written
    out = Path(out)
    frame_names = [f"frames/f{k:03d}.npz" for k in range(frames)]
    gt_names = [f"gt/f{k:03d}.npz" for k in range(frames - 1)]
    # (before the render, as every check of the outputs)
    earlier = sorted(p.name for p in (out / "frames").glob("f*.npz") if f"frames/{p.name}" not in frame_names)
    if earlier:
        raise ValueError(f"{out / 'frames'}: holds frames of an earlier sequence ({', '.join(earlier[:3])}"
                         f"{' …' if len(earlier) > 3 else ''}) that a batch would pair with these; remove them "
                         "or choose another --out")
    lfs, gts = render_sequence(scene, frames, size=size, grid=grid, supersample=supersample, colour=colour,
                               device=device, images=images)
    lfs = [add_noise(lf, noise, seed=k) for k, lf in enumerate(lfs)]
    _warn_beyond_ranges(gts, out)
    name = get_scene(scene).name
    with file_set(out, frame_names + gt_names) as tmp:
        (tmp / "frames").mkdir()
        (tmp / "gt").mkdir()
        for lf, frame in zip(lfs, frame_names):
            write_lightfield(lf, tmp / frame)
        for gt, gt_name in zip(gts, gt_names):
            savez_atomic(tmp / gt_name, compressed=True, scene=np.str_(name), **gt)
    return {"frames": [out / f for f in frame_names], "gt": [out / g for g in gt_names]}
