"""Reading and writing light fields and the formats results are exchanged in.

Light fields
    :class:`LightField` holds the sub-aperture views ``views[a, b, y, x]`` (grey) or
    ``views[a, b, y, x, c]`` (RGB) as float32 in [0, 1] (``help(lfsf)``, MODEL.md §1).
    :func:`read_lightfield` reads a folder in the HCI 4D benchmark layout, a folder of
    ``<name>_RR_CC.png`` views, or a ``.npz`` with key ``views``; :func:`write_lightfield`
    writes a ``.npz`` or a folder of 16-bit (or 8-bit) PNGs.

Lenslet images
    :func:`views_to_lenslet` and :func:`lenslet_to_views` convert between views and the
    rectangular synthetic raw image of the paper, one ``A×B`` block per micro-lens.

Result formats
    PFM (:func:`read_pfm`, :func:`write_pfm`; HCI disparity), Middlebury ``.flo``
    (:func:`read_flo`, :func:`write_flo`) and KITTI 16-bit PNG flow and disparity
    (:func:`read_kitti_flow`, :func:`write_kitti_flow`, :func:`read_kitti_disparity`,
    :func:`write_kitti_disparity`).

Images
    :func:`read_image` and :func:`write_png`. Pillow (under imageio) reads 16-bit RGB and
    RGBA PNGs as 8-bit, silently dropping the low byte, and cannot write them at all, so
    this module carries its own small PNG codec (:func:`decode_png`, :func:`encode_png`):
    every PNG is written by it, and 16-bit colour PNGs are read by it.

Every writer goes through :mod:`lfsf._files`: a failed or interrupted write leaves the
previous file, if any, untouched and no partial file behind. Every reader reports bad
input as a ``ValueError`` (a missing file as ``FileNotFoundError``) whose message starts
with the file's name.
"""

from __future__ import annotations

import configparser
import contextlib
import itertools
import lzma
import math
import os
import re
import struct
import threading
import tokenize
import warnings
import zipfile
import zlib
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import imageio.v3 as iio
import numpy as np
from numpy.typing import ArrayLike

from lfsf._errors import LfsfWarning, shown_number, warn_at_caller, whole
from lfsf._files import file_name, interrupts_held, not_a_file, output_folder, savez_atomic, write_bytes_atomic
from lfsf._files import refuse_special_file as _refuse_special_file

__all__ = [
    "BT601_LUMA",
    "LightField",
    "centre_view",
    "luma",
    "block_mean",
    "check_pair",
    "read_lightfield",
    "write_lightfield",
    "views_to_lenslet",
    "lenslet_to_views",
    "read_pfm",
    "write_pfm",
    "read_flo",
    "write_flo",
    "read_kitti_flow",
    "write_kitti_flow",
    "read_kitti_disparity",
    "write_kitti_disparity",
    "read_image",
    "write_png",
    "write_ply",
    "decode_png",
    "encode_png",
]

#: ITU-R BT.601 luma weights for (R, G, B).
BT601_LUMA = (0.299, 0.587, 0.114)

# Suffixes of single images: given to read_lightfield they can only be a raw lenslet image.
_IMAGE_SUFFIXES = {
    ".png", ".tif", ".tiff", ".jpg", ".jpeg", ".bmp", ".dng", ".raw", ".lfr", ".lfp",
}
#: Suffixes of file formats that lfsf does not write: :func:`write_lightfield` refuses to
#: make a folder of views under such a name (an existing folder of that name is used).
_OTHER_FILE_SUFFIXES = {
    ".h5", ".hdf5", ".hdf", ".mat", ".npy", ".pkl", ".pickle", ".zip", ".tar", ".gz", ".bz2",
    ".xz", ".json", ".txt", ".csv", ".exr", ".pfm", ".flo", ".webp", ".gif", ".mp4", ".avi",
}
_HCI_NAME = re.compile(r"input_Cam(\d+)\.png", re.IGNORECASE)
_ROWCOL_NAME = re.compile(r"(.+)_(\d+)_(\d+)\.png", re.IGNORECASE)
_LAYOUTS_LOOKED_FOR = (
    "the HCI layout (input_Cam000.png, input_Cam001.png, … in row-major order), "
    "views named <name>_RR_CC.png (1-based row and column, e.g. scene_01_01.png), "
    "or a views.npz"
)
_MAX_NAMES_LISTED = 8
# Single images that are no raw lenslet image either (lossy, or 8-bit only): said so.
_NOT_RAW_SUFFIXES = {".jpg", ".jpeg", ".bmp"}
#: What to do with the light-field files of other tools that lfsf does not read, by suffix
#: (the README's "Other layouts" gives the recipes whole).
_VIEWS_ORDER = "ordered [a, b, y, x] or [a, b, y, x, 3] (view row, view column, image row, image column)"
_OTHER_FORMATS = {
    ".npy": f"a .npy array: lfsf reads an .npz with key 'views'; np.savez('lf.npz', views=np.load(PATH)) with "
            f"the array {_VIEWS_ORDER}",
    ".h5": f"an HDF5 file: read its light-field array with h5py and save it as an .npz with key 'views', "
           f"{_VIEWS_ORDER}",
    ".mat": "a MATLAB file (LFToolbox's *__Decoded.mat holds LF as [j, i, l, k, c], which is lfsf's [a, b, y, x, c] "
            "with a weight channel last; a v7.3 file is HDF5, which h5py reads in the reverse order): save "
            "LF[..., :3] as an .npz with key 'views'",
}
_OTHER_FORMATS[".hdf5"] = _OTHER_FORMATS[".h5"]


# --------------------------------------------------------------------------------------
# LightField
# --------------------------------------------------------------------------------------


@dataclass(init=False, eq=False, repr=False)
class LightField:
    """A 4-D light field: a grid of sub-aperture views.

    Parameters
    ----------
    views : array_like, shape (A, B, H, W) or (A, B, H, W, C)
        ``views[a, b, y, x]`` (grey) or ``views[a, b, y, x, c]`` with C = 3 (RGB); ``a`` is
        the view row (η = a − a_c), ``b`` the view column (ξ = b − b_c), ``help(lfsf)``, MODEL.md §1.
        Stored as C-contiguous float32 with values meant to lie in [0, 1]: float input is
        converted (not copied when already float32 and C-contiguous), integer input is
        scaled by its dtype's maximum (uint8, uint16; integers of more than 16 bits are
        refused), a trailing channel axis of size 1 is dropped.
    source : str
        Where the views came from (a path); starts every error message.
    meta : dict
        Anything known about the light field, e.g. ``meta["layout"]`` (``"hci"``,
        ``"rowcol"``, ``"npz"``) and, for the HCI layout, ``meta["parameters"]``:
        ``parameters.cfg`` as ``{section: {key: value}}``; views decoded from a lenslet
        image (:func:`lfsf.decode.decode`, or a folder with ``lfsf decode``'s
        ``decode.json``) have ``meta["lattice"]`` and ``meta["lens_views"]`` (N views
        across a lens), and the estimator keeps its samples off the micro-images' rims
        (:data:`lfsf.estimate.RIM_FRACTION`).

    Raises
    ------
    ValueError
        If the array is not 4-D or 5-D, has a channel count other than 1 or 3 (RGBA must
        have its alpha dropped first), is empty, is not real-valued, is of integers wider
        than 16 bits (int64 from ``np.array`` of Python ints: say which), or holds NaN or
        infinite values (the message says how many pixels and the first view hit).
    """

    views: np.ndarray
    source: str = "<array>"
    meta: dict = field(default_factory=dict)

    # (written out, not the dataclass's, so that type checkers take array_like views: a
    # list, a memmap; the attribute is the float32 array that __post_init__ makes)
    def __init__(self, views: ArrayLike, source: str = "<array>", meta: Mapping[str, Any] | None = None) -> None:
        self.views = views  # type: ignore[assignment]
        self.source = source
        self.meta = meta  # type: ignore[assignment]
        self.__post_init__()

    # (kept as __post_init__, so that a dataclass that extends LightField, whose generated
    # __init__ calls it, gets the same checks)
    def __post_init__(self) -> None:
        self.source = str(self.source)
        self.views = _validated_views(self.views, self.source)
        if self.meta is not None and not isinstance(self.meta, Mapping):
            raise ValueError(f"{self.source}: meta must be a dict (what is known of the light field), got "
                             f"{type(self.meta).__name__}")
        self.meta = dict(self.meta) if self.meta is not None else {}

    def __repr__(self) -> str:
        rows, cols = self.grid
        kind = "RGB" if self.is_colour else "grey"
        return (f"LightField(grid={rows}×{cols}, size={self.width}×{self.height}, {kind}, "
                f"source={self.source!r})")

    def _repr_png_(self) -> bytes:
        """The centre view as a picture, which IPython and Jupyter show for a light field
        at a cell's end (:func:`lfsf.viz.view_picture`)."""
        from lfsf.viz import view_picture

        return encode_png(view_picture(self.centre), source=self.source)

    @property
    def grid(self) -> tuple[int, int]:
        """(rows, cols) of the view grid."""
        return self.views.shape[0], self.views.shape[1]

    @property
    def shape(self) -> tuple[int, ...]:
        """``views.shape``."""
        return self.views.shape

    @property
    def height(self) -> int:
        """Height of every view in pixels."""
        return self.views.shape[2]

    @property
    def width(self) -> int:
        """Width of every view in pixels."""
        return self.views.shape[3]

    @property
    def is_colour(self) -> bool:
        """True for RGB views (``views`` is 5-D)."""
        return self.views.ndim == 5

    @property
    def centre_index(self) -> tuple[float, float]:
        """Angular centre ``(a_c, b_c) = ((rows − 1)/2, (cols − 1)/2)``; half-integer for
        even grid sizes, where the centre lies between views."""
        rows, cols = self.grid
        return (rows - 1) / 2, (cols - 1) / 2

    @property
    def centre(self) -> np.ndarray:
        """The centre view ``I(p) = L(p, 0)``, shape (H, W) or (H, W, 3).

        For odd grid sizes this is the middle view itself (not a copy). Along an even grid
        size the centre lies half-way between the two middle views, and bilinear
        interpolation there is their mean: the result is the mean of 2 or 4 views.
        """
        return centre_view(self.views)

    def grey(self) -> "LightField":
        """The luma light field, ITU-R BT.601 weights (0.299, 0.587, 0.114).

        Returns
        -------
        LightField
            4-D views with the same ``source`` and ``meta``; ``self`` if already grey.
        """
        if not self.is_colour:
            return self
        return LightField(luma(self.views), source=self.source, meta=self.meta)

    def crop(self, top: int, left: int, height: int, width: int) -> "LightField":
        """The same region of every view: rows ``top`` … ``top + height − 1`` and columns
        ``left`` … ``left + width − 1`` (0-based). Disparities and flows keep their values
        (px per view step, px); a ground-truth map is cropped alike, ``gt[top:top +
        height, left:left + width]``.

        Returns
        -------
        LightField
            A copy, with the same ``source`` and ``meta``.

        Raises
        ------
        ValueError
            If the region is empty or reaches beyond the views (the message gives their
            size).
        """
        for name, value in (("top", top), ("left", left), ("height", height), ("width", width)):
            if whole(value) is None:
                raise ValueError(f"{self.source}: crop's {name} must be a whole number of pixels, got {value!r}")
        top, left, height, width = (whole(v) for v in (top, left, height, width))  # (no int8 wrapping round)
        if height < 1 or width < 1:
            raise ValueError(f"{self.source}: the crop of {width}×{height} px is empty")
        if top < 0 or left < 0 or top + height > self.height or left + width > self.width:
            raise ValueError(f"{self.source}: the crop of {width}×{height} px at column {left}, row {top} does "
                             f"not lie within the {self.width}×{self.height} views")
        views = self.views[:, :, top:top + height, left:left + width].copy()
        return LightField(views, source=self.source, meta=_pixel_meta(self.meta))

    def downsample(self, factor: int) -> "LightField":
        """Every view shrunk ``factor`` times along each axis, each pixel the mean of a
        ``factor`` × ``factor`` block (rows and columns left over at the bottom and right
        are dropped). Disparities (px per view step) and flows (px) shrink by the same
        factor: an estimate on the result is compared with a ground truth shrunk alike,
        :func:`lfsf.evaluate.downsample_truth`.

        Raises
        ------
        ValueError
            If ``factor`` is not a whole number ≥ 1, or leaves views under 1 px.
        """
        k = _check_factor(factor, self.source)
        if self.height // k < 1 or self.width // k < 1:
            raise ValueError(f"{self.source}: a factor of {k} leaves nothing of {self.width}×{self.height} views")
        if k == 1:
            return LightField(self.views.copy(), source=self.source, meta=self.meta)
        return LightField(block_mean(self.views, k, axes=(2, 3)), source=self.source, meta=_pixel_meta(self.meta))

    def view(self, a: int, b: int) -> np.ndarray:
        """The view in grid row ``a``, column ``b`` (0-based, negative from the end as in
        NumPy; not a copy).

        Raises
        ------
        IndexError
            If ``(a, b)`` is outside the grid, or not whole numbers.
        """
        rows, cols = self.grid
        for value in (a, b):  # (True had given a whole row of views; 4.5 NumPy's message)
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
                raise IndexError(f"{self.source}: a view's row and column are whole numbers, got ({a!r}, {b!r})")
        if not (-rows <= a < rows and -cols <= b < cols):
            raise IndexError(f"{self.source}: view ({a}, {b}) is outside the {rows}×{cols} grid")
        return self.views[a, b]


