"""Peer methods, wrapped so that their outputs are in lfsf's conventions (``help(lfsf)``, MODEL.md §1).

Used by ``scripts/compare_peers.py`` (the acceptance comparison) and ``lfsf bench peers``, and checked by
``tests/test_peers.py``. Needs the ``peers`` extra (``pip install -e '.[peers]'``):
OpenCV contrib, scikit-image and plenpy. Each peer is imported only when its wrapper is
first called, so this module imports without them.

Conventions (``help(lfsf)``, MODEL.md §1), which every wrapper returns:

* flow ``(u, v)``, float32 H×W: the point seen at pixel ``p`` of the first image is seen
  at ``p + (u, v)`` in the second image (x to the right, y down), i.e.
  ``c1(p) ≈ c2(p + u)``;
* disparity ``δ``, float32 H×W, pixels per view step: the point seen at centre pixel
  ``p`` appears in the view at angular offset ``φ = (ξ, η) = (col − c, row − c)`` at
  ``p − δ·φ``.

How each peer's own convention was established is written in its wrapper's docstring;
``python -m lfsf.peers`` re-runs those checks and prints the numbers.

Timing: :func:`timed` returns ``(result, seconds)`` of any call (wall clock,
``time.perf_counter``); the comparison script times every peer call with it.
"""

from __future__ import annotations

import logging
import sys
import time
import warnings

import numpy as np

#: The package that installs each peer of ``lfsf bench peers``, and the extra that installs
#: them all from the lfsf checkout (which the extra needs): what the line of a peer not
#: installed says to do.
PEER_PACKAGES = {"opencv DualTVL1": "opencv-contrib-python-headless", "skimage TV-L1": "scikit-image"}
PEERS_EXTRA_HINT = "(or pip install -e '.[peers]' in the lfsf checkout)"

#: ITU-R BT.601 luma weights, as ``lfsf.io.LightField.grey`` uses.
_LUMA = np.asarray((0.299, 0.587, 0.114), dtype=np.float32)


def timed(fn, *args, **kwargs):
    """Call ``fn(*args, **kwargs)``; return ``(result, wall-clock seconds)``."""
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


def _unit_float32(values, name: str, what: str) -> np.ndarray:
    """``values`` as float32 in [0, 1] as :class:`lfsf.LightField` takes them: integers
    scaled by their type's maximum (uint8 ÷ 255, uint16 ÷ 65535; wider ones refused),
    floats as they are. ValueError where floats lie far outside [0, 1], for every peer:
    OpenCV's input is quantised from [0, 1] to 8 bits, so 0…255 had been clipped to an
    image of 255s (zero flow); scikit-image's TV-L1 weighs its data term by the
    intensities' scale (0…255: (1.33, −0.64) for a shift of (1.3, −0.7)); plenpy's
    structure tensor alone does not mind the scale."""
    from lfsf.estimate import far_outside_unit
    from lfsf.io import _to_unit_float32, refuse_wide_integers

    a = np.asarray(values)
    if a.dtype.kind not in "biuf":
        raise ValueError(f"{name}: expected real-valued pixels, got dtype {a.dtype}")
    refuse_wide_integers(a, name, what)
    a = _to_unit_float32(a)  # (float32, integers and bools too)
    far = far_outside_unit(a)
    if far:
        raise ValueError(f"{name}: values {far[0]:.4g}…{far[1]:.4g}, where the peers take [0, 1]: divide 8-bit "
                         "values by 255 (or give them as uint8), 16-bit ones by 65535")
    return a


def _grey_image(img, name: str) -> np.ndarray:
    """H×W float32 grey image in [0, 1] (:func:`_unit_float32`); an H×W×3 colour image is
    turned into BT.601 luma."""
    a = _unit_float32(img, name, "pixels")
    if a.ndim == 3 and a.shape[2] == 3:
        a = a @ _LUMA
    if a.ndim != 2:
        raise ValueError(f"{name}: expected an H×W grey (or H×W×3) image, got shape {a.shape}")
    return a


