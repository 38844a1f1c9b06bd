"""The renderer against its NumPy reference, and the ground truth against the images."""

import re

import numpy as np
import pytest

from lfsf import synth
from lfsf._errors import LfsfWarning

import reference_render as ref

SCENES = list(synth.list_scenes())


def bilinear(img, x, y):
    """Sample img at (x, y) (x = column), clamped at the borders."""
    h, w = img.shape
    x = np.clip(x, 0, w - 1)
    y = np.clip(y, 0, h - 1)
    x0 = np.minimum(np.floor(x).astype(int), w - 2)
    y0 = np.minimum(np.floor(y).astype(int), h - 2)
    fx, fy = x - x0, y - y0
    return ((1 - fy) * ((1 - fx) * img[y0, x0] + fx * img[y0, x0 + 1])
            + fy * ((1 - fx) * img[y0 + 1, x0] + fx * img[y0 + 1, x0 + 1]))


@pytest.mark.parametrize("scene", SCENES)
def test_render_matches_numpy_reference(scene, device):
    size, grid = (20, 15), 3
    lf1, lf2, gt = synth.render_scene(scene, size=size, grid=grid, supersample=2, device=device)
    want1, want2 = ref.render(scene, size, grid, 2)
    for got, want in ((lf1.views, want1), (lf2.views, want2)):
        diff = np.abs(got - want)
        # float32 kernel against float64 reference: a ray grazing an edge may flip
        assert np.mean(diff < 1e-3) > 0.99, np.sort(diff.ravel())[-10:]
        assert np.median(diff) < 1e-5


@pytest.mark.parametrize("scene", SCENES)
def test_ground_truth_matches_numpy_reference(scene, device):
    size = (40, 30)
    _, _, gt = synth.render_scene(scene, size=size, grid=1, supersample=1, device=device)
    want = ref.ground_truth(scene, size)
    for key in ("valid", "occluded"):
        assert np.mean(gt[key] == want[key]) > 0.99, key
    m = gt["valid"] & want["valid"]
    for key in ("disp1", "disp2", "u", "v"):
        np.testing.assert_allclose(gt[key][m], want[key][m], atol=2e-3, rtol=1e-4, err_msg=key)


def _median_abs(a, b, mask):
    # the median: pixels hidden in a side view (not flagged: `occluded` is about t2) are
    # outliers that a mean would count
    return float(np.median(np.abs(a - b)[mask]))


def _smoothed(scene, factor=4.0):
    """The same scene with textures `factor` times coarser: bilinear interpolation is then
    nearly exact, so what remains of the residual is any error in the ground truth."""
    from dataclasses import replace

    sc = synth.get_scene(scene)
    objs = tuple(replace(o, texture=replace(o.texture, period=o.texture.period * factor)) for o in sc.objects)
    return replace(sc, objects=objs)


def _warp_residuals(scene, size=(128, 96), grid=5):
    """Median |warped − t1 centre| and |unwarped − t1 centre| for a few views, warping the
    side views at t1 by δ1 and every view at t2 by (u, δ2), on valid, non-occluded pixels."""
    lf1, lf2, gt = synth.render_scene(scene, size=size, grid=grid)
    c = (grid - 1) // 2
    centre = lf1.views[c, c]
    h, w = centre.shape
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    d1, d2, u, v = gt["disp1"], gt["disp2"], gt["u"], gt["v"]
    b = 6  # samples that fall outside the image are clamped: leave the border out
    keep = gt["valid"] & ~gt["occluded"]
    keep[:b], keep[-b:], keep[:, :b], keep[:, -b:] = False, False, False, False
    out = []
    for a, bb in ((0, 0), (0, grid - 1), (grid - 1, c), (c, 0), (c, c)):
        xi, eta = bb - c, a - c
        if (a, bb) != (c, c):  # stereo at t1: L(p − δ1 φ, φ, t1) = L(p, 0, t1)
            out.append((f"t1 view {a},{bb}", lf1.views[a, bb], x - d1 * xi, y - d1 * eta))
        # flow and stereo at t2: L(p + u − δ2 φ, φ, t2) = L(p, 0, t1)
        out.append((f"t2 view {a},{bb}", lf2.views[a, bb], x + u - d2 * xi, y + v - d2 * eta))
    rows = []
    for name, img, sx, sy in out:
        inside = keep & (sx >= 0) & (sx <= w - 1) & (sy >= 0) & (sy <= h - 1)
        assert inside.mean() > 0.5
        rows.append((name, _median_abs(bilinear(img, sx, sy), centre, inside), _median_abs(img, centre, inside)))
    return rows