#: What a light field's ``meta`` says of its pixels' places (a decoded one's lattice in
#: the raw image and its origin): no longer true of a crop or a smaller copy, so left out
#: of theirs. (``lens_views``, the views across a lens, stays true.)
_PIXEL_META = ("lattice", "plane_origin", "decode")


def _pixel_meta(meta: dict) -> dict:
    """``meta`` without what :data:`_PIXEL_META` names."""
    return {k: v for k, v in meta.items() if k not in _PIXEL_META}


def _check_factor(factor, source: str) -> int:
    if whole(factor) is None or factor < 1:
        raise ValueError(f"{source}: the factor must be a whole number, 1 or more, got {factor!r}")
    return whole(factor)


def block_mean(array: np.ndarray, factor: int, axes=(0, 1)) -> np.ndarray:
    """``array`` (float) shrunk ``factor`` times along two neighbouring ``axes``, each
    value the mean of a ``factor`` × ``factor`` block (the rest at the ends dropped), as
    float32 (a NaN in a block makes its mean NaN). :meth:`LightField.downsample`."""
    array = np.asarray(array, dtype=np.float32)
    a0, a1 = (int(a) % array.ndim for a in axes)  # (-3, -2 as 0, 1 of a 3-D array)
    if a1 != a0 + 1:
        raise ValueError("block_mean: the axes must be neighbours")
    k = _check_factor(factor, "block_mean")
    h, w = array.shape[a0] // k, array.shape[a1] // k
    if h < 1 or w < 1:  # (an empty array had come back)
        raise ValueError(f"block_mean: a factor of {k} leaves nothing of axes of {array.shape[a0]}×{array.shape[a1]}")
    lead = (slice(None),) * a0
    # the k² strided sub-grids summed (float32, a few ulps from float64's mean): one pass
    # each, where a mean over the blocks' axes of a reshaped view ran 10–20× slower
    total = np.zeros(array.shape[:a0] + (h, w) + array.shape[a1 + 1:], np.float32)
    for dy in range(k):
        for dx in range(k):
            total += array[lead + (slice(dy, h * k, k), slice(dx, w * k, k))]
    total *= np.float32(1.0 / (k * k))
    return total


def luma(rgb: np.ndarray) -> np.ndarray:
    """The ITU-R BT.601 luma of RGB values (…, 3), float32: :meth:`LightField.grey`."""
    rgb = np.asarray(rgb)
    if rgb.ndim < 1 or rgb.shape[-1] != 3:  # (matmul's own message had named its core dimensions)
        raise ValueError(f"luma: expected RGB values (…, 3), got shape {rgb.shape}")
    return rgb @ np.asarray(BT601_LUMA, dtype=np.float32)


def centre_view(views: np.ndarray) -> np.ndarray:
    """The centre view of views [a, b, y, x(, c)]: :attr:`LightField.centre`."""
    rows, cols = views.shape[:2]
    a_lo, a_hi = (rows - 1) // 2, rows // 2
    b_lo, b_hi = (cols - 1) // 2, cols // 2
    if a_lo == a_hi and b_lo == b_hi:
        return views[a_lo, b_lo]
    middle = views[a_lo:a_hi + 1, b_lo:b_hi + 1]
    count = middle.shape[0] * middle.shape[1]
    return middle.sum(axis=(0, 1), dtype=np.float32) / np.float32(count)


#: Two light fields whose brightest values are more than this factor apart were scaled
#: differently (one in [0, 1], the other in counts; or integers of another width, as
#: uint8 against int64, which scales by 2^63 − 1): the estimate would be meaningless.
#: 16 is four stops, beyond the three that the estimator's exposure matching undoes (a gain of 8).
_SCALED_APART = 16.0


def check_pair(lf1: LightField, lf2: LightField) -> None:
    """Check that two light fields (times t1 and t2) can be matched against each other.

    Their view grids and view sizes must agree, both must be grey or both RGB (grey
    stored as RGB, R = G = B throughout, counts as grey; the estimator matches luma, but
    takes the t1 centre view's colours for δ1's diffusion tensor and the depth edges: one
    grey light field beside an RGB one is most often a frame saved the wrong way), and
    their intensities must be scaled alike.

    Raises
    ------
    ValueError
        Naming both sources, if the grids or the view sizes differ, if one is grey and
        the other RGB, or if one light field's brightest value is more than 16 times the
        other's (one in [0, 1], the other in counts such as [0, 255]; uint8 against int64).
    """
    _check_pair_brightest(lf1, lf2, None)


def _a(n: int) -> str:
    """The article before the number ``n`` as read aloud: "an" for 8, 11, 18, 80–89, 800…,
    else "a" ("an 8×9 grid", "a 9×9 grid")."""
    digits = str(int(n))
    return "an" if digits.startswith("8") or (len(digits) % 3 == 2 and digits[:2] in ("11", "18")) else "a"


#: Views are taken for an array whose axes are the wrong way round ([y, x, a, b]) where
#: the grid has this many times more rows and more columns of views than the views have
#: pixels (a row of 120×160 views of 9×9 px).
AXES_RATIO = 4


def _check_axes(lf: LightField) -> None:
    """A ValueError where ``lf``'s views look ordered [y, x, a, b] (:data:`AXES_RATIO`)."""
    rows, cols = lf.grid
    # (120×160 views of 9×9 px: the axes the wrong way round; a scene rendered small on a
    # large grid, 19×19 views of 17 px, is not)
    if rows > AXES_RATIO * lf.height and cols > AXES_RATIO * lf.width:
        raise ValueError(f"{lf.source}: {rows}×{cols} views of {lf.width}×{lf.height} pixels, more views than pixels "
                         "across: are the views ordered [y, x, a, b]? lfsf reads [a, b, y, x] (view row, view "
                         "column, then the pixels); np.moveaxis(views, (2, 3), (0, 1)) turns them round")


def _check_pair_brightest(lf1: LightField, lf2: LightField, highs) -> None:
    """:func:`check_pair` given each light field's brightest value (``highs``; None:
    found here), which the estimator has already taken for its intensity range."""
    def describe(lf: LightField) -> str:
        rows, cols = lf.grid
        return f"{_a(rows)} {rows}×{cols} grid of {lf.width}×{lf.height} views"

    for lf in (lf1, lf2):  # (each on its own first: else t2 is blamed for t1's axes)
        _check_axes(lf)
    # (one source for both, a light field and its crop: "x.npz: expected … of x.npz" had named one file twice)
    name1, name2 = ((lf1.source, lf2.source) if lf1.source != lf2.source
                    else (f"{lf1.source} (t1)", f"{lf2.source} (t2)"))
    if lf1.grid != lf2.grid or lf1.views.shape[2:4] != lf2.views.shape[2:4]:
        raise ValueError(f"{name2}: expected the grid and view size of {name1} "
                         f"({describe(lf1)}), got {describe(lf2)}")
    if lf1.is_colour != lf2.is_colour and not _grey_in_rgb(lf1 if lf1.is_colour else lf2):
        kinds = ["RGB" if lf.is_colour else "grey" for lf in (lf1, lf2)]
        raise ValueError(f"{name2}: {kinds[1]} views, but those of {name1} are {kinds[0]}: give both "
                         "light fields in colour, or both grey (in Python LightField.grey() makes the luma of an "
                         "RGB one; lfsf decode --bayer none decodes a raw image grey)")
    if highs is None:
        highs = [float(np.max(lf.views)) for lf in (lf1, lf2)]
    if min(highs) > 0.0 and max(highs) > _SCALED_APART * min(highs):   # (all black: no scale to compare)
        raise ValueError(f"{name2}: its brightest value is {highs[1]:g} against {highs[0]:g} in "
                         f"{name1}: the two light fields look scaled differently (float views "
                         "belong in [0, 1]; integer ones are scaled by their type's maximum, so give "
                         "both the same type), or lie more than four stops apart in exposure")


def _stack_hint(shape) -> str:
    """A hint for views given as one stack (N, H, W) or (N, H, W, C) instead of a grid,
    where N is a square number ("" otherwise)."""
    if len(shape) not in (3, 4) or (len(shape) == 4 and shape[3] not in (1, 3)):
        return ""
    n = shape[0]
    side = math.isqrt(n)
    if side < 2 or side * side != n:
        return ""
    return (f": a stack of {n} views? give them as {_a(side)} {side}×{side} grid, row by row: "
            f"views.reshape({side}, {side}, {', '.join(map(str, shape[1:]))})")


def _grey_in_rgb(lf: LightField) -> bool:
    """Whether an RGB light field's three channels are equal everywhere (a grey image
    saved as RGB), so that it pairs with a grey one as it is."""
    v = lf.views
    return bool(np.array_equal(v[..., 0], v[..., 1]) and np.array_equal(v[..., 1], v[..., 2]))


def refuse_wide_integers(array: np.ndarray, source: str, what: str = "views", fix: str | None = None) -> None:
    """Raise a ValueError for an integer array of more than 16 bits a value (int32,
    int64, uint32, uint64), which lfsf would scale by its type's maximum like any
    integer image: ``np.array`` of Python ints or ``.astype(int)`` gives int64, and its
    0…255 would become 0…2.8e-17, views of nothing. Light-field files are read as 8 or
    16 bits and scaled by that; an array of wider integers says nothing of its scale.
    ``what`` names the values in the message; ``fix`` replaces its advice (what to do
    with a file rather than an array)."""
    if array.dtype.kind not in "iu" or array.dtype.itemsize <= 2:
        return
    lo, hi = (int(array.min()), int(array.max())) if array.size else (0, 0)
    top = np.iinfo(array.dtype).max
    if fix is None:
        fits = ("uint8" if hi <= 255 else "uint16" if hi <= 65535 else None) if lo >= 0 else None
        if fits and hi <= 1:
            fix = "give them as bool, or as floats in [0, 1] (.astype(np.float32))"
        elif fits:
            fix = (f"give them as np.{fits} (.astype(np.{fits})) if they are {fits[4:]}-bit values, or as floats "
                   "in [0, 1]")
        else:
            fix = "give them as floats in [0, 1] (divided by their full scale)"
    tiny = max(hi, 0) / top
    raise ValueError(f"{source}: integer {what} of dtype {array.dtype} (values {lo}…{hi}); lfsf scales integers "
                     f"by their type's maximum and takes those of 8 and 16 bits"
                     + (f" (these would be {tiny:.2g} at most)" if tiny < 1e-3 else "") + f": {fix}")


def _to_unit_float32(array: np.ndarray) -> np.ndarray:
    """Float arrays as float32; integer arrays scaled by their dtype's maximum."""
    if array.dtype.kind in "iu":
        scaled = array.astype(np.float32)
        scaled /= np.float32(np.iinfo(array.dtype).max)
        return scaled
    # values beyond float32's range become inf, which the caller reports as non-finite
    with np.errstate(over="ignore"):
        return array.astype(np.float32, copy=False)