def _grey_views(views) -> np.ndarray:
    """[a, b, y, x] float32 grey views in [0, 1] (:func:`_unit_float32`); [a, b, y, x, 3]
    colour views become BT.601 luma."""
    v = _unit_float32(getattr(views, "views", views), "views", "views")
    if v.ndim == 5 and v.shape[4] == 3:
        v = v @ _LUMA
    if v.ndim == 5 and v.shape[4] == 1:
        v = v[..., 0]
    if v.ndim != 4:
        raise ValueError(f"expected views [a, b, y, x] (grey) or [a, b, y, x, 3], got shape {v.shape}")
    return v


def _check_pair(c1, c2):
    c1 = _grey_image(c1, "c1")
    c2 = _grey_image(c2, "c2")
    if c1.shape != c2.shape:
        raise ValueError(f"the two images differ in shape: {c1.shape} and {c2.shape}")
    return c1, c2


# --------------------------------------------------------------------------- optical flow

#: Getters of the parameters of cv2.optflow.DualTVL1OpticalFlow, recorded by the comparison.
_OPENCV_TVL1_GETTERS = {"tau": "getTau", "lambda": "getLambda", "theta": "getTheta",
                        "nscales": "getScalesNumber", "warps": "getWarpingsNumber",
                        "epsilon": "getEpsilon", "innerIterations": "getInnerIterations",
                        "outerIterations": "getOuterIterations", "scaleStep": "getScaleStep",
                        "gamma": "getGamma", "medianFiltering": "getMedianFiltering",
                        "useInitialFlow": "getUseInitialFlow"}


def _opencv_dual_tvl1():
    """A default ``cv2.optflow.DualTVL1OpticalFlow_create()``. ImportError where OpenCV is
    missing, or installed without its contrib modules (``opencv-python`` has no
    ``cv2.optflow``), so that a caller that skips a peer it lacks skips this one too."""
    import cv2

    optflow = getattr(cv2, "optflow", None)
    if optflow is None or not hasattr(optflow, "DualTVL1OpticalFlow_create"):
        raise ImportError(f"OpenCV {getattr(cv2, '__version__', '')} lacks its contrib modules (cv2.optflow): "
                          "pip install opencv-contrib-python-headless")
    return optflow.DualTVL1OpticalFlow_create()


def opencv_tvl1_parameters() -> dict:
    """The parameters of a default ``cv2.optflow.DualTVL1OpticalFlow_create()``."""
    tv = _opencv_dual_tvl1()
    out = {}
    for name, getter in _OPENCV_TVL1_GETTERS.items():
        if hasattr(tv, getter):
            value = getattr(tv, getter)()
            out[name] = value if isinstance(value, (bool, int, float)) else float(value)
    return out


def opencv_tvl1(c1, c2) -> tuple[np.ndarray, np.ndarray]:
    """Optical flow by OpenCV's Dual TV-L1 (Zach, Pock & Bischof 2007; Wedel et al. 2009),
    ``cv2.optflow.DualTVL1OpticalFlow_create()`` with its defaults.

    Input: two H×W grey images in [0, 1], or uint8 or uint16 (scaled by their type's
    maximum); H×W×3 colour is turned into BT.601 luma. They are quantised to 8 bits,
    ``(img*255).round().astype(np.uint8)`` (clipped to [0, 1] first), as the comparison
    prescribes. Floats far outside [0, 1] are refused (0…255 would be clipped to 255s).

    Output: ``(u, v)``, float32 H×W, in lfsf's convention ``c1(p) ≈ c2(p + (u, v))``.
    OpenCV returns an H×W×2 array ``flow[..., 0] = u`` (x), ``flow[..., 1] = v`` (y) that
    is already in this convention: no sign change, no swap.

    Check: ``c2(q) = c1(q − (1.3, −0.7))`` (a textured image shifted by u = +1.3,
    v = −0.7, cubic interpolation) gives a mean flow of (+1.27, −0.73) inside a 10-px
    border (``python -m lfsf.peers``; ``tests/test_peers.py`` repeats it).

    OpenCV runs this on all cores (its own thread pool).
    """
    tv = _opencv_dual_tvl1()
    c1, c2 = _check_pair(c1, c2)
    q1 = (np.clip(c1, 0.0, 1.0) * 255).round().astype(np.uint8)
    q2 = (np.clip(c2, 0.0, 1.0) * 255).round().astype(np.uint8)
    flow = tv.calc(q1, q2, None)
    return (np.ascontiguousarray(flow[..., 0], dtype=np.float32),
            np.ascontiguousarray(flow[..., 1], dtype=np.float32))


