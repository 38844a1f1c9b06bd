"""Pictures of scene-flow results: colour-coded flow, disparity and error maps, and an
overview figure that sets estimates beside ground truth.

Everything here returns RGB ``uint8`` arrays of shape ``(H, W, 3)``; nothing draws on
screen, and the only dependencies are NumPy, imageio and Pillow (no matplotlib). Every PNG
is written atomically (:func:`lfsf._files.atomic_path`), so an interrupted run never
leaves a half-written picture.

Conventions (see ``help(lfsf)``, MODEL.md §1): pixel ``x`` to the right, ``y`` down; flow ``(u, v)`` moves
the point seen at ``p`` in the centre view at t1 to ``p + (u, v)`` at t2; disparity in
pixels per view step.

References
----------
.. [1] S. Baker, D. Scharstein, J. P. Lewis, S. Roth, M. J. Black and R. Szeliski,
   "A Database and Evaluation Methodology for Optical Flow", IJCV 92(1), 2011.
   Colour coding of flow: the authors' ``flow-code`` (``colorcode.cpp``,
   ``computeColor.m``).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from lfsf._errors import whole
from lfsf._files import atomic_path

__all__ = [
    "disparity_to_color",
    "error_to_color",
    "flow_to_color",
    "flow_wheel_legend",
    "make_color_wheel",
    "overview_figure",
    "save_png",
]

# Segment lengths of the Middlebury colour wheel [1]_: red-yellow, yellow-green,
# green-cyan, cyan-blue, blue-magenta, magenta-red. Chosen by the authors so that the
# hues are perceptually roughly equally spaced; 55 colours in all.
_WHEEL_SEGMENTS = (
    (15, (255, 0, 0), (255, 255, 0)),
    (6, (255, 255, 0), (0, 255, 0)),
    (4, (0, 255, 0), (0, 255, 255)),
    (11, (0, 255, 255), (0, 0, 255)),
    (13, (0, 0, 255), (255, 0, 255)),
    (6, (255, 0, 255), (255, 0, 0)),
)

# Middlebury .flo files mark unknown flow with 1e10; the reference code treats any
# component above 1e9 as unknown, and so do we.
_UNKNOWN_FLOW_THRESH = 1e9

# Viridis (CC0, van der Walt & Smith) sampled at t = 0, 0.1, ..., 1. Linear interpolation
# between these stops keeps its two properties that matter here: luminance rises
# monotonically, and it stays readable in greyscale and for colour-blind readers.
_VIRIDIS_STOPS = (
    (68, 1, 84), (72, 36, 117), (65, 68, 135), (53, 95, 141), (42, 120, 142),
    (33, 145, 140), (34, 168, 132), (68, 191, 112), (122, 209, 81), (189, 223, 38),
    (253, 231, 37),
)

# White -> yellow -> orange -> red -> dark red (close to ColorBrewer YlOrRd): zero error
# vanishes into the white background, luminance falls monotonically with the error.
_ERROR_STOPS = (
    (255, 255, 255), (255, 237, 160), (254, 178, 76), (240, 59, 32), (128, 0, 38),
)


def _lut_from_stops(stops: Sequence[tuple[int, int, int]], n: int = 256) -> np.ndarray:
    """Piecewise-linear ``(n, 3)`` uint8 lookup table through equally spaced RGB stops."""
    stops_arr = np.asarray(stops, dtype=np.float64)
    at = np.linspace(0.0, 1.0, len(stops_arr))
    t = np.linspace(0.0, 1.0, n)
    lut = np.stack([np.interp(t, at, stops_arr[:, c]) for c in range(3)], axis=-1)
    return np.round(lut).astype(np.uint8)


_DISPARITY_LUT = _lut_from_stops(_VIRIDIS_STOPS)
_ERROR_LUT = _lut_from_stops(_ERROR_STOPS)


# --------------------------------------------------------------------------- flow


def make_color_wheel() -> np.ndarray:
    """The 55-colour Middlebury flow colour wheel [1]_.

    Returns
    -------
    wheel : ndarray of uint8, shape (55, 3)
        RGB colours in hue order: index 0 is red ``(255, 0, 0)``, then yellow (15), green
        (21), cyan (25), blue (36), magenta (49), back towards red (54 is
        ``(255, 0, 43)``). Within a segment one channel ramps by ``floor(255 i / n)``,
        exactly as in the reference code.
    """
    rows = []
    for n, start, end in _WHEEL_SEGMENTS:
        ramp = np.floor(255.0 * np.arange(n) / n)
        step = np.sign(np.subtract(end, start))
        rows.append(np.asarray(start, dtype=np.float64) + ramp[:, None] * step)
    return np.concatenate(rows).astype(np.uint8)


_WHEEL = make_color_wheel()


def _check_flow(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    u = np.asarray(u)
    v = np.asarray(v)
    if u.ndim != 2 or u.shape != v.shape:
        raise ValueError(
            f"expected u and v as 2-D arrays of one shape (H, W), got {u.shape} and {v.shape}"
        )
    return u.astype(np.float64), v.astype(np.float64)


def flow_scale(u, v) -> float:
    """The magnitude that :func:`flow_to_color` draws at full colour when given no
    ``max_flow``: the largest valid ``|(u, v)|`` (0 where there is none)."""
    return _max_magnitude(*_check_flow(u, v))


def _flow_valid(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return (
        np.isfinite(u)
        & np.isfinite(v)
        & (np.abs(u) <= _UNKNOWN_FLOW_THRESH)
        & (np.abs(v) <= _UNKNOWN_FLOW_THRESH)
    )


def _max_magnitude(u: np.ndarray, v: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Largest ``|(u, v)|`` over valid pixels (and ``mask``), 0 where there is none."""
    valid = _flow_valid(u, v)
    if mask is not None:
        valid &= mask
    if not valid.any():
        return 0.0
    return float(np.hypot(u[valid], v[valid]).max())