def _validated_views(views, source: str) -> np.ndarray:
    if isinstance(views, np.ma.MaskedArray) and np.ma.is_masked(views):
        # (np.asarray drops the mask: the values under it were estimated from as any others)
        raise ValueError(f"{source}: a masked array with {int(np.ma.count_masked(views))} masked values; lfsf "
                         "needs a value at every pixel of every view: fill them (views.filled(...)) or crop "
                         "them away")
    array = np.asarray(views)
    if array.dtype.kind not in "biuf":
        raise ValueError(f"{source}: expected real-valued views, got dtype {array.dtype}")
    if array.ndim not in (4, 5):
        raise ValueError(f"{source}: expected views of shape [a, b, y, x] or [a, b, y, x, c], "
                         f"got an array of {array.ndim} dimensions, shape {array.shape}" + _stack_hint(array.shape))
    if array.ndim == 5:
        channels = array.shape[4]
        if channels not in (1, 3):
            # (channels before the pixels, [a, b, c, y, x], as a deep-learning loader gives them)
            first = ("; are the channels before the pixels, [a, b, c, y, x]? np.moveaxis(views, 2, -1) "
                     "puts them last" if array.shape[2] in (1, 3, 4) and channels > 4 else "")
            raise ValueError(f"{source}: expected 1 or 3 colour channels (grey or RGB; drop "
                             f"alpha first), got {channels} in shape {array.shape}{first}")
        if channels == 1:
            array = array[..., 0]
    if array.size == 0:
        raise ValueError(f"{source}: expected a non-empty light field, got shape {array.shape}")
    refuse_wide_integers(array, source)
    given = array
    array = np.ascontiguousarray(_to_unit_float32(array))
    # A float64 sum of float32 values cannot overflow, so it is finite exactly when every
    # value is: one cheap pass instead of a full boolean mask in the common case.
    if not np.isfinite(array.sum(dtype=np.float64)):
        _refuse_non_finite(array, source, given)
    return array


def _refuse_non_finite(array: np.ndarray, source: str, given: np.ndarray | None = None) -> None:
    """Raise the ValueError that names how many of the views' values (``array``, [a, b, y,
    x] or [a, b, y, x, c]) are NaN or infinite, and the first view holding one; nothing if
    none is. Where ``given`` (the values before their conversion to float32) was finite
    there, the values lay beyond float32's range, and the message says so."""
    bad = ~np.isfinite(array)
    expected, what = "finite pixel values", "NaN or infinite pixel(s)"
    if given is not None and given.shape == array.shape and given.dtype.kind == "f":
        beyond = bad & np.isfinite(given)
        if beyond.any():
            bad = beyond
            expected = f"pixel values within float32's range (±{float(np.finfo(np.float32).max):.3g})"
            what = "pixel(s) beyond it"
    if bad.ndim == 5:
        bad = bad.any(axis=4)
    per_view = bad.sum(axis=(2, 3))
    bad_views = np.argwhere(per_view)
    if len(bad_views):
        first = tuple(int(i) for i in bad_views[0])
        raise ValueError(f"{source}: expected {expected}, got {int(per_view.sum())} {what} in "
                         f"{len(bad_views)} view(s), the first in view (a, b) = {first}")


# --------------------------------------------------------------------------------------
# Reading and writing light fields
# --------------------------------------------------------------------------------------


def read_lightfield(path: str | os.PathLike) -> LightField:
    """Read a light field from a folder of views or a ``.npz``.

    Parameters
    ----------
    path : str or path-like
        One of

        * a folder in the HCI 4D benchmark layout, ``input_Cam000.png … input_CamNNN.png``
          in row-major view order; the grid is ``parameters.cfg``'s ``num_cams_y`` ×
          ``num_cams_x`` where it gives them, else square, its size inferred from the
          count (with a warning for 4–25 views, which a rig of one row could be); an
          optional ``parameters.cfg`` is parsed into ``meta["parameters"]``;
        * a folder of views ``<name>_RR_CC.png`` (1-based row and column, e.g.
          ``2067_01_01.png``); the grid must be complete;
        * a folder holding neither but a ``views.npz`` (as ``lfsf decode`` writes);
        * a ``.npz`` with key ``views``, ``[a, b, y, x]`` or ``[a, b, y, x, c]``; float
          arrays are used as they are, integer arrays scaled by their dtype's maximum.

        8-bit and 16-bit PNGs are scaled by 255 and 65535; alpha is dropped; grey PNGs
        give grey (4-D) views.

    Returns
    -------
    LightField

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        If the folder holds no recognisable views, the grid is incomplete or (HCI) not
        square, views differ in size, a file is corrupt, or ``path`` is a single image:
        a raw lenslet image must first be decoded with ``lfsf decode``; or ``path`` is
        no path at all (None, a number, an empty string).
    """
    if not isinstance(path, (str, os.PathLike)) or not str(path).strip():
        raise ValueError(f"read_lightfield needs the path of a light field (a folder of views or a .npz), "
                         f"got {path!r}")
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such light field (file or folder)")
    if path.is_dir():
        return _read_folder(path)
    _refuse_special_file(path)
    suffix = path.suffix.lower()
    if suffix == ".npz":
        return _read_npz(path)
    if suffix in _IMAGE_SUFFIXES:
        if path.name.lower().endswith(".eslf.png"):
            raise ValueError(f"{path}: an ESLF image (decoded views tiled one block of N×N pixels a micro-lens, as "
                             "the Stanford and EPFL Lytro archives give them), not a raw lenslet image: split it "
                             f"with views = lfsf.io.lenslet_to_views(lfsf.io.read_image('{path}'), (N, N)), N = 14 for "
                             "the Lytro Illum's (an alpha channel dropped first, image[..., :3], and an image whose "
                             "size is no multiple of N cropped to one), keep the inner views, whose brightness is "
                             "even, and save them: np.savez('lf.npz', views=views[3:-3, 3:-3]) (README: Other layouts)")
        if _HCI_NAME.fullmatch(path.name) or _ROWCOL_NAME.fullmatch(path.name):
            raise ValueError(f"{path}: one view of a light field; give the folder of all its views, "
                             f"{path.parent}")
        if suffix in _NOT_RAW_SUFFIXES:
            raise ValueError(f"{path}: a single image, not a light field (a folder of its views: "
                             f"{_LAYOUTS_LOOKED_FOR}), nor a raw lenslet image that lfsf decode reads (16-bit PNG or "
                             "TIFF, Lytro .lfr/.lfp/.raw, a camera's raw format)")
        raise ValueError(f"{path}: a single image is a raw lenslet image, which must be "
                         f"decoded first: run `lfsf decode {path} --white WHITE --out DIR` "
                         f"and read DIR (one view of a light field? give the folder of all its views)")
    other = _OTHER_FORMATS.get(suffix)
    raise ValueError(f"{path}: unknown light-field format {suffix!r}; expected a folder of "
                     f"views ({_LAYOUTS_LOOKED_FOR}) or a .npz with key 'views'"
                     + (f"; this is {other.replace('PATH', repr(str(path)))} (README: Other layouts)" if other else ""))


def _read_npz(path: Path) -> LightField:
    """The light field of a ``.npz`` (key ``views``)."""
    keys, arrays = _read_npz_arrays(path, ("views",))
    if "views" not in arrays:
        raise ValueError(f"{path}: expected an array under key 'views', found keys {keys}")
    return LightField(arrays["views"], source=str(path), meta={"layout": "npz"})


# A damaged .npz fails in the zip layer, in the decompressor (zlib for np.savez_compressed;
# bz2 raises OSError) or in numpy's parsing of a member's .npy header.
_NPZ_ERRORS = (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error, lzma.LZMAError,
               NotImplementedError, SyntaxError, tokenize.TokenError)
# What a zip archive starts with: a member's local header, or the end record of an empty one.
_ZIP_MAGICS = (b"PK\x03\x04", b"PK\x05\x06")


def _read_npz_arrays(path: Path, keys) -> tuple[list[str], dict[str, np.ndarray]]:
    """The names in a ``.npz`` and those of its arrays named in ``keys``, read in full.

    Also used by :mod:`lfsf.evaluate`. Any damage is a ``ValueError`` naming the file.
    """
    _refuse_special_file(Path(path))
    # Opened here, not by np.load, which leaves the file open when the zip is unreadable.
    with open(path, "rb") as f:
        head = f.read(4)
        if not head:
            raise ValueError(f"{path}: empty file (0 bytes), not a .npz")
        if head not in _ZIP_MAGICS:
            # np.load would try it as a .npy or a pickle and blame pickling
            raise ValueError(f"{path}: not a valid .npz (zip) file: it starts with {head!r}, "
                             f"expected {_ZIP_MAGICS[0]!r}")
        f.seek(0)
        try:
            with np.load(f, allow_pickle=False) as data:
                names = list(data.files)
                # members are decompressed lazily, on access: read them inside the try
                for k in keys:
                    if k in names:
                        _check_npz_member_size(path, data.zip, k)
                arrays = {k: np.asarray(data[k]) for k in keys if k in names}
        except _DamagedMember:
            raise
        except _NPZ_ERRORS as err:
            kind = type(err).__name__
            if type(err).__module__ != "builtins":
                kind = f"{type(err).__module__}.{kind}"    # zlib.error, zipfile.BadZipFile
            raise ValueError(f"{path}: cannot read as .npz ({kind}: {err})") from err
    return names, arrays


class _DamagedMember(ValueError):
    """A ``.npz`` member that cannot be what its header says (the message names the file)."""


def _check_npz_member_size(path: Path, archive: zipfile.ZipFile, key: str) -> None:
    """Refuse a member whose ``.npy`` header claims more data than the member holds.

    Read before the member itself, so that a small damaged (or hostile) file claiming a
    huge shape is a ``ValueError`` naming it rather than a ``MemoryError`` from the
    allocation ``np.load`` would make for that shape.
    """
    member = key + ".npy"
    if member not in archive.namelist():
        return                               # not a .npy member; np.load reports it
    size = archive.getinfo(member).file_size
    with archive.open(member) as f:
        version = np.lib.format.read_magic(f)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(f)
        elif version in ((2, 0), (3, 0)):
            # (3.0 is 2.0's layout with UTF-8 field names: a huge shape there had reached
            # np.load's allocation, "out of memory")
            try:
                shape, _, dtype = np.lib.format.read_array_header_2_0(f)
            except ValueError:
                if version == (2, 0):
                    raise
                return                       # (field names beyond Latin-1: left to np.load)
        else:
            return                           # (a version NumPy does not know: np.load says so)
        header = f.tell()
    if dtype.hasobject:
        return                               # np.load refuses these without allow_pickle
    claimed = math.prod(shape) * dtype.itemsize
    if claimed > size - header:
        raise _DamagedMember(f"{path}: '{key}' is damaged: its header claims shape {tuple(shape)} "
                         f"of {dtype} ({claimed} bytes) but the file holds {size - header} bytes "
                         f"of data")


