"""Per-view gain fields: the brightness differences between the views of one capture.

A real camera's views of the same point differ in brightness by more than noise: the
lens's vignetting darkens the outer sub-apertures, most towards one side of the image,
and glossy surfaces look brighter from some directions. The data term compares views
(MODEL.md §3, ρ1 and ρ2), so such differences pull the disparities. The structure–texture
split removes part of them (the smooth structure it subtracts), but not all: on the HCI
scene its views, warped to the centre by the ground truth, still differ from it by 0.4–0.7
% of the range on the floor and up to 4 % on the wall (docs/accuracy.md).

:func:`view_gains` measures them: a quick stereo pilot on the t1 light field reduced to
about :data:`PILOT_SIZE` px gives the disparity; every view, warped to the centre by it,
is compared with the centre view, and its gain field is the local least-squares ratio
g = G_σ(C·W) / G_σ(W·W) over the pixels that match (|C − g'·W| small, g' the view's
median ratio and then the first fit; neither dark), G_σ a (three-pass box) Gaussian of
σ = ``Params.view_gain_sigma`` full-resolution px. Where the fields change the views by
more than :data:`GAIN_CHANGE` (:func:`gain_change`), the estimator multiplies each view
by its field at both times (the camera is the same); below it, as on rendered
Lambertian scenes, it leaves the views as they are. A field varies over tens of pixels,
far slower than the texture the data term matches, so it cannot encode a disparity;
where few pixels match it leans towards the view's median ratio.
"""

from __future__ import annotations

import math

import numpy as np

#: Longer side (px) of the pilot's views: the light field is box-averaged by the largest
#: whole factor that leaves at least this many pixels (HCI's 512 px: factor 3).
PILOT_SIZE = 160
#: A pixel takes part in a view's fit where it differs from the centre view by less than
#: this (intensities in [0, 1]; a mismatch: an occlusion, or the pilot's error) and both
#: are brighter than :data:`DARK`.
MATCH = 0.05
DARK = 0.02
#: Where the Gaussian weight of the matching pixels is below this fraction, the gain
#: leans towards the view's first, global gain (the median ratio), linearly to it at 0.
SUPPORT = 0.2
#: Fits: the first tests the matches on the view times its global gain, the next on the
#: view times the previous fit.
PASSES = 2
#: The gains are clipped to [1 / MAX_GAIN, MAX_GAIN].
MAX_GAIN = 1.25
#: The gains are used only where they change the views by more than this: the 95th
#: percentile of |g − 1| over the views' pixels (an 8-px border left out). Rendered
#: Lambertian scenes, whose views agree, gave 0.0005–0.0053 (the pilot's own error);
#: HCI antinous 0.0165, the Lytro scene 0.024, synthetic vignetting of k = 0.02 and 0.05
#: 0.017 and 0.038 (twenty-second session). Below it the estimate is that without them.
#: Over the views the samples read alone (:func:`sampled_views`, as the estimator now
#: measures it): HCI 0.0136 (37 of 81 views, `paper`), Lytro 0.0244 (45, `lytro`),
#: vignetting 0.012 and 0.027, `paper` clean 0.0040, `random-1/5/14` 0.0014–0.0048
#: (twenty-ninth session: :func:`fit_view_gains` of all views, then :func:`gain_change`
#: of the sampled ones): the same side of the threshold.
GAIN_CHANGE = 0.01
#: Views with fewer pixels than this along their shorter side are not fitted: there the
#: parallax spans much of the image and reads as gains. Rendered scenes of one
#: brightness (`paper` preset, 5 scenes) gave changes of 5–20 % at 24×18, 1.1–2.3 % on
#: 3 of 5 at 32×24 and 2 of 5 at 40×30, none above GAIN_CHANGE from 48×36 up (nor at
#: 320×40 and 40×200).
MIN_VIEW_SIZE = 40


def gain_change(gains: np.ndarray, border: int = 8) -> float:
    """How much the gain fields (…, h, w) change the views: the 95th percentile of
    |g − 1| over their pixels, ``border`` px left out at each edge where the fields are
    larger than four borders (:data:`GAIN_CHANGE`)."""
    g = np.asarray(gains)
    if border > 0 and min(g.shape[-2:]) > 4 * border:
        g = g[..., border:-border, border:-border]
    return float(np.percentile(np.abs(g - 1.0), 95.0))