def skimage_tvl1(c1, c2) -> tuple[np.ndarray, np.ndarray]:
    """Optical flow by scikit-image's TV-L1,
    ``skimage.registration.optical_flow_tvl1(c1, c2)`` with its defaults.

    Input: two H×W grey float images in [0, 1], or uint8 or uint16 (scaled by their type's
    maximum); H×W×3 colour is turned into BT.601 luma. Passed as float32 without
    quantisation. Floats far outside [0, 1] are refused (:func:`_unit_float32`).

    Output: ``(u, v)``, float32 H×W, in lfsf's convention ``c1(p) ≈ c2(p + (u, v))``.
    scikit-image returns a (2, H, W) array ordered **(row, col) = (v, u)**; its sign is
    already lfsf's: the flow is such that ``moving_image`` (c2) warped by it — sampled at
    ``p + flow`` — matches ``reference_image`` (c1). So the wrapper only swaps the order.

    Check: ``c2(q) = c1(q − (1.3, −0.7))`` gives ``flow[0]`` ≈ −0.70 (v) and ``flow[1]``
    ≈ +1.31 (u) in the mean inside a 10-px border (``python -m lfsf.peers``;
    ``tests/test_peers.py`` repeats it).

    Single-threaded NumPy/SciPy.
    """
    from skimage.registration import optical_flow_tvl1

    c1, c2 = _check_pair(c1, c2)
    flow = optical_flow_tvl1(c1, c2)
    return (np.ascontiguousarray(flow[1], dtype=np.float32),
            np.ascontiguousarray(flow[0], dtype=np.float32))


# --------------------------------------------------------------------------- disparity

def import_plenpy_lightfield():
    """``plenpy.lightfields.LightField``, imported quietly.

    plenpy 0.9.2 (the latest release) imports and runs with Python 3.11, NumPy 2.4,
    SciPy 1.17 and imageio 2.38, but it uses deprecated names: ``numpy.core.multiarray``
    (a NumPy 2 alias that warns), ``scipy.ndimage.filters`` (SciPy says it goes in SciPy
    2.0), ``imageio.formats.sort`` (goes in imageio v3), and ``np.int`` in
    ``_get_disparity_brute_force_4d`` only (NumPy ≥ 1.24 removed it; not used here). The
    import silences those DeprecationWarnings, and if ``scipy.ndimage.filters`` is ever
    gone it aliases it to ``scipy.ndimage`` (the only names plenpy takes from it,
    ``gaussian_filter`` and ``convolve``, live there). plenpy also logs every step at
    INFO on the root logger's handler; its logger is set to WARNING here. And its import
    reorders imageio's plugins for every caller (``imageio.formats.sort('PNG-FI')``,
    ``('-FI', '-PIL')``): lfsf's own reading of views after it had failed on grey views
    with alpha (KeyError) and named TIFF errors otherwise. The order is put back.
    """
    try:
        import scipy.ndimage.filters  # noqa: F401
    except ImportError:  # SciPy >= 2.0: give plenpy back the old module name
        import scipy.ndimage

        sys.modules["scipy.ndimage.filters"] = scipy.ndimage
    from imageio.config import known_extensions, known_plugins

    plugins = dict(known_plugins)  # (in their order)
    priorities = [(extension, list(extension.priority)) for listed in known_extensions.values()
                  for extension in listed]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            import plenpy.logg  # sets the "plenpy" logger to INFO; quieten it before the rest

            logging.getLogger("plenpy").setLevel(logging.WARNING)
            from plenpy.lightfields import LightField
    finally:
        known_plugins.clear()
        known_plugins.update(plugins)
        for extension, priority in priorities:
            extension.priority[:] = priority
    return LightField


