"""Raw plenoptic images: decode a lenslet image into sub-aperture views (``lfsf decode``).

A plenoptic camera puts a micro-lens array in front of its sensor; behind each lens lies
a small image of the main lens's aperture, the *micro-image*. A pixel's position within
its micro-image says from which direction its ray came, the lens's position says where
in the scene. Decoding turns the raw sensor image into the 4-D light field
``views[a, b, y, x]`` of ``help(lfsf)`` (MODEL.md §1), in four stages, each a function here:

1. **Reading** (:func:`read_raw`): 16-bit PNG/TIFF, Lytro containers through imageio's
   Lytro plugins (which unpack the 10/12-bit sensor data and the metadata), other raw
   formats through rawpy. Values are scaled to [0, 1] after the black level.
2. **Calibration** (:func:`calibrate`), from the white image alone: the micro-lens
   centres, then a lattice (hexagonal or rectangular; pitch, rotation, offset) fitted to
   all of them by least squares.
3. **Devignetting and demosaicing**: the raw image is divided by the white image,
   photosite by photosite, relative to the white's bright level (its 99.9th percentile:
   the white's exposure does not matter, only its shape), then a Bayer mosaic is
   interpolated bilinearly (:func:`demosaic`).
4. **Resampling** (:func:`decode`): each micro-image is sampled at the sub-pixel offset of
   every view, then the lens values are resampled from the lens lattice onto a
   rectangular grid of square pixels one lens pitch wide (barycentric interpolation over
   the lattice's triangles on a hexagonal lattice, bilinear on a rectangular one).

Conventions
-----------
* Sensor pixel (row, column) has its centre at sensor coordinates (x, y) = (column, row).
* Lens (i, j) of a hexagonal lattice sits at lattice-plane coordinates (u, v) =
  (j + (i mod 2)/2, i·√3/2) lens pitches; of a rectangular lattice at (j, i). The sensor
  position is ``origin + M·(u, v)`` with the lattice matrix M = pitch·R(rotation) (a
  fitted lattice may carry a slightly more general M). Rotations are canonical: in
  (−30°, 30°] for a hexagonal lattice, (−45°, 45°] for a rectangular one.
* The angular axes are the sensor's axes, and N views span one lens pitch: the pixel at
  offset (dx, dy) from a lens centre belongs to the view at angular offset
  (ξ, η) = (dx, dy)·N/pitch view steps — no inversion (``flip=True`` for optics that
  invert, which negates it). View (a, b) has (ξ, η) = (b − (N−1)/2, a − (N−1)/2).
* Output pixel (x, y) sits at lattice-plane position (u0 + x, v0 + y): the spatial unit
  is one lens pitch, along the lattice's axes. The decoded light field then follows
  the disparity convention of ``help(lfsf)`` (a point at centre pixel p appears at p − δ·φ).

>>> from lfsf import synth                                                                     # doctest: +SKIP
>>> lf1, _, _ = synth.render_scene("paper", size=(60, 45), grid=9)                            # doctest: +SKIP
>>> raw, white = synthetic_lenslet(lf1.views, Lattice.regular("hex", 14.2), (800, 600), views=9)  # doctest: +SKIP
>>> lf = decode(raw, white, views=9)                                                          # doctest: +SKIP
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from lfsf import device as _device
from lfsf._errors import LfsfWarning
from lfsf._filters import box_mean as _box_blur

if TYPE_CHECKING:
    from lfsf.io import LightField

__all__ = [
    "HEX_ROW_HEIGHT",
    "BAYER_PATTERNS",
    "Lattice",
    "RawImage",
    "read_raw",
    "demosaic",
    "calibrate",
    "decode",
    "decode_files",
    "synthetic_lenslet",
]

#: Distance between lens rows of a hexagonal lattice, in lens pitches.
HEX_ROW_HEIGHT = math.sqrt(3.0) / 2.0
#: Colour (0 = R, 1 = G, 2 = B) of the photosites at (row, column) parity (0, 0), (0, 1),
#: (1, 0), (1, 1).
BAYER_PATTERNS = {
    "RGGB": (0, 1, 1, 2),
    "BGGR": (2, 1, 1, 0),
    "GRBG": (1, 0, 2, 1),
    "GBRG": (1, 2, 0, 1),
}
#: Byte counts of the Lytro cameras' packed raw files (Illum: 7728×5368 at 10 bit; F01:
#: 3280×3280 at 12 bit), by which a ``.raw`` file is told apart from other raw formats.
_LYTRO_RAW_BYTES = {7728 * 5368 * 10 // 8: ("LYTRO-ILLUM-RAW", 1023.0, "GRBG"),
                    3280 * 3280 * 12 // 8: ("LYTRO-F01-RAW", 4095.0, "BGGR")}
#: Decoded views with more than this share of their values at SATURATED or above (the raw
#: divided by the white, clipped at 1) are refused: the raw was brighter than the white
#: nearly everywhere, as where the two are swapped (the views all came out ~1.0 without
#: a word). An overexposed sky or highlight takes a part of the views, not half of them.
SATURATED = 0.999
MAX_SATURATED_SHARE = 0.5
#: ``bayer`` for a grey (monochrome) sensor, overriding a pattern in the files' metadata.
GREY = "none"
#: The white image's floor, as a fraction of its bright level, below which it is not
#: trusted for devignetting (the dark gaps between micro-images).
_WHITE_FLOOR = 0.02
#: A fit whose RMS residual exceeds this fraction of the pitch shows no lattice.
_MAX_RESIDUAL = 0.1


# --------------------------------------------------------------------------------------
# The lattice
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Lattice:
    """A micro-lens lattice on the sensor.

    Parameters
    ----------
    kind : {"hex", "rect"}
    origin : (x, y)
        Sensor position of lens (0, 0), pixels.
    matrix : 2×2 nested tuple
        M, mapping lattice-plane coordinates (u, v) in lens pitches to sensor offsets in
        pixels; ``pitch·R(rotation)`` for a regular lattice (:meth:`regular`).
    residual : float
        RMS distance (pixels) between the measured lens centres and the fitted lattice;
        0 for a lattice that was not fitted.
    lenses : int
        Number of lens centres the fit used.
    """

    kind: str
    origin: tuple[float, float]
    matrix: tuple[tuple[float, float], tuple[float, float]]
    residual: float = 0.0
    lenses: int = 0

    def __post_init__(self):
        if self.kind not in ("hex", "rect"):
            raise ValueError(f"expected lattice kind 'hex' or 'rect', got {self.kind!r}")

    @classmethod
    def regular(cls, kind: str, pitch: float, rotation: float = 0.0, origin=(0.0, 0.0)) -> "Lattice":
        """A lattice of square (rect) or equilateral (hex) cells: M = pitch·R(rotation).

        ``rotation`` is in radians, ``pitch`` and ``origin`` in pixels."""
        c, s = math.cos(rotation), math.sin(rotation)
        m = ((pitch * c, -pitch * s), (pitch * s, pitch * c))
        return cls(kind, (float(origin[0]), float(origin[1])), m)

    @property
    def m(self) -> np.ndarray:
        return np.array(self.matrix, dtype=np.float64)

    @property
    def pitch(self) -> float:
        """Lens pitch in pixels, sqrt(|det M|)."""
        return float(math.sqrt(abs(np.linalg.det(self.m))))

    @property
    def rotation(self) -> float:
        """Rotation of the lattice's u axis from the sensor's x axis, radians."""
        return float(math.atan2(self.matrix[1][0], self.matrix[0][0]))

    @property
    def row_shift(self) -> float:
        """Shift of odd lens rows along u, in pitches (0.5 hex, 0 rect)."""
        return 0.5 if self.kind == "hex" else 0.0

    @property
    def row_height(self) -> float:
        """Distance between lens rows, in pitches (√3/2 hex, 1 rect)."""
        return HEX_ROW_HEIGHT if self.kind == "hex" else 1.0

    def plane_position(self, i, j):
        """Lattice-plane coordinates (u, v), in pitches, of lens (i, j)."""
        i = np.asarray(i)
        return np.asarray(j) + self.row_shift * np.mod(i, 2), i * self.row_height

    def centres(self, i, j):
        """Sensor positions (x, y) of lens (i, j)."""
        u, v = self.plane_position(i, j)
        return self.to_sensor(u, v)

    def to_sensor(self, u, v):
        """Sensor coordinates of lattice-plane coordinates (u, v)."""
        m = self.m
        u, v = np.asarray(u, np.float64), np.asarray(v, np.float64)
        return self.origin[0] + m[0, 0] * u + m[0, 1] * v, self.origin[1] + m[1, 0] * u + m[1, 1] * v

    def to_plane(self, x, y):
        """Lattice-plane coordinates (u, v) of sensor coordinates (x, y)."""
        inv = np.linalg.inv(self.m)
        dx = np.asarray(x, np.float64) - self.origin[0]
        dy = np.asarray(y, np.float64) - self.origin[1]
        return inv[0, 0] * dx + inv[0, 1] * dy, inv[1, 0] * dx + inv[1, 1] * dy

    def nearest_lens(self, x, y):
        """Indices (i, j) of the lens whose centre is nearest to sensor position (x, y).

        The nearest centre lies in one of the two lens rows around the point (a lattice
        cell's circumradius is less than the row height), at the rounded column there."""
        x = np.asarray(x, np.float64)
        y = np.asarray(y, np.float64)
        u, v = self.to_plane(x, y)
        i0 = np.floor(v / self.row_height).astype(np.int64)
        best_i = best_j = best_d = None
        for i in (i0, i0 + 1):
            j = np.rint(u - self.row_shift * np.mod(i, 2)).astype(np.int64)
            cx, cy = self.centres(i, j)
            d = (cx - x) ** 2 + (cy - y) ** 2
            if best_d is None:
                best_i, best_j, best_d = i, j, d
            else:
                nearer = d < best_d
                best_i = np.where(nearer, i, best_i)
                best_j = np.where(nearer, j, best_j)
                best_d = np.where(nearer, d, best_d)
        return best_i, best_j

    def describe(self) -> str:
        return (f"{'hexagonal' if self.kind == 'hex' else 'rectangular'} lattice, pitch {self.pitch:.4f} px, "
                f"rotation {self.rotation * 1e3:.3f} mrad, lens (0, 0) at ({self.origin[0]:.3f}, "
                f"{self.origin[1]:.3f}) px" + (f", {self.lenses} lenses fitted, RMS residual "
                                               f"{self.residual:.3f} px" if self.lenses else ""))

    def as_dict(self) -> dict:
        return {"kind": self.kind, "pitch": self.pitch, "rotation": self.rotation,
                "origin": list(self.origin), "matrix": [list(r) for r in self.matrix],
                "residual": self.residual, "lenses": self.lenses}


# --------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------


@dataclass
class RawImage:
    """A sensor image as read: ``data`` float32 (H, W) (grey or a Bayer mosaic) or
    (H, W, 3) (already RGB), in [0, 1] after the black level; ``bayer`` the mosaic's
    pattern (a key of :data:`BAYER_PATTERNS`) when known; ``source`` its path."""

    data: np.ndarray
    bayer: str | None = None
    source: str = "<array>"


def _bayer_name(text: str, source: str) -> str:
    name = str(text).strip().upper()
    if name not in BAYER_PATTERNS:
        raise ValueError(f"{source}: unknown Bayer pattern {text!r}; expected one of "
                         f"{', '.join(BAYER_PATTERNS)}")
    return name


def _bayer_option(text, source: str) -> str | None:
    """``bayer`` as :func:`decode` takes it: None (the files' pattern), :data:`GREY` (any
    case), or a key of :data:`BAYER_PATTERNS`."""
    if text is None:
        return None
    if str(text).strip().lower() == GREY:
        return GREY
    if str(text).strip().upper() not in BAYER_PATTERNS:
        raise ValueError(f"{source}: unknown Bayer pattern {text!r}; expected one of "
                         f"{', '.join(BAYER_PATTERNS)}, or {GREY} for a grey sensor")
    return str(text).strip().upper()


def _find_key(tree, key):
    """The first value stored under ``key`` anywhere in nested dicts/lists, else None."""
    if isinstance(tree, dict):
        if key in tree:
            return tree[key]
        children = tree.values()
    elif isinstance(tree, list):
        children = tree
    else:
        return None
    for child in children:
        found = _find_key(child, key)
        if found is not None:
            return found
    return None


def _lytro_levels(meta, full_scale: float):
    """Black and white levels from Lytro metadata (``pixelFormat``), as fractions of
    ``full_scale``; (0, 1) when absent."""
    fmt = _find_key(meta, "pixelFormat")
    try:
        black = np.mean([float(v) for v in fmt["black"].values()]) / full_scale
        white = np.mean([float(v) for v in fmt["white"].values()]) / full_scale
        if 0.0 <= black < white:
            return black, white
    except (TypeError, KeyError, AttributeError, ValueError):
        pass
    return 0.0, 1.0


def _lytro_bayer(meta) -> str | None:
    """The Bayer pattern from Lytro metadata: ``mosaic.tile`` (e.g. ``"r,gr:gb,b"``, the
    2×2 tile row by row) read from ``mosaic.upperLeftPixel`` on."""
    mosaic = _find_key(meta, "mosaic")
    try:
        tile = [c.strip().lower() for row in mosaic["tile"].split(":") for c in row.split(",")]
        first = str(mosaic["upperLeftPixel"]).strip().lower()
        k = tile.index(first)
    except (TypeError, KeyError, AttributeError, ValueError):
        return None
    if len(tile) != 4:
        return None
    r, c = divmod(k, 2)
    order = [tile[((r + dr) % 2) * 2 + (c + dc) % 2] for dr in (0, 1) for dc in (0, 1)]
    return "".join("R" if t == "r" else "B" if t == "b" else "G" for t in order)


def _read_lytro(path: Path, fmt: str, full_scale: float, default_bayer: str | None) -> RawImage:
    import logging
    import warnings

    import imageio.v2 as iio2

    if path.suffix.lower() == ".raw" and not any(path.with_suffix(ext).is_file()
                                                 for ext in (".txt", ".TXT", ".json", ".JSON")):
        # (imageio's plugin logs its own line for this, twice and unprefixed: silenced below)
        warnings.warn(f"{path}: no metadata file beside it ({path.stem}.txt or .json): black level 0, white "
                      f"level full scale, Bayer pattern {default_bayer} (the camera's usual)", LfsfWarning,
                      stacklevel=3)
    logger = logging.getLogger("imageio")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        image = iio2.imread(path, format=fmt)
    except Exception as err:        # the plugins raise many kinds for a corrupt file
        raise ValueError(f"{path}: cannot read as {fmt} ({type(err).__name__}: {err})") from err
    finally:
        logger.setLevel(level)
    meta = dict(getattr(image, "meta", {}) or {})
    data = np.asarray(image, dtype=np.float64)
    if data.ndim != 2 or data.size == 0:
        raise ValueError(f"{path}: expected a 2-D sensor image from {fmt}, got shape {data.shape}")
    black, white = _lytro_levels(meta, full_scale)
    data = np.clip((data - black) / (white - black), 0.0, 1.0).astype(np.float32)
    return RawImage(data, _lytro_bayer(meta) or default_bayer, str(path))


def _read_rawpy(path: Path) -> RawImage:
    import rawpy

    try:
        with rawpy.imread(str(path)) as raw:
            data = np.array(raw.raw_image_visible, dtype=np.float64)
            pattern = np.array(raw.raw_pattern) if raw.raw_pattern is not None else None
            desc = raw.color_desc.decode(errors="replace") if raw.color_desc else ""
            black = np.asarray(raw.black_level_per_channel, np.float64)
            white = float(raw.white_level or data.max() or 1.0)
    except Exception as err:        # LibRaw errors for anything it does not know
        kind = type(err).__name__
        reason = {"LibRawFileUnsupportedError": "not a raw format that LibRaw knows",
                  "LibRawIOError": "LibRaw could not read it: not a raw image, or a truncated one"}.get(kind)
        raise ValueError(f"{path}: cannot read as a raw image "
                         f"({reason + f'; {kind}' if reason else f'{kind}: {err}'})") from err
    bayer = None
    if pattern is not None and pattern.shape == (2, 2) and len(desc) >= 3:
        letters = "".join(desc[int(k)] for k in pattern.ravel()).upper()   # color_desc e.g. "RGBG"
        bayer = letters if letters in BAYER_PATTERNS else None
    level = float(black.mean()) if black.size else 0.0
    data = np.clip((data - level) / max(white - level, 1.0), 0.0, 1.0).astype(np.float32)
    return RawImage(data, bayer, str(path))


def read_raw(path: str | os.PathLike, *, role: str = "raw") -> RawImage:
    """Read a raw lenslet (or white) image.

    Parameters
    ----------
    path : str or path-like
        A 16-bit (or 8-bit) PNG or TIFF, grey (a mosaic or a monochrome sensor) or RGB; a
        Lytro ``.lfr``/``.lfp`` container (imageio's ``LYTRO-LFR``/``LYTRO-LFP``); a
        Lytro ``.raw`` (Illum or F01, told apart by size; metadata from the ``.txt`` or
        ``.json`` beside it); or any raw format rawpy reads.
    role : str
        What the image is (``"raw"``, ``"white"``), for the messages.

    Returns
    -------
    RawImage
        Values scaled to [0, 1] by the integer type's maximum, or for Lytro and rawpy
        files by the black and white levels of their metadata; ``bayer`` from the
        metadata (Lytro ``mosaic``, rawpy ``raw_pattern``), else for a Lytro camera its
        usual pattern (Illum GRBG, F01 BGGR), else None.

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        If it cannot be read (unknown format, truncated, corrupt), naming the file.
    """
    from lfsf._files import file_name
    from lfsf.io import read_image, refuse_wide_integers

    path = file_name(path, f"a {role} image file's name")
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such {role} image file")
    if not path.is_file():
        raise ValueError(f"{path}: expected a {role} image file, got "
                         f"{'a folder' if path.is_dir() else 'something else (a pipe or a device)'}")
    suffix = path.suffix.lower()
    if suffix == ".lfr":
        return _read_lytro(path, "LYTRO-LFR", 1023.0, "GRBG")
    if suffix == ".lfp":
        return _read_lytro(path, "LYTRO-LFP", 4095.0, "BGGR")
    if suffix == ".raw" and path.stat().st_size in _LYTRO_RAW_BYTES:
        fmt, full_scale, bayer = _LYTRO_RAW_BYTES[path.stat().st_size]
        return _read_lytro(path, fmt, full_scale, bayer)
    if suffix in (".png", ".tif", ".tiff"):
        image = read_image(path)
        if image.ndim == 3:
            if image.shape[2] in (1, 2):
                image = image[..., 0]
            elif image.shape[2] in (3, 4):
                image = image[..., :3]
            else:
                raise ValueError(f"{path}: expected a grey or RGB image, got an array of shape {image.shape}: "
                                 f"{image.shape[2]} channels, or a stack of images (pages of a TIFF)")
        if image.ndim not in (2, 3) or image.size == 0:
            raise ValueError(f"{path}: expected a 2-D sensor image, got shape {image.shape}")
        # (a 16-bit sensor image saved as int32 had been scaled by int32's maximum, to views of 1e-5)
        refuse_wide_integers(image, str(path), "pixels", fix="save the sensor image with 8 or 16 bits (uint8 or "
                             "uint16), or as floats in [0, 1]")
        if image.dtype.kind in "iu":
            data = image.astype(np.float32) / np.float32(np.iinfo(image.dtype).max)
        elif image.dtype.kind == "f":
            data = image.astype(np.float32)
        else:
            raise ValueError(f"{path}: expected integer or float pixels, got {image.dtype}")
        if not np.isfinite(data).all():
            raise ValueError(f"{path}: expected finite pixel values, got NaN or infinity")
        return RawImage(data, None, str(path))
    return _read_rawpy(path)


# --------------------------------------------------------------------------------------
# Image helpers (calibration runs once per camera; plain NumPy)
# --------------------------------------------------------------------------------------


def _blur_axis(image: np.ndarray, kernel: np.ndarray, axis: int) -> np.ndarray:
    r = len(kernel) // 2
    pad = [(0, 0), (0, 0)]
    pad[axis] = (r, r)
    padded = np.pad(image, pad, mode="reflect" if image.shape[axis] > r else "edge")
    out = np.zeros_like(image)
    n = image.shape[axis]
    for k, w in enumerate(kernel):
        sl = [slice(None), slice(None)]
        sl[axis] = slice(k, k + n)
        out += np.float32(w) * padded[tuple(sl)]
    return out


def _gaussian_blur(image: np.ndarray, sigma: float) -> np.ndarray:
    r = max(1, int(math.ceil(3.0 * sigma)))
    x = np.arange(-r, r + 1, dtype=np.float64)
    kernel = np.exp(-0.5 * (x / sigma) ** 2)
    kernel /= kernel.sum()
    return _blur_axis(_blur_axis(image.astype(np.float32), kernel, 0), kernel, 1)


def _grey_white(white: RawImage) -> np.ndarray:
    """The white image as one grey plane for calibration: RGB as luma; a Bayer mosaic
    filtered by [1 2 1]⊗[1 2 1]/16, which cancels the 2×2 pattern exactly and is
    symmetric (it moves no peak)."""
    data = white.data
    if data.ndim == 3:
        if data.shape[2] != 3:  # (matmul's own message had named its core dimensions)
            raise ValueError(f"{white.source}: expected a white image of shape (H, W) or (H, W, 3), got "
                             f"{data.shape}")
        return (data @ np.array([0.299, 0.587, 0.114], np.float32)).astype(np.float32)
    if white.bayer:
        k = np.array([0.25, 0.5, 0.25])
        return _blur_axis(_blur_axis(data.astype(np.float32), k, 0), k, 1)
    return data.astype(np.float32)


# --------------------------------------------------------------------------------------
# Calibration
# --------------------------------------------------------------------------------------


def _no_lattice(source: str, why: str) -> ValueError:
    return ValueError(f"{source}: the white image shows no micro-lens lattice ({why})")


def _parabola_offset(lm, l0, lp):
    """Sub-sample offset of the vertex of the parabola through (−1, lm), (0, l0), (1, lp)."""
    den = lm - 2.0 * l0 + lp
    with np.errstate(divide="ignore", invalid="ignore"):
        off = np.where(den < 0, 0.5 * (lm - lp) / np.where(den < 0, den, -1.0), 0.0)
    return np.clip(off, -0.5, 0.5)


def _rough_lattice(grey: np.ndarray, source: str):
    """Kind, pitch and rotation from the autocorrelation of a central crop: its nearest
    peak off the origin is a lattice vector; a peak 60° from it means hexagonal, 90°
    rectangular."""
    h, w = grey.shape
    n = min(h, w, 768)
    if n < 24:
        raise _no_lattice(source, f"an image of {w}×{h} pixels is too small to calibrate")
    y0, x0 = (h - n) // 2, (w - n) // 2
    crop = grey[y0:y0 + n, x0:x0 + n].astype(np.float64)
    yy, xx = np.mgrid[0:n, 0:n]
    design = np.stack([np.ones(n * n), xx.ravel(), yy.ravel()], 1)
    coef, *_ = np.linalg.lstsq(design, crop.ravel(), rcond=None)
    crop = crop - (design @ coef).reshape(n, n)         # main-lens vignetting: a ramp
    spec = np.fft.rfft2(crop, s=(2 * n, 2 * n))
    ac = np.fft.irfft2(np.abs(spec) ** 2, s=(2 * n, 2 * n))
    half = n // 3
    lags = np.arange(-half, half + 1)
    ac = ac[np.ix_(lags % (2 * n), lags % (2 * n))]
    overlap = (n - np.abs(lags))[:, None] * (n - np.abs(lags))[None, :]
    ac = ac / overlap
    ac0 = ac[half, half]
    if not ac0 > 1e-12:
        raise _no_lattice(source, "it is uniform")
    inner = ac[1:-1, 1:-1]
    peak = np.ones_like(inner, bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy or dx:
                peak &= inner > ac[1 + dy:ac.shape[0] - 1 + dy, 1 + dx:ac.shape[1] - 1 + dx]
    py, px = np.nonzero(peak)
    py, px = py + 1 - half, px + 1 - half
    far = py ** 2 + px ** 2 >= 4
    py, px = py[far], px[far]
    if py.size == 0:
        raise _no_lattice(source, "its autocorrelation has no peak off the origin")
    values = ac[py + half, px + half]
    best = values.max()
    if best < 0.25 * ac0:
        # (an autocorrelation's peaks off the origin may be negative: an image of no period)
        raise _no_lattice(source, f"its strongest periodic component holds {max(best / ac0, 0.0):.0%} of the "
                                  f"contrast, less than 25%")
    strong = values >= 0.5 * best
    py, px = py[strong], px[strong]
    k = np.argmin(py ** 2 + px ** 2)
    cy, cx = py[k] + half, px[k] + half
    vy = py[k] + _parabola_offset(ac[cy - 1, cx], ac[cy, cx], ac[cy + 1, cx])
    vx = px[k] + _parabola_offset(ac[cy, cx - 1], ac[cy, cx], ac[cy, cx + 1])
    pitch = math.hypot(vx, vy)
    if pitch < 3.0:
        raise _no_lattice(source, f"the period found, {pitch:.1f} px, is below the 3-px minimum pitch")

    def ac_at(angle):
        c, s = math.cos(angle), math.sin(angle)
        x, y = c * vx - s * vy + half, s * vx + c * vy + half
        if not (0 <= x < ac.shape[1] - 1 and 0 <= y < ac.shape[0] - 1):
            return -np.inf
        j, i = int(x), int(y)
        fx, fy = x - j, y - i
        return ((1 - fy) * ((1 - fx) * ac[i, j] + fx * ac[i, j + 1])
                + fy * ((1 - fx) * ac[i + 1, j] + fx * ac[i + 1, j + 1]))

    kind = "hex" if ac_at(math.pi / 3) > ac_at(math.pi / 2) else "rect"
    period = math.pi / 3 if kind == "hex" else math.pi / 2
    angle = math.atan2(vy, vx)
    angle = (angle + period / 2) % period - period / 2
    return kind, pitch, angle


def _peaks_near(smooth: np.ndarray, x, y, search: int):
    """The local maximum of ``smooth`` within ``search`` pixels of each (x, y), refined to
    sub-pixel by a parabola through the logarithm (exact for a Gaussian peak). Returns
    (x, y, ok); ``ok`` is false where the maximum lies on the search window's edge."""
    h, w = smooth.shape
    ix = np.rint(x).astype(np.int64)
    iy = np.rint(y).astype(np.int64)
    offs = np.arange(-search, search + 1)
    gy = np.clip(iy[:, None, None] + offs[None, :, None], 0, h - 1)
    gx = np.clip(ix[:, None, None] + offs[None, None, :], 0, w - 1)
    patch = smooth[gy, gx].reshape(len(ix), -1)
    k = np.argmax(patch, axis=1)
    dy, dx = np.divmod(k, 2 * search + 1)
    ok = (dy > 0) & (dy < 2 * search) & (dx > 0) & (dx < 2 * search)
    py = np.clip(iy + dy - search, 1, h - 2)
    px = np.clip(ix + dx - search, 1, w - 2)
    ok &= (py == iy + dy - search) & (px == ix + dx - search)
    log = np.log(np.maximum(smooth, 1e-12))
    ox = _parabola_offset(log[py, px - 1], log[py, px], log[py, px + 1])
    oy = _parabola_offset(log[py - 1, px], log[py, px], log[py + 1, px])
    return px + ox, py + oy, ok


def _lens_grid(lattice: Lattice, shape, margin: float):
    """Indices (i, j) of every lens whose centre lies ``margin`` pixels inside the sensor."""
    h, w = shape
    corners = np.array([(0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1)], np.float64)
    u, v = lattice.to_plane(corners[:, 0], corners[:, 1])
    i = np.arange(int(math.floor(v.min() / lattice.row_height)) - 1,
                  int(math.ceil(v.max() / lattice.row_height)) + 2)
    j = np.arange(int(math.floor(u.min())) - 2, int(math.ceil(u.max())) + 3)
    ii, jj = (a.ravel() for a in np.meshgrid(i, j, indexing="ij"))
    x, y = lattice.centres(ii, jj)
    inside = (x >= margin) & (y >= margin) & (x <= w - 1 - margin) & (y <= h - 1 - margin)
    return ii[inside], jj[inside]


def _fit(kind: str, i, j, x, y):
    """Least-squares lattice through measured centres (x, y) of lenses (i, j): origin and
    matrix M, six unknowns, linear."""
    probe = Lattice(kind, (0.0, 0.0), ((1.0, 0.0), (0.0, 1.0)))
    u, v = probe.plane_position(i, j)
    design = np.stack([np.ones_like(u, dtype=np.float64), u, v], 1)
    cx, *_ = np.linalg.lstsq(design, x, rcond=None)
    cy, *_ = np.linalg.lstsq(design, y, rcond=None)
    lattice = Lattice(kind, (float(cx[0]), float(cy[0])),
                      ((float(cx[1]), float(cx[2])), (float(cy[1]), float(cy[2]))))
    px, py = lattice.centres(i, j)
    return lattice, np.hypot(px - x, py - y)


def calibrate(white: RawImage | ArrayLike, *, bayer: str | None = None, source: str | None = None) -> Lattice:
    """Fit the micro-lens lattice to a white image.

    Parameters
    ----------
    white : RawImage or array_like, shape (H, W) or (H, W, 3)
        The white image (a diffuse white scene through the same camera); a mosaic if
        ``bayer`` (or ``white.bayer``) names a pattern.
    bayer : str, optional
        The mosaic's Bayer pattern; overrides the one ``white`` carries.
    source : str, optional
        Name for error messages (default ``white.source``).

    Returns
    -------
    Lattice
        Kind, origin (the lens nearest the sensor's centre), matrix M (pitch and
        rotation), the fit's RMS residual and the number of lenses fitted.

    Raises
    ------
    ValueError
        If the white image shows no lattice: no periodic structure, a period under
        3 px, or lens centres that no lattice fits to a tenth of the pitch.

    Notes
    -----
    1. The autocorrelation of a central crop gives the kind, a rough pitch and rotation.
    2. The white image, divided by its local mean over two pitches (main-lens
       vignetting), is smoothed with a Gaussian of a quarter pitch; its maxima are the
       lens centres (a micro-image and its neighbours are symmetric about its centre).
       Each is refined to sub-pixel by a parabola through the logarithm.
    3. The lattice is fitted by least squares to the centres within a radius of the
       centre lens, each centre given its integer indices by the previous fit; the
       radius grows threefold until the whole sensor is covered, so an index is never
       wrong by the accumulated error of a rough pitch. Centres off by more than six
       times the median residual are dropped and the lattice refitted.
    """
    if not isinstance(white, RawImage):
        white = RawImage(np.asarray(white, np.float32), None, source or "<white>")
    source = source or white.source
    if bayer is not None:
        white = RawImage(white.data, _bayer_name(bayer, source), white.source)
    grey = _grey_white(white)
    if grey.ndim != 2 or min(grey.shape) < 1:
        raise ValueError(f"{source}: expected a 2-D white image, got shape {white.data.shape}")
    kind, pitch, angle = _rough_lattice(grey, source)
    local = _box_blur(_box_blur(grey, int(round(2 * pitch))), int(round(2 * pitch)))
    smooth = _gaussian_blur(grey / np.maximum(local, 1e-6 * max(float(local.max()), 1e-30)), pitch / 4.0)
    h, w = grey.shape
    search = max(1, int(round(pitch / 5.0)))
    cx, cy, ok = _peaks_near(smooth, np.array([(w - 1) / 2.0]), np.array([(h - 1) / 2.0]),
                             int(math.ceil(pitch)))
    lattice = Lattice.regular(kind, pitch, angle, (float(cx[0]), float(cy[0])))
    margin = pitch / 2.0 + 2.0
    radius = 6.0
    extent = math.hypot(h, w) / pitch
    while True:
        i, j = _lens_grid(lattice, (h, w), margin)
        u, v = lattice.plane_position(i, j)
        near = u ** 2 + v ** 2 <= radius ** 2
        i, j = i[near], j[near]
        x0, y0 = lattice.centres(i, j)
        x, y, ok = _peaks_near(smooth, x0, y0, search)
        i, j, x, y = i[ok], j[ok], x[ok], y[ok]
        if i.size < 6:
            raise _no_lattice(source, f"only {i.size} lens centres found near the sensor's centre")
        fitted, res = _fit(kind, i, j, x, y)
        keep = res <= max(6.0 * float(np.median(res)), 0.02 * pitch)
        fitted, res = _fit(kind, i[keep], j[keep], x[keep], y[keep])
        lattice = fitted
        if radius >= extent:
            break
        radius *= 3.0
    rms = float(np.sqrt(np.mean(res ** 2)))
    if rms > _MAX_RESIDUAL * lattice.pitch or keep.mean() < 0.5:
        raise _no_lattice(source, f"the lens centres found fit no lattice: RMS residual {rms:.2f} px "
                                  f"at a pitch of {lattice.pitch:.2f} px, {keep.mean():.0%} of them kept")
    # Name the lens nearest the sensor's centre (0, 0); keep the row parity (even shift).
    ci, cj = lattice.nearest_lens((w - 1) / 2.0, (h - 1) / 2.0)
    ci = int(ci) - int(ci) % 2 if kind == "hex" else int(ci)
    ox, oy = lattice.centres(ci, int(cj))
    return Lattice(kind, (float(ox), float(oy)), lattice.matrix, residual=rms, lenses=int(keep.sum()))


# --------------------------------------------------------------------------------------
# Devignetting, demosaicing, resampling (Warp kernels: lfsf.kernels.decode)
# --------------------------------------------------------------------------------------


def demosaic(mosaic, bayer: str, *, device: str | None = None) -> np.ndarray:
    """Bilinear demosaicing of a Bayer mosaic.

    Parameters
    ----------
    mosaic : array_like, shape (H, W)
    bayer : str
        A key of :data:`BAYER_PATTERNS`, e.g. ``"RGGB"``: the colours of the 2×2 tile at
        the sensor's top-left corner, row by row.
    device : str, optional
        Warp device (default as :func:`lfsf.device.resolve_device`).

    Returns
    -------
    numpy.ndarray, float32, shape (H, W, 3)
    """
    mosaic = np.asarray(mosaic)
    if mosaic.ndim != 2 or min(mosaic.shape) < 1:  # (Warp's launch error had named its kernel)
        raise ValueError(f"demosaic: expected a 2-D mosaic (H, W), got shape {mosaic.shape}")
    wp = _device.warp()
    dev = _device.resolve_device(device)
    planes = _demosaic_planes(wp.array(np.ascontiguousarray(mosaic, np.float32), dtype=float, device=dev),
                              _bayer_name(bayer, "demosaic"), dev)
    return np.stack([p.numpy() for p in planes], -1)


def _demosaic_planes(mosaic, bayer: str, dev):
    from lfsf.kernels import decode as K

    wp = _device.warp()
    pattern = wp.vec4i(*BAYER_PATTERNS[bayer])
    planes = []
    for channel in range(3):
        out = wp.empty(mosaic.shape, dtype=float, device=dev)
        _device.launch_rows(K.demosaic_bilinear, dim=mosaic.shape, inputs=[mosaic, pattern, channel],
                            outputs=[out], device=dev)
        planes.append(out)
    return planes


def _output_grid(lattice: Lattice, shape):
    """The rectangular output grid in lattice-plane coordinates, and the lens block that
    supports it: every output point lies a pitch inside the lenses whose micro-images
    lie wholly on the sensor. Returns (u0, v0, width, height, first_row, rows,
    first_col, cols)."""
    h, w = shape
    m = lattice.pitch / 2.0 + 1.0
    cx = np.array([m, w - 1 - m, m, w - 1 - m])
    cy = np.array([m, m, h - 1 - m, h - 1 - m])
    u, v = lattice.to_plane(cx, cy)
    u_lo, u_hi = max(u[0], u[2]), min(u[1], u[3])
    v_lo, v_hi = max(v[0], v[1]), min(v[2], v[3])
    u0, v0 = math.ceil(u_lo + 1.0), math.ceil(v_lo + 1.0)
    width = int(math.floor(u_hi - 1.0)) - u0 + 1
    height = int(math.floor(v_hi - 1.0)) - v0 + 1
    first_row = int(math.floor(v_lo / lattice.row_height)) - 1
    last_row = int(math.ceil(v_hi / lattice.row_height)) + 1
    first_col = int(math.floor(u_lo)) - 2
    last_col = int(math.ceil(u_hi)) + 2
    return (float(u0), float(v0), width, height, first_row, last_row - first_row + 1,
            first_col, last_col - first_col + 1)


def view_offsets(lattice: Lattice, views: int, flip: bool = False) -> np.ndarray:
    """Sensor offsets (dx, dy) from a lens centre of the N×N views, row-major:
    (ξ, η)·pitch/N with (ξ, η) = (b − (N−1)/2, a − (N−1)/2), negated if ``flip``."""
    c = (views - 1) / 2.0
    a, b = np.mgrid[0:views, 0:views]
    step = lattice.pitch / views * (-1.0 if flip else 1.0)
    return np.stack([(b - c).ravel() * step, (a - c).ravel() * step], 1).astype(np.float32)


def _default_views(pitch: float) -> int:
    """The largest odd number not above the pitch: one view step is at least a pixel. A
    pitch fitted a hair under a whole number counts as it (3 px fitted as 2.9994 gave 1×1
    views, which only the flow preset takes)."""
    n = int(math.floor(pitch + 0.01))
    return max(1, n if n % 2 else n - 1)


def _check_raw(raw, source: str) -> RawImage:
    if isinstance(raw, RawImage):
        return raw
    data = np.asarray(raw)
    if data.ndim not in (2, 3) or (data.ndim == 3 and data.shape[2] != 3) or data.size == 0:
        raise ValueError(f"{source}: expected a sensor image (H, W) or (H, W, 3), got shape {data.shape}")
    if data.dtype.kind in "iu":
        data = data.astype(np.float32) / np.float32(np.iinfo(data.dtype).max)
    return RawImage(np.asarray(data, np.float32), None, source)


def white_level(white) -> float:
    """A white image's bright level: the 99.9th percentile of its values (a sample,
    :func:`_value_ends`), at least 1e-6. :func:`decode` divides the raw image by the white relative
    to it, so a decoded view is the raw's brightness through the unvignetted centre of
    the lenses: a scene as bright as the white scene, taken at the white's exposure,
    decodes to about this level (0.994 for :func:`synthetic_lenslet`'s white, whose peak
    is 1), whatever the exposure of the white itself."""
    return _bright_level(_value_ends(white)[1])


#: :func:`_value_ends` reads every this-many-th value in memory order: a prime, so that
#: row after row the values read shift across the micro-images. (Every 7th row and
#: column had read the same place of each lens where the pitch is a whole number: 7 px,
#: rectangular, gave a white level of 0.052 for 0.998, the views 19× too dark.)
VALUE_STRIDE = 47


def _value_ends(image) -> np.ndarray:
    """The 0.1th and 99.9th percentiles of an image's values (a sample of every
    :data:`VALUE_STRIDE`-th): its range, a few hot or dead pixels left out."""
    values = np.asarray(image).reshape(-1)
    return np.percentile(values[::VALUE_STRIDE] if values.size >= 1000 * VALUE_STRIDE else values, [0.1, 99.9])


def _bright_level(high) -> float:
    return max(float(high), 1e-6)


#: The raw image must be darker towards its micro-images' rims (beyond 0.4 pitch from a
#: lens centre of the white's lattice) than near their centres (within 0.2), as the white
#: is: the share by which it is darker there, over the white's, per tile of a 3×3 split of
#: the sensor (:func:`_check_white_fits`). A white of another camera setting was decoded
#: without a word (a helper's raws, hexagonal, pitch 9.6: views at 9–20 dB PSNR against 47
#: with the right white): its ratio over the tiles was −1.5 (lattice shifted), −0.4
#: (rotated 20 mrad), −0.1 (pitch 10.37), 0.0 (rectangular), 0.76 with one tile at 0.24
#: (pitch 9.65); the right white's 0.99, no tile below 0.80. Below WHITE_FIT_REFUSED on the
#: mean the decode is refused, below WHITE_FIT_WARNED in a tile it is warned of.
WHITE_FIT_REFUSED = 0.3
WHITE_FIT_WARNED = 0.5
#: A white image's neighbouring lens centres differ by a median of at most this share of
#: their level (vignetting changes slowly from lens to lens; 2×2 px means at the centres,
#: one of each filter on a mosaic): the helper's white 1.4 % (noise 0.001), a raw of a
#: smoothly textured scene given as the white 4.9 %, which had been decoded without a word.
WHITE_LENS_STEP = 0.03


def _rim_darkening(values: np.ndarray, distance: np.ndarray, tiles: np.ndarray, count: int):
    """Per tile, 1 − (mean value beyond 0.4 pitch from a lens centre) / (mean within 0.2),
    and the mean within 0.2 (NaN where a tile has neither)."""
    near, far = distance < 0.2, distance > 0.4
    centre = np.bincount(tiles[near], values[near], count) / np.maximum(np.bincount(tiles[near], None, count), 1)
    rim = np.bincount(tiles[far], values[far], count) / np.maximum(np.bincount(tiles[far], None, count), 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return 1.0 - rim / centre, centre


def _check_white_fits(raw: "RawImage", white: "RawImage", lattice: Lattice, samples: int = 300_000) -> None:
    """Refuse a white image that does not fit the raw (another zoom or focus, another
    camera), or that is no white image at all (a scene), and warn where it fits part of
    the sensor only (:data:`WHITE_FIT_REFUSED`, :data:`WHITE_FIT_WARNED`,
    :data:`WHITE_LENS_STEP`). Read from ``samples`` pixels drawn at random (the same
    every time); tiles where the raw is too dark to tell (below 2 % of the white's
    level) are left out."""
    import warnings

    h, w = raw.data.shape[:2]
    rng = np.random.default_rng(0)
    y = rng.integers(0, h, samples)
    x = rng.integers(0, w, samples)
    i, j = lattice.nearest_lens(x, y)
    cx, cy = lattice.centres(i, j)
    distance = np.hypot(cx - x, cy - y) / lattice.pitch
    tiles = (3 * y // h) * 3 + (3 * x // w)

    def grey(image, yy, xx):
        # (the values at (yy, xx) alone, in float64: the whole image would be 330 MB on an Illum's sensor)
        values = np.asarray(image.data)[yy, xx].astype(np.float64)
        return values.mean(-1) if values.ndim == 2 else values

    white_dark, white_level = _rim_darkening(grey(white, y, x), distance, tiles, 9)
    raw_dark, raw_level = _rim_darkening(grey(raw, y, x), distance, tiles, 9)
    told = (white_dark > 0.05) & (raw_level > 0.02 * np.nanmax(white_level))
    # the white's neighbouring lens centres: a white changes slowly from lens to lens
    li, lj = _lens_grid(lattice, (h, w), lattice.pitch)
    lx, ly = lattice.centres(li, lj)
    # (a 2×2 block's mean: on a mosaic, one of each filter wherever the centre lies)
    top = np.clip(np.floor(ly).astype(np.int64), 0, h - 2)
    left = np.clip(np.floor(lx).astype(np.int64), 0, w - 2)
    centre_values = 0.25 * (grey(white, top, left) + grey(white, top + 1, left) + grey(white, top, left + 1)
                            + grey(white, top + 1, left + 1))
    # (on the lenses' index grid, NaN where a lens lies off the sensor: lens (i, j) beside (i, j + 1))
    steps = np.empty(0)
    if len(li):
        grid = np.full((np.ptp(li) + 1, np.ptp(lj) + 1), np.nan)
        grid[li - li.min(), lj - lj.min()] = centre_values
        steps = np.abs(np.diff(grid, axis=1))
        steps = steps[np.isfinite(steps)]
    level = float(np.median(centre_values)) if len(centre_values) else 0.0
    if steps.size and level > 0 and float(np.median(steps)) > WHITE_LENS_STEP * level:
        raise ValueError(f"{white.source}: not a white image: its neighbouring micro-images differ by a median of "
                         f"{100 * float(np.median(steps)) / level:.0f} % (a white image is a diffuse white scene, "
                         f"alike in every micro-image but for a slow vignetting); were RAW ({raw.source}) and "
                         "--white swapped, or a scene given as --white?")
    if not told.any():
        return
    ratio = raw_dark[told] / white_dark[told]
    if float(np.mean(ratio)) < WHITE_FIT_REFUSED:
        raise ValueError(f"{raw.source}: the white image {white.source} does not fit it: the raw is not darker at "
                         f"the rims of the white's micro-images (pitch {lattice.pitch:.2f} px, rotation "
                         f"{1000 * lattice.rotation:.1f} mrad) as the white is (by "
                         f"{100 * float(np.mean(ratio)):.0f} % of the white's darkening); a white image taken at "
                         "another zoom or focus, or with another camera?")
    if float(np.min(ratio)) < WHITE_FIT_WARNED:
        warnings.warn(f"{raw.source}: the white image {white.source} fits part of the sensor only (the raw's "
                      f"darkening at the micro-images' rims is {100 * float(np.min(ratio)):.0f} % of the white's in "
                      "one ninth of it): a white of a slightly different zoom or focus? The views will be poor "
                      "there", LfsfWarning, stacklevel=3)


#: The largest rotation of the lens lattice from the sensor's rows that decode takes
#: (radians): its view grid follows the lattice's axes, the views' parallax the sensor's,
#: so on a turned lattice the two part (a helper: 5° made δ1's MSE 3.7× as large; a
#: hexagonal lattice with its rows down the sensor, found as turned by 30°, gave views of
#: 12×4 px with status 0). Real cameras' lattices lie within a few mrad.
MAX_ROTATION = math.radians(10.0)
#: A white image whose bright level is below this share of its file's full scale is said
#: to use few of its bits (10-bit values in a 16-bit file): its views are as dark.
WHITE_FEW_BITS = 1.0 / 8.0
#: A white image with more than this share of its values at full scale is said to be
#: clipped: its micro-images' shapes are lost where it is, and the views are poor there.
WHITE_CLIPPED = 0.01


def _note_white_levels(white: "RawImage", high: float) -> None:
    """Warn of a white image that uses few of its file's levels (:data:`WHITE_FEW_BITS`)
    or is clipped (:data:`WHITE_CLIPPED`)."""
    import warnings

    if 0 < high < WHITE_FEW_BITS:
        warnings.warn(f"{white.source}: its brightest values are {high:.4f} of the file's full scale (data of "
                      f"{-round(math.log2(high))} bits fewer than the file holds, such as 10-bit values in a 16-bit "
                      "file?): the views are as dark; scale the raw and the white image to full scale first for "
                      "views that look right (the estimate does not mind)", LfsfWarning, stacklevel=3)
    clipped = float(np.mean(np.asarray(white.data)[::3, ::3] >= SATURATED))
    if clipped > WHITE_CLIPPED:
        warnings.warn(f"{white.source}: {100 * clipped:.0f} % of the white image is at full scale (clipped): the "
                      "micro-images' shapes are lost there, and the views will be poor; take the white image at a "
                      "lower exposure", LfsfWarning, stacklevel=3)


def decode(raw: RawImage | ArrayLike, white: RawImage | ArrayLike, *, views: int | None = None,
           bayer: str | None = None, flip: bool = False, lattice: Lattice | None = None,
           device: str | None = None) -> LightField:
    """Decode a raw lenslet image into an N×N light field.

    Parameters
    ----------
    raw, white : RawImage or array_like, shape (H, W) or (H, W, 3)
        The raw image and the white image of the same camera, same size (float values in
        [0, 1], or integers scaled by their type's maximum).
    views : int, optional
        N, the views per side; N views span one lens pitch. Default: the largest odd
        number not above the pitch (one view step ≥ one sensor pixel); at most the pitch
        rounded up (more views than pixels across a micro-image only interpolate).
    bayer : str, optional
        Bayer pattern of a colour sensor (a key of :data:`BAYER_PATTERNS`, any case), or
        ``"none"`` for a grey sensor whatever the images' metadata say; default (None)
        the pattern the images carry, else grey (also for an RGB image).
    flip : bool
        Negate the angular offsets, for optics that invert the micro-images.
    lattice : Lattice, optional
        Skip calibration and use this lattice.
    device : str, optional
        Warp device (default as :func:`lfsf.device.resolve_device`).

    Returns
    -------
    LightField
        ``views[a, b, y, x]`` (grey) or ``[a, b, y, x, c]`` (colour), float32 clipped to
        [0, 1]; ``meta["lattice"]`` the :class:`Lattice`, ``meta["lens_views"]`` N (the
        views across a lens), ``meta["white_level"]`` the white's
        bright level it was divided relative to (:func:`white_level`), ``meta["plane_origin"]`` the
        lattice-plane position (u0, v0) of output pixel (0, 0), in pitches;
        ``meta["bayer"]`` the pattern used (None: grey or RGB).

    Raises
    ------
    ValueError
        Images of different sizes, no lattice in the white image, a bad option, more
        views than the pitch allows.
    """
    from lfsf.io import LightField
    from lfsf.kernels import decode as K

    raw = _check_raw(raw, "raw")
    white = _check_raw(white, "white")
    ends = {}
    for image, role in ((raw, "raw"), (white, "white")):
        # float values in counts (0…65535) made views of ~1e-5 and a negative white clipped
        # them all, each with status 0
        low, high = ends[role] = _value_ends(image.data)
        if not (-0.5 <= low and high <= 2.0):
            raise ValueError(f"{image.source}: the {role} image's values run from {low:g} to {high:g}; "
                             "expected [0, 1] (floats) or integers, which are scaled by their type's maximum")
    if raw.data.shape[:2] != white.data.shape[:2]:
        rh, rw = raw.data.shape[:2]
        wh, ww = white.data.shape[:2]
        named = "" if white.source == "white" else f" {white.source}"  # (an array's: "the white image white")
        raise ValueError(f"{raw.source}: the raw image is {rw}×{rh} pixels but the white image{named} is "
                         f"{ww}×{wh}; they must come from the same camera")
    if (raw.data.ndim == 3) != (white.data.ndim == 3):
        raise ValueError(f"{raw.source}: one of raw and white ({white.source}) is RGB and the other a "
                         f"single plane; give both as mosaics or both as RGB")
    if ends["raw"][0] == ends["raw"][1] and not np.ptp(np.asarray(raw.data)):  # (it decoded to a blank light field)
        raise ValueError(f"{raw.source}: every pixel of the raw image is {ends['raw'][0]:g}: a blank image (the lens "
                         "cap on, or nothing read), with nothing to decode")
    bayer = _bayer_option(bayer, raw.source)
    pattern = None if bayer == GREY else bayer or raw.bayer or white.bayer
    if pattern is not None:
        pattern = _bayer_name(pattern, raw.source)
        if raw.data.ndim == 3:
            raise ValueError(f"{raw.source}: a Bayer pattern was given for an RGB image")
    if lattice is None:
        lattice = calibrate(RawImage(white.data, pattern, white.source))
    if abs(lattice.rotation) > MAX_ROTATION:
        raise ValueError(f"{white.source}: the micro-lens lattice is turned by {math.degrees(lattice.rotation):.1f}° "
                         f"from the sensor's rows; lfsf decode takes lattices within {math.degrees(MAX_ROTATION):.0f}° "
                         "of them (rows of lenses along the sensor's rows): turn the raw and the white image by 90° "
                         "first where the lenses' rows run down the sensor")
    _check_white_fits(raw, white, lattice)
    _note_white_levels(white, ends["white"][1])
    n = int(views) if views is not None else _default_views(lattice.pitch)
    if n < 1:
        raise ValueError(f"expected at least 1 view per side, got {views}")
    # N views span one pitch: beyond the pixels across a micro-image they only interpolate,
    # and the buffers below grow as N²: at this bound they hold about (N/pitch)² times the
    # sensor's pixels per colour: about twice the images already read at most (pitch ≥ 3 px).
    max_views = max(1, math.ceil(lattice.pitch))
    if n > max_views:
        raise ValueError(f"{raw.source}: expected at most {max_views} views per side at a lens pitch of "
                         f"{lattice.pitch:.2f} px (N views span one pitch; more than the pixels across a "
                         f"micro-image would only interpolate between them), got {n}")
    u0, v0, width, height, first_row, rows, first_col, cols = _output_grid(lattice, raw.data.shape[:2])
    if width < 2 or height < 2:
        raise ValueError(f"{raw.source}: the sensor holds too few whole micro-lenses at pitch "
                         f"{lattice.pitch:.2f} px to decode ({max(width, 0)}×{max(height, 0)} output pixels)")
    wp = _device.warp()
    dev = _device.resolve_device(device)
    # the raw is divided by the white relative to its bright level, so that a white taken
    # at a lower exposure than the raw (half scale: every view pixel brighter than half
    # clipped to 1) devignettes the same as one at full scale
    level = _bright_level(ends["white"][1])   # (white_level, from the range found above)
    floor = np.float32(_WHITE_FLOOR * level)

    def on_device(a):
        return wp.array(np.ascontiguousarray(a, np.float32), dtype=float, device=dev)

    def devignetted(r, w):
        out = wp.empty(r.shape, dtype=float, device=dev)
        _device.launch_rows(K.devignette, dim=r.shape, inputs=[r, w, float(floor), float(np.float32(level))],
                            outputs=[out], device=dev)
        return out

    if raw.data.ndim == 3:
        planes = [devignetted(on_device(raw.data[..., c]), on_device(white.data[..., c])) for c in range(3)]
    else:
        ratio = devignetted(on_device(raw.data), on_device(white.data))
        planes = _demosaic_planes(ratio, pattern, dev) if pattern else [ratio]
    offsets = wp.array(view_offsets(lattice, n, flip), dtype=wp.vec2, device=dev)
    m = lattice.m
    e1 = wp.vec2(float(m[0, 0]), float(m[1, 0]))
    e2 = wp.vec2(float(m[0, 1] * lattice.row_height), float(m[1, 1] * lattice.row_height))
    origin = wp.vec2(*lattice.origin)
    lens_values = wp.empty((n * n, rows, cols), dtype=float, device=dev)
    out = wp.empty((n * n, height, width), dtype=float, device=dev)
    result = []
    for plane in planes:
        _device.launch_rows(K.sample_micro_images, dim=(n * n * rows, cols),
                            inputs=[plane, origin, e1, e2, lattice.row_shift, first_row, first_col, offsets],
                            outputs=[lens_values], device=dev)
        _device.launch_rows(K.resample_lattice, dim=(n * n * height, width),
                            inputs=[lens_values, lattice.row_shift, lattice.row_height, first_row, first_col,
                                    u0, v0],
                            outputs=[out], device=dev)
        result.append(np.clip(out.numpy(), 0.0, 1.0).reshape(n, n, height, width))
    array = result[0] if len(result) == 1 else np.stack(result, -1)
    saturated = float(np.mean(array >= SATURATED))
    if saturated > MAX_SATURATED_SHARE:
        raise ValueError(f"{raw.source}: {100 * saturated:.0f} % of the decoded views' values are at full scale: "
                         f"the raw image is brighter than the white image {white.source} nearly everywhere; "
                         "were RAW and --white swapped, or is the raw overexposed? (the white image is a "
                         "diffuse white scene, taken brighter than any raw)")
    return LightField(array, source=raw.source,
                      meta={"layout": "lenslet", "lattice": lattice, "lens_views": n, "plane_origin": (u0, v0),
                            "flip": flip, "bayer": pattern, "white_level": level})


def decode_files(raw_path, white_path, out, *, views: int | None = None, bayer: str | None = None,
                 flip: bool = False, device: str | None = None):
    """Read, decode and write: ``out`` in the HCI layout (16-bit PNGs), ``out/views.npz``
    (key ``views``) and ``out/decode.json`` (the lattice and settings).

    The outputs are checked before any work, and written as one set: into a temporary
    folder inside ``out`` first, moved into place only once every one is complete
    (``decode.json`` last), so a failure or an interruption leaves none of them — a
    partial set of views would read as a smaller light field.

    Returns
    -------
    (LightField, dict)
        The decoded light field and the report written to ``decode.json``.

    Raises
    ------
    FileNotFoundError
        If RAW or WHITE does not exist.
    ValueError
        As :func:`read_raw` and :func:`decode`; if ``out`` is a file, one of the outputs'
        names is a folder, or ``out`` holds views of another grid that these would mix
        with (delete them first).
    """
    from lfsf._files import file_set, output_folder, refuse_replacing_inputs
    from lfsf.io import _HCI_NAME, _refuse_mixed_views, _view_names, write_lightfield

    out = output_folder(out, create=False)
    if out.is_dir():
        for entry in out.iterdir():
            if entry.name in ("views.npz", "decode.json") or _HCI_NAME.fullmatch(entry.name):
                if entry.is_dir():
                    raise ValueError(f"{entry}: is a folder; the decoded {entry.name} cannot be written there")
                # (the raw image or the white one there, or linked from there, would be replaced)
                refuse_replacing_inputs(out, [entry.name], [raw_path, white_path])
    bayer = _bayer_option(bayer, "--bayer")
    if views is not None and isinstance(views, int) and views >= 1:
        _refuse_mixed_views(out, _view_names("hci", views, views))   # known: checked before the decode
    raw = read_raw(raw_path)
    white = read_raw(white_path, role="white")
    lf = decode(raw, white, views=views, bayer=bayer, flip=flip, device=device)
    lattice = lf.meta["lattice"]
    report = {"raw": str(raw_path), "white": str(white_path), "views": lf.grid[0], "bayer": lf.meta["bayer"],
              "flip": flip, "size": [lf.width, lf.height], "plane_origin": list(lf.meta["plane_origin"]),
              "white_level": lf.meta["white_level"], "lattice": lattice.as_dict()}
    rows, cols = lf.grid
    views_written = _view_names("hci", rows, cols)
    _refuse_mixed_views(out, views_written)
    # (parameters.cfg: the grid, which write_lightfield gives, in place of an earlier one that
    # gave another; decode.json last, as the moves go, and every earlier file put back where one fails)
    with file_set(out, [*views_written, "parameters.cfg", "views.npz", "decode.json"]) as tmp:
        write_lightfield(lf, tmp)
        with open(tmp / "views.npz", "wb") as f:
            np.savez(f, views=lf.views)
        (tmp / "decode.json").write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    return lf, report


# --------------------------------------------------------------------------------------
# Synthetic lenslet images (tests, docs)
# --------------------------------------------------------------------------------------


def _sample_views(views: np.ndarray, u, v, xi, eta):
    """Quadrilinear sample of views [A, B, H, W(, C)] at pixel (u, v) and angular offset
    (ξ, η) from the grid centre, clamped to the grid and the image."""
    rows, cols, h, w = views.shape[:4]
    out = 0.0
    a = np.clip(eta + (rows - 1) / 2.0, 0, rows - 1)
    b = np.clip(xi + (cols - 1) / 2.0, 0, cols - 1)
    x = np.clip(u, 0, w - 1)
    y = np.clip(v, 0, h - 1)
    corners = []
    for q, n in ((a, rows), (b, cols), (y, h), (x, w)):
        q0 = np.minimum(np.floor(q).astype(np.int64), max(n - 2, 0))
        corners.append((q0, np.minimum(q0 + 1, n - 1), q - q0))
    (a0, a1, fa), (b0, b1, fb), (y0, y1, fy), (x0, x1, fx) = corners
    extra = (slice(None),) if views.ndim == 5 else ()
    for ia, wa in ((a0, 1 - fa), (a1, fa)):
        for ib, wb in ((b0, 1 - fb), (b1, fb)):
            for iy, wy in ((y0, 1 - fy), (y1, fy)):
                for ix, wx in ((x0, 1 - fx), (x1, fx)):
                    weight = wa * wb * wy * wx
                    if extra:
                        weight = weight[..., None]
                    out = out + weight * views[ia, ib, iy, ix]
    return out


def synthetic_lenslet(light_field, lattice: Lattice, sensor: tuple[int, int], *, views: int,
                      flip: bool = False, vignetting: float = 0.4, noise: float = 0.0,
                      white_noise: float = 0.0, bayer: str | None = None,
                      gains=(0.55, 1.0, 0.75), seed: int = 0):
    """A raw lenslet image and its white image, made from a known light field.

    Each sensor pixel belongs to its nearest lens; its offset (dx, dy) from the lens
    centre is the angular offset (ξ, η) = (dx, dy)·N/pitch (negated if ``flip``), the
    lens's lattice-plane position (u, v) its spatial position: the pixel records
    L(u, v, ξ, η) — the inverse of :func:`decode`'s conventions.

    Parameters
    ----------
    light_field : callable or array_like
        ``L(u, v, xi, eta)`` returning values of the arrays' shape (grey) or with a
        trailing axis of 3 (RGB); or views [A, B, H, W(, 3)], sampled quadrilinearly
        with (u, v) in pixels and (ξ, η) from the grid centre (clamped).
    lattice : Lattice
    sensor : (width, height)
    views : int
        N, the views spanning one lens pitch.
    flip : bool
    vignetting : float
        Main-lens falloff: the white level drops by this fraction from the centre to the
        sensor's corners (quadratically). Micro-images fall off too: 1/(1 + (r/0.42)^8)
        at r pitches from their centre.
    noise, white_noise : float
        Standard deviation of Gaussian noise added to the raw and to the white image.
    bayer : str, optional
        Record an RGB light field through this Bayer mosaic, with colour ``gains``
        (applied to the white image too, as a real sensor's filters are).
    seed : int

    Returns
    -------
    raw, white : float32 arrays (H, W) (grey or mosaic) or (H, W, 3) (RGB without
        ``bayer``), in [0, 1]
    """
    width, height = (int(s) for s in sensor)
    if min(width, height) < lattice.pitch:          # (0×0 returned (None, None), 1×1 NaN)
        raise ValueError(f"synthetic_lenslet: a sensor of {width}×{height} pixels holds no whole "
                         f"micro-image (pitch {lattice.pitch:g} px)")
    source = light_field if callable(light_field) else None
    array = None if source else np.asarray(getattr(light_field, "views", light_field), np.float32)
    if bayer is not None:
        pattern = np.array(BAYER_PATTERNS[_bayer_name(bayer, "synthetic_lenslet")]).reshape(2, 2)
    rng = np.random.default_rng(seed)
    raw = white = None
    pitch = lattice.pitch
    half_diag2 = ((width - 1) / 2.0) ** 2 + ((height - 1) / 2.0) ** 2
    band = max(1, 2 ** 20 // max(width, 1))
    for y0 in range(0, height, band):
        y, x = np.mgrid[y0:min(height, y0 + band), 0:width].astype(np.float64)
        i, j = lattice.nearest_lens(x, y)
        cx, cy = lattice.centres(i, j)
        dx, dy = x - cx, y - cy
        sign = -1.0 if flip else 1.0
        xi, eta = sign * dx * views / pitch, sign * dy * views / pitch
        u, v = lattice.plane_position(i, j)
        values = np.asarray(source(u, v, xi, eta) if source else _sample_views(array, u, v, xi, eta), np.float64)
        r = np.hypot(dx, dy) / pitch
        vig = 1.0 / (1.0 + (r / 0.42) ** 8)
        vig *= 1.0 - vignetting * (((x - (width - 1) / 2.0) ** 2 + (y - (height - 1) / 2.0) ** 2) / half_diag2)
        if bayer is not None:
            if values.ndim != 3:
                raise ValueError("synthetic_lenslet: a Bayer mosaic needs an RGB light field")
            channel = pattern[y.astype(np.int64) % 2, x.astype(np.int64) % 2]
            vig = vig * np.asarray(gains, np.float64)[channel]
            values = np.take_along_axis(values, channel[..., None], -1)[..., 0]
        elif values.ndim == 3:
            vig = vig[..., None]
        raw_band = values * vig
        white_band = vig.copy()
        if noise:
            raw_band += rng.normal(0.0, noise, raw_band.shape)
        if white_noise:
            white_band += rng.normal(0.0, white_noise, white_band.shape)
        if raw is None:
            raw = np.empty((height,) + raw_band.shape[1:], np.float32)
            white = np.empty_like(raw)
        raw[y0:y0 + band] = np.clip(raw_band, 0.0, 1.0)
        white[y0:y0 + band] = np.clip(white_band, 0.0, 1.0)
    return raw, white