@pytest.mark.parametrize("scene", SCENES)
def test_ground_truth_explains_the_light_fields(scene):
    """Warping side views and the t2 views by the ground truth reproduces the t1 centre view
    on non-occluded pixels, with a residual far below the unwarped one."""
    sharp = _warp_residuals(scene)
    for name, res, base in sharp:
        assert res < 0.15 * base, (name, res, base)
    # With coarser textures bilinear interpolation errs less, and so must the residual:
    # what is left is interpolation, not the ground truth (an error of 0.1 px in δ1 alone
    # would raise it several times).
    smooth = _warp_residuals(_smoothed(scene))
    for (name, res, base), (_, res_sharp, _) in zip(smooth, sharp):
        assert res < 0.08 * base, (name, res, base)
        assert res <= 0.7 * res_sharp + 1e-4, (name, res, res_sharp)


def _photos(seed=0, count=2, shape=(37, 53)):
    """Small random 'photographs': smooth colour noise with a few sharp edges."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        img = rng.random((shape[0] // 4 + 2, shape[1] // 4 + 2, 3))
        img = np.kron(img, np.ones((4, 4, 1)))[:shape[0], :shape[1]]
        img[:, shape[1] // 3] = 1.0
        out.append(img.astype(np.float32))
    return out


@pytest.mark.parametrize("scene, size, span", [("paper", (24, 18), (60.0, 200.0)), ("random-2", (24, 18), (60.0, 200.0)),
                                               ("random-2", (48, 36), (150.0, 400.0))])
def test_render_with_images_matches_numpy_reference(scene, size, span, device):
    """Image textures on planes, spheres and boxes (random-2 has a box; every face and
    the mirrored repeats are reached), seen shrunk 1–3.5× (a Gaussian prefilter) and 4–7×
    (block means and a Gaussian), against the NumPy reference: its own prefilter of each
    object's image, then the same sampling."""
    grid = 3
    images = _photos(shape=(120, 160))
    sc = synth.with_images(scene, len(images), seed=1, span=span)
    lf1, lf2, _ = synth.render_scene(sc, size=size, grid=grid, supersample=2, device=device, images=images)
    stack = [images[p.texture.image] for p in sc.objects if p.texture.image >= 0]
    want1, want2 = ref.render(sc, size, grid, 2, stack=stack)
    for got, want in ((lf1.views, want1), (lf2.views, want2)):
        diff = np.abs(got - want)
        assert np.mean(diff < 1e-3) > 0.99, np.sort(diff.ravel())[-10:]
        assert np.median(diff) < 1e-5


def test_an_image_texture_spans_its_width_and_keeps_the_ground_truth():
    """A horizontal ramp on a fronto-parallel plane: its w texels span ``image_span``
    pixels (at 640 px wide; half that at 320), so from the first texel's centre to the
    last it climbs 1 over (w − 1)/w of the span, also where the image is seen shrunk 10×
    (block means, then a Gaussian); it is repeated mirrored beyond its edges. The
    geometry and so the ground truth are those of the solid-textured scene."""
    for w, width, span in ((101, 640, 200.0), (101, 320, 200.0), (1000, 640, 100.0)):
        ramp = np.tile(np.linspace(0.0, 1.0, w, dtype=np.float32), (9, 1))
        plane = synth.Primitive("plane", (0.5, 0.5), 6.0, (2.0, 2.0), synth.Texture(image=0, image_span=span))
        lf, _, _ = synth.render_scene(synth.Scene("ramp", "a ramp", (plane,)), size=(width, 24), grid=1,
                                      images=[ramp])
        row = lf.centre[12].astype(np.float64)
        span_px = span * width / 640
        centre = (width - 1) / 2
        x = np.arange(width)
        inner = np.abs(x - centre) < 0.4 * span_px
        slope = np.polyfit(x[inner], row[inner], 1)[0]
        assert abs(slope * span_px - w / (w - 1)) < 2e-3, (w, width, slope * span_px)
        assert abs(row[int(round(centre))] - 0.5) < 0.01
        # past the image's right edge the ramp comes back down (mirrored)
        right = (x > centre + 0.6 * span_px) & (x < centre + 1.4 * span_px)
        assert np.polyfit(x[right], row[right], 1)[0] < 0
    _, _, gt = synth.render_scene("random-5", size=(40, 30), grid=3)
    _, _, gt_img = synth.render_scene(synth.with_images("random-5", 2, seed=3), size=(40, 30), grid=3,
                                      images=_photos())
    for key in ("disp1", "disp2", "u", "v", "valid", "occluded"):
        np.testing.assert_array_equal(gt[key], gt_img[key], err_msg=key)