def _read_folder(folder: Path) -> LightField:
    # (hidden files skipped: macOS's AppleDouble ._view_01_01.png beside each view had read
    # as a second light field's prefix)
    names = []
    for p in sorted((p for p in folder.iterdir() if not p.name.startswith(".")), key=lambda p: p.name):
        if p.is_file():
            names.append(p.name)
        elif _HCI_NAME.fullmatch(p.name) or _ROWCOL_NAME.fullmatch(p.name):  # (had been told as a view missing)
            raise ValueError(f"{p}: named as a view, but {not_a_file(p)}")
    hci = [(m, name) for name in names if (m := _HCI_NAME.fullmatch(name))]
    rowcol = [(m, name) for name in names if (m := _ROWCOL_NAME.fullmatch(name))]
    if hci and rowcol:
        raise ValueError(f"{folder}: holds views in two layouts, HCI ({hci[0][1]}, …) and row-column "
                         f"({rowcol[0][1]}, …); keep one light field per folder")
    if hci:
        meta = {"layout": "hci"}
        cfg = folder / "parameters.cfg"
        if cfg.is_file():
            meta["parameters"] = _read_hci_parameters(cfg)
        files = _hci_grid(folder, hci, _hci_cameras(meta.get("parameters", {}), cfg))
        report = _read_decode_report(folder / "decode.json")
        if report is not None:
            meta["decode"], meta["lattice"], meta["lens_views"] = report, report["lattice"], report["views"]
    elif rowcol:
        files, prefix = _rowcol_grid(folder, rowcol)
        meta = {"layout": "rowcol", "prefix": prefix}
    elif (folder / "views.npz").is_file():
        return _read_npz(folder / "views.npz")
    else:
        # views named as lfsf reads them but in another image format: say so, not "none found"
        as_png = [(name, Path(name).stem + ".png") for name in names if Path(name).suffix.lower() != ".png"]
        other = [name for name, png in as_png if _HCI_NAME.fullmatch(png) or _ROWCOL_NAME.fullmatch(png)]
        if other:
            raise ValueError(f"{folder}: views are read from PNG files only; found {len(other)} named as views but "
                             f"in another format ({other[0]}, …): convert them to PNG (8 or 16 bits), or give "
                             "the views as an .npz")
        # PNGs named by a row and column in another way (01_01.png, cam-01-01.png): the rule they miss
        near = [name for name in names if re.fullmatch(r"(?:.*[^0-9])?\d+[-_. ]\d+\.png", name, re.IGNORECASE)]
        hint = (f"; {near[0]} is not named <name>_RR_CC.png: rename the views so, e.g. view_01_01.png"
                if near else "")
        raise ValueError(f"{folder}: found no light-field views; looked for {_LAYOUTS_LOOKED_FOR}{hint}")
    return LightField(_read_view_grid(files), source=str(folder), meta=meta)


#: The most views across a micro-lens a decode report may give (Lytro's 15, Raytrix's
#: ~25); one beyond is not taken as a report.
MAX_LENS_VIEWS = 1024


def _read_decode_report(path: Path) -> dict | None:
    """``lfsf decode``'s report beside the views it wrote (the lattice, the number of
    views across a lens, …), or None where there is none that reads as one: the views
    are then taken as any others."""
    import json

    if not path.is_file():
        return None
    try:
        report = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return None
    if not isinstance(report, dict):
        return None
    views = report.get("views")
    # (a count no lens holds, 10⁴⁰⁰ say, had been an OverflowError's traceback in the estimate)
    if not (isinstance(report.get("lattice"), dict) and isinstance(views, int) and not isinstance(views, bool)
            and 0 < views <= MAX_LENS_VIEWS):
        return None
    return report


def _listed(items: list) -> str:
    return _listed_first(iter(items), len(items))


def _listed_first(items, count: int) -> str:
    """:func:`_listed` of an iterator of ``count`` items, of which only the first few are taken."""
    shown = list(itertools.islice(items, _MAX_NAMES_LISTED))
    more = count - len(shown)
    return ", ".join(str(i) for i in shown) + (f" and {more} more" if more > 0 else "")


#: The most cameras across or down a grid that ``parameters.cfg`` may give (HCI's 9; the
#: largest arrays, Stanford's 17; 10³⁰⁰ had been taken, and printed in full).
MAX_CAMS = 1024


def _hci_cameras(parameters: dict, cfg: Path) -> tuple[int, int] | None:
    """(rows, cols) of the views as ``parameters.cfg`` (``cfg``) gives them: ``num_cams_y``
    and ``num_cams_x``, in any section (the benchmark's [extrinsics]); None where it names
    neither. One without the other, or either not a whole number ≥ 1, is a ValueError
    naming the file (read as a square grid instead, a 1×9 rig had been 3×3)."""
    found = {key.lower(): value for section in parameters.values() for key, value in section.items()
             if key.lower() in ("num_cams_x", "num_cams_y")}
    if not found:
        return None
    counts = []
    for key in ("num_cams_y", "num_cams_x"):
        value = found.get(key)
        if isinstance(value, float) and value.is_integer():  # (9.0)
            value = int(value)
        if not isinstance(value, int) or not 1 <= value <= MAX_CAMS:
            other = "num_cams_x" if key == "num_cams_y" else "num_cams_y"
            why = (f"it gives {other} but not {key}" if value is None else
                   f"{key} = {shown_number(found[key]) if isinstance(found[key], int) else repr(found[key])}")
            raise ValueError(f"{cfg}: {why}; the grid of views needs num_cams_x and num_cams_y as whole numbers "
                             f"1…{MAX_CAMS} (or no such line, for a square grid)")
        counts.append(value)
    return counts[0], counts[1]


#: An HCI folder of at most this many views and no grid given is read as a square grid
#: with a warning: 4, 9, 16 or 25 views may as well be a rig of one row (a helper's 1×9
#: rig read as 3×3 gave δ1 errors 60 times as large, with status 0).
SQUARE_NOTE_VIEWS = 25


def _hci_grid(folder: Path, matches: list, cameras: tuple[int, int] | None = None) -> list[list[Path]]:
    """The HCI views input_CamNNN.png in rows of the grid: ``cameras`` (rows, cols) from
    parameters.cfg, else a square grid of the views' count."""
    by_index: dict[int, str] = {}
    for m, name in matches:
        index = int(m.group(1))
        if index in by_index:
            raise ValueError(f"{folder}: two files for view {index}: {by_index[index]} and {name}")
        by_index[index] = name
    count = max(by_index) + 1
    if len(by_index) < count:
        # counted, and only the first few named: a stray input_Cam99999999.png must not
        # make a list of 10^8 names
        missing = (f"input_Cam{i:03d}.png" for i in range(count) if i not in by_index)
        # (views numbered from 1, input_Cam001 … input_Cam081: only the first is missing)
        from_one = ("; the views seem numbered from 1: the HCI layout numbers them from 0 (input_Cam000.png is "
                    "the top left view), rename them so" if 0 not in by_index and len(by_index) == count - 1 else "")
        raise ValueError(f"{folder}: the HCI views input_Cam000 … input_Cam{count - 1:03d} "
                         f"are incomplete, {count - len(by_index)} missing: "
                         f"{_listed_first(missing, count - len(by_index))}{from_one}")
    if cameras is not None:
        rows, cols = cameras
        if rows * cols != count:
            raise ValueError(f"{folder}: parameters.cfg gives a grid of {rows}×{cols} views (num_cams_y × "
                             f"num_cams_x), but there are {count} (input_Cam000 … input_Cam{count - 1:03d}): "
                             "correct num_cams_x and num_cams_y in its [extrinsics] (a subset of the views "
                             "kept?), or remove the file, and a square grid is read")
        return [[folder / by_index[r * cols + c] for c in range(cols)] for r in range(rows)]
    side = math.isqrt(count)
    if side * side != count:
        # a few short of the next square: likely its last views missing (input_Cam080.png of 9×9)
        short = (side + 1) ** 2 - count
        tail = "" if short > side else (f"; {_a(side + 1)} {side + 1}×{side + 1} grid misses " + _listed_first(
            (f"input_Cam{i:03d}.png" for i in range(count, (side + 1) ** 2)), short))
        raise ValueError(f"{folder}: expected a square number of HCI views (e.g. {side}×{side} "
                         f"= {side * side} or {side + 1}×{side + 1} = {(side + 1) ** 2}), got "
                         f"{count} (input_Cam000 … input_Cam{count - 1:03d}){tail}; for a grid that is not square, "
                         "give num_cams_x and num_cams_y in parameters.cfg's [extrinsics], name the views "
                         "<name>_RR_CC.png, or give an .npz")
    if 4 <= count <= SQUARE_NOTE_VIEWS and not (folder / "decode.json").is_file():  # (one view is no rig)
        warnings.warn(f"{folder}: {count} HCI views with no grid given (parameters.cfg's num_cams_x and "
                      f"num_cams_y) are read as {_a(side)} {side}×{side} grid; a rig of one row or column of {count} "
                      f"cameras needs them", LfsfWarning, stacklevel=4)
    return [[folder / by_index[r * side + c] for c in range(side)] for r in range(side)]


def _rowcol_grid(folder: Path, matches: list) -> tuple[list[list[Path]], str]:
    prefixes = sorted({m.group(1) for m, _ in matches})
    if len(prefixes) > 1:
        raise ValueError(f"{folder}: expected the views of one light field, got several name "
                         f"prefixes: {_listed(prefixes)}")
    prefix = prefixes[0]
    by_position: dict[tuple[int, int], str] = {}
    for m, name in matches:
        position = int(m.group(2)), int(m.group(3))
        if min(position) < 1:
            raise ValueError(f"{folder / name}: expected 1-based view row and column "
                             f"(<name>_RR_CC.png), got {position}: numbered from 0? rename the views from "
                             f"{prefix}_01_01.png (or give them as an .npz)")
        if position in by_position:
            raise ValueError(f"{folder}: two files for view (row, col) = {position}: "
                             f"{by_position[position]} and {name}")
        by_position[position] = name
    rows = max(r for r, _ in by_position)
    cols = max(c for _, c in by_position)
    width_r, width_c = len(matches[0][0].group(2)), len(matches[0][0].group(3))
    if len(by_position) < rows * cols:
        # counted, and only the first few named (IMG_20240101_120000.png alone would be
        # a grid of 2.4·10^12 views)
        missing = (f"{prefix}_{r:0{width_r}d}_{c:0{width_c}d}.png"
                   for r in range(1, rows + 1) for c in range(1, cols + 1)
                   if (r, c) not in by_position)
        r0 = min(r for r, _ in by_position)
        c0 = min(c for _, c in by_position)
        inner = (rows - r0 + 1) * (cols - c0 + 1)
        # the views present a whole grid that starts past 01 (a subset chosen on purpose)
        subset = (f"; the views there make a whole {rows - r0 + 1}×{cols - c0 + 1} grid from "
                  f"{by_position[r0, c0]}: to read it alone, number its views from 01 (or give "
                  "the views as an array)" if len(by_position) == inner >= 4 and (r0, c0) != (1, 1) else "")
        raise ValueError(f"{folder}: the {rows}×{cols} grid of views is incomplete, "
                         f"{rows * cols - len(by_position)} missing: "
                         f"{_listed_first(missing, rows * cols - len(by_position))}{subset}")
    files = [[folder / by_position[r, c] for c in range(1, cols + 1)] for r in range(1, rows + 1)]
    return files, prefix


def _parse_cfg_value(text: str):
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def _read_hci_parameters(path: Path) -> dict:
    """``parameters.cfg`` as ``{section: {key: int | float | str}}``; a malformed file is
    only metadata, so it is skipped with a warning rather than failing the read."""
    parser = configparser.ConfigParser(interpolation=None)
    parser.optionxform = str
    try:
        parser.read_string(path.read_text(encoding="utf-8", errors="replace"), source=str(path))
    except configparser.Error as err:
        # (configparser's first line says what; the others repeat the file, the line and its text)
        why = str(err).splitlines()[0].rstrip(".") if str(err).strip() else type(err).__name__
        warnings.warn(f"{path}: ignored, not an INI file ({why})", LfsfWarning, stacklevel=3)
        return {}
    return {section: {key: _parse_cfg_value(value) for key, value in parser[section].items()}
            for section in parser.sections()}


def _describe_image(shape: tuple) -> str:
    kind = "RGB" if len(shape) == 3 else "grey"
    return f"{shape[1]}×{shape[0]} {kind}"


def _read_view(path: Path) -> np.ndarray:
    """One view as float32 (H, W) or (H, W, 3) in [0, 1]; alpha dropped."""
    image = read_image(path)
    if image.ndim == 3:
        channels = image.shape[2]
        if channels in (1, 2):      # grey, grey + alpha
            image = image[..., 0]
        elif channels == 4:         # RGBA
            image = image[..., :3]
        elif channels != 3:
            raise ValueError(f"{path}: expected a grey, RGB or RGBA image, got one of shape {image.shape}"
                             + (" (an animated image's frames?)" if channels > 4 else ""))
    elif image.ndim != 2:
        raise ValueError(f"{path}: expected a 2-D image, got shape {image.shape}")
    if image.dtype.kind not in "biuf":
        raise ValueError(f"{path}: expected integer or float pixels, got {image.dtype}")
    return _to_unit_float32(image)