def plenpy_disparity(views, *, nan_guard: bool = True) -> np.ndarray:
    """Disparity of the centre view by plenpy's structure-tensor EPI method fused by TV-L1:
    ``plenpy.lightfields.LightField(views[..., None]).get_disparity(
    method="structure_tensor", fusion_method="tv_l1")``, defaults otherwise.

    Input: ``views[a, b, y, x]`` grey float in [0, 1] (or uint8 / uint16; floats far
    outside [0, 1] are refused, as by the other wrappers) on a grid of at
    least 3×3 (a = view row, b = view column, as ``help(lfsf)``, MODEL.md §1), or colour
    ``[a, b, y, x, 3]`` (turned into BT.601 luma first), or an ``lfsf.io.LightField``.
    plenpy's axes ``(u, v, s, t, ch)`` are then exactly ours
    ``(a, b, y, x, 1)``: its horizontal EPIs are ``L[u_c, :, s, :]`` (view column × x),
    its vertical ones ``L[:, v_c, :, t]`` (view row × y). Check: a plane with δ = 1 gives
    0.94 in this layout and −0.18 with only the image axes swapped.

    Output: float32 H×W in lfsf's convention (px per view step, the sign of ``help(lfsf)``, MODEL.md §1).
    **Conversion rule: identity.** plenpy's output is already in our sign and unit:

    * source (``plenpy/lightfields.py``, ``_estimate_orientation_structure_tensor`` and
      ``_get_disparity_structure_tensor``): the slope of the EPI lines is measured in
      EPI index units, i.e. pixels per view index, along the centre row and centre
      column of views, and returned negated; nothing scales it by the grid size or by an
      angular spacing, so the unit is px per view step;
    * synthetic check (``python -m lfsf.peers``): a 9×9 light field made by sampling
      one textured image at ``p + δ·φ`` (so the point of centre pixel p is at p − δφ),
      for δ = ±0.1 … ±2.5, gives medians of 0.93δ … 0.97δ, same sign, both EPI
      directions agreeing; on HCI antinous (ground truth in our convention) the
      least-squares slope of plenpy against the truth is +0.94.

    The 3–7 % shortfall on a 9×9 grid (22–30 % on 5×5) is plenpy's own bias, not a unit:
    its EPIs are Gaussian-smoothed (σ 0.75, then σ 2 for the structure tensor) across
    only 9 views with mirror boundaries, which flattens the lines; it depends on δ and
    on the texture. It is left in (no per-scene or per-grid rescaling).

    ``nan_guard`` (default on): plenpy's structure tensor divides 0 by 0 on EPIs that are
    exactly flat (e.g. the black, 8-bit-clipped areas of the Lytro views): on the Lytro
    scene 1794 of the 2 × 211 416 EPI estimates are NaN (one is infinite), both at 419
    pixels; its TV-L1 fusion starts from ``nanmean`` of the two, which is NaN there, and
    the NaN spreads by a pixel per iteration (100 iterations): 29 751 of the 211 416
    output pixels come out NaN. With the guard
    on, the same computation is done in two steps — ``get_disparity(...,
    fusion_method="no_fusion", vmin=-inf, vmax=inf)``, then plenpy's own fusion
    ``denoise_multi_images_tvl1(disp, n_iter=100, w_lambdas=normalised confidence)`` and
    the clip to [−3, 3], exactly as ``get_disparity`` does — except that at pixels where
    *every* estimate is non-finite the estimates are set to 0 with confidence 0 (so the
    TV term fills them in, as the fusion intends for zero-confidence data), and an
    infinite estimate (non-zero / 0 in the same formula) is treated as NaN with
    confidence 0 (plenpy's fusion already skips NaN data through ``nansum``; an infinite
    one would make its start ``nanmean`` infinite and spread NaN the same way). Where no such
    pixel exists the result is bit-identical to the one-call version (checked on the
    four synthetic scenes); on Lytro it differs only where the one-call version is NaN.
    ``nan_guard=False`` is the literal one-call version.

    plenpy clips its output to [vmin, vmax] = [−3, 3] (its defaults, kept). It uses only
    the centre row and column of views (2 × grid − 1 of them). Single-threaded NumPy:
    ~0.06 s at 80×64, ~0.13 s at 160×120, ~2.5 s at 512×512 (9×9 views) on this
    project's 2-core CPU.
    """
    LightField = import_plenpy_lightfield()
    v = _grey_views(views)
    if min(v.shape[:2]) < 3:
        # (one row of views gives its vertical EPIs a single line: a map of noise, no error)
        raise ValueError(f"plenpy's EPIs need at least 3 views along each axis of the grid, got "
                         f"{v.shape[0]}×{v.shape[1]}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        warnings.simplefilter("ignore", RuntimeWarning)  # 0/0 in its structure tensor
        lf = LightField(v[..., None])
        if not nan_guard:
            disp, _conf = lf.get_disparity(method="structure_tensor", fusion_method="tv_l1")
            return np.ascontiguousarray(disp, dtype=np.float32)
        from plenpy.utilities import denoise

        disp_all, conf_all = lf.get_disparity(method="structure_tensor", fusion_method="no_fusion",
                                              vmin=-np.inf, vmax=np.inf)
        disp_all = np.asarray(disp_all, dtype=np.float64)
        conf_all = np.asarray(conf_all, dtype=np.float64)
        bad = ~np.isfinite(disp_all)
        if bad.any():
            disp_all = disp_all.copy()
            conf_all = conf_all.copy()
            disp_all[bad] = np.nan  # ±inf (0 denominator): no measurement, like NaN
            conf_all[bad] = 0.0
            hopeless = bad.all(axis=-1)
            disp_all[hopeless] = 0.0
        # below: get_disparity's "tv_l1" branch and final clip, verbatim (plenpy 0.9.2)
        confidence_norm = (conf_all - conf_all.min()) / (conf_all.max() - conf_all.min())
        disp = denoise.denoise_multi_images_tvl1(disp_all, n_iter=100, w_lambdas=confidence_norm)
        disp = np.clip(disp, -3, 3)
    return np.ascontiguousarray(disp, dtype=np.float32)


def sample_bilinear(img, x, y) -> np.ndarray:
    """``img`` sampled at real positions ``(x, y)`` (same shape arrays), bilinear,
    clamped at the border. Used to bring a t2 disparity map to lfsf's δ2 convention:
    ``δ2(p) = D2(p + u(p))``."""
    from scipy.ndimage import map_coordinates

    img = np.asarray(img, dtype=np.float64)
    out = map_coordinates(img, [np.asarray(y, np.float64), np.asarray(x, np.float64)],
                          order=1, mode="nearest")
    return out.astype(np.float32)


def disparity_at_t1_pixels(disp_t2_map, u, v) -> np.ndarray:
    """lfsf's δ2 from a disparity map of the t2 centre view: ``δ2(p) = D2(p + (u, v))``,
    bilinear, clamped. ``(u, v)`` is a flow in lfsf's convention (ground truth for the
    oracle comparison, or a peer's flow)."""
    h, w = np.shape(disp_t2_map)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    return sample_bilinear(disp_t2_map, xx + np.asarray(u), yy + np.asarray(v))


# --------------------------------------------------------------------------- versions

def versions() -> dict:
    """Versions of the peers (and of NumPy/SciPy) that are importable."""
    from importlib import metadata

    out = {"python": sys.version.split()[0]}
    for dist in ("numpy", "scipy", "opencv-contrib-python-headless", "scikit-image", "plenpy"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = None
    return out


# --------------------------------------------------------------------------- synthetic checks

def texture(height: int, width: int, *, seed: int = 0, sigma: float = 1.5, pad: int = 32):
    """A smooth random texture in [0, 1] of ``(height + 2 pad) × (width + 2 pad)``."""
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(seed)
    t = gaussian_filter(rng.random((height + 2 * pad, width + 2 * pad)), sigma)
    return (t - t.min()) / (t.max() - t.min())


def _sample(tex, x, y, pad):
    from scipy.ndimage import map_coordinates

    return map_coordinates(tex, [y + pad, x + pad], order=3, mode="reflect")


def shifted_pair(u: float, v: float, size=(64, 48), *, seed: int = 0, pad: int = 32):
    """Two float32 images ``c1, c2`` (H×W, size = (W, H)) with ``c2(q) = c1(q − (u, v))``:
    every point moves by ``(u, v)``, i.e. lfsf flow ``(u, v)`` everywhere."""
    w, h = size
    tex = texture(h, w, seed=seed, pad=pad)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    c1 = _sample(tex, xx, yy, pad)
    c2 = _sample(tex, xx - u, yy - v, pad)
    return (np.clip(c1, 0, 1).astype(np.float32), np.clip(c2, 0, 1).astype(np.float32))


def constant_disparity_views(delta: float, grid: int = 9, size=(64, 48), *, seed: int = 0,
                             pad: int = 32, sigma: float = 1.5):
    """Grey views [a, b, y, x] (float32) of a fronto-parallel textured plane with constant
    disparity ``delta`` in lfsf's convention: ``view(φ)(q) = T(q + δφ)``, so the point of
    centre pixel p (``T(p)``) is seen in view φ at ``p − δφ``."""
    w, h = size
    tex = texture(h, w, seed=seed, pad=pad, sigma=sigma)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    c = (grid - 1) / 2
    views = np.empty((grid, grid, h, w), np.float32)
    for a in range(grid):
        for b in range(grid):
            views[a, b] = _sample(tex, xx + delta * (b - c), yy + delta * (a - c), pad)
    return np.clip(views, 0, 1)


def _selfcheck() -> None:
    """Print the convention checks quoted in the docstrings."""
    import_plenpy_lightfield()  # import once, outside the timings
    inner = (slice(10, -10), slice(10, -10))
    print("versions:", versions())
    c1, c2 = shifted_pair(1.3, -0.7, size=(80, 64))
    for name, fn in (("opencv_tvl1", opencv_tvl1), ("skimage_tvl1", skimage_tvl1)):
        (u, v), s = timed(fn, c1, c2)
        print(f"{name}: true (u, v) = (+1.30, -0.70); mean in 10-px border "
              f"({u[inner].mean():+.3f}, {v[inner].mean():+.3f}); {s:.3f} s")
    from skimage.registration import optical_flow_tvl1

    raw = optical_flow_tvl1(c1, c2)
    print(f"  raw skimage output: flow[0] mean {raw[0][inner].mean():+.3f}, "
          f"flow[1] mean {raw[1][inner].mean():+.3f}  (so flow = (v, u), lfsf sign)")
    for grid in (9, 5):
        for delta in (0.1, 0.5, 1.0, 2.0, -2.0, 2.5):
            views = constant_disparity_views(delta, grid, size=(80, 64))
            d, s = timed(plenpy_disparity, views)
            med = float(np.median(d[inner]))
            print(f"plenpy_disparity grid {grid}x{grid}: true δ {delta:+.2f}, median {med:+.4f} "
                  f"(ratio {med / delta:.3f}), std {d[inner].std():.4f}; {s:.3f} s")
    # Axes: with only the image axes transposed (y <-> x, not a <-> b), points move along
    # x with the view row: not a light field, and plenpy must then see flat EPIs (≈ 0).
    # That it finds δ for the proper layout and ≈ 0 for this one shows that its
    # (u, v, s, t) is our (a, b, y, x).
    views = constant_disparity_views(1.0, 9, size=(64, 64))
    good = np.median(plenpy_disparity(views)[inner])
    bad = np.median(plenpy_disparity(views.transpose(0, 1, 3, 2))[inner])
    print(f"plenpy axes check (δ = 1): proper layout {good:+.4f}, image axes swapped {bad:+.4f}")


if __name__ == "__main__":
    _selfcheck()