def test_an_image_seen_shrunk_is_filtered_not_aliased():
    """Stripes one texel wide seen 3× and 10× shrunk render as their mean, grey, not as
    a moiré of their phases."""
    for w, span in ((300, 100.0), (1000, 100.0)):
        stripes = np.tile((np.arange(w) % 2).astype(np.float32), (64, 1))
        plane = synth.Primitive("plane", (0.5, 0.5), 6.0, (2.0, 2.0), synth.Texture(image=0, image_span=span))
        lf, _, _ = synth.render_scene(synth.Scene("stripes", "stripes", (plane,)), size=(640, 24), grid=1,
                                      images=[stripes])
        seen = lf.centre[4:-4, 280:360]
        assert abs(seen.mean() - 0.5) < 0.02 and seen.std() < 0.02, (w, seen.mean(), seen.std())
    # block means keep at least 2 × 2 texels (the renderer's bilinear lookup needs them),
    # however small the image is seen
    tiny = np.repeat(np.eye(3, dtype=np.float32)[..., None], 3, axis=2)
    for shrink in (4.0, 6.0, 50.0):
        img, k = synth._prefiltered(tiny, shrink)
        assert min(img.shape[:2]) >= 2 and k == 1, (shrink, img.shape, k)
    img, k = synth._prefiltered(np.zeros((40, 30, 3), np.float32), 50.0)
    assert k == 15 and img.shape == (2, 2, 3)


def test_image_textures_are_checked():
    sc = synth.with_images("paper", 3, seed=0)
    assert {p.texture.image for p in sc.objects} <= {0, 1, 2} and sc.name == "paper+images"
    assert sc == synth.with_images("paper", 3, seed=0) and sc != synth.with_images("paper", 3, seed=1)
    need = max(p.texture.image for p in sc.objects) + 1
    with pytest.raises(ValueError, match=f"shows image {need - 1}, but {need - 1} image"):
        synth.render_scene(sc, size=(16, 16), grid=1, images=_photos(count=need - 1) if need > 1 else None)
    for bad, why in ((np.zeros((5, 5, 5)), "shape"), (np.zeros((1, 5)), "shape"), (np.array([["a", "b"]] * 2), "numbers"),
                     (np.full((5, 5), 1.5), r"in \[0, 1\]"), (np.full((5, 5), np.nan), "finite")):
        with pytest.raises(ValueError, match=why):
            synth.render_scene(sc, size=(16, 16), grid=1, images=[bad] * 3)
    # integers are scaled by their type's maximum, booleans are 0 and 1, alpha is dropped
    u8 = np.full((6, 7, 4), 255, np.uint8)
    u8[..., :3] = 51
    for img, value in ((u8, 0.2), (np.ones((6, 7), bool), 1.0), (np.full((6, 7, 2), 0.25), 0.25)):
        np.testing.assert_allclose(synth._check_images(sc, [img] * 3)[0], value, atol=1e-7)
    for span in (0.0, -10.0, float("nan")):
        flat = synth.Primitive("plane", (0.5, 0.5), 6.0, (2.0, 2.0), synth.Texture(image=0, image_span=span))
        with pytest.raises(ValueError, match="image_span"):
            synth.render_scene(synth.Scene("s", "s", (flat,)), size=(16, 16), grid=1, images=_photos(count=1))
    with pytest.raises(ValueError, match="at least one image"):
        synth.with_images("paper", 0)