def _read_view_grid(files: list[list[Path]]) -> np.ndarray:
    rows, cols = len(files), len(files[0])
    flat = [p for row in files for p in row]
    first = _read_view(flat[0])
    views = np.empty((rows, cols) + first.shape, dtype=np.float32)
    views[0, 0] = first

    def load(k: int) -> None:
        image = _read_view(flat[k])
        if image.shape != first.shape:
            what = "the size" if image.shape[:2] != first.shape[:2] else "the colour"  # (96×72 RGB, got 96×72 grey)
            raise ValueError(f"{flat[k]}: expected {what} of {flat[0].name} "
                             f"({_describe_image(first.shape)}), got {_describe_image(image.shape)}")
        views[k // cols, k % cols] = image

    # PNG decoding (zlib inside Pillow) releases the GIL, so threads overlap the views.
    with ThreadPoolExecutor(max_workers=min(8, os.cpu_count() or 1)) as pool:
        futures = [pool.submit(load, k) for k in range(1, len(flat))]
        try:
            for future in futures:      # in view order: the first bad view is reported
                future.result()
        except BaseException:
            for future in futures:
                future.cancel()
            raise
    return views


def _refuse_mixed_views(folder: Path, names: list[str]) -> None:
    """Raise ValueError if ``folder`` holds views (of either layout) other than ``names``
    (:func:`_view_names`): writing these beside them would mix two light fields."""
    if not folder.is_dir():
        return
    # views of either layout that are not these: the reader would refuse the folder or
    # read the wrong light field
    ours = set(names)
    stale = sorted(p.name for p in folder.iterdir()
                   if not p.name.startswith(".")  # (hidden files, as the reader skips them)
                   and (_HCI_NAME.fullmatch(p.name) or _ROWCOL_NAME.fullmatch(p.name)) and p.name not in ours)
    if stale:
        raise ValueError(f"{folder}: already holds views that these would mix with "
                         f"({_listed(stale)}); write to an empty folder")


def _view_names(layout: str, rows: int, cols: int) -> list[str]:
    """Row-major file names of a grid in the given layout."""
    if layout == "hci":
        digits = max(3, len(str(rows * cols - 1)))
        return [f"input_Cam{k:0{digits}d}.png" for k in range(rows * cols)]
    digits = max(2, len(str(max(rows, cols))))
    return [f"view_{r:0{digits}d}_{c:0{digits}d}.png"
            for r in range(1, rows + 1) for c in range(1, cols + 1)]


def write_lightfield(lf_or_views, path: str | os.PathLike, *, bit_depth: int = 16,
                     layout: str = "hci") -> Path:
    """Write a light field to a ``.npz`` or to a folder of PNG views.

    Parameters
    ----------
    lf_or_views : LightField or array_like
        The light field, or views as :class:`LightField` accepts them.
    path : str or path-like
        Ending in ``.npz``: one file with key ``views`` (float32, exact). Otherwise a
        folder (created if needed) of PNG views that :func:`read_lightfield` reads back.
    bit_depth : {16, 8}
        PNG sample depth; values are clipped to [0, 1] and rounded to the nearest level.
    layout : {"hci", "rowcol"}
        ``"hci"``: ``input_Cam000.png …`` row-major (square grids only), and a
        ``parameters.cfg`` giving the grid (``num_cams_x``, ``num_cams_y``) where the
        folder has none; ``"rowcol"``: ``view_RR_CC.png``, 1-based, for any grid.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ValueError
        For an invalid light field or option, a non-square grid in the HCI layout, a
        single-image path, or a folder already holding views of another light field
        that would be mixed with these (delete them first).

    Notes
    -----
    ``meta`` is not written. Each file is written atomically; a failure part-way through
    a folder leaves complete files only.
    """
    if not os.fspath(path):
        raise ValueError("an empty path (it would be the current folder; give '.' for that)")
    path = Path(path)
    lf = (lf_or_views if isinstance(lf_or_views, LightField)
          else LightField(lf_or_views, source=f"views for {path}"))
    if path.suffix.lower() == ".npz":
        savez_atomic(path, views=lf.views)
        return path
    if path.suffix.lower() in _IMAGE_SUFFIXES:
        raise ValueError(f"{path}: a light field is written to a folder or a .npz, not to a "
                         f"single image")
    if path.suffix.lower() in _OTHER_FILE_SUFFIXES and not path.is_dir():
        # a folder of PNG views under a file format's name (out.h5) misleads every reader
        raise ValueError(f"{path}: lfsf writes a light field to a .npz or to a folder of PNG views, "
                         f"not as {path.suffix}; give a .npz or a folder name")
    if bit_depth not in (8, 16):
        raise ValueError(f"{path}: expected bit_depth 8 or 16, got {bit_depth!r}")
    if layout not in ("hci", "rowcol"):
        raise ValueError(f"{path}: expected layout 'hci' or 'rowcol', got {layout!r}")
    rows, cols = lf.grid
    if layout == "hci" and rows != cols:
        raise ValueError(f"{path}: the HCI layout needs a square grid, got {rows}×{cols}; "
                         f"use layout='rowcol' or a .npz")
    names = _view_names(layout, rows, cols)
    _refuse_mixed_views(path, names)
    output_folder(path)
    dtype = np.uint16 if bit_depth == 16 else np.uint8
    levels = np.float32(np.iinfo(dtype).max)

    def save(k: int) -> None:
        view = lf.views[k // cols, k % cols]
        quantised = np.rint(np.clip(view, 0.0, 1.0) * levels).astype(dtype)
        write_png(path / names[k], quantised)

    pool = ThreadPoolExecutor(max_workers=min(8, os.cpu_count() or 1))
    futures: list = []
    try:
        futures = [pool.submit(save, k) for k in range(rows * cols)]
        for future in futures:
            future.result()
    finally:
        # an error or Ctrl-C ends the writing: the views not begun are dropped, and those
        # being written are waited for (a Ctrl-C during that wait too), so that no thread
        # writes on into a folder that the caller removes (lfsf decode's temporary one)
        for future in futures:
            future.cancel()
        with interrupts_held():
            pool.shutdown(wait=True)
    if layout == "hci" and not os.path.lexists(path / "parameters.cfg"):
        # (the grid, which the views' count alone leaves open: 9 views may be a rig of one row)
        write_bytes_atomic(path / "parameters.cfg",
                           f"[extrinsics]\nnum_cams_x = {cols}\nnum_cams_y = {rows}\n".encode())
    return path


# --------------------------------------------------------------------------------------
# Lenslet images
# --------------------------------------------------------------------------------------


def views_to_lenslet(views) -> np.ndarray:
    """Interleave views into a rectangular lenslet image (the paper's synthetic raw).

    Each micro-lens is an ``A×B`` block holding one pixel of every view, without the
    inversion a real camera adds: ``raw[y*A + a, x*B + b] = views[a, b, y, x]``.

    Parameters
    ----------
    views : LightField or array_like, shape (A, B, H, W) or (A, B, H, W, C)

    Returns
    -------
    numpy.ndarray, shape (H*A, W*B) or (H*A, W*B, C)
        Same dtype as ``views``; the channel axis stays last.
    """
    array = views.views if isinstance(views, LightField) else np.asarray(views)
    if array.ndim not in (4, 5):
        raise ValueError(f"views_to_lenslet: expected views [a, b, y, x] or [a, b, y, x, c], "
                         f"got shape {array.shape}")
    rows, cols, height, width = array.shape[:4]
    order = (2, 0, 3, 1) + tuple(range(4, array.ndim))
    return array.transpose(order).reshape((height * rows, width * cols) + array.shape[4:])


def lenslet_to_views(raw, grid: tuple[int, int]) -> np.ndarray:
    """Split a rectangular lenslet image into views; the inverse of :func:`views_to_lenslet`.

    Parameters
    ----------
    raw : array_like, shape (H*A, W*B) or (H*A, W*B, C)
    grid : (int, int)
        ``(A, B)``: view rows and columns, i.e. the micro-lens block size.

    Returns
    -------
    numpy.ndarray, shape (A, B, H, W) or (A, B, H, W, C)
        C-contiguous, same dtype as ``raw``.

    Raises
    ------
    ValueError
        If ``raw`` is not 2-D or 3-D or its size is not a multiple of the grid.
    """
    rows, cols = (int(n) for n in grid)
    if rows < 1 or cols < 1:
        raise ValueError(f"lenslet_to_views: expected a grid of positive sizes, got {grid}")
    raw = np.asarray(raw)
    if raw.ndim not in (2, 3):
        raise ValueError(f"lenslet_to_views: expected a raw image (H, W) or (H, W, C), "
                         f"got shape {raw.shape}")
    height, width = raw.shape[:2]
    if height % rows or width % cols:
        raise ValueError(f"lenslet_to_views: expected a raw image whose size is a multiple of "
                         f"the {rows}×{cols} grid, got {width}×{height} (width×height)")
    blocks = raw.reshape((height // rows, rows, width // cols, cols) + raw.shape[2:])
    order = (1, 3, 0, 2) + tuple(range(4, raw.ndim + 2))
    return np.ascontiguousarray(blocks.transpose(order))


# --------------------------------------------------------------------------------------
# PFM
# --------------------------------------------------------------------------------------

# Magic, width, height and scale separated by any whitespace; the header ends with the
# line break after the scale (trailing blanks allowed) or, failing that, one whitespace byte.
_PFM_HEADER = re.compile(rb"(\S+)\s+(\S+)\s+(\S+)\s+(\S+)\s")


#: The lines of a PFM header looked at for comments (the magic, the size, the scale and
#: comments between them).
PFM_HEADER_LINES = 8


def _without_pfm_comments(data: bytes) -> bytes:
    """PFM bytes with the header's comment lines (``#`` …, after the magic, before the
    scale: some writers put them there, and the HCI toolkit's reader skips them) taken
    out; the data untouched. Only the first PFM_HEADER_LINES lines are looked at."""
    lines = data.split(b"\n", PFM_HEADER_LINES)
    if not any(line.lstrip().startswith(b"#") for line in lines[1:-1]):
        return data
    kept, fields = [], 0
    for k, line in enumerate(lines[:-1]):
        if fields >= 4:        # (magic, width, height and scale read: the data follow)
            return b"\n".join(kept + lines[k:])
        if k > 0 and line.lstrip().startswith(b"#"):
            continue
        kept.append(line)
        fields += len(line.split())
    return b"\n".join(kept + lines[-1:])


def _cut(text: bytes, most: int = 24) -> str:
    """``text`` for a message: its repr, cut after ``most`` bytes (a header's 5000 digits
    had filled the message)."""
    return repr(text) if len(text) <= most else f"{text[:most]!r}… ({len(text)} bytes)"


def _read_bytes(path: str | os.PathLike) -> bytes:
    path = file_name(path)
    _refuse_special_file(path)
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise ValueError(f"{path}: expected a file, got a folder") from None
    except ValueError as exc:                       # a NUL byte in the name
        raise ValueError(f"{str(path)!r}: not a usable file name ({exc})") from None
    except OSError as exc:                          # not permitted, a symbolic link loop, …
        raise ValueError(f"{path}: cannot read ({exc.strerror or exc})") from None


def read_pfm(path: str | os.PathLike) -> np.ndarray:
    """Read a PFM image (e.g. HCI ``gt_disp_lowres.pfm``).

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    numpy.ndarray, float32, shape (H, W) for ``Pf`` or (H, W, 3) for ``PF``
        Rows top to bottom (the file stores them bottom to top). Values as stored; the
        magnitude of the scale is not applied (it is 1 in lfsf's files, the HCI
        benchmark's and Middlebury's): another is warned about (an LfsfWarning), as the
        HCI toolkit's reader multiplies the values by it. Header lines that start with
        ``#`` are skipped, as that reader does (the format has no comments).

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        For a bad magic, dimensions or scale, or truncated data. A negative scale means
        little-endian data, a positive one big-endian.
    """
    data = _read_bytes(path)
    if data[:2] not in (b"PF", b"Pf"):
        raise ValueError(f"{path}: not a PFM file: expected magic 'PF' or 'Pf', got {data[:2]!r}")
    data = _without_pfm_comments(data)
    header = _PFM_HEADER.match(data)
    if header is None or header.group(1) not in (b"PF", b"Pf"):
        raise ValueError(f"{path}: malformed PFM header {data[:40]!r}: expected "
                         f"'PF' or 'Pf', width, height and scale separated by whitespace")
    magic, width_text, height_text, scale_text = header.groups()
    try:
        width, height = int(width_text), int(height_text)
    except ValueError:
        width = height = 0
    if width < 1 or height < 1:
        raise ValueError(f"{path}: bad PFM dimensions: expected positive integers width "
                         f"height, got {_cut(width_text)} {_cut(height_text)}")
    try:
        scale = float(scale_text)
    except ValueError:
        scale = math.nan
    if scale == 0 or not math.isfinite(scale):
        raise ValueError(f"{path}: bad PFM scale: expected a non-zero number (negative for "
                         f"little-endian), got {scale_text.decode('ascii', 'replace')!r}")
    if abs(scale) != 1:
        warn_at_caller(f"{path}: PFM scale {scale_text.decode('ascii', 'replace')}: the values are read as stored; "
                       f"the HCI toolkit's reader multiplies them by {abs(scale):g}")
    channels = 3 if magic == b"PF" else 1
    count = width * height * channels
    # The scale ends with one whitespace byte; writers that put more (a trailing space or
    # "\r" before the "\n") are told apart from data that starts with such a byte by the
    # data's size: the data are the file's last 4·count bytes where the bytes between are
    # all whitespace.
    start = header.end()
    tail = len(data) - 4 * count
    if tail > start and data[start:tail].isspace():
        start = tail
    available = len(data) - start
    if available < 4 * count:
        # (numbers of a damaged header cut to their magnitude: they had filled the message)
        raise ValueError(f"{path}: truncated PFM data: expected {shown_number(4 * count)} bytes for "
                         f"{shown_number(width)}×{shown_number(height)}×{channels} float32, got {available}")
    dtype = "<f4" if scale < 0 else ">f4"
    image = np.frombuffer(data, dtype=dtype, count=count, offset=start)
    image = image.reshape((height, width, 3) if channels == 3 else (height, width))
    return np.ascontiguousarray(image[::-1], dtype=np.float32)


def write_pfm(path: str | os.PathLike, array, little_endian: bool = True) -> None:
    """Write a PFM image atomically.

    Parameters
    ----------
    path : str or path-like
    array : array_like, shape (H, W), (H, W, 1) or (H, W, 3)
        Written as float32 (``Pf`` grey or ``PF`` colour), rows bottom to top as the
        format wants; NaN and infinities are stored as they are.
    little_endian : bool
        Byte order; the scale is written as ``-1`` (little) or ``1`` (big).

    Notes
    -----
    The header is ``b"Pf\\n{W} {H}\\n-1\\n"``, as in the HCI benchmark's files.
    """
    image = np.asarray(array)
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[..., 0]
    if image.ndim == 2:
        magic = b"Pf"
    elif image.ndim == 3 and image.shape[2] == 3:
        magic = b"PF"
    else:
        raise ValueError(f"{path}: expected an array of shape (H, W) or (H, W, 3) for PFM, "
                         f"got {image.shape}")
    if image.dtype.kind not in "biuf":
        raise ValueError(f"{path}: expected real values for PFM, got dtype {image.dtype}")
    height, width = image.shape[:2]
    if height == 0 or width == 0:
        raise ValueError(f"{path}: expected a non-empty image for PFM, got shape {image.shape}")
    header = b"%s\n%d %d\n%s\n" % (magic, width, height, b"-1" if little_endian else b"1")
    body = np.ascontiguousarray(image[::-1], dtype="<f4" if little_endian else ">f4")
    write_bytes_atomic(path, header + body.tobytes())


# --------------------------------------------------------------------------------------
# Middlebury .flo
# --------------------------------------------------------------------------------------

_FLO_MAGIC = b"PIEH"               # 202021.25 as a little-endian float32
_FLO_UNKNOWN_ABOVE = 1e9           # |value| above this means "unknown" (Middlebury)
_FLO_UNKNOWN_WRITTEN = 1e10
_FLO_MAX_SIDE = 99_999             # the Middlebury reference reader's sanity limit


def read_flo(path: str | os.PathLike) -> np.ndarray:
    """Read a Middlebury ``.flo`` optical flow file.

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    numpy.ndarray, float32, shape (H, W, 2)
        ``(u, v)`` per pixel. Pixels marked unknown (either component NaN or above 1e9 in
        magnitude) are NaN in both components.

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        For a bad magic (expected 202021.25, bytes ``PIEH``), an absurd size (either side
        outside 1 … 99999) or truncated data.
    """
    data = _read_bytes(path)
    if len(data) < 12:
        raise ValueError(f"{path}: truncated FLO header: expected 12 bytes, got {len(data)}")
    if data[:4] != _FLO_MAGIC:
        raise ValueError(f"{path}: not a Middlebury .flo file: expected magic {_FLO_MAGIC!r} "
                         f"(202021.25), got {data[:4]!r}")
    width, height = struct.unpack("<ii", data[4:12])
    if not (1 <= width <= _FLO_MAX_SIDE and 1 <= height <= _FLO_MAX_SIDE):
        raise ValueError(f"{path}: implausible FLO size {width}×{height}: expected each side "
                         f"in 1 … {_FLO_MAX_SIDE}")
    count = width * height * 2
    if len(data) - 12 < 4 * count:
        raise ValueError(f"{path}: truncated FLO data: expected {4 * count} bytes for "
                         f"{width}×{height}×2 float32, got {len(data) - 12}")
    flow = np.frombuffer(data, dtype="<f4", count=count, offset=12).reshape(height, width, 2)
    flow = flow.astype(np.float32)
    with np.errstate(invalid="ignore"):
        unknown = ~(np.abs(flow) <= _FLO_UNKNOWN_ABOVE).all(axis=2)
    flow[unknown] = np.nan
    return flow


def write_flo(path: str | os.PathLike, flow) -> None:
    """Write a Middlebury ``.flo`` file atomically.

    Parameters
    ----------
    path : str or path-like
    flow : array_like, shape (H, W, 2)
        ``(u, v)`` per pixel; a pixel with a non-finite component is written as unknown
        (1e10 in both components).
    """
    flow = np.asarray(flow)
    if flow.ndim != 3 or flow.shape[2] != 2 or flow.dtype.kind not in "biuf":
        raise ValueError(f"{path}: expected a real (H, W, 2) flow array, got shape "
                         f"{flow.shape} dtype {flow.dtype}")
    height, width = flow.shape[:2]
    if not (1 <= width <= _FLO_MAX_SIDE and 1 <= height <= _FLO_MAX_SIDE):
        raise ValueError(f"{path}: expected each side of the flow in 1 … {_FLO_MAX_SIDE}, "
                         f"got {width}×{height}")
    body = flow.astype("<f4")       # always a copy, safe to mark unknown pixels in
    body[~np.isfinite(body).all(axis=2)] = _FLO_UNKNOWN_WRITTEN
    write_bytes_atomic(path, _FLO_MAGIC + struct.pack("<ii", width, height) + body.tobytes())


def write_ply(path: str | os.PathLike, points, colours=None, vectors=None, comment: str = "") -> int:
    """Write a point cloud as a binary little-endian PLY file, atomically.

    Parameters
    ----------
    path : str or path-like
    points : array_like, shape (..., 3)
        x, y, z of each point (float32); points with a non-finite coordinate (or vector
        component) are left out.
    colours : array_like, shape (..., 3) or (...), optional
        RGB or grey per point, floats in [0, 1] (clipped), uint8, or integers of 8 or 16
        bits (scaled by their type's maximum): the ``red``, ``green``, ``blue`` properties.
    vectors : array_like, shape (..., 3), optional
        A vector per point (the 3-D scene flow): the float properties ``flow_x``,
        ``flow_y``, ``flow_z``, which point-cloud viewers show as scalar fields.
    comment : str
        One line for the header.

    Returns
    -------
    int : the number of points written.
    """
    pts = np.asarray(points, dtype=np.float32)
    if pts.ndim < 2 or pts.shape[-1] != 3:
        raise ValueError(f"{path}: expected points of shape (..., 3), got {pts.shape}")
    pts = pts.reshape(-1, 3)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    keep = np.isfinite(pts).all(axis=1)
    rgb = vec = None
    if colours is not None:
        col = np.asarray(colours)
        if col.shape == np.shape(points)[:-1]:       # grey
            col = np.repeat(col.reshape(-1, 1), 3, axis=1)
        elif col.shape == np.shape(points):
            col = col.reshape(-1, 3)
        else:
            raise ValueError(f"{path}: colours of shape {col.shape} for points of shape {np.shape(points)}: "
                             "give one grey value or an RGB triple a point")
        if col.dtype.kind in "iu" and col.dtype != np.uint8:   # (scaled by their type's maximum, as views are)
            refuse_wide_integers(col, str(path), what="colours")
            col = _to_unit_float32(col)
        rgb = col if col.dtype == np.uint8 else np.round(np.clip(col, 0.0, 1.0) * 255.0).astype(np.uint8)
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    if vectors is not None:
        vec = np.asarray(vectors, dtype=np.float32)
        if vec.shape != np.shape(points):
            raise ValueError(f"{path}: vectors of shape {vec.shape}, points {np.shape(points)}")
        vec = vec.reshape(-1, 3)
        keep &= np.isfinite(vec).all(axis=1)
        fields += [("flow_x", "<f4"), ("flow_y", "<f4"), ("flow_z", "<f4")]
    body = np.empty(int(keep.sum()), dtype=fields)
    for k, name in enumerate("xyz"):
        body[name] = pts[keep, k]
        if vec is not None:
            body[f"flow_{name}"] = vec[keep, k]
    if rgb is not None:
        for k, name in enumerate(("red", "green", "blue")):
            body[name] = rgb[keep, k]
    kinds = {"<f4": "float", "u1": "uchar"}
    header = ["ply", "format binary_little_endian 1.0"]
    header += [f"comment {line}" for line in comment.splitlines() if line.strip()]
    header += [f"element vertex {body.size}"] + [f"property {kinds[t]} {n}" for n, t in fields] + ["end_header"]
    write_bytes_atomic(path, ("\n".join(header) + "\n").encode("ascii", "replace") + body.tobytes())
    return int(body.size)


# --------------------------------------------------------------------------------------
# KITTI 16-bit PNG flow and disparity
# --------------------------------------------------------------------------------------

_KITTI_FLOW_OFFSET = 2 ** 15
_KITTI_FLOW_SCALE = 64.0
_KITTI_DISP_SCALE = 256.0


def read_kitti_flow(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read KITTI optical flow: a 16-bit RGB PNG.

    ``u = (R − 2¹⁵)/64``, ``v = (G − 2¹⁵)/64``, valid where ``B > 0``.

    Returns
    -------
    flow : numpy.ndarray, float32, shape (H, W, 2)
        ``(u, v)``; NaN at invalid pixels, so that they cannot be used by mistake.
    valid : numpy.ndarray, bool, shape (H, W)
    """
    image = read_image(path)
    if image.dtype != np.uint16 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"{path}: expected a 16-bit RGB PNG (KITTI flow), got "
                         f"{image.dtype} of shape {image.shape}")
    valid = image[..., 2] > 0
    flow = (image[..., :2].astype(np.float32) - np.float32(_KITTI_FLOW_OFFSET))
    flow /= np.float32(_KITTI_FLOW_SCALE)
    flow[~valid] = np.nan
    return flow, valid


def write_kitti_flow(path: str | os.PathLike, flow, valid=None) -> None:
    """Write KITTI optical flow (16-bit RGB PNG) atomically.

    Parameters
    ----------
    path : str or path-like
    flow : array_like, shape (H, W, 2)
        ``(u, v)``, rounded to the nearest 1/64 px.
    valid : array_like of bool, shape (H, W), optional
        Pixels to mark valid; default: those with finite flow. Invalid pixels are written
        as (0, 0, 0), as the KITTI devkit does.

    Raises
    ------
    ValueError
        If a valid pixel has non-finite flow or flow outside the format's range
        [−512, 511.98] px (rather than clipping it silently).
    """
    flow = np.asarray(flow, dtype=np.float64)
    if flow.ndim != 3 or flow.shape[2] != 2:
        raise ValueError(f"{path}: expected flow of shape (H, W, 2), got {flow.shape}")
    finite = np.isfinite(flow).all(axis=2)
    valid = finite if valid is None else _valid_mask(path, valid, flow.shape[:2], finite)
    encoded = np.rint(flow[valid] * _KITTI_FLOW_SCALE + _KITTI_FLOW_OFFSET)
    if encoded.size and (encoded.min() < 0 or encoded.max() > 65535):
        raise ValueError(f"{path}: expected flow within the KITTI range [-512, 511.98] px, "
                         f"got {flow[valid].min():.6g} … {flow[valid].max():.6g}")
    image = np.zeros(flow.shape[:2] + (3,), dtype=np.uint16)
    image[valid, :2] = encoded.astype(np.uint16)
    image[valid, 2] = 1
    write_png(path, image)


def read_kitti_disparity(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a KITTI disparity map: a 16-bit grey PNG, ``disp = value/256``, 0 = invalid.

    Returns
    -------
    disparity : numpy.ndarray, float32, shape (H, W)
        NaN at invalid pixels.
    valid : numpy.ndarray, bool, shape (H, W)
    """
    image = read_image(path)
    if image.dtype != np.uint16 or image.ndim != 2:
        raise ValueError(f"{path}: expected a 16-bit grey PNG (KITTI disparity), got "
                         f"{image.dtype} of shape {image.shape}")
    valid = image > 0
    disparity = image.astype(np.float32) / np.float32(_KITTI_DISP_SCALE)
    disparity[~valid] = np.nan
    return disparity, valid


def write_kitti_disparity(path: str | os.PathLike, disparity, valid=None) -> None:
    """Write a KITTI disparity map (16-bit grey PNG) atomically.

    Parameters
    ----------
    path : str or path-like
    disparity : array_like, shape (H, W)
        Rounded to the nearest 1/256. A valid disparity that rounds to 0 is stored as
        1/256, since 0 means invalid in this format.
    valid : array_like of bool, shape (H, W), optional
        Default: the pixels with finite disparity. Invalid pixels are written as 0.

    Raises
    ------
    ValueError
        If a valid pixel is non-finite or outside [0, 255.996]: the format cannot hold
        negative disparities (light-field disparities often are; use PFM for those).
    """
    disparity = np.asarray(disparity, dtype=np.float64)
    if disparity.ndim != 2:
        raise ValueError(f"{path}: expected a disparity map of shape (H, W), got {disparity.shape}")
    finite = np.isfinite(disparity)
    valid = finite if valid is None else _valid_mask(path, valid, disparity.shape, finite)
    encoded = np.rint(disparity[valid] * _KITTI_DISP_SCALE)
    if encoded.size and (encoded.min() < 0 or encoded.max() > 65535):
        raise ValueError(f"{path}: expected disparities within the KITTI range [0, 255.996], "
                         f"got {disparity[valid].min():.6g} … {disparity[valid].max():.6g}")
    image = np.zeros(disparity.shape, dtype=np.uint16)
    image[valid] = np.maximum(encoded, 1).astype(np.uint16)
    write_png(path, image)


def _valid_mask(path, valid, shape: tuple, finite: np.ndarray) -> np.ndarray:
    valid = np.asarray(valid, dtype=bool)
    if valid.shape != tuple(shape):
        raise ValueError(f"{path}: expected a valid mask of shape {tuple(shape)}, got {valid.shape}")
    if (valid & ~finite).any():
        y, x = np.argwhere(valid & ~finite)[0]
        raise ValueError(f"{path}: pixel (y, x) = ({y}, {x}) is marked valid but is not finite")
    return valid


# --------------------------------------------------------------------------------------
# Images and the PNG codec
# --------------------------------------------------------------------------------------

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_CHANNELS = {0: 1, 2: 3, 4: 2, 6: 4}        # colour type -> samples per pixel
#: The most pixels a PNG may have: Pillow's own limit for the PNGs it reads (twice its
#: MAX_IMAGE_PIXELS), four times a Lytro Illum's raw image. A 1.5-MB file of 16000×16000
#: blank 16-bit pixels had asked for 1.5 GB and more (a fuzzing helper).
MAX_PNG_PIXELS = 2 * 89_478_485
#: The most values a TIFF's series may hold (pages × pixels × samples): an RGBA image of
#: :data:`MAX_PNG_PIXELS`.
MAX_TIFF_VALUES = 4 * MAX_PNG_PIXELS
_PNG_COLOUR_TYPE = {1: 0, 2: 4, 3: 2, 4: 6}     # samples per pixel -> colour type
# Adam7 passes: (x0, y0, dx, dy)
_ADAM7 = ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4),
          (0, 2, 2, 4), (1, 0, 2, 2), (0, 1, 1, 2))
# The wavefront unfilter works on bands of rows holding about this many bytes at a time.
_WAVEFRONT_BAND_BYTES = 1 << 25


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read an image file as stored: (H, W) or (H, W, C), usually uint8 or uint16.

    16-bit colour PNGs (RGB, RGBA, grey + alpha) are decoded by :func:`decode_png`, since
    Pillow would truncate them to 8 bits; TIFFs (by name or header) by tifffile, else by
    Pillow (:func:`_read_tiff`); everything else goes through imageio.

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        If the file cannot be decoded.
    """
    path = file_name(path, "an image file's name")
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such image file")
    if not path.is_file():
        raise ValueError(f"{path}: expected an image file, got "
                         f"{'a folder' if path.is_dir() else 'something else (a pipe or a device)'}")
    with open(path, "rb") as f:
        head = f.read(26)
    if not head:
        raise ValueError(f"{path}: cannot read image: empty file (0 bytes)")
    if (len(head) == 26 and head.startswith(_PNG_SIGNATURE) and head[12:16] == b"IHDR"
            and head[24] == 16 and head[25] in (2, 4, 6)):
        return decode_png(path.read_bytes(), source=str(path))
    told: list[str] = []
    # (by its name, or by its header: classic TIFF or BigTIFF, either byte order)
    tiff = path.suffix.lower() in (".tif", ".tiff") or head.startswith((b"II*\0", b"MM\0*", b"II+\0", b"MM\0+"))
    # (tifffile logs what it finds wrong with a corrupt TIFF and returns no pixels: its
    # lines are kept for the error below rather than printed on their own; one TIFF at a
    # time, as the logger is shared by the threads that read a folder's views)
    kept = _log_lines("tifffile", told) if tiff else contextlib.nullcontext()
    try:
        # (from a file this function closes: imageio leaves its own open when no plugin reads it)
        with kept, open(path, "rb") as f:
            if tiff:
                image = _read_tiff(f, path)
            else:
                image = np.asarray(iio.imread(f, extension=path.suffix or None))
    except Exception as err:        # imageio/Pillow raise many kinds for a corrupt file
        if isinstance(err, _TooLarge):
            raise ValueError(str(err)) from None
        first_line = (str(err).strip().splitlines() or [""])[0]
        if first_line.startswith("Could not find a backend"):
            # imageio's multi-line advice to install a video plugin does not apply
            reason = "no image format recognised"
        elif isinstance(err, struct.error):  # a decoder's header read ran past the end
            reason = "the file ends inside its header: truncated, or not an image"
        else:
            reason = f"{type(err).__name__}: {first_line}" if first_line else type(err).__name__
        raise ValueError(f"{path}: cannot read image ({reason})") from err
    if image.size == 0:
        why = re.sub(r"^<[^>]*> ", "", told[0]) if told else "the file holds none"
        raise ValueError(f"{path}: cannot read image: no pixels decoded ({why}); a corrupt or truncated file?")
    return image


class _TooLarge(Exception):
    """An image of more pixels than lfsf reads (:data:`MAX_PNG_PIXELS`), said as it is."""


def _read_tiff(f, path: Path) -> np.ndarray:
    """A TIFF's first series by tifffile (as imageio's plugin reads it); a one-page TIFF
    that tifffile cannot decode (LZW or JPEG without imagecodecs) by Pillow; never by
    imageio's other plugins, OpenCV's of which printed its own WARN and ERROR lines for a
    truncated file and named no fault. The size is checked before any pixel is decoded
    (an 825-KB tiled TIFF of 20000×20000 had taken 2.9 GB): the first page's pixels
    against :data:`MAX_PNG_PIXELS`, the series' values against :data:`MAX_TIFF_VALUES`."""
    import warnings

    import tifffile
    from PIL import Image

    try:
        with tifffile.TiffFile(f) as tif:
            if not len(tif.pages):   # (what tifffile logged says why: read_image's "no pixels decoded")
                return np.zeros((0,), np.uint8)
            page = tif.pages[0]
            width, height = int(page.imagewidth), int(page.imagelength)
            if width * height > MAX_PNG_PIXELS:
                raise _TooLarge(f"{path}: a TIFF of {width}×{height} pixels, more than the {MAX_PNG_PIXELS} that "
                                "lfsf reads")
            series = tif.series[0]
            if series.size > MAX_TIFF_VALUES:
                raise _TooLarge(f"{path}: a TIFF of shape {tuple(series.shape)}, {series.size} values, more than "
                                f"the {MAX_TIFF_VALUES} that lfsf reads")
            return np.asarray(tif.asarray(series=0))
    except (_TooLarge, MemoryError):
        raise
    except Exception as first:   # noqa: BLE001 - Pillow's try; tifffile's error is the one said
        f.seek(0)
        try:
            with warnings.catch_warnings():   # (Pillow's "Corrupt EXIF data" of a truncated file)
                warnings.simplefilter("ignore")
                with Image.open(f) as image:
                    pages = getattr(image, "n_frames", 1)
                f.seek(0)
                if pages == 1:   # (of a stack, Pillow would give the first page alone)
                    return np.asarray(iio.imread(f, plugin="pillow"))
        except Exception:   # noqa: BLE001
            pass
        raise first from None


@contextlib.contextmanager
def _log_lines(name: str, lines: list):
    """Within the block, what the logger ``name`` says at WARNING or above goes into
    ``lines`` instead of stderr (one such block at a time, in any thread)."""
    import logging

    class Keep(logging.Handler):
        def emit(self, record):
            lines.append(record.getMessage())

    with _LOG_LINES_LOCK:
        logger = logging.getLogger(name)
        keep, propagate = Keep(logging.WARNING), logger.propagate
        logger.addHandler(keep)
        logger.propagate = False
        try:
            yield
        finally:
            logger.removeHandler(keep)
            logger.propagate = propagate


_LOG_LINES_LOCK = threading.Lock()


def write_png(path: str | os.PathLike, array) -> None:
    """Write an image as PNG atomically.

    Parameters
    ----------
    path : str or path-like
    array : array_like, shape (H, W) or (H, W, C), C = 1 (grey), 2 (grey + alpha),
        3 (RGB) or 4 (RGBA)
        uint8 and uint16 are written as 8-bit and 16-bit PNG; bool as 0/255; float
        values in [0, 1] as 8-bit (clipped, rounded).

    Raises
    ------
    ValueError
        For another dtype, a non-finite float value, or an unsupported shape.
    """
    image = np.asarray(array)
    if image.dtype == bool:
        image = image.astype(np.uint8) * np.uint8(255)
    elif image.dtype.kind == "f":
        if not np.isfinite(image).all():
            raise ValueError(f"{path}: expected finite values to write as PNG, got NaN or infinity")
        image = np.rint(np.clip(image, 0.0, 1.0) * 255.0).astype(np.uint8)
    elif image.dtype.kind == "u" and image.dtype.itemsize == 2 and not image.dtype.isnative:
        image = image.astype(np.uint16)              # big-endian samples: the values are what count
    elif image.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"{path}: expected a uint8, uint16, bool or float image, got {image.dtype}")
    write_bytes_atomic(path, encode_png(image, source=str(path)))


def _png_chunk(kind: bytes, body: bytes) -> bytes:
    return (struct.pack(">I", len(body)) + kind + body
            + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF))


