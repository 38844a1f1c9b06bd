"""Per-view gain fields (lfsf.gains): the views' brightness matched to the centre's."""

import numpy as np
import pytest

from lfsf import LightField, gains, synth
from lfsf._filters import gaussian_blur
from lfsf.estimate import estimate_scene_flow
from lfsf.params import Params

INNER = (slice(None), slice(None), slice(8, -8), slice(8, -8))


@pytest.mark.parametrize("grid", [(5, 5), (4, 4), (5, 3)])
def test_view_gains_undo_vignetting_and_leave_a_clean_light_field_alone(grid):
    """On `paper` darkened view by view (synth.add_vignetting, k = 0.1: up to 20 %), the
    fitted gains undo most of it: over the views' interiors the product's error falls
    from a median of 0.023–0.030 and a 95th percentile of 0.080–0.092 to below 0.009 and
    0.04 (0.005–0.007 and 0.024–0.029 measured; with the warp's sign flipped 0.010–0.015
    and 0.054–0.057), on odd, even (the views around the centre are the reference) and
    non-square grids, with no steps. On the clean light field they stay within 0.3 % of
    1, below the threshold of use; an odd grid's centre view keeps exactly 1."""
    lf, _lf2, _gt = synth.render_scene("paper", size=(96, 72), grid=5 if grid != (4, 4) else 4)
    if grid == (5, 3):
        lf = type(lf)(lf.views[:, 1:4])
    assert lf.grid == grid
    g = synth.vignetting_gains(grid, (96, 72), 0.1)
    fitted = gains.view_gains(synth.add_vignetting(lf, 0.1).grey().views, 24.0, "cpu")
    assert fitted.shape == (*grid, 72, 96) and fitted.dtype == np.float32
    error = np.abs(fitted * g - 1)[INNER]
    assert np.median(np.abs(g - 1)[INNER]) > 0.02 and np.percentile(np.abs(g - 1)[INNER], 95) > 0.07
    assert np.median(error) < 0.009 and np.percentile(error, 95) < 0.04
    assert max(np.abs(np.diff(fitted, axis=-1)).max(), np.abs(np.diff(fitted, axis=-2)).max()) < 0.01  # no steps
    if grid[0] % 2 and grid[1] % 2:
        np.testing.assert_array_equal(fitted[grid[0] // 2, grid[1] // 2], 1.0)
    clean = gains.view_gains(lf.grey().views, 24.0, "cpu")
    assert np.median(np.abs(clean - 1)[INNER]) < 0.003
    assert 1 / gains.MAX_GAIN <= clean.min() and clean.max() <= gains.MAX_GAIN
    # the estimator uses them on the vignetted views only
    assert gains.gain_change(clean) < gains.GAIN_CHANGE < gains.gain_change(fitted)
    assert gains.gain_change(np.full((3, 3, 40, 50), 1.02)) == pytest.approx(0.02)


def test_view_gains_on_views_reduced_for_their_fit():
    """Views of 640×480 are fitted on 2× block means: the pilot's border, where its
    disparity is least sure, is 8 px of the full views, i.e. 4 of the reduced ones. The
    product of the fields and the vignetting stays within 1.5 % of 1 at the 95th
    percentile (0.72 % measured; 4.8 % with the border taken as 8 × 2 reduced px)."""
    lf, _lf2, _gt = synth.render_scene("paper", size=(640, 480), grid=5)
    assert gains.reduction_factor(480, 640) >= 2
    g = synth.vignetting_gains((5, 5), (640, 480), 0.1)
    fitted = gains.view_gains(synth.add_vignetting(lf, 0.1).grey().views, 24.0, "cpu")
    error = np.abs(fitted * g - 1)[INNER]
    assert np.percentile(error, 95) < 0.015 and np.median(error) < 0.005, (np.median(error), np.percentile(error, 95))


def test_gain_change_is_the_95th_percentile_of_the_change_inside_the_border():
    """The change that decides whether the fields are used: the 95th percentile of |g − 1|
    without an 8-px border (a median would read moderate vignetting 3–4× lower and skip
    it)."""
    g = 1.0 + np.random.default_rng(2).normal(0, 0.02, (3, 3, 40, 50))
    assert gains.gain_change(g) == pytest.approx(np.percentile(np.abs(g - 1)[..., 8:-8, 8:-8], 95.0))
    assert gains.gain_change(g, border=0) == pytest.approx(np.percentile(np.abs(g - 1), 95.0))
    # fields of at most four borders keep theirs: a 24×24 field whose top 3 rows are
    # 1.5 changes the views there (8 px off each edge would leave 8×8 of ones)
    rim = np.ones((24, 24))
    rim[:3] = 1.5
    assert gains.gain_change(rim) == pytest.approx(0.5)
    wide = np.ones((40, 40))
    wide[:3] = 1.5
    assert gains.gain_change(wide) == 0.0   # (larger: its rows are the border left out)


def test_the_pilots_reduction_leaves_pilot_size_along_the_longer_side():
    """320×240 views are reduced 2× (160 px along the longer side), not by the shorter
    side's 1× (a pilot at full size read vignetting of 0.45 less well: δ1 MSE 0.0014 →
    0.0024 at 320×240, `fast`); a 1000×40 strip 6×."""
    assert gains.PILOT_SIZE == 160
    assert gains.reduction_factor(240, 320) == 2 and gains.reduction_factor(320, 240) == 2
    assert gains.reduction_factor(40, 1000) == 6 and gains.reduction_factor(100, 150) == 1


def test_view_gains_where_there_is_nothing_to_fit():
    """A single view, views too small for a pilot, or a grid it cannot sample (one row)
    give None."""
    lf1, _lf2, _gt = synth.render_scene("weak_texture", size=(96, 72), grid=4)
    assert gains.view_gains(lf1.grey().views[:1, :1], 24.0, "cpu") is None
    assert gains.view_gains(lf1.grey().views[:, :, :12, :12], 24.0, "cpu") is None
    assert gains.view_gains(lf1.grey().views[1:2], 24.0, "cpu") is None


def mirror(k, n):
    """Index k into n pixels mirrored at the edges (the edge pixel repeated), as often as
    needed."""
    period = 2 * n
    k %= period
    return k if k < n else period - 1 - k


def _box_reference(stack, sigma):
    """Three box filters of :func:`lfsf.gains._box_widths` along each axis, pixel by pixel:
    each output the mean of the b inputs around it, indices past an edge mirrored (the
    edge pixel repeated, as often as a wide box needs)."""
    out = np.asarray(stack, np.float64)
    for axis in (1, 2):
        for b in gains._box_widths(sigma):
            r = b // 2
            moved = np.moveaxis(out, axis, -1)
            n = moved.shape[-1]
            blurred = np.empty_like(moved)
            for j in range(n):
                blurred[..., j] = moved[..., [mirror(k, n) for k in range(j - r, j + r + 1)]].mean(-1)
            out = np.moveaxis(blurred, -1, axis)
    return out


def _blurred(stack, sigma, device="cpu"):
    from lfsf.device import warp

    return gains.box_blur(warp().array(np.asarray(stack, np.float32), dtype=float, device=device), sigma,
                          device).numpy()


@pytest.mark.parametrize("shape,sigma", [((3, 11, 14), 1.5), ((2, 6, 9), 4.0), ((1, 5, 4), 8.0)])
def test_box_blur_kernel_matches_boxes_pixel_by_pixel(device, shape, sigma):
    """The blur on the device (a kernel per box pass) equals three box filters per axis
    computed pixel by pixel, boxes wider than the image included (σ = 8 on 5×4: widths
    of 15, mirrored more than once)."""
    stack = np.random.default_rng(1).random(shape).astype(np.float32)
    np.testing.assert_allclose(_blurred(stack, sigma, device), _box_reference(stack, sigma), rtol=1e-5, atol=1e-6)


def test_box_blur_is_a_gaussian_of_that_sigma_and_upsampling_keeps_ramps():
    """The three-pass box blur keeps constants and mass, and an impulse spreads with the
    variance of the Gaussian it stands for (σ² within 10 %), close to
    :func:`lfsf._filters.gaussian_blur`'s; the upsampling puts each block's value at its
    centre, so a ramp sampled at block centres comes back exactly inside."""
    impulse = np.zeros((1, 241, 241))
    impulse[0, 120, 120] = 1.0
    for sigma in (6.0, 8.0, 24.0):  # (the widths are odd whole numbers: at σ = 2 the variance is 17 % short)
        b = _blurred(impulse, sigma)[0].astype(np.float64)
        assert b.sum() == pytest.approx(1.0, abs=1e-5)
        yy, xx = np.mgrid[0:241, 0:241]
        assert (b * (xx - 120.0) ** 2).sum() == pytest.approx(sigma ** 2, rel=0.1)
        # (three boxes are flatter on top than a Gaussian: 8 and 9 % of the peak at σ = 6 and 8, 12 % at 24)
        assert np.abs(b - gaussian_blur(impulse[0], sigma)).max() < 0.13 * b.max()
    np.testing.assert_allclose(_blurred(np.full((2, 9, 7), 0.3), 3.0), 0.3, rtol=1e-6)
    factor = 4
    small = np.arange(6, dtype=np.float64)[None, None, :] * 2.0 + np.arange(5)[None, :, None]  # 2x + y
    full = gains._upsample(small, factor, 20, 24)
    px = (np.arange(24) + 0.5) / factor - 0.5
    py = (np.arange(20) + 0.5) / factor - 0.5
    inside = (slice(2, -2), slice(2, -2))
    np.testing.assert_allclose(full[0][inside], (2 * px[None, :] + py[:, None])[inside], atol=1e-5)


def test_the_estimator_matches_the_views_brightness_by_default():
    """`paper`, `lytro` and `fast` fit the gain fields (Params.view_gain_sigma 24 px;
    `flow`, of the centre views alone, has none to fit): on a vignetted scene the
    progress names them, their time is a stage,
    and δ1 comes out closer to the truth than without them, δ2 and the flow no worse;
    on the clean scene they change the views too little to be used. (`weak_texture`,
    where the vignetting costs most: δ1 MSE 0.054 without the gains, 0.024 with them,
    0.023 on the clean pair; δ2 0.061 → 0.038, EPE 0.109 → 0.106. Not on every scene:
    `paper` at this size gave δ1 0.051 against 0.043.)"""
    lf1, lf2, gt = synth.render_scene("weak_texture", size=(96, 72), grid=5)
    lf1, lf2 = synth.add_vignetting(lf1, 0.1), synth.add_vignetting(lf2, 0.1)
    base = Params.preset("paper").replace(warps=3, iterations=60, final_iterations=0)
    said = []
    on = estimate_scene_flow(lf1, lf2, base, device="cpu", progress=said.append)
    off = estimate_scene_flow(lf1, lf2, base.replace(view_gain_sigma=0.0), device="cpu")
    assert any("view gains" in m for m in said) and "view gains" in on.timings
    assert "view gains" not in off.timings
    inner = (slice(8, -8), slice(8, -8))
    mse = [float(np.mean((r.disp1 - gt["disp1"])[inner] ** 2)) for r in (on, off)]
    assert mse[0] < 0.6 * mse[1]
    # and at both times: δ2 and the flow no worse (fields at t1 alone: EPE 0.106 → 0.385)
    mse2 = [float(np.mean((r.disp2 - gt["disp2"])[inner] ** 2)) for r in (on, off)]
    epe = [float(np.hypot(r.u - gt["u"], r.v - gt["v"])[inner].mean()) for r in (on, off)]
    assert mse2[0] < 1.1 * mse2[1] and epe[0] < 1.1 * epe[1]
    # on the clean pair the fields stay below GAIN_CHANGE: the estimate is that without them
    clean1, clean2, _ = synth.render_scene("weak_texture", size=(96, 72), grid=5)
    said.clear()
    a = estimate_scene_flow(clean1, clean2, base, device="cpu", progress=said.append)
    b = estimate_scene_flow(clean1, clean2, base.replace(view_gain_sigma=0.0), device="cpu")
    assert "view gains" in a.timings and not any("view gains:" in m for m in said)
    for name in ("disp1", "disp2", "u", "v"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert all(Params.preset(name).view_gain_sigma == 24.0 for name in ("paper", "lytro", "fast"))


def test_the_progress_says_when_the_gains_reach_their_bound():
    """The gains are clipped to [1/MAX_GAIN, MAX_GAIN]: views 0.72× as bright as the centre
    need 1.39, which the fields cannot give, and the view gains' line says so; views 0.9×
    as bright are matched within the bound, without the remark."""
    from lfsf.gains import MAX_GAIN

    lf1, lf2, _ = synth.render_scene("random-2", size=(96, 72), grid=9)
    a, b = np.mgrid[:9, :9] - 4

    def dimmed(lf, factor):
        views = lf.views.copy()
        views[a ** 2 + b ** 2 > 4] *= factor
        return LightField(views)

    for factor, bound in ((0.72, True), (0.9, False)):
        said = []
        estimate_scene_flow(dimmed(lf1, factor), dimmed(lf2, factor), "fast", device="cpu", progress=said.append)
        line = [str(m) for m in said if str(m).startswith("view gains:")]
        assert len(line) == 1, said
        assert ("reach their bound" in line[0]) == bound, line
        assert (f"{MAX_GAIN:.3f}" in line[0]) == bound, line  # (the gains' range ends at the bound)


# --- on the device: block means, gains applied, the views sampled ---------------------------


@pytest.mark.parametrize("factor, shape", [(1, (3, 7, 9)), (3, (4, 17, 23)), (4, (2, 16, 16))])
def test_block_mean_kernel_matches_numpy(device, factor, shape):
    """The views reduced by block means of ``factor`` (the gains' pilot's input), the
    pixels past the last whole block left out, as fit_view_gains reduces them on the host."""
    from conftest import arr, launch
    from lfsf.device import warp
    from lfsf.kernels import gains as kernels

    n, h, w = shape
    views = np.random.default_rng(3).random(shape).astype(np.float32)
    hs, ws = h // factor, w // factor
    small = warp().zeros((n, hs, ws), dtype=float, device=device)
    launch(kernels.block_mean, (n * hs, ws), [arr(views, float, device), factor], [small], device)
    want = views[:, :hs * factor, :ws * factor].reshape(n, hs, factor, ws, factor).mean((2, 4))
    np.testing.assert_allclose(small.numpy(), want, rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("factor, small_shape, size", [(4, (15, 20), (62, 83)), (1, (6, 5), (6, 5)),
                                                       (3, (1, 4), (4, 13))])
def test_apply_gains_kernel_matches_full_gains(device, factor, small_shape, size):
    """Views times their gain fields upsampled to full size, on the views named only,
    against lfsf.gains.full_gains (bilinear, block centres, clamped edges; the sizes
    leave pixels past the last whole block, and one field is a single row)."""
    from conftest import arr, launch
    from lfsf.device import warp
    from lfsf.kernels import gains as kernels

    r = np.random.default_rng(5)
    n, (h, w) = 6, size
    fields = r.uniform(0.8, 1.25, (n, *small_shape)).astype(np.float32)
    views = r.random((n, h, w)).astype(np.float32)
    index = [0, 2, 5]
    out = arr(views, float, device)
    launch(kernels.apply_gains, (len(index) * h, w),
           [arr(fields, float, device), warp().array(np.int32(index), dtype=warp().int32, device=device), factor],
           [out], device)
    full = gains.full_gains(fields.reshape(2, 3, *small_shape), factor, h, w).reshape(n, h, w)
    want = views.copy()
    want[index] *= full[index]
    np.testing.assert_allclose(out.numpy(), want, rtol=2e-6, atol=1e-7)


@pytest.mark.parametrize("grid, preset", [((9, 9), "paper"), ((9, 9), "fast"), ((4, 5), "paper"), ((15, 15), "lytro")])
def test_sampled_views_are_the_views_the_samples_read(device, grid, preset):
    """sampled_views names exactly the views that sample_subaperture reads with a weight
    above 0: changing any other view leaves every sample as it was, and changing any view
    named changes some sample."""
    from conftest import arr, launch
    from lfsf.device import row_span, warp
    from lfsf.kernels import sampling

    rows, cols = grid
    phis, _radius = Params.preset(preset).sample_offsets(grid)
    used = gains.sampled_views(phis, rows, cols)
    h, w = 3, 4
    views = np.random.default_rng(8).random((rows * cols, h, w)).astype(np.float32)

    def samples(v):
        out = warp().zeros((len(phis), h, w), dtype=float, device=device)
        span, per_row = row_span(device, w)
        launch(sampling.sample_subaperture, (len(phis) * h, per_row),
               [arr(v, float, device), rows, cols, arr(phis, warp().vec2, device), span], [out], device)
        return out.numpy()

    base = samples(views)
    others = views.copy()
    others[[k for k in range(rows * cols) if k not in used]] += 7.0
    np.testing.assert_array_equal(samples(others), base)
    for k in used:
        changed = views.copy()
        changed[k] += 7.0
        assert np.any(samples(changed) != base), k
    if preset == "paper" and grid == (9, 9):
        assert len(used) == 37


def test_gains_fitted_for_some_views_are_those_of_the_full_fit():
    """Fitting only the views named (the ones the samples read) gives them the fields of
    the fit of all views, bit for bit (each view's fit involves only it and the reference
    views), and the others 1."""
    lf, _lf2, _gt = synth.render_scene("paper", size=(96, 72), grid=5)
    views = synth.add_vignetting(lf, 0.1).grey().views
    full, factor = gains.fit_view_gains(views, 24.0, "cpu")
    used = [0, 3, 7, 19]  # (the centre view, 12, not among them: it is the reference)
    some, factor_some = gains.fit_view_gains(views, 24.0, "cpu", used=used)
    assert factor_some == factor
    full, some = full.reshape(25, *full.shape[2:]), some.reshape(25, *some.shape[2:])
    np.testing.assert_array_equal(some[used], full[used])
    others = [k for k in range(25) if k not in used]
    assert np.all(some[others] == 1.0) and not np.all(full[others] == 1.0)
    with pytest.raises(ValueError, match="used must name views"):
        gains.fit_view_gains(views, 24.0, "cpu", used=[25])


# --- the fit on the device ---------------------------------------------------------------------


def test_warp_to_centre_and_mean_of_views_kernels_match_numpy(device):
    """Each view named, seen from the centre through the disparity (bilinear, clamped:
    the tent-weights reference), and the mean of the slots named."""
    from conftest import arr, launch
    from reference_kernels import bilinear

    from lfsf.device import warp

    wp = warp()
    r = np.random.default_rng(11)
    n, h, w = 5, 9, 12
    views = r.random((n, h, w)).astype(np.float32)
    index = [4, 0, 2]
    offsets = np.float32([[1.0, -2.0], [-1.5, 0.5], [0.0, 3.0]])
    disparity = r.uniform(-3, 3, (h, w)).astype(np.float32)  # (reaching past the edges: clamped)
    warped = wp.zeros((len(index), h, w), dtype=float, device=device)
    launch(gain_kernels().warp_to_centre, (len(index) * h, w),
           [arr(views, float, device), arr(np.int32(index), wp.int32, device), arr(offsets, wp.vec2, device),
            arr(disparity, float, device)], [warped], device)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    want = np.stack([bilinear(views[k], xx - disparity * xi, yy - disparity * eta)
                     for k, (xi, eta) in zip(index, offsets)])
    np.testing.assert_allclose(warped.numpy(), want, rtol=1e-5, atol=1e-5)
    mean = wp.zeros((h, w), dtype=float, device=device)
    launch(gain_kernels().mean_of_views, (h, w), [warped, arr(np.int32([2, 0]), wp.int32, device)], [mean], device)
    np.testing.assert_allclose(mean.numpy(), warped.numpy()[[2, 0]].mean(0), rtol=1e-6)


def gain_kernels():
    from lfsf.kernels import gains as kernels

    return kernels


@pytest.mark.parametrize("first", [1, 0])
def test_gain_sums_and_gains_from_sums_kernels_match_numpy(device, first):
    """One pass of the fit: the masked sums (dark pixels, the border and mismatches left
    out; the view's global gain on the first pass, its field after), then the fields
    from (here unblurred) sums: the ratio blended towards the global gain where the
    support is weak, clipped."""
    from conftest import arr, launch

    from lfsf.device import warp

    wp = warp()
    r = np.random.default_rng(12)
    n, h, w, border = 3, 10, 13, 2
    centre = r.uniform(0.0, 0.6, (h, w)).astype(np.float32)
    warped = (centre * r.uniform(0.85, 1.15, (n, h, w))).astype(np.float32)
    warped[1, 4, 5] = 0.01  # dark
    field = r.uniform(0.9, 1.1, (n, h, w)).astype(np.float32)
    base = np.float32([0.9, 1.0, 1.12])
    sums = wp.zeros((3 * n, h, w), dtype=float, device=device)
    launch(gain_kernels().gain_sums, (n * h, w),
           [arr(warped, float, device), arr(centre, float, device), arr(field, float, device),
            arr(base, float, device), first, border, gains.DARK, gains.MATCH], [sums], device)
    g = base[:, None, None] if first else field
    inside = np.zeros((h, w), bool)
    inside[border:-border, border:-border] = True
    on = ((warped > gains.DARK) & (centre > gains.DARK) & inside & (np.abs(g * warped - centre) < gains.MATCH))
    assert 0 < on.sum() < on.size
    want = np.concatenate([centre * warped * on, warped * warped * on, on.astype(np.float32)])
    np.testing.assert_allclose(sums.numpy(), want, rtol=1e-6, atol=1e-7)
    # the fields from sums: a ratio where the denominator is above 0, the support blends
    s = np.concatenate([r.uniform(0.5, 1.5, (n, h, w)), r.uniform(0.5, 1.5, (n, h, w)),
                        r.uniform(0.0, 0.4, (n, h, w))]).astype(np.float32)
    s[n:2 * n][:, 0] = 0.0  # no matches: the global gain
    out = wp.zeros((n, h, w), dtype=float, device=device)
    launch(gain_kernels().gains_from_sums, (n * h, w), [arr(s, float, device), arr(base, float, device),
                                                       gains.SUPPORT, gains.MAX_GAIN], [out], device)
    num, den, support = s[:n], s[n:2 * n], s[2 * n:]
    ratio = np.where(den > 0, num / np.where(den > 0, den, 1.0), base[:, None, None])
    weight = np.clip(support / gains.SUPPORT, 0.0, 1.0)
    want = np.clip(base[:, None, None] + (ratio - base[:, None, None]) * weight, 1 / gains.MAX_GAIN, gains.MAX_GAIN)
    np.testing.assert_allclose(out.numpy(), want, rtol=1e-5, atol=1e-6)
    assert np.any(want == gains.MAX_GAIN) or np.any(want == 1 / gains.MAX_GAIN)


@pytest.mark.parametrize("span", [1, 3, 17])
@pytest.mark.parametrize("along_rows", [1, 0])
def test_box_pass_kernel_matches_numpy_at_any_span(device, span, along_rows):
    """One box pass, each thread taking ``span`` pixels of a line by a running sum (1: the
    CUDA layout, the whole line: the CPU's), boxes wider than the line mirrored twice."""
    from conftest import arr, launch

    from lfsf.device import warp

    n, h, w = 2, 7, 17
    src = np.random.default_rng(13).random((n, h, w)).astype(np.float32)
    for radius in (0, 2, 9):
        out = warp().zeros((n, h, w), dtype=float, device=device)
        lines, length = (h, w) if along_rows else (w, h)
        launch(gain_kernels().box_pass, (n * lines, -(-length // span)), [arr(src, float, device), radius,
                                                                          along_rows, span], [out], device)
        axis = 2 if along_rows else 1
        moved = np.moveaxis(src, axis, -1)
        want = np.stack([moved[..., [mirror(j + t, length) for t in range(-radius, radius + 1)]].mean(-1)
                         for j in range(length)], -1)
        np.testing.assert_allclose(out.numpy(), np.moveaxis(want, -1, axis), rtol=1e-5, atol=1e-6)


def _fit_reference(small, disparity, factor, sigma, used):
    """The fit in float64 NumPy, as lfsf.gains ran it on the host before the thirtieth
    session: the views warped by the tent-weights bilinear reference, the box blur pixel
    by pixel (_box_reference)."""
    from reference_kernels import bilinear

    small = np.asarray(small, np.float64)
    rows, cols, hs, ws = small.shape
    yy, xx = np.mgrid[0:hs, 0:ws].astype(np.float64)
    ac, bc = (rows - 1) / 2, (cols - 1) / 2
    near = [k for k in range(rows * cols) if abs(k // cols - ac) <= 0.5 and abs(k % cols - bc) <= 0.5]
    fitted = sorted(set(used) | set(near))
    flat = small.reshape(rows * cols, hs, ws)
    d = np.asarray(disparity, np.float64)
    warped = np.stack([bilinear(flat[k], xx - d * (k % cols - bc), yy - d * (k // cols - ac)) for k in fitted])
    centre = warped[[fitted.index(k) for k in near]].mean(0)
    seen = (warped > gains.DARK) & (centre > gains.DARK)
    border = max(2, int(round(8 / factor)))
    seen[:, :border] = seen[:, -border:] = False
    seen[:, :, :border] = seen[:, :, -border:] = False
    base = np.ones(len(fitted))
    for m in range(len(fitted)):
        if seen[m].sum() >= 16:
            base[m] = np.median(centre[seen[m]] / warped[m][seen[m]])
    base = np.clip(base, 1 / gains.MAX_GAIN, gains.MAX_GAIN)[:, None, None]
    s = max(sigma / factor, 1.0)
    g = np.broadcast_to(base, warped.shape)
    for _ in range(gains.PASSES):
        m = (seen & (np.abs(g * warped - centre) < gains.MATCH)).astype(np.float64)
        num, den, support = (_box_reference(x, s) for x in (centre * warped * m, warped * warped * m, m))
        ratio = np.where(den > 0, num / np.where(den > 0, den, 1.0), base)
        g = np.clip(base + (ratio - base) * np.clip(support / gains.SUPPORT, 0, 1), 1 / gains.MAX_GAIN, gains.MAX_GAIN)
    if len(near) == 1:
        g[fitted.index(near[0])] = 1.0
    out = np.ones((rows * cols, hs, ws))
    out[used] = g[[fitted.index(k) for k in used]]
    return out.reshape(rows, cols, hs, ws)


@pytest.mark.parametrize("grid", [(5, 5), (4, 4)])
def test_the_fit_on_the_device_matches_its_numpy_reference(device, grid):
    """lfsf.gains.fit_gains_at (warps, masked sums, box blurs and ratios as kernels, in
    float32; the medians on the host) against the float64 NumPy fit it replaced, on a
    vignetted `paper` with the ground truth's disparity as the pilot's: within 2e-5
    (float32 sums and blurs: 3e-6 measured on the CPU; a pixel whose match test flips on
    rounding would move more, so at most 0.1 % of the pixels may), on an odd grid (the
    centre view the reference) and an even one (the four nearest). The views' offsets
    mirrored left to right fail it."""
    lf, _lf2, gt = synth.render_scene("paper", size=(64, 48), grid=grid[0])
    views = synth.add_vignetting(lf, 0.1).grey().views
    used = [0, 2, 5, 7, 8, grid[0] * grid[1] - 1]
    got = gains.fit_gains_at(views, gt["disp1"], 1, 6.0, device, used=used)
    want = _fit_reference(views, gt["disp1"], 1, 6.0, used)
    assert got.shape == want.shape
    far = np.abs(got - want) > 2e-5
    assert far.mean() < 1e-3, float(np.abs(got - want).max())
    assert np.abs(want - 1).max() > 0.05  # (the fields are not trivially 1)
    others = [k for k in range(grid[0] * grid[1]) if k not in used]
    assert np.all(got.reshape(-1, 48, 64)[others] == 1.0)


def test_the_host_filters_against_their_definitions():
    """``lfsf._filters``: the Gaussian blur is Σ_k g(k) I(p + k) over |k| ≤ ⌈3σ⌉ per
    axis, g normalised, the image mirrored with its edge pixel repeated (… 1 0 | 0 1 …);
    the box mean is the mean over a (2⌊width/2⌋ + 1)² box, the image's edge pixels
    repeated beyond it. Both written out pixel by pixel on a random image."""
    from lfsf._filters import box_mean

    rng = np.random.default_rng(3)
    image = rng.random((9, 11))
    h, w = image.shape

    def mirrored(i, n):
        return -i - 1 if i < 0 else (2 * n - 1 - i if i >= n else i)

    sigma = 1.3
    r = 4  # ⌈3σ⌉
    g = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    g /= g.sum()
    rows = np.array([[sum(g[k + r] * image[mirrored(i + k, h), j] for k in range(-r, r + 1)) for j in range(w)]
                     for i in range(h)])
    want = np.array([[sum(g[k + r] * rows[i, mirrored(j + k, w)] for k in range(-r, r + 1)) for j in range(w)]
                     for i in range(h)])
    np.testing.assert_allclose(gaussian_blur(image, sigma), want, rtol=0, atol=1e-12)
    for width in (5, 4):  # both a 5×5 box
        want = np.array([[np.mean([image[min(max(i + a, 0), h - 1), min(max(j + b, 0), w - 1)]
                                   for a in range(-2, 3) for b in range(-2, 3)]) for j in range(w)]
                         for i in range(h)])
        np.testing.assert_allclose(box_mean(image, width), want, rtol=0, atol=1e-6)