def test_scene_catalogue():
    names = synth.list_scenes()
    assert len(names) >= 4
    assert {"paper", "slanted", "large_motion", "weak_texture"} <= set(names)
    with pytest.raises(ValueError, match="unknown scene"):
        synth.render_scene("nope", size=(16, 16), grid=1)


def test_random_scenes_are_reproducible_distinct_and_in_range():
    a, b, c = synth.get_scene("random-3"), synth.random_scene(3), synth.random_scene(4)
    assert a == b and a.name == "random-3"
    assert a != c
    for seed in range(12):
        sc = synth.random_scene(seed)
        assert 3 <= len(sc.objects) <= 5
        for prim in sc.objects:
            disparity = synth.FOCAL_BASELINE / prim.depth - synth.FOCAL_BASELINE / synth.ZERO_DISPARITY_DEPTH
            assert -2.4 <= disparity <= 2.4, (seed, prim)
            assert np.hypot(*prim.shift) <= 12.0
            assert 0.08 <= prim.texture.contrast <= 0.5
    _, _, gt = synth.render_scene("random-3", size=(32, 24), grid=3, supersample=1)
    assert np.isfinite(gt["disp1"]).all() and gt["valid"].any()
    for bad in ("random--1", "random-", "random-x", "random-²"):
        with pytest.raises(ValueError, match="unknown scene"):
            synth.get_scene(bad)
    with pytest.raises(ValueError, match="≥ 0"):
        synth.random_scene(-1)


def test_add_vignetting_darkens_each_view_by_its_own_smooth_field():
    """The centre view is untouched; a view's gain falls with its distance from the
    centre, most towards the image side its offset points to (a corner view at that
    corner: 1 − 2k), never above 1; the field is smooth; both times get the same."""
    lf1, lf2, _ = synth.render_scene("weak_texture", size=(40, 30), grid=5)
    k = 0.1
    v1, v2 = synth.add_vignetting(lf1, k), synth.add_vignetting(lf2, k)
    assert synth.add_vignetting(lf1, 0.0) is lf1
    g = synth.vignetting_gains((5, 5), (40, 30), k)
    assert g.shape == (5, 5, 30, 40) and g.max() <= 1.0
    np.testing.assert_array_equal(g[2, 2], 1.0)
    np.testing.assert_array_equal(v1.views[2, 2], lf1.views[2, 2])
    assert g[0, 0, 0, 0] == pytest.approx(1 - 2 * k) and g[0, 0, -1, -1] == pytest.approx(1.0)
    assert g[4, 4, -1, -1] == pytest.approx(1 - 2 * k) and g[0, 4, 0, -1] == pytest.approx(1 - 2 * k)
    assert g[2, 0, 15, 0] < g[2, 1, 15, 0] < 1.0  # further out, darker
    assert np.abs(np.diff(g, axis=-1)).max() < 4 * k / 39 + 1e-6  # smooth: no steps
    inner = (lf1.views < 0.9)
    np.testing.assert_allclose(v1.views[inner], (lf1.views * g)[inner], rtol=1e-6)
    np.testing.assert_allclose(v2.views[lf2.views < 0.9], (lf2.views * g)[lf2.views < 0.9], rtol=1e-6)
    assert v1.meta["vignetting"] == k and "vignetting" in v1.source
    for bad in (-0.1, 0.5, float("nan")):
        with pytest.raises(ValueError, match="vignetting strength"):
            synth.add_vignetting(lf1, bad)


def test_add_noise_is_gaussian_reproducible_independent_and_clipped():
    lf, _, _ = synth.render_scene("weak_texture", size=(64, 48), grid=3, supersample=1)
    assert synth.add_noise(lf, 0.0) is lf
    a, b, c = synth.add_noise(lf, 0.02, seed=5), synth.add_noise(lf, 0.02, seed=5), synth.add_noise(lf, 0.02, seed=6)
    np.testing.assert_array_equal(a.views, b.views)
    noise_a, noise_c = a.views - lf.views, c.views - lf.views
    inner = (lf.views > 0.1) & (lf.views < 0.9)  # away from the clip
    assert abs(noise_a[inner].std() - 0.02) < 0.001 and abs(noise_a[inner].mean()) < 0.001
    assert abs(np.corrcoef(noise_a[inner], noise_c[inner])[0, 1]) < 0.05  # seeds give independent noise
    assert a.views.min() >= 0.0 and a.views.max() <= 1.0 and a.views.dtype == np.float32
    assert a.grid == lf.grid and a.meta["noise_sigma"] == 0.02 and "noise" in a.source
    for bad in (-0.1, float("nan")):
        with pytest.raises(ValueError, match="noise sigma"):
            synth.add_noise(lf, bad)