def encode_png(image, *, compress_level: int = 6, source: str = "encode_png") -> bytes:
    """Encode an image as PNG bytes (non-interlaced).

    Parameters
    ----------
    image : array_like, uint8 or uint16, shape (H, W) or (H, W, C) with C in 1 … 4
        Grey, grey + alpha, RGB or RGBA; the dtype gives the bit depth (8 or 16).
    compress_level : int
        zlib level, 0 … 9.
    source : str
        Name for error messages.

    Notes
    -----
    Every row uses the "Up" filter: cheap to compute and good on smooth images.
    """
    image = np.asarray(image)
    if image.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"{source}: expected a uint8 or uint16 image, got {image.dtype}")
    if image.ndim == 2:
        image = image[..., None]
    if image.ndim != 3 or image.shape[2] not in _PNG_COLOUR_TYPE:
        raise ValueError(f"{source}: expected an image of shape (H, W) or (H, W, C) with C in "
                         f"1 … 4, got {image.shape}")
    height, width, channels = image.shape
    level = whole(compress_level)
    if level is None or not -1 <= level <= 9:  # (−1: zlib's default, 6)
        raise ValueError(f"{source}: compress_level must be a whole number −1…9, got {compress_level!r}")
    if not (1 <= height < 2 ** 31 and 1 <= width < 2 ** 31):
        raise ValueError(f"{source}: expected a non-empty image, got shape {image.shape}")
    depth = 8 * image.dtype.itemsize
    rows = np.ascontiguousarray(image, dtype=">u2" if depth == 16 else np.uint8)
    rows = rows.view(np.uint8).reshape(height, -1)
    scanlines = np.empty((height, rows.shape[1] + 1), dtype=np.uint8)
    scanlines[:, 0] = 2                                  # filter type "Up"
    scanlines[0, 1:] = rows[0]                           # the row above the first is zero
    np.subtract(rows[1:], rows[:-1], out=scanlines[1:, 1:])
    compressed = zlib.compress(scanlines.tobytes(), level)
    ihdr = struct.pack(">IIBBBBB", width, height, depth, _PNG_COLOUR_TYPE[channels], 0, 0, 0)
    step = 1 << 30                                       # chunks hold at most 2³¹ − 1 bytes
    idat = b"".join(_png_chunk(b"IDAT", compressed[i:i + step])
                    for i in range(0, len(compressed), step))
    return _PNG_SIGNATURE + _png_chunk(b"IHDR", ihdr) + idat + _png_chunk(b"IEND", b"")