def flow_to_color(u, v, max_flow: float | None = None) -> np.ndarray:
    """Colour-code a flow field with the Middlebury colour wheel [1]_.

    Parameters
    ----------
    u, v : array_like, shape (H, W)
        Horizontal (to the right) and vertical (downwards) flow in pixels.
    max_flow : float, optional
        Magnitude drawn at full saturation. Default: the largest valid magnitude in this
        field. Pass a fixed value to give several fields one scale; vectors longer than
        ``max_flow`` are then drawn darkened (colour × 0.75), as in the reference code.

    Returns
    -------
    rgb : ndarray of uint8, shape (H, W, 3)
        Hue encodes direction, saturation magnitude: zero flow is white. Pixels where
        ``u`` or ``v`` is not finite (or above 1e9, the ``.flo`` "unknown" marker) are
        black.

    Notes
    -----
    Direction follows the reference ``computeColor``: the wheel position is
    ``fk = (atan2(-v, -u) / π + 1) / 2 · 54``, interpolated linearly between wheel colours
    ``floor(fk)`` and ``floor(fk) + 1``, then ``colour = 1 − r (1 − colour)`` for
    normalised magnitude ``r ≤ 1`` and the result floored to ``0…255``. Hence:

    * right (``u > 0, v = 0``): ``atan2(−0, −u) = −π`` → ``fk = 0`` → red ``(255, 0, 0)``;
    * down (``v > 0``): ``fk = 13.5`` → orange-yellow ``(255, 229, 0)``;
    * left (``u < 0, v = 0``): ``fk = 27`` → wheel colour 27, ``(0, 209, 255)``;
    * up (``v < 0``): ``fk = 40.5`` → violet ``(88, 0, 255)``.

    Right-pointing flow relies on ``-v`` being ``−0.0``; a ``v`` of ``−0.0`` would land on
    the other side of the wheel's seam (``fk = 54``, ``(255, 0, 43)``), so signed zeros in
    ``v`` are made ``+0.0`` first and every exactly rightward vector is red.
    """
    u, v = _check_flow(u, v)
    if max_flow is not None and not (math.isfinite(max_flow) and max_flow > 0):
        raise ValueError(f"expected max_flow as a finite number > 0, got {max_flow!r}")
    valid = _flow_valid(u, v)
    u = np.where(valid, u, 0.0)
    v = np.where(valid, v, 0.0) + 0.0  # -0.0 -> +0.0, see Notes
    scale = _max_magnitude(u, v, valid) if max_flow is None else float(max_flow)
    rgb = np.full(u.shape + (3,), 255, dtype=np.uint8)
    if scale == 0.0:  # every valid vector is zero: all white
        rgb[~valid] = 0
        return rgb

    rad = np.hypot(u, v) / scale
    ncols = len(_WHEEL)
    fk = (np.arctan2(-v, -u) / np.pi + 1.0) / 2.0 * (ncols - 1)
    k0 = np.floor(fk).astype(np.intp)
    k1 = (k0 + 1) % ncols
    f = (fk - k0)[..., None]
    wheel = _WHEEL.astype(np.float64) / 255.0
    col = (1.0 - f) * wheel[k0] + f * wheel[k1]
    inside = (rad <= 1.0)[..., None]
    col = np.where(inside, 1.0 - rad[..., None] * (1.0 - col), col * 0.75)
    rgb = np.floor(255.0 * col).astype(np.uint8)
    rgb[~valid] = 0
    return rgb


#: The largest flow_wheel_legend: a figure's key, not a poster.
MAX_LEGEND_SIZE = 4096


def flow_wheel_legend(size: int = 128) -> np.ndarray:
    """The flow colour wheel itself, as a key for figures.

    Parameters
    ----------
    size : int
        Side of the square image in pixels, 1 … MAX_LEGEND_SIZE.

    Returns
    -------
    rgb : ndarray of uint8, shape (size, size, 3)
        Pixel ``(x, y)`` shows the colour :func:`flow_to_color` gives the vector from the
        image centre to that pixel, with the inscribed disc's radius as ``max_flow`` (so
        the rim is fully saturated and the centre white). Outside the disc: white.
    """
    if whole(size) is None:  # (2.7 had become 2)
        raise ValueError(f"expected a whole number of pixels for the size, got {size!r}")
    size = whole(size)
    if not 1 <= size <= MAX_LEGEND_SIZE:  # (10**5 asked numpy for 75 GiB)
        raise ValueError(f"expected a size in 1…{MAX_LEGEND_SIZE} px, got {size}")
    half = (size - 1) / 2.0
    coords = (np.arange(size) - half) / max(half, 1.0)
    x, y = np.meshgrid(coords, coords)
    rgb = flow_to_color(x, y, max_flow=1.0)
    rgb[np.hypot(x, y) > 1.0] = 255
    return rgb


# --------------------------------------------------------------------------- scalar maps


def _robust_range(values: np.ndarray) -> tuple[float, float]:
    """1st / 99th percentile of the finite values; a degenerate range is widened."""
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return 0.0, 1.0
    # in units of the largest magnitude: percentiles of a map spanning ±1e308 interpolate
    # between neighbours whose difference overflows
    unit = float(np.max(np.abs(finite)))
    unit = unit if unit > 0.0 else 1.0
    lo, hi = (float(x) * unit for x in np.percentile(finite / unit, [1.0, 99.0]))
    if hi <= lo:
        pad = max(abs(lo) * 1e-3, 1e-6)
        lo, hi = lo - pad, hi + pad
    return lo, hi


def _apply_lut(values: np.ndarray, lo: float, hi: float, lut: np.ndarray,
               invalid_color: Sequence[int]) -> np.ndarray:
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ValueError(f"expected finite ends of the colour scale, got {lo!r} and {hi!r}")
    finite = np.isfinite(values)
    # in units of the larger end: hi − lo of a map spanning ±1e308 overflows to inf
    unit = max(abs(lo), abs(hi))
    t = np.clip((np.where(finite, values, lo) / unit - lo / unit) / (hi / unit - lo / unit), 0.0, 1.0)
    rgb = lut[np.round(t * (len(lut) - 1)).astype(np.intp)]
    rgb[~finite] = np.asarray(invalid_color, dtype=np.uint8)
    return rgb