def test_paper_scene_has_independent_motions_and_both_disparity_signs():
    _, _, gt = synth.render_scene("paper", size=(160, 120), grid=1)
    d = gt["disp1"][gt["valid"]]
    assert d.min() < -1.0 and d.max() > 1.0
    flows = {(round(float(a), 1), round(float(b), 1)) for a, b in zip(gt["u"][::8, ::8].ravel(), gt["v"][::8, ::8].ravel())}
    assert len(flows) > 20
    assert not np.allclose(gt["disp1"], gt["disp2"])  # motion in depth


def test_large_motion_scene_moves_more_than_10_px():
    for size in ((160, 120), (640, 480)):
        _, _, gt = synth.render_scene("large_motion", size=size, grid=1, supersample=1)
        mag = np.hypot(gt["u"], gt["v"])[gt["valid"]]
        assert np.mean(mag > 10.0) > 0.08, size  # the moving objects, not a few pixels
        assert mag.max() > 15.0, size


def test_slanted_scene_has_piecewise_linear_disparity():
    # δ = f·B/Z − s is affine in the image for a plane: its second differences vanish
    # away from the depth edges.
    _, _, gt = synth.render_scene("slanted", size=(160, 120), grid=1, supersample=1)
    d, valid = gt["disp1"].astype(np.float64), gt["valid"]
    dxx = d[:, 2:] - 2 * d[:, 1:-1] + d[:, :-2]
    inner = valid[:, 2:] & valid[:, 1:-1] & valid[:, :-2]
    assert np.median(np.abs(dxx[inner])) < 1e-4
    assert np.ptp(d[valid]) > 1.0  # and it does vary


def test_weak_texture_scene_has_low_contrast():
    lf_weak, _, _ = synth.render_scene("weak_texture", size=(80, 60), grid=1)
    lf_paper, _, _ = synth.render_scene("paper", size=(80, 60), grid=1)
    assert lf_weak.views.std() < 0.3 * lf_paper.views.std()


def test_size_keeps_disparity_and_translation_in_pixels():
    _, _, small = synth.render_scene("large_motion", size=(80, 60), grid=1, supersample=1)
    _, _, big = synth.render_scene("large_motion", size=(320, 240), grid=1, supersample=1)
    # the backdrop's disparity range and the scene's largest motions match across sizes
    for key in ("disp1",):
        assert abs(np.nanmax(small[key]) - np.nanmax(big[key])) < 0.1
    assert abs(np.nanmax(np.abs(small["u"])) - np.nanmax(np.abs(big["u"]))) < 2.5


def test_colour_render_has_three_channels_and_grey_is_its_luma():
    lfc, _, _ = synth.render_scene("paper", size=(24, 18), grid=3, colour=True)
    lfg, _, _ = synth.render_scene("paper", size=(24, 18), grid=3)
    assert lfc.views.shape == (3, 3, 18, 24, 3)
    luma = lfc.views @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
    np.testing.assert_allclose(luma, lfg.views, atol=1e-5)


def test_even_grid_is_centred_between_views():
    lf, _, gt = synth.render_scene("paper", size=(40, 30), grid=(2, 4), supersample=1)
    assert lf.views.shape == (2, 4, 30, 40)
    assert lf.grid == (2, 4)
    # its views at half steps from the centre: the middle rows of a 4×4 grid's
    square = synth.render_scene("paper", size=(40, 30), grid=(4, 4), supersample=1)[0]
    np.testing.assert_array_equal(lf.views, square.views[1:3])