def decode_png(data: bytes, source: str = "<bytes>") -> np.ndarray:
    """Decode PNG bytes: 8- or 16-bit grey, grey + alpha, RGB or RGBA, Adam7 or not.

    Parameters
    ----------
    data : bytes
        The whole file.
    source : str
        Name for error messages.

    Returns
    -------
    numpy.ndarray, uint8 or uint16, shape (H, W) or (H, W, C)
        Samples as stored; ancillary chunks (gamma, transparency, …) are ignored.

    Raises
    ------
    ValueError
        For a bad signature or CRC, missing or truncated chunks or image data, or a
        palette or sub-byte format (those are left to Pillow).
    """
    if not data.startswith(_PNG_SIGNATURE):
        raise ValueError(f"{source}: not a PNG file (bad signature {data[:8]!r})")
    header = None
    idat = []
    pos = len(_PNG_SIGNATURE)
    while True:
        if pos + 8 > len(data):
            raise ValueError(f"{source}: truncated PNG: ends at byte {len(data)} without an "
                             f"IEND chunk")
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        end = pos + 12 + length
        if end > len(data):
            raise ValueError(f"{source}: truncated PNG: chunk {kind!r} at byte {pos} needs "
                             f"{12 + length} bytes, {len(data) - pos} left")
        body = data[pos + 8:end - 4]
        (crc,) = struct.unpack(">I", data[end - 4:end])
        if zlib.crc32(kind + body) & 0xFFFFFFFF != crc:
            raise ValueError(f"{source}: corrupt PNG: CRC mismatch in chunk {kind!r} at byte {pos}")
        if kind == b"IHDR":
            if length != 13:
                raise ValueError(f"{source}: corrupt PNG: IHDR of {length} bytes, expected 13")
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
        pos = end
    if header is None or not idat:
        raise ValueError(f"{source}: corrupt PNG: missing {'IHDR' if header is None else 'IDAT'}")
    width, height, depth, colour_type, compression, filtering, interlace = header
    if colour_type not in _PNG_CHANNELS or depth not in (8, 16):
        raise ValueError(f"{source}: unsupported PNG: bit depth {depth}, colour type "
                         f"{colour_type} (this decoder reads 8- and 16-bit grey, grey + alpha, "
                         f"RGB and RGBA)")
    if compression != 0 or filtering != 0 or interlace not in (0, 1) or width < 1 or height < 1:
        raise ValueError(f"{source}: corrupt PNG header: size {width}×{height}, compression "
                         f"{compression}, filter method {filtering}, interlace {interlace}")
    if width * height > MAX_PNG_PIXELS:
        raise ValueError(f"{source}: a PNG of {width}×{height} pixels, more than the {MAX_PNG_PIXELS} that lfsf reads "
                         "(as Pillow does; a light field's views or a camera's raw image are far fewer)")
    channels = _PNG_CHANNELS[colour_type]
    bpp = channels * depth // 8                          # bytes per pixel
    # the bytes the header promises, filter bytes included; no more is decompressed, and
    # nothing is allocated for the image before they are there (a 70-byte file may claim
    # 100000×100000 pixels, and a small IDAT may inflate without end)
    passes = [(width, height)] if interlace == 0 else [
        (-(-(width - x0) // dx) if width > x0 else 0, -(-(height - y0) // dy) if height > y0 else 0)
        for x0, y0, dx, dy in _ADAM7]
    expected = sum(h * (w * bpp + 1) for w, h in passes if w and h)
    try:
        raw = zlib.decompressobj().decompress(b"".join(idat), expected)
    except zlib.error as err:
        raise ValueError(f"{source}: corrupt PNG image data ({err})") from err
    if len(raw) < expected:
        raise ValueError(f"{source}: truncated PNG image data: expected {expected} bytes for "
                         f"{width}×{height} pixels, got {len(raw)}")
    if interlace == 0:
        pixels, _ = _unfilter_pass(raw, 0, width, height, bpp, source)
        pixels = pixels.reshape(height, width, bpp)
    else:
        pixels = np.empty((height, width, bpp), dtype=np.uint8)
        offset = 0
        for (x0, y0, dx, dy), (pass_width, pass_height) in zip(_ADAM7, passes):
            if pass_width == 0 or pass_height == 0:
                continue                                 # an empty pass has no bytes at all
            block, offset = _unfilter_pass(raw, offset, pass_width, pass_height, bpp, source)
            pixels[y0::dy, x0::dx] = block.reshape(pass_height, pass_width, bpp)
    if depth == 16:
        samples = pixels.view(">u2").astype(np.uint16)
    else:
        samples = pixels
    samples = samples.reshape(height, width, channels)
    return samples[..., 0] if channels == 1 else samples


def _unfilter_pass(raw: bytes, offset: int, width: int, height: int, bpp: int,
                   source: str) -> tuple[np.ndarray, int]:
    """Reconstruct one (sub-)image's scanlines starting at ``raw[offset]``; returns the
    (height, width·bpp) bytes and the offset after them."""
    stride = width * bpp
    needed = height * (stride + 1)
    if len(raw) - offset < needed:
        raise ValueError(f"{source}: truncated PNG image data: expected {needed} bytes for "
                         f"{width}×{height} pixels, got {len(raw) - offset}")
    block = np.frombuffer(raw, dtype=np.uint8, count=needed, offset=offset)
    block = block.reshape(height, stride + 1)
    filters, filtered = block[:, 0], block[:, 1:]
    if filters.max() > 4:
        row = int(np.argmax(filters > 4))
        raise ValueError(f"{source}: corrupt PNG: unknown filter type {filters[row]} in row {row}")
    return _unfilter(filtered, filters, bpp), offset + needed


def _unfilter(filtered: np.ndarray, filters: np.ndarray, bpp: int) -> np.ndarray:
    """Undo the PNG row filters (None, Sub, Up, Average, Paeth) of an image.

    None, Sub and Up vectorise along a row, so images using only those are done row by
    row. Average and Paeth depend on the reconstructed left neighbour, which makes each row
    sequential; those images are swept along anti-diagonals instead (a wavefront), where
    every pixel's left, upper and upper-left neighbours are already known.
    """
    height, stride = filtered.shape
    if filters.max() <= 2:
        out = np.empty_like(filtered)
        previous = np.zeros(stride, dtype=np.uint8)
        for r in range(height):
            kind = filters[r]
            if kind == 0:
                out[r] = filtered[r]
            elif kind == 1:     # uint8 arithmetic wraps modulo 256, as the format wants
                out[r] = np.cumsum(filtered[r].reshape(-1, bpp), axis=0, dtype=np.uint8).ravel()
            else:
                np.add(filtered[r], previous, out=out[r])
            previous = out[r]
        return out
    width = stride // bpp
    # A band of h rows takes about 4·bpp·h·(h + width) bytes of int16 work arrays.
    per_row = _WAVEFRONT_BAND_BYTES / (4 * bpp)
    band = max(1, min(height, int((math.sqrt(width * width + 4 * per_row) - width) / 2)))
    out = np.empty_like(filtered)
    previous = np.zeros(stride, dtype=np.uint8)
    for r0 in range(0, height, band):
        r1 = min(height, r0 + band)
        out[r0:r1] = _unfilter_wavefront(filtered[r0:r1], filters[r0:r1], previous, bpp)
        previous = out[r1 - 1]
    return out


def _unfilter_wavefront(filtered: np.ndarray, filters: np.ndarray, previous: np.ndarray,
                        bpp: int) -> np.ndarray:
    """Unfilter a band of rows, any filter types, given the reconstructed row above it.

    Pixels are stored skewed, pixel (r, i) at column d = r + i, so that anti-diagonal d is
    one column: ``recon[r + 1, d + 2]`` holds pixel (r, i), with a zero row and columns of
    padding for the neighbours outside the image, and row 0 holding ``previous``.
    """
    height, stride = filtered.shape
    width = stride // bpp
    diagonals = height + width - 1
    r = np.arange(height)[:, None]
    i = np.arange(width)[None, :]
    skewed = np.zeros((height, diagonals, bpp), dtype=np.int16)
    skewed[r, r + i] = filtered.reshape(height, width, bpp)
    recon = np.zeros((height + 1, diagonals + 2, bpp), dtype=np.int16)
    recon[0, 1:width + 1] = previous.reshape(width, bpp)
    kinds = filters.astype(np.intp)[:, None, None]
    zero = np.zeros((1, 1), dtype=np.int16)
    for d in range(diagonals):
        lo, hi = max(0, d - width + 1), min(height, d + 1)         # rows on this diagonal
        left = recon[lo + 1:hi + 1, d + 1]
        up = recon[lo:hi, d + 1]
        up_left = recon[lo:hi, d]
        estimate = left + up - up_left
        dist_left = np.abs(estimate - left)
        dist_up = np.abs(estimate - up)
        dist_up_left = np.abs(estimate - up_left)
        paeth = np.where((dist_left <= dist_up) & (dist_left <= dist_up_left), left,
                         np.where(dist_up <= dist_up_left, up, up_left))
        average = (left + up) >> 1
        predictor = np.choose(kinds[lo:hi, 0], (zero, left, up, average, paeth))
        recon[lo + 1:hi + 1, d + 2] = (skewed[lo:hi, d] + predictor) & 0xFF
    return recon[r + 1, r + i + 2].astype(np.uint8).reshape(height, stride)