def _check_color(color: Sequence[int]) -> tuple[int, int, int]:
    c = tuple(int(x) for x in color)
    if len(c) != 3 or not all(0 <= x <= 255 for x in c):
        raise ValueError(f"expected an RGB colour of three ints in 0..255, got {color!r}")
    return c


def _check_map(name: str, a) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim != 2 or a.size == 0:
        raise ValueError(f"expected {name} as a 2-D array (H, W) of at least one pixel, got shape {a.shape}")
    return a.astype(np.float64)


def disparity_to_color(disp, vmin: float | None = None, vmax: float | None = None,
                       invalid_color: Sequence[int] = (0, 0, 0)) -> np.ndarray:
    """Colour-code a disparity map with a viridis-like colormap.

    Parameters
    ----------
    disp : array_like, shape (H, W)
        Disparity δ in pixels per view step.
    vmin, vmax : float, optional
        Values drawn at the dark (purple) and bright (yellow) ends; values beyond are
        clipped. Default: the 1st and 99th percentiles of the finite values.
    invalid_color : tuple of 3 ints
        RGB colour of NaN / infinite pixels.

    Returns
    -------
    rgb : ndarray of uint8, shape (H, W, 3)
        Luminance rises monotonically from ``vmin`` to ``vmax`` (a 256-entry table
        interpolated from 11 viridis stops).
    """
    disp = _check_map("disp", disp)
    invalid_color = _check_color(invalid_color)
    lo, hi = _robust_range(disp)
    lo = lo if vmin is None else float(vmin)
    hi = hi if vmax is None else float(vmax)
    if not hi > lo:
        raise ValueError(f"expected vmin < vmax, got vmin={lo!r}, vmax={hi!r}")
    return _apply_lut(disp, lo, hi, _DISPARITY_LUT, invalid_color)


def error_to_color(err, vmax: float | None = None,
                   invalid_color: Sequence[int] = (0, 0, 0)) -> np.ndarray:
    """Colour-code an absolute-error map, white (no error) to dark red (``≥ vmax``).

    Parameters
    ----------
    err : array_like, shape (H, W)
        Non-negative error (negative values are drawn as 0).
    vmax : float, optional
        Error drawn at the dark-red end; larger errors are clipped. Default: the 99th
        percentile of the finite values (1 if there are none or all are 0).
    invalid_color : tuple of 3 ints
        RGB colour of NaN / infinite pixels (e.g. outside the ground truth's valid mask).

    Returns
    -------
    rgb : ndarray of uint8, shape (H, W, 3)
        Luminance falls monotonically with the error.
    """
    err = _check_map("err", err)
    invalid_color = _check_color(invalid_color)
    if vmax is None:
        vmax = _error_scale(err)
    if not (math.isfinite(vmax) and vmax > 0):
        raise ValueError(f"expected vmax as a finite number > 0, got {vmax!r}")
    return _apply_lut(err, 0.0, float(vmax), _ERROR_LUT, invalid_color)


def _error_scale(*errors: np.ndarray) -> float:
    """Shared error scale: the 99th percentile of all finite values (else their max,
    else 1)."""
    finite = np.concatenate([e[np.isfinite(e)].ravel() for e in errors])
    if finite.size == 0:
        return 1.0
    for candidate in (np.percentile(finite, 99.0), finite.max()):
        if candidate > 0:
            return float(candidate)
    return 1.0


# --------------------------------------------------------------------------- PNG output