@pytest.mark.parametrize("grid", [(3, 5), (1, 5), (5, 3)])
def test_the_middle_view_of_any_odd_grid_is_the_centre_view(grid):
    """Each axis centred on its own: the middle view of a 3×5, 1×5 or 5×3 grid is the view
    a 1×1 grid renders (the rows' and columns' centres swapped, a 3×5 grid's middle view
    differed by 0.61, its views no longer matching the ground truth beside them)."""
    one = synth.render_scene("paper", size=(32, 24), grid=(1, 1), supersample=1)[0]
    lf = synth.render_scene("paper", size=(32, 24), grid=grid, supersample=1)[0]
    np.testing.assert_array_equal(lf.view(grid[0] // 2, grid[1] // 2), one.view(0, 0))


def test_added_noise_stays_within_the_unit_range():
    from lfsf.io import LightField

    for level in (0.02, 0.98):
        noisy = synth.add_noise(LightField(np.full((3, 3, 8, 8), level, np.float32)), 0.1, 1).views
        assert noisy.min() >= 0.0 and noisy.max() <= 1.0
        assert (noisy == (0.0 if level < 0.5 else 1.0)).any()  # (clipped, not just small)


@pytest.mark.parametrize("frames", [2, 4])
def test_an_interrupted_write_leaves_no_partial_set(tmp_path, monkeypatch, frames):
    """A pair without its ground truth, or a sequence cut short, would be read as data:
    the files of one `lfsf synth` are moved into place only when all are written."""
    from lfsf import io

    real = io.write_lightfield
    calls = []

    def flaky(lf, path):
        calls.append(path)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(lf, path)

    monkeypatch.setattr(io, "write_lightfield", flaky)
    with pytest.raises(KeyboardInterrupt):
        if frames == 2:
            synth.write_scene("paper", tmp_path / "s", size=(16, 16), grid=3, device="cpu")
        else:
            synth.write_sequence("paper", tmp_path / "s", frames, size=(16, 16), grid=3, device="cpu")
    left = sorted(str(p.relative_to(tmp_path / "s")) for p in (tmp_path / "s").rglob("*"))
    assert left == [], left
    monkeypatch.setattr(io, "write_lightfield", real)
    paths = (synth.write_scene("paper", tmp_path / "s", size=(16, 16), grid=3, device="cpu") if frames == 2
             else synth.write_sequence("paper", tmp_path / "s", frames, size=(16, 16), grid=3, device="cpu"))
    assert all(p.is_file() for group in paths.values() for p in (group if isinstance(group, list) else [group]))


def test_a_sequence_over_an_earlier_longer_one_is_refused(tmp_path):
    synth.write_sequence("paper", tmp_path / "s", 4, size=(16, 16), grid=3, device="cpu")
    with pytest.raises(ValueError, match="f003.npz"):
        synth.write_sequence("paper", tmp_path / "s", 3, size=(16, 16), grid=3, device="cpu")
    assert len(list((tmp_path / "s" / "frames").glob("*.npz"))) == 4


@pytest.mark.parametrize(
    "kwargs,needle",
    [
        ({"size": (48.5, 40)}, "image width must be a whole number, got 48.5"),
        ({"size": 48}, "size must be (width, height)"),
        ({"grid": (2,)}, "grid must be a number of views per side or (rows, cols), got (2,)"),
        ({"grid": True}, "grid rows must be a whole number"),
        ({"grid": (3, 0)}, "grid columns must be in 1…33, got 0"),
        ({"size": (100_000, 40)}, "image width must be in 8…8192"),
        ({"supersample": 0}, "supersample must be in 1…16"),
        ({"size": (8192, 8192), "grid": 9}, "use a smaller size, grid or number of frames"),
    ],
)
def test_render_settings_out_of_range_are_value_errors_naming_them(kwargs, needle):
    """Not truncated (48.5 → 48), not an unpacking TypeError, not a Warp allocation error."""
    settings = {"size": (48, 40), "grid": 3, **kwargs}
    with pytest.raises(ValueError) as info:
        synth.render_scene("paper", **settings)
    assert needle in str(info.value)


def test_check_render_normalises_what_it_accepts():
    assert synth.check_render((48.0, np.int64(40)), (3, 5), supersample=2.0, frames=3, noise=0.01) == {
        "size": (48, 40), "grid": (3, 5), "supersample": 2, "frames": 3, "noise": 0.01}


def test_camera_effects_and_scene_choices_refuse_odd_arguments_clearly():
    """Each was a TypeError, an AttributeError, an OverflowError, a string-format error,
    or silently something else (seed 1.5 read as 1; counts clipped to all white)."""
    import lfsf

    views = np.random.default_rng(0).random((2, 2, 8, 8)).astype(np.float32)
    lf = lfsf.LightField(views)
    assert synth.add_noise(views, 0.01).views.shape == views.shape       # views as an array: fine
    for call, needle in ((lambda: synth.add_vignetting(lf, "0.1"), "vignetting strength must be a number"),
                         (lambda: synth.add_vignetting(lf, None), "vignetting strength must be a number"),
                         (lambda: synth.add_noise(lf, 0.1, seed=1.5), "seed must be a whole number, got 1.5"),
                         (lambda: synth.add_noise(lf, "0.1"), "noise sigma must be a finite number"),
                         (lambda: synth.add_noise(lfsf.LightField(views * 4095), 0.01), "intensities up to 40"),
                         (lambda: synth.random_scene(1.5), "seed must be a whole number, got 1.5"),
                         (lambda: synth.random_scene(float("inf")), "seed must be a whole number"),
                         (lambda: synth.random_scene(10 ** 400), "seed must be in"),  # (was an OverflowError)
                         (lambda: synth.add_noise(lf, 0.1, seed=-(10 ** 400)), "seed must be in"),
                         (lambda: synth.get_scene(["paper"]), "unknown scene ['paper']")):
        with pytest.raises(ValueError, match=re.escape(needle)):
            call()


def test_image_textures_refuse_odd_arguments_clearly():
    """A span of 1e-300 px overflowed in the prefilter; three numbers, a None count and
    one array for the list of images were TypeErrors or numpy's 'ambiguous'."""
    for call, needle in ((lambda: synth.with_images("paper", 1, span=(1e-300, 1e-300)), "span must be (least, most)"),
                         (lambda: synth.with_images("paper", 1, span=(1, 2, 3)), "span must be (least, most)"),
                         (lambda: synth.with_images("paper", None), "the count of images must be a whole number"),
                         (lambda: synth.render_scene(synth.with_images("paper", 1), size=(48, 40), grid=3,
                                                     device="cpu", images=np.zeros((4, 4, 3))),
                          "images must be a list of images")):
        with pytest.raises(ValueError, match=re.escape(needle)):
            call()



@pytest.mark.parametrize("colour", ["no", 0, None, "False"])
def test_colour_must_be_a_bool(colour):
    """colour='no' rendered RGB (a non-empty string is true); like Params' switches, it
    must be True or False."""
    with pytest.raises(ValueError, match=r"colour must be True or False, got"):
        synth.render_scene("paper", size=(32, 24), grid=3, colour=colour)


def test_a_sequence_beyond_the_estimators_ranges_is_warned_of(tmp_path):
    """Ten frames of `paper` reach disparities no preset follows; the batch's last pairs
    had been garbage without a word (a helper). Four frames keep within them."""
    import warnings

    with pytest.warns(LfsfWarning, match=r"from pair f00\d on, the ground truth reaches \|δ\| = .* beyond the "
                                         r"estimator's defaults \(disparity_range 4, flow search ±24 px\)"):
        synth.write_sequence("paper", tmp_path / "long", 10, size=(32, 24), grid=3, supersample=1, device="cpu")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        synth.write_sequence("paper", tmp_path / "short", 4, size=(32, 24), grid=3, supersample=1, device="cpu")


def test_the_sequence_warning_knows_what_the_coarsest_level_can_search(tmp_path):
    """On a strip of 4000×14 px views the pyramid has one level, which searches ±64 px,
    not the ±100 px that 2.5 % of 4000 px would give: a flow of 80 px is warned of, one
    of 60 px is not (the warning had read the share's range alone)."""
    import warnings

    def gt(flow):
        zeros = np.zeros((14, 4000), np.float32)
        return {"disp1": zeros, "disp2": zeros, "u": zeros + flow, "v": zeros}

    with pytest.warns(LfsfWarning, match=r"flows of 80\.0 px, .*flow search ±64 px\)"):
        synth._warn_beyond_ranges([gt(80.0)], tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        synth._warn_beyond_ranges([gt(60.0)], tmp_path)