def _box_widths(sigma: float, passes: int = 3) -> list[int]:
    """Odd widths of ``passes`` box filters whose variances, (b² − 1)/12 each, add up to
    about σ²: m passes of the odd width b just below the ideal one, the rest of b + 2."""
    ideal = math.sqrt(12.0 * sigma * sigma / passes + 1.0)
    lower = int(ideal)
    lower -= 1 - lower % 2  # odd, at most the ideal width
    lower = max(lower, 1)
    m = round((12.0 * sigma * sigma - passes * lower * lower - 4 * passes * lower - 3 * passes) / (-4.0 * lower - 4.0))
    m = min(max(m, 0), passes)
    return [lower] * m + [lower + 2] * (passes - m)


def box_blur(stack, sigma: float, device: str, spare=None):
    """A Gaussian blur of σ = ``sigma`` of every image of a (n, h, w) stack on the device
    (a Warp array, blurred in place; returned): three passes of box filters
    (:func:`_box_widths`: their variances add up to σ²) along the rows, then three along
    the columns, each pixel the mean of the box around it, the edges mirrored (the edge
    pixel repeated, as often as a wide box needs); on the CPU by running sums along each
    line (:func:`lfsf.kernels.gains.box_pass`). ``spare``: a Warp array of the same
    shape to work in (allocated where not given)."""
    from lfsf import device as _device
    from lfsf.kernels import gains as kernels

    wp = _device.warp()
    n, h, w = stack.shape
    work = wp.empty_like(stack) if spare is None else spare
    src, dst = stack, work
    for along_rows, lines, length in ((1, h, w), (0, w, h)):
        span, per_line = _device.row_span(device, length)
        for b in _box_widths(sigma):
            _device.launch_rows(kernels.box_pass, dim=(n * lines, per_line), inputs=[src, b // 2, along_rows, span],
                                outputs=[dst], device=device)
            src, dst = dst, src
    if src is not stack:  # (six passes: never, but the widths' count may change)
        wp.copy(stack, src)
    return stack


def _upsample(images: np.ndarray, factor: int, h: int, w: int) -> np.ndarray:
    """(n, hs, ws) images reduced by block means of ``factor`` back to (n, h, w):
    bilinear, each block's value at its centre, clamped at the edges (as two matrix
    products per image)."""
    def weights(size: int, small: int) -> np.ndarray:
        pos = np.clip((np.arange(size) + 0.5) / factor - 0.5, 0, small - 1)
        lo = np.minimum(pos.astype(np.int64), max(small - 2, 0))
        frac = pos - lo
        m = np.zeros((size, small), np.float32)
        m[np.arange(size), lo] += 1 - frac
        m[np.arange(size), np.minimum(lo + 1, small - 1)] += frac
        return m

    n, hs, ws = images.shape
    return weights(h, hs) @ images.astype(np.float32) @ weights(w, ws).T


def view_gains(views: np.ndarray, sigma: float, device: str | None = None) -> np.ndarray | None:
    """Gain fields (a, b, h, w), float32, by which to multiply each grey view of ``views``
    (a, b, h, w) so that it matches the centre view in brightness (module docstring);
    ``sigma``: their smoothness in px. The centre view (of an odd grid) keeps 1; on an
    even grid the reference is the mean of the views nearest the centre (four where both
    sides are even), each warped to it. None where the light field is too small for a
    pilot (under 16 px after the reduction), has a single view, or lies in one row or
    column. (:func:`fit_view_gains`, then :func:`full_gains`.)"""
    small, factor = fit_view_gains(views, sigma, device)
    if small is None:
        return None
    return full_gains(small, factor, *np.shape(views)[-2:])


def full_gains(small: np.ndarray, factor: int, h: int, w: int) -> np.ndarray:
    """The fields of :func:`fit_view_gains` (a, b, hs, ws) at the views' full size
    (a, b, h, w), float32."""
    rows, cols = small.shape[:2]
    flat = small.reshape(rows * cols, *small.shape[2:])
    full = _upsample(flat, factor, h, w) if factor > 1 else flat.astype(np.float32)
    return full.reshape(rows, cols, h, w)


def sampled_views(phis, rows: int, cols: int) -> list[int]:
    """The views (indices a·cols + b of a rows × cols grid) that the sub-aperture sampling
    at the angular offsets ``phis`` ((ξ, η) in view steps from the grid's centre) reads
    with a weight above 0, as :func:`lfsf.kernels.sampling.sample_subaperture` finds
    them: only their gains change the samples. The paper's 17 samples on a 9×9 grid read
    37 of the 81 views."""
    used = set()
    for xi, eta in np.asarray(phis, np.float32).reshape(-1, 2):
        a = min(max(np.float32(0.5) * np.float32(rows - 1) + eta, np.float32(0.0)), np.float32(rows - 1))
        b = min(max(np.float32(0.5) * np.float32(cols - 1) + xi, np.float32(0.0)), np.float32(cols - 1))
        a0, b0 = min(int(a), max(rows - 2, 0)), min(int(b), max(cols - 2, 0))
        fa, fb = float(a - a0), float(b - b0)
        for da, wa in ((0, 1.0 - fa), (1, fa)):
            for db, wb in ((0, 1.0 - fb), (1, fb)):
                if wa * wb > 0.0:
                    used.add(min(a0 + da, rows - 1) * cols + min(b0 + db, cols - 1))
    return sorted(used)


def fit_view_gains(views: np.ndarray, sigma: float, device: str | None = None, used=None):
    """The gain fields of :func:`view_gains` on the pilot's reduced views: (fields (a, b,
    hs, ws), the reduction factor), or (None, factor) where there is nothing to fit.
    ``used``: the views (indices a·cols + b) whose fields are wanted (:func:`sampled_views`);
    the others get 1 (default: all)."""
    views = np.asarray(views, np.float32)
    rows, cols, h, w = views.shape
    factor = reduction_factor(h, w)
    hs, ws = h // factor, w // factor
    if rows * cols < 2 or min(hs, ws) < 16:
        return None, factor
    small = views[:, :, :hs * factor, :ws * factor].reshape(rows, cols, hs, factor, ws, factor).mean((3, 5))
    return fit_reduced_gains(small, factor, sigma, device, used), factor


def reduction_factor(h: int, w: int) -> int:
    """The factor by which the pilot's views are reduced (block means): the largest whole
    one that leaves at least :data:`PILOT_SIZE` px along the longer side."""
    return max(1, max(h, w) // PILOT_SIZE)


def fit_reduced_gains(small: np.ndarray, factor: int, sigma: float, device: str | None = None, used=None):
    """:func:`fit_view_gains` on the views already reduced by block means of ``factor``,
    (a, b, hs, ws): the fields (a, b, hs, ws), or None where there is nothing to fit (a
    single view, under 16 px, or a grid the pilot's circles do not fit). The pilot's
    disparity, then :func:`fit_gains_at`."""
    from lfsf import device as _device
    from lfsf.estimate import pilot_estimate
    from lfsf.params import Params

    small = np.asarray(small, np.float32)
    rows, cols, hs, ws = small.shape
    if rows * cols < 2 or min(hs, ws) < 16:
        return None
    # (30 ROF steps, as the `fast` preset took until the forty-third session: the gains
    # were measured and tuned on this pilot's disparity)
    pilot = Params.preset("fast").replace(view_gain_sigma=0.0, match_exposure=False, rof_iterations=30)
    if pilot.sample_offsets((rows, cols))[1] <= 0:  # a grid the pilot's circles do not fit (one row)
        return None
    dev = _device.resolve_device(device)
    disparity = pilot_estimate(small, small, pilot, dev).disp1
    return fit_gains_at(small, disparity, factor, sigma, dev, used)


def fit_gains_at(small: np.ndarray, disparity: np.ndarray, factor: int, sigma: float, device: str, used=None):
    """The fit of :func:`fit_reduced_gains` given the disparity (hs, ws) of the reduced
    views' centre (the pilot's): every view named warped to the centre by it, the
    reference (the centre view, or the views nearest it) their mean; each view's global
    gain the median ratio over the pixels both see (on the host); then :data:`PASSES`
    fits of the local ratio G_σ(C·W·M) / G_σ(W·W·M) over the matching pixels M, blended
    towards the global gain where their weight G_σ(M) is below :data:`SUPPORT` and
    clipped (on ``device``, float32; σ = ``sigma`` / ``factor`` px, at least 1)."""
    from lfsf import device as _device
    from lfsf.kernels import gains as kernels

    wp = _device.warp()
    dev = device
    small = np.asarray(small, np.float32)
    rows, cols, hs, ws = small.shape
    ac, bc = (rows - 1) / 2, (cols - 1) / 2
    near = [k for k in range(rows * cols) if abs(k // cols - ac) <= 0.5 and abs(k % cols - bc) <= 0.5]
    wanted = list(range(rows * cols)) if used is None else sorted({int(k) for k in used})
    if any(not 0 <= k < rows * cols for k in wanted):
        raise ValueError(f"used must name views 0…{rows * cols - 1}, got {wanted}")
    fitted = sorted(set(wanted) | set(near))  # (the near views make the reference)
    n = len(fitted)
    offsets = np.array([(k % cols - bc, k // cols - ac) for k in fitted], np.float32)
    warped = wp.empty((n, hs, ws), dtype=float, device=dev)
    _device.launch_rows(kernels.warp_to_centre, dim=(n * hs, ws),
                        inputs=[wp.array(small.reshape(rows * cols, hs, ws), dtype=float, device=dev),
                                wp.array(np.int32(fitted), dtype=wp.int32, device=dev),
                                wp.array(offsets, dtype=wp.vec2, device=dev),
                                wp.array(np.ascontiguousarray(disparity, np.float32), dtype=float, device=dev)],
                        outputs=[warped], device=dev)
    centre = wp.empty((hs, ws), dtype=float, device=dev)
    _device.launch_rows(kernels.mean_of_views, dim=(hs, ws),
                        inputs=[warped, wp.array(np.int32([fitted.index(k) for k in near]), dtype=wp.int32,
                                                 device=dev)],
                        outputs=[centre], device=dev)
    border = max(2, int(round(8 / factor)))  # the pilot's own border, where its disparity is least sure
    # a first gain per view, the median ratio over the pixels both see: a view much darker
    # than the centre then still finds its matches (the test below is on the corrected view)
    w_host, c_host = warped.numpy()[:, border:-border, border:-border], centre.numpy()[border:-border, border:-border]
    c_seen = c_host > DARK
    base = np.ones(n, np.float32)
    for m in range(n):
        seen = c_seen & (w_host[m] > DARK)
        if seen.sum() >= 16:
            base[m] = np.median(c_host[seen] / w_host[m][seen])
    base = wp.array(np.clip(base, 1.0 / MAX_GAIN, MAX_GAIN).astype(np.float32), dtype=float, device=dev)
    s = max(sigma / factor, 1.0)  # (below 1 px the box widths would be 1: no blur)
    gains = wp.empty((n, hs, ws), dtype=float, device=dev)
    sums = wp.empty((3 * n, hs, ws), dtype=float, device=dev)
    spare = wp.empty_like(sums)
    for p in range(PASSES):
        _device.launch_rows(kernels.gain_sums, dim=(n * hs, ws),
                            inputs=[warped, centre, gains, base, int(p == 0), border, DARK, MATCH], outputs=[sums],
                            device=dev)
        box_blur(sums, s, dev, spare)
        _device.launch_rows(kernels.gains_from_sums, dim=(n * hs, ws), inputs=[sums, base, SUPPORT, MAX_GAIN],
                            outputs=[gains], device=dev)
    out = gains.numpy()
    if len(near) == 1:
        out[fitted.index(near[0])] = 1.0
    fields = np.ones((rows * cols, hs, ws), np.float32)
    fields[wanted] = out[[fitted.index(k) for k in wanted]]
    return fields.reshape(rows, cols, hs, ws)