def _to_uint8_image(img) -> np.ndarray:
    """uint8 as it is, uint16 scaled to 8 bits, floats in [0, 1] (slightly beyond: clipped;
    NaN: 0) scaled; floats far outside [0, 1] (0…255 given as floats, which had come out
    an image of 255s) and other types refused."""
    from lfsf.estimate import far_outside_unit

    img = np.asarray(img)
    if not (img.ndim == 2 or (img.ndim == 3 and img.shape[2] == 3)):
        raise ValueError(f"expected an image of shape (H, W) or (H, W, 3), got {img.shape}")
    if img.dtype == np.uint8:
        return img
    if img.dtype == np.uint16:
        return ((img.astype(np.uint32) * 255 + 32767) // 65535).astype(np.uint8)
    if np.issubdtype(img.dtype, np.floating):
        far = far_outside_unit(img)
        if far:
            raise ValueError(f"expected a float image in [0, 1], got values {far[0]:.4g}…{far[1]:.4g}: divide 8-bit "
                             "values by 255 (or give them as uint8)")
        scaled = np.round(np.clip(np.nan_to_num(img, nan=0.0), 0.0, 1.0) * 255.0)
        return scaled.astype(np.uint8)
    raise ValueError(f"expected a uint8 or uint16 image or a float image in [0, 1], got dtype {img.dtype}")


def save_png(path: str | os.PathLike, img, text: Mapping[str, str] | None = None) -> None:
    """Write an image as PNG, atomically (the target appears only once complete).

    Parameters
    ----------
    path : str or path-like
        Target file; missing parent folders are created.
    img : array_like, shape (H, W) or (H, W, 3)
        ``uint8``, ``uint16`` (written as 8 bits), or float in [0, 1] (clipped; NaN written
        as 0; values far outside [0, 1] are refused).
    text : mapping of str to str, optional
        Text chunks to store in the file (``{"Comment": …}``: what the colours mean,
        which image viewers and ``PIL.Image.open(path).text`` show).
    """
    suffix = os.path.splitext(os.fspath(path))[1]
    if suffix.lower() != ".png":   # (PNG bytes under another name mislead every reader)
        raise ValueError(f"{os.fspath(path)}: save_png writes PNG files, so the name must end in .png"
                         f"{f', not {suffix}' if suffix else ''}")
    img = _to_uint8_image(img)
    with atomic_path(path, suffix=".png") as tmp:
        info = None
        if text:
            from PIL.PngImagePlugin import PngInfo

            info = PngInfo()
            for key, value in text.items():
                # (a file name not in UTF-8 reaches Python with stand-ins, which PNG text
                # cannot hold: the whole result had failed to save)
                info.add_text(*(str(t).encode("utf-8", "backslashreplace").decode("utf-8") for t in (key, value)))
        # (a file of lfsf's own, closed however the save ends: Pillow closes the one it opens
        # on an Exception only, and an interrupt left it open until collected)
        with open(tmp, "wb") as f:
            Image.fromarray(img).save(f, format="PNG", pnginfo=info)


# --------------------------------------------------------------------------- overview

_MIN_PANEL_WIDTH = 240  # small inputs are upscaled (nearest) to at least this width
_WHEEL_KEY = 32  # the flow panels' colour wheel, px across (16 was too small to read)
_BAR_HEIGHT = 16  # a colour bar's height
_MAX_PANEL_HEIGHT = 2048  # … but not taller than this (or their own height, if taller)
_FONT_SIZE = 13
_PANEL_WIDTH_PER_FONT_PX = 30  # … and larger for panels wider than 13 × this
_PAD = 4
_GAP = 8
_MARGIN = 8
_BACKGROUND_RGB = (255, 255, 255)
_HEADER_RGB = (222, 226, 232)
_TEXT_RGB = (0, 0, 0)


@dataclass(frozen=True, eq=False)
class _ColorBar:
    """Footer: the colormap ``lut`` from ``lo`` to ``hi``, with the numbers beside it.
    Two are equal where their colours and numbers are (a dataclass's own ``==`` compares
    the arrays with ``==``, which Python 3.13 then asks for one truth value)."""

    lut: np.ndarray
    lo: float
    hi: float
    below: bool = False  # values below lo are drawn in lo's colour: the number reads "<=lo"
    above: bool = False  # … and above hi in hi's: ">=hi" (the default font has no ≤, ≥)

    @classmethod
    def of(cls, lut: np.ndarray, lo: float, hi: float, *maps: np.ndarray) -> "_ColorBar":
        """The bar from ``lo`` to ``hi``, its ends marked where a finite value of ``maps``
        lies beyond them."""
        finite = [m[np.isfinite(m)] for m in maps]
        below = any(f.size and float(f.min()) < lo for f in finite)
        above = any(f.size and float(f.max()) > hi for f in finite)
        return cls(lut, lo, hi, bool(below), bool(above))

    def __eq__(self, other) -> bool:
        if not isinstance(other, _ColorBar):
            return NotImplemented
        return ((self.lo, self.hi, self.below, self.above) == (other.lo, other.hi, other.below, other.above)
                and np.array_equal(self.lut, other.lut))


@dataclass(frozen=True)
class _WheelKey:
    """Footer: the flow colour wheel and the magnitude drawn at full saturation."""

    max_flow: float


@dataclass(frozen=True)
class _Panel:
    label: str
    image: np.ndarray  # (H, W, 3) uint8 at the input's resolution
    footer: _ColorBar | _WheelKey | None = None
    missing: np.ndarray | None = None  # (H, W) bool: the pixels without a value, hatched (_hatch)


#: The two greys of the hatching drawn over the pixels without a value in the overview
#: (black had also been the far end of the error colours under protanopia and in print).
HATCH_GREYS = ((96, 96, 96), (176, 176, 176))
_HATCH_PERIOD = 6  # px of the drawn picture: diagonal stripes 3 px wide


def _hatch(picture: np.ndarray, missing: np.ndarray) -> None:
    """Draw diagonal stripes of :data:`HATCH_GREYS` over ``picture`` (H, W, 3, uint8,
    in place) where ``missing`` (H, W) is set: no colour of a map, and told apart from
    every one of them by its pattern in greyscale and to colour-blind readers too."""
    ys, xs = np.nonzero(missing)
    stripe = ((ys + xs) // (_HATCH_PERIOD // 2)) % 2
    picture[ys, xs] = np.asarray(HATCH_GREYS, np.uint8)[stripe]


def _font(size: int = _FONT_SIZE) -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: only the fixed-size bitmap font
        return ImageFont.load_default()


def _view_to_rgb(name: str, view, shape: tuple[int, int]) -> np.ndarray:
    view = np.asarray(view)
    if view.shape[:2] != shape or view.ndim not in (2, 3) or (
        view.ndim == 3 and view.shape[2] != 3
    ):
        raise ValueError(
            f"expected {name} of shape {shape} or {shape + (3,)}, got {view.shape}"
        )
    rgb = _to_uint8_image(view)
    return np.repeat(rgb[..., None], 3, axis=2) if rgb.ndim == 2 else rgb


def _shown_together(centre1, centre2):
    """The two centre views on one scale for display: float views beyond [0, 1] (counts
    given as floats, 0…255, which the estimator stretches to [0, 1] for itself) mapped
    from their joint range onto [0, 1], so that they are not clipped to white; views
    within [0, 1], and integer ones, as they are."""
    views = [np.asarray(c) for c in (centre1, centre2)]
    if not all(np.issubdtype(c.dtype, np.floating) and c.size for c in views):
        return centre1, centre2
    with np.errstate(invalid="ignore"):
        lo = min(float(np.nanmin(c)) if np.isfinite(c).any() else 0.0 for c in views)
        hi = max(float(np.nanmax(c)) if np.isfinite(c).any() else 1.0 for c in views)
    if lo >= 0.0 and hi <= 1.0 or not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return centre1, centre2
    lo, hi = min(lo, 0.0), max(hi, 1.0)
    return tuple((c.astype(np.float64) - lo) / (hi - lo) for c in views)


def view_picture(view) -> np.ndarray:
    """A view (H, W) or (H, W, 3) as an 8-bit picture, as the overview draws the centre
    views: float views beyond [0, 1] (counts given as floats) mapped from their range."""
    shown, _ = _shown_together(view, view)
    return _to_uint8_image(shown)


def _check_map_shape(name: str, a, shape: tuple[int, ...]) -> np.ndarray:
    a = _check_map(name, a)
    if a.shape != shape:
        raise ValueError(f"expected {name} of shape {shape} (the centre view's), got {a.shape}")
    return a


def _fmt(x: float) -> str:
    return f"{x:.3g}"


#: The colour of the points not seen at t2 in the overview's mask panel: a dark magenta
#: (L* 40) on the view dimmed into light greys (L* 72–94), so that the mask stays in
#: print and greyscale too (255, 0, 255, L* 60, had vanished into the view's L* 27–77).
OCCLUDED_COLOUR = (170, 0, 170)


def occluded_picture(centre1, occluded) -> np.ndarray:
    """The t1 centre view (H, W) or (H, W, 3), dimmed into light greys (176…240), with the
    points not seen at t2 (``occluded``, bool (H, W)) in :data:`OCCLUDED_COLOUR`: uint8
    (H, W, 3)."""
    occluded = np.asarray(occluded)
    shape = occluded.shape
    if occluded.dtype != bool or occluded.ndim != 2:
        raise ValueError(f"expected occluded as a bool (H, W) mask, got {occluded.dtype} {occluded.shape}")
    rgb = _view_to_rgb("centre1", centre1, shape).astype(np.float32)
    grey = 176.0 + 0.25 * rgb.mean(axis=2, keepdims=True)
    out = np.where(occluded[..., None], np.asarray(OCCLUDED_COLOUR, np.float32), grey)
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def _overview_panels(centre1, centre2, disp1, disp2, u, v, gt, max_flow, label="estimate",
                     occluded=None, disparities=True, border: int = 0) -> list[list[_Panel]]:
    """The overview's panels, row by row (see :func:`overview_figure`)."""
    from lfsf.evaluate import check_border, inner_pixels

    border = check_border(border)
    # the maps are the t1 centre view's: its (H, W) is what each must have (a map of
    # another shape is named, not the first map taken as the measure)
    shape = tuple(np.shape(centre1)[:2]) if np.ndim(centre1) in (2, 3) else _check_map("disp1", disp1).shape
    maps = {np.shape(a) for a in (disp1, disp2, u, v)}
    if len(maps) == 1 and np.ndim(disp1) == 2 and np.shape(disp1) != shape:
        # the four maps agree with each other: the centre view is the odd one
        raise ValueError(f"expected centre1 of the maps' shape {np.shape(disp1)} (the views they were estimated "
                         f"on), got {np.shape(centre1)}")
    est = {k: _check_map_shape(k, a, shape)
           for k, a in (("disp1", disp1), ("disp2", disp2), ("u", u), ("v", v))}
    centre1, centre2 = _shown_together(centre1, centre2)
    rows = [[
        _Panel("centre view t1", _view_to_rgb("centre1", centre1, shape)),
        _Panel("centre view t2", _view_to_rgb("centre2", centre2, shape)),
    ]]
    if occluded is not None:
        if np.shape(occluded) != shape:
            raise ValueError(f"expected occluded of shape {shape}, got {np.shape(occluded)}")
        # whose mask it is (the estimate's, or in a preview the truth's), and an empty one said
        marked = bool(np.any(occluded))
        rows[0].append(_Panel(f"{label}: not seen at t2" + (" (magenta)" if marked else ": none"),
                              occluded_picture(centre1, occluded)))
    if max_flow is not None and not (math.isfinite(max_flow) and max_flow > 0):
        raise ValueError(f"expected max_flow as a finite number > 0, got {max_flow!r}")

    truth, valid = ground_truth_maps(gt, shape)

    # one range for δ1 and δ2 (and their truth): the same colour is the same disparity in
    # every panel, as in the disp1.png and disp2.png of a result
    shown = [est[k] for k in ("disp1", "disp2") if disparities] + [truth[k] for k in ("disp1", "disp2") if k in truth]
    lo, hi = _robust_range(np.concatenate([m.ravel() for m in shown])) if shown else (0.0, 1.0)
    if max_flow is None:
        max_flow = _max_magnitude(est["u"], est["v"])
        if "u" in truth:
            max_flow = max(max_flow, _max_magnitude(truth["u"], truth["v"]))
    scale = max_flow if max_flow > 0 else None  # all-zero flow: flow_to_color draws white

    def disparity_row(maps: Mapping[str, np.ndarray], tag: str, estimated: bool = True) -> list[_Panel]:
        row = []
        for k in ("disp1", "disp2"):
            if k not in maps:
                row.append(_blank(f"{k}: no ground truth", shape))
            elif estimated:
                row.append(_Panel(f"{k} {tag}", disparity_to_color(maps[k], lo, hi),
                                  _ColorBar.of(_DISPARITY_LUT, lo, hi, *shown), ~np.isfinite(maps[k])))
            else:
                row.append(_not_estimated(k, shape))
        row.append(_Panel(f"flow {tag}", flow_to_color(maps["u"], maps["v"], scale), _WheelKey(max_flow),
                          ~_flow_valid(maps["u"], maps["v"]))
                   if "u" in maps else _blank("flow: no ground truth", shape))
        return row

    rows.append(disparity_row(est, label, disparities))
    if not truth:
        return rows
    rows.append(disparity_row(truth, "ground truth"))
    scored = inner_pixels(shape, border)  # the error panels' means: over the pixels lfsf eval scores

    errors = {k: np.abs(est[k] - truth[k]) for k in ("disp1", "disp2") if k in truth}
    if "u" in truth:
        errors["flow"] = np.hypot(est["u"] - truth["u"], est["v"] - truth["v"])
    errors = {k: np.where(np.isfinite(e), e, np.nan) for k, e in errors.items()}
    # the scales from the scored pixels alone: one wrong corner in the border (HCI, its
    # 15 px) had set a 2.8-px scale for errors mostly under 0.5, the panel near white
    inner = {k: np.where(scored, e, np.nan) for k, e in errors.items()}
    disp_errors = [inner[k] for k in ("disp1", "disp2") if k in inner]
    disp_scale = _error_scale(*disp_errors) if disp_errors else 1.0
    flow_scale = _error_scale(inner["flow"]) if "flow" in inner else 1.0
    error_row = []
    for k, title in (("disp1", "|disp1 - GT|"), ("disp2", "|disp2 - GT|"), ("flow", "flow EPE")):
        if k != "flow" and not disparities:
            error_row.append(_not_estimated(k, shape))
            continue
        if k not in errors:
            error_row.append(_blank(f"{title}: no ground truth", shape))
            continue
        e, scored_e = errors[k], inner[k]
        finite = np.isfinite(scored_e)
        mean = f"{float(scored_e[finite].mean()):.3g}" if finite.any() else "n/a"
        vmax = flow_scale if k == "flow" else disp_scale
        shared = (inner["flow"],) if k == "flow" else tuple(inner[d] for d in ("disp1", "disp2") if d in inner)
        picture = error_to_color(e, vmax)
        pale = ~scored & np.isfinite(e)  # the border that the means and the scale leave out (no value: hatched)
        picture[pale] = (0.4 * picture[pale] + 0.6 * 255).astype(np.uint8)
        error_row.append(_Panel(f"{title}  mean {mean}", picture, _ColorBar.of(_ERROR_LUT, 0.0, vmax, *shared),
                                ~np.isfinite(e)))
    rows.append(error_row)
    return rows


#: The grey of a panel of a map that was not estimated (δ1, δ2 of a flow-only run).
NOT_ESTIMATED_GREY = (200, 200, 200)


def _blank(label: str, shape: tuple[int, int]) -> _Panel:
    """A grey panel in place of a map that is not there."""
    return _Panel(label, np.full(shape + (3,), NOT_ESTIMATED_GREY, np.uint8))


def _not_estimated(name: str, shape: tuple[int, int]) -> _Panel:
    return _blank(f"{name}: not estimated (flow only)", shape)


def _overview_notes(rows: list[list[_Panel]], gt, disparities: bool = True, border: int = 0) -> str:
    """The figure's last line: the units, and what the marks of its keys mean where
    they appear (the flow's errors where drawn; the hatching where the ground truth leaves
    pixels out, by its ``valid`` mask or by values that are not finite, and where the
    estimate is not finite; the border the error means leave out)."""
    flow = "flow and its errors in px" if gt is not None and "u" in gt and "v" in gt else "flow in px"
    notes = [f"disparities in px per view step, {flow}" if disparities or gt is not None else flow]
    bars = [p.footer for row in rows for p in row if isinstance(p.footer, _ColorBar)]
    if any(b.below or b.above for b in bars):
        notes.append("<= or >= at a bar's end: values beyond it take its colour")
    hatched = []
    if gt is not None:
        valid = gt.get("valid")
        maps = [np.asarray(gt[k], np.float64) for k in ("disp1", "disp2", "u", "v") if k in gt]
        if (valid is not None and not np.all(valid)) or any(not np.isfinite(m).all() for m in maps):
            hatched.append("no ground truth there")
    if any(p.missing is not None and p.missing.any() for p in rows[1]):  # (the estimate's row)
        hatched.append("the estimate not finite there")
    if hatched:
        notes.append(f"hatched grey: {' or '.join(hatched)}")
    if gt is not None:
        if border > 0:
            notes.append(f"error means and scales without the {border}-px border (paler), as lfsf eval")
    return "; ".join(notes)


def _fit_text(draw: ImageDraw.ImageDraw, text: str, font, width: int) -> str:
    """``text`` on one line (line breaks and tabs become spaces: Pillow measures no
    multi-line text), shortened with '..' until it fits in ``width`` pixels."""
    text = " ".join(text.split())
    if draw.textlength(text, font=font) <= width:
        return text
    # the longest prefix that fits, by bisection (a 10000-character title took 33 s one
    # character at a time); a prefix is never wider than a longer one
    fits, over = 0, len(text)
    while over - fits > 1:
        middle = (fits + over) // 2
        if draw.textlength(text[:middle] + "..", font=font) <= width:
            fits = middle
        else:
            over = middle
    return text[:fits] + ".."


def _wrap(draw: ImageDraw.ImageDraw, text: str, font, width: int) -> list[str]:
    """``text`` in lines of at most ``width`` pixels, broken between words (a word wider
    than that shortened by :func:`_fit_text`)."""
    lines: list[str] = []
    for word in text.split():
        if lines and draw.textlength(f"{lines[-1]} {word}", font=font) <= width:
            lines[-1] = f"{lines[-1]} {word}"
        else:
            lines.append(_fit_text(draw, word, font, width))
    return lines


def _compose(rows: list[list[_Panel]], title: str | None, notes: str | None = None) -> np.ndarray:
    """Lay the panels out on a grid: header label, upscaled image, footer key; the
    ``notes`` below, wrapped to the grid's width."""
    h, w = rows[0][0].image.shape[:2]
    # narrow images are enlarged for the labels, but never past _MAX_PANEL_HEIGHT: a
    # 3000×8 image would otherwise become a 360000-px-tall picture
    s = max(1, min(math.ceil(_MIN_PANEL_WIDTH / w), _MAX_PANEL_HEIGHT // h))
    pw, ph = w * s, h * s
    # the text and keys grow with wide panels: a 640×480 input's 13-px labels read as 7 px
    # once its 1952-px-wide overview is fitted to a page
    size = max(_FONT_SIZE, round(pw / _PANEL_WIDTH_PER_FONT_PX))
    font = _font(size)
    probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    top, bottom = probe.textbbox((0, 0), "Ag|0.9", font=font)[1::2]
    line_h = bottom - top
    header_h = line_h + 2 * _PAD
    key = max(_WHEEL_KEY, round(_WHEEL_KEY * size / _FONT_SIZE))
    footer_h = max(line_h, key) + 2 * _PAD
    # a row without keys (the centre views) gets no footer strip: no blank band under it
    cells_h = [header_h + ph + (footer_h if any(p.footer is not None for p in row) else 0) for row in rows]
    tops = [_MARGIN + (header_h if title else 0) + sum(cells_h[:r]) + r * _GAP for r in range(len(rows))]
    ncols = max(len(r) for r in rows)
    width = 2 * _MARGIN + ncols * pw + (ncols - 1) * _GAP
    note_lines = _wrap(probe, notes, font, width - 2 * _MARGIN) if notes else []
    notes_h = len(note_lines) * (line_h + _PAD) + (_PAD if note_lines else 0)
    grid_end = tops[-1] + cells_h[-1]
    height = grid_end + _MARGIN + notes_h

    canvas = Image.new("RGB", (width, height), _BACKGROUND_RGB)
    draw = ImageDraw.Draw(canvas)

    def text_at(x: int, y: int, text: str) -> None:
        # (x, y) is the top left of the line box; textbbox's top offset is removed so
        # every line sits _PAD below its strip's top edge
        draw.text((x, y - top), text, fill=_TEXT_RGB, font=font)

    if title:
        text_at(_MARGIN, _MARGIN + _PAD, _fit_text(draw, title, font, width - 2 * _MARGIN))
    for r, row in enumerate(rows):
        y0 = tops[r]
        for c, panel in enumerate(row):
            x0 = _MARGIN + c * (pw + _GAP)
            draw.rectangle([x0, y0, x0 + pw - 1, y0 + header_h - 1], fill=_HEADER_RGB)
            text_at(x0 + _PAD, y0 + _PAD, _fit_text(draw, panel.label, font, pw - 2 * _PAD))
            big = np.repeat(np.repeat(panel.image, s, axis=0), s, axis=1)
            if panel.missing is not None and panel.missing.any():
                _hatch(big, np.repeat(np.repeat(panel.missing, s, axis=0), s, axis=1))
            canvas.paste(Image.fromarray(big), (x0, y0 + header_h))
            _draw_footer(canvas, draw, panel.footer, x0, y0 + header_h + ph, pw, footer_h,
                         font, text_at, line_h)
    y = grid_end + _PAD
    for line in note_lines:
        text_at(_MARGIN, y, line)
        y += line_h + _PAD
    return np.asarray(canvas, dtype=np.uint8).copy()


def _draw_footer(canvas, draw, footer, x0, y0, pw, footer_h, font, text_at, line_h: int) -> None:
    inner = footer_h - 2 * _PAD
    text_y = y0 + (footer_h - line_h) // 2  # (text and bars centred in the strip)
    if isinstance(footer, _WheelKey):
        key = flow_wheel_legend(inner)
        canvas.paste(Image.fromarray(key), (x0 + _PAD, y0 + _PAD))
        label = _wheel_label(draw, font, footer.max_flow, pw - 3 * _PAD - inner)
        text_at(x0 + 2 * _PAD + inner, text_y, label)
    elif isinstance(footer, _ColorBar):
        lo = ("<=" if footer.below else "") + _fmt(footer.lo)
        hi = (">=" if footer.above else "") + _fmt(footer.hi)
        lo_w = math.ceil(draw.textlength(lo, font=font))
        hi_w = math.ceil(draw.textlength(hi, font=font))
        bar_x0 = x0 + 2 * _PAD + lo_w
        bar_w = pw - 4 * _PAD - lo_w - hi_w
        text_at(x0 + _PAD, text_y, lo)
        text_at(bar_x0 + max(bar_w, 0) + _PAD, text_y, hi)
        if bar_w > 0:
            bar_h = min(inner, max(_BAR_HEIGHT, line_h))
            idx = np.round(np.linspace(0, len(footer.lut) - 1, bar_w)).astype(np.intp)
            bar = np.repeat(footer.lut[idx][None], bar_h, axis=0)
            canvas.paste(Image.fromarray(bar), (bar_x0, y0 + (footer_h - bar_h) // 2))


def _wheel_label(draw: ImageDraw.ImageDraw, font, max_flow: float, width: int) -> str:
    """The flow key's words, for ``width`` pixels: shortened before its number is (a
    narrow panel had cut "full colour at |(u,v)| = 9.28 px" to "… = ..")."""
    labels = [f"{words}{_fmt(max_flow)} px" for words in ("full colour at |(u,v)| = ", "full: ", "")]
    fits = [text for text in labels if draw.textlength(text, font=font) <= width]
    return fits[0] if fits else _fit_text(draw, labels[-1], font, width)


def ground_truth_maps(gt, shape: tuple[int, int]) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The ground truth's maps (any of δ1, δ2 and the flow, u with v; an HCI benchmark's is
    δ1 alone), NaN outside its ``valid`` mask, and that mask (all true where it has none),
    checked against the estimate's ``shape``: ({} and all true for ``gt`` None)."""
    truth: dict[str, np.ndarray] = {}
    valid = np.ones(shape, dtype=bool)
    if gt is None:
        return truth, valid
    if not isinstance(gt, Mapping):
        raise ValueError(f"expected gt as a mapping of maps (disp1, disp2, u, v, valid), got {type(gt).__name__} "
                         "(lfsf.evaluate.load_ground_truth returns the maps and a border: (gt, border))")
    if ("u" in gt) != ("v" in gt):  # (the one that lacks its pair, not every key absent)
        raise ValueError(f"expected gt's flow as u with v; it has {'u' if 'u' in gt else 'v'} without "
                         f"{'v' if 'u' in gt else 'u'}")
    if not any(k in gt for k in ("disp1", "disp2", "u", "v")):
        raise ValueError(f"expected gt with keys disp1, disp2 and/or u with v; it has {sorted(map(str, gt))}")
    truth = {k: _check_map_shape(f"gt[{k!r}]", gt[k], shape) for k in ("disp1", "disp2", "u", "v") if k in gt}
    if gt.get("valid") is not None:
        mask = np.asarray(gt["valid"])
        if mask.shape != shape or mask.dtype != bool:
            raise ValueError(f"expected gt['valid'] as a bool array of shape {shape}, got {mask.dtype} {mask.shape}")
        valid = mask.copy()
    # outside the mask the ground truth means nothing: draw it as invalid too
    return {k: np.where(valid, a, np.nan) for k, a in truth.items()}, valid


def maps_figure(disp1, disp2, u, v, *, title: str | None = None, label: str = "estimate",
                disparities: bool = True, max_flow: float | None = None) -> np.ndarray:
    """The estimate's row of :func:`overview_figure` alone: δ1, δ2 (one colour scale) and
    the flow, each with its key, under an optional ``title``, as an (H', W', 3) uint8
    picture; for a result without its centre views at hand (a notebook shows a
    :class:`lfsf.SceneFlow` so). ``disparities`` False draws δ1 and δ2 as not estimated
    (a flow-only result's)."""
    blank = np.zeros(np.shape(disp1), np.float32)   # (the centre views' row, left out)
    rows = _overview_panels(blank, blank, disp1, disp2, u, v, None, max_flow, label, None, disparities)
    return _compose(rows[1:], title, _overview_notes(rows, None, disparities))


def overview_figure(centre1, centre2, disp1, disp2, u, v, gt: Mapping | None = None,
                    path: str | os.PathLike | None = None, title: str | None = None,
                    max_flow: float | None = None, label: str = "estimate", occluded=None,
                    disparities: bool = True, border: int = 0) -> np.ndarray:
    """A labelled grid of panels showing a scene-flow result, optionally against truth.

    Rows: (1) centre views at t1 and t2; (2) estimated δ1, δ2 and flow; with ``gt`` also
    (3) the ground truth on the same colour scales and (4) the errors ``|δ1 − δ1*|``,
    ``|δ2 − δ2*|`` and the flow end-point error, their means in the labels (over the
    valid pixels less ``border``, the pixels ``lfsf eval`` scores). Each panel has a
    header strip with its label and a footer with its key: a colour bar with its end
    values under disparity and error maps, the colour wheel and the full-saturation
    magnitude under flow.

    Parameters
    ----------
    centre1, centre2 : array_like, shape (H, W) or (H, W, 3)
        Centre views at t1 and t2, float in [0, 1] or uint8.
    disp1, disp2 : array_like, shape (H, W)
        Estimated disparities δ1 and δ2 (``help(lfsf)``, MODEL.md §1: δ2 is the t2 disparity of the
        point seen at ``p`` at t1). NaN is drawn as invalid (hatched).
    u, v : array_like, shape (H, W)
        Estimated flow of the centre view, pixels.
    gt : mapping, optional
        Ground truth with keys ``disp1``, ``disp2``, ``u``, ``v`` (same conventions and
        shape), or some of them (``u`` with ``v``; an HCI benchmark's ``disp1`` alone:
        the panels of the others say "no ground truth" on grey), and optionally
        ``valid``, a bool (H, W) mask; pixels outside it are drawn as invalid in the
        ground-truth and error panels and left out of the means.
    path : str or path-like, optional
        Where to write the figure as PNG (atomically).
    title : str, optional
        A line of text above the grid (line breaks become spaces; shortened to fit).
    max_flow : float, optional
        Flow magnitude at full saturation for both estimate and ground truth. Default:
        the largest valid magnitude over both.
    label : str, optional
        What the maps of row 2 are, in their panel labels (``"ground truth"`` when the
        figure shows a synthetic scene's truth alone).
    occluded : array_like of bool, shape (H, W), optional
        The points not seen at t2 (``SceneFlow.occluded``): a third panel in row 1, the
        t1 centre view dimmed with them in magenta (:func:`occluded_picture`).
    disparities : bool, optional
        False for a flow-only result (one circle, ``--preset flow``): its δ1 and δ2
        are zeros, not estimates, and their panels (and error panels) say "not
        estimated" on grey instead of drawing them.
    border : int, optional
        Pixels at each side that the error means leave out, as
        :func:`lfsf.evaluate.evaluate` does (its ``border``: 8 for the synthetic scenes,
        15 for HCI's). The maps are drawn whole; the error maps' colour scales leave the
        border out too, and draw it paler. The notes line names the border.

    Returns
    -------
    figure : ndarray of uint8, shape (Hf, Wf, 3)
        The figure. Panels keep the input's aspect ratio; inputs narrower than 240 px
        are upscaled by an integer factor (nearest neighbour) so labels stay readable.

    Notes
    -----
    The disparity panels, δ1 and δ2, estimate and ground truth, share one range: the
    1st/99th percentiles of all their finite values together (so the same colour is the
    same disparity everywhere). Error maps of δ1 and δ2 share one scale (99th percentile
    of both), the end-point error has its own. A bar's end value reads "<=" or ">=" where
    values lie beyond it, drawn in its colour. A last line gives the units and those
    marks' meaning.
    """
    rows = _overview_panels(centre1, centre2, disp1, disp2, u, v, gt, max_flow, label, occluded, disparities, border)
    notes = _overview_notes(rows, gt, disparities, border)
    figure = _compose(rows, title, notes)
    if path is not None:  # (its text in the file too, as the single maps' pictures have theirs)
        panels = ", ".join(panel.label for row in rows for panel in row)
        save_png(path, figure, text={"Title": " ".join(title.split()) if title else "lfsf overview",
                                     "Comment": f"panels: {panels}. {notes}"})
    return figure
