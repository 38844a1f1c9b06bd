"""Tests of lfsf.viz: flow colour wheel, scalar colormaps, the overview figure, PNG output.

Expected wheel colours are derived by hand from the Middlebury reference code
(``colorcode.cpp`` / ``computeColor.m``, Baker et al. 2011):

* wheel: segments RY=15, YG=6, GC=4, CB=11, BM=13, MR=6; in a segment one channel ramps
  by ``floor(255 i / n)``. So colour 0 = (255, 0, 0), 15 = (255, 255, 0), 21 = (0, 255, 0),
  25 = (0, 255, 255), 27 = (0, 255 - floor(510/11), 255) = (0, 209, 255),
  36 = (0, 0, 255), 49 = (255, 0, 255), 54 = (255, 0, 255 - floor(1275/6)) = (255, 0, 43).
* position ``fk = (atan2(-v, -u)/π + 1)/2 · 54``:
  right (u>0, v=0): atan2(-0.0, -u) = -π -> fk = 0 -> red (255, 0, 0);
  left (u<0, v=0): atan2(0, |u|) = 0 -> fk = 27 -> (0, 209, 255);
  down (v>0): fk = 13.5 -> halfway between 13 = (255, 221, 0) and 14 = (255, 238, 0)
  -> G = floor(229.5) = 229 -> (255, 229, 0).
  (So the brief's "index 0 is red for u<0" is the other way round: index 0 is u>0.)
* saturation: ``1 - r (1 - c)`` for r <= 1, ``0.75 c`` beyond; then floor(255 ·).
"""

from __future__ import annotations

import re

import numpy as np
import pytest

import imageio.v3 as iio

from lfsf import viz


def _luminance(rgb: np.ndarray) -> np.ndarray:
    return rgb.astype(np.float64) @ np.array([0.2126, 0.7152, 0.0722])


# --------------------------------------------------------------------------- flow wheel


def test_color_wheel_table_matches_reference():
    wheel = viz.make_color_wheel()
    assert wheel.shape == (55, 3) and wheel.dtype == np.uint8
    expected = {
        0: (255, 0, 0), 1: (255, 17, 0), 15: (255, 255, 0), 21: (0, 255, 0),
        25: (0, 255, 255), 27: (0, 209, 255), 36: (0, 0, 255), 49: (255, 0, 255),
        54: (255, 0, 43),
    }
    for k, rgb in expected.items():
        assert tuple(wheel[k]) == rgb, k


def test_zero_flow_is_white():
    u = np.array([[0.0, 3.0], [0.0, -1.0]])
    v = np.array([[0.0, 4.0], [0.0, 0.5]])
    rgb = viz.flow_to_color(u, v)
    assert rgb.shape == (2, 2, 3) and rgb.dtype == np.uint8
    assert tuple(rgb[0, 0]) == (255, 255, 255)
    assert tuple(rgb[1, 0]) == (255, 255, 255)
    # an all-zero field has no scale at all: still white, no division by zero
    assert (viz.flow_to_color(np.zeros((3, 4)), np.zeros((3, 4))) == 255).all()


@pytest.mark.parametrize(
    "uv, expected",
    [
        ((2.0, 0.0), (255, 0, 0)),      # right: wheel colour 0
        ((-2.0, 0.0), (0, 209, 255)),   # left: wheel colour 27
        ((0.0, 2.0), (255, 229, 0)),    # down: between wheel colours 13 and 14
        ((1.0, 0.0), (255, 127, 127)),  # right at half the maximum: half saturated
    ],
)
def test_direction_colours_at_known_magnitudes(uv, expected):
    # pixel 0 sets the scale (|(u, v)| = 2), pixel 1 is the vector under test
    u = np.array([[2.0, uv[0]]])
    v = np.array([[0.0, uv[1]]])
    assert tuple(viz.flow_to_color(u, v)[0, 1]) == expected


def test_rightward_flow_with_negative_zero_v_is_still_red():
    rgb = viz.flow_to_color(np.array([[1.0]]), np.array([[-0.0]]))
    assert tuple(rgb[0, 0]) == (255, 0, 0)


def test_invalid_flow_is_black():
    u = np.array([[1.0, np.nan, 1.0, np.inf, 1e10]])
    v = np.array([[0.5, 0.0, np.nan, 0.0, 0.0]])
    rgb = viz.flow_to_color(u, v)
    assert (rgb[0, 1:] == 0).all()
    assert tuple(rgb[0, 0]) != (0, 0, 0)


def test_fixed_max_flow_shares_the_scale_between_images():
    a_u = np.array([[1.0, 2.0]]); a_v = np.array([[1.0, 0.0]])   # max |u| = 2
    b_u = np.array([[1.0, 5.0]]); b_v = np.array([[1.0, 0.0]])   # max |u| = 5
    auto_a, auto_b = viz.flow_to_color(a_u, a_v), viz.flow_to_color(b_u, b_v)
    assert tuple(auto_a[0, 0]) != tuple(auto_b[0, 0])
    fixed_a = viz.flow_to_color(a_u, a_v, max_flow=5.0)
    fixed_b = viz.flow_to_color(b_u, b_v, max_flow=5.0)
    assert tuple(fixed_a[0, 0]) == tuple(fixed_b[0, 0])


def test_flow_beyond_max_flow_is_darkened():
    rgb = viz.flow_to_color(np.array([[10.0]]), np.array([[0.0]]), max_flow=5.0)
    assert tuple(rgb[0, 0]) == (191, 0, 0)  # floor(255 * 0.75)


def test_flow_to_color_rejects_bad_inputs():
    with pytest.raises(ValueError, match="shape"):
        viz.flow_to_color(np.zeros((2, 3)), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="max_flow"):
        viz.flow_to_color(np.zeros((2, 2)), np.zeros((2, 2)), max_flow=0.0)


def test_wheel_legend_size_and_layout():
    legend = viz.flow_wheel_legend(65)
    assert legend.shape == (65, 65, 3) and legend.dtype == np.uint8
    assert tuple(legend[32, 32]) == (255, 255, 255)   # centre: zero flow
    assert tuple(legend[32, 64]) == (255, 0, 0)       # right rim: full red
    assert tuple(legend[0, 0]) == (255, 255, 255)     # corner: outside the disc
    assert viz.flow_wheel_legend(10).shape == (10, 10, 3)
    assert viz.flow_wheel_legend(np.int64(3)).shape == (3, 3, 3)
    for bad in (0, 10**5, 2.7, True, "64"):  # (10**5 asked for 75 GiB; 2.7 became 2)
        with pytest.raises(ValueError, match="size"):
            viz.flow_wheel_legend(bad)


# --------------------------------------------------------------------------- scalar maps


def test_disparity_colormap_is_monotone_in_luminance():
    ramp = np.linspace(-2.0, 3.0, 256)[None, :]
    rgb = viz.disparity_to_color(ramp, vmin=-2.0, vmax=3.0)
    lum = _luminance(rgb[0])
    assert np.all(np.diff(lum) >= -1e-9)
    assert lum[-1] - lum[0] > 150
    # clipped beyond the range: ends equal the end colours
    clipped = viz.disparity_to_color(np.array([[-10.0, 10.0]]), vmin=-2.0, vmax=3.0)
    assert tuple(clipped[0, 0]) == tuple(rgb[0, 0])
    assert tuple(clipped[0, 1]) == tuple(rgb[0, -1])


def test_disparity_default_range_uses_robust_percentiles():
    disp = np.linspace(0.0, 1.0, 1000).reshape(20, 50)
    disp[0, 0] = 1e6  # one wild outlier must not wash out the rest
    rgb = viz.disparity_to_color(disp)
    lum = _luminance(rgb.reshape(-1, 3))
    assert lum[1:].max() - lum[1:].min() > 150


def test_disparity_nan_is_invalid_colour():
    disp = np.array([[0.0, np.nan], [1.0, np.inf]])
    rgb = viz.disparity_to_color(disp, invalid_color=(255, 0, 255))
    assert tuple(rgb[0, 1]) == (255, 0, 255) and tuple(rgb[1, 1]) == (255, 0, 255)
    assert tuple(viz.disparity_to_color(disp)[0, 1]) == (0, 0, 0)
    # constant maps and all-NaN maps do not crash
    assert viz.disparity_to_color(np.full((2, 2), 0.5)).shape == (2, 2, 3)
    assert (viz.disparity_to_color(np.full((2, 2), np.nan)) == 0).all()
    with pytest.raises(ValueError, match="vmin < vmax"):
        viz.disparity_to_color(disp, vmin=1.0, vmax=1.0)


def test_error_colormap_white_at_zero_darker_with_error_nan_invalid():
    err = np.array([[0.0, 0.5, 1.0, 2.0, np.nan]])
    rgb = viz.error_to_color(err, 1.0)
    assert tuple(rgb[0, 0]) == (255, 255, 255)
    lum = _luminance(rgb[0, :4])
    assert lum[0] > lum[1] > lum[2] and lum[2] == lum[3]  # clipped at vmax
    assert tuple(rgb[0, 4]) == (0, 0, 0)
    with pytest.raises(ValueError, match="vmax"):
        viz.error_to_color(err, -1.0)


def test_error_scale_is_the_99th_percentile_and_the_table_rounds_to_nearest():
    """The default error scale is the 99th percentile, as documented (an error of 0.97 of
    a 0…1 ramp is not yet the darkest colour; with a 95th percentile it was), and a value
    is drawn with the nearest entry of the colour table (not the one below)."""
    err = np.linspace(0.0, 1.0, 10001)[None]
    assert viz._error_scale(err) == pytest.approx(0.99)
    rgb = viz.error_to_color(err)
    np.testing.assert_array_equal(rgb[0, 9700], viz.error_to_color(np.array([[0.97]]), 0.99)[0, 0])
    assert tuple(rgb[0, 9700]) != tuple(rgb[0, -1])
    table = viz._DISPARITY_LUT
    step = 1.0 / (len(table) - 1)
    near = viz.disparity_to_color(np.array([[1.0 - 0.4 * step, 0.4 * step, 0.6 * step]]), vmin=0.0, vmax=1.0)
    np.testing.assert_array_equal(near[0], [table[-1], table[0], table[1]])


# --------------------------------------------------------------------------- overview


def _scene(h=48, w=64, seed=0):
    """A made-up scene: a disparity ramp and a rotating flow field, noisy estimates."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    centre1 = 0.4 + 0.3 * np.sin(x / 4.0) * np.cos(y / 5.0)  # stays below header grey
    centre2 = np.roll(centre1, 2, axis=1)
    gt = {
        "disp1": -1.0 + 2.0 * x / (w - 1),
        "disp2": -0.9 + 2.0 * x / (w - 1),
        "u": -(y - h / 2) * 0.1,
        "v": (x - w / 2) * 0.1,
    }
    est = {k: a + rng.normal(0.0, 0.05, a.shape) for k, a in gt.items()}
    return centre1, centre2, est, gt


def _count_panels(fig: np.ndarray) -> int:
    """Number of header strips: runs of header colour on each strip's top pixel row."""
    mask = (fig == np.array(viz._HEADER_RGB, dtype=np.uint8)).all(axis=-1)
    has = mask.any(axis=1)
    tops = np.flatnonzero(has & ~np.concatenate([[False], has[:-1]]))
    count = 0
    for y in tops:
        row = np.concatenate([[False], mask[y], [False]]).astype(np.int8)
        starts = np.flatnonzero(np.diff(row) == 1)
        ends = np.flatnonzero(np.diff(row) == -1)
        count += int(np.sum(ends - starts >= 32))
    return count


def test_overview_panel_count_grows_with_ground_truth(tmp_path):
    c1, c2, est, gt = _scene()
    plain = viz.overview_figure(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"])
    full = viz.overview_figure(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"], gt=gt)
    assert plain.dtype == np.uint8 and plain.ndim == 3 and plain.shape[2] == 3
    assert _count_panels(plain) == 5    # 2 centre views + disp1, disp2, flow
    assert _count_panels(full) == 11    # + 3 ground truth + 3 errors
    assert full.shape[1] == plain.shape[1]
    # two more rows of equal height: the grid grows by twice the pitch of one row (the
    # grids alone, without the notes below them, which say more with ground truth)
    grids = [viz._compose(viz._overview_panels(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"], truth, None),
                          None) for truth in (None, gt)]
    row_pitch = (grids[1].shape[0] - grids[0].shape[0]) // 2
    assert row_pitch > 48 and grids[1].shape[0] - grids[0].shape[0] == 2 * row_pitch
    # a 64-pixel-wide input is upscaled by an integer factor: panels are wider than it
    assert plain.shape[1] > 3 * 4 * 64


def test_overview_shows_the_points_not_seen_at_t2_beside_the_centre_views():
    """With ``occluded`` a third panel joins row 1: the t1 centre view dimmed to grey and
    the marked points in magenta, at the marked points only; the rest of the figure is
    the same pixel for pixel. A mask of the wrong shape or type is an error."""
    c1, c2, est, gt = _scene()
    occluded = np.zeros(c1.shape, bool)
    occluded[10:20, 30:40] = True
    plain = viz.overview_figure(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"], gt=gt)
    marked = viz.overview_figure(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"], gt=gt, occluded=occluded)
    assert _count_panels(marked) == _count_panels(plain) + 1 and marked.shape == plain.shape
    changed = np.any(marked != plain, axis=2)
    ys, xs = np.nonzero(changed)
    assert xs.min() > 2 * plain.shape[1] // 3  # only in the third column
    magenta = np.all(marked == viz.OCCLUDED_COLOUR, axis=2)
    factor = int(round(np.sqrt(magenta.sum() / occluded.sum())))  # the panel's upscaling
    assert magenta.sum() == occluded.sum() * factor ** 2
    picture = viz.occluded_picture(c1, occluded)
    assert picture.shape == c1.shape + (3,) and (picture[occluded] == viz.OCCLUDED_COLOUR).all()
    grey = picture[~occluded]
    assert (grey[:, 0] == grey[:, 1]).all() and grey.min() >= 64  # dimmed, never black
    # whose mask it is, and an empty one said (a dimmed photo without a word on HCI)
    def mask_label(mask, **kw):
        return viz._overview_panels(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"], None, None,
                                    occluded=mask, **kw)[0][2].label

    assert mask_label(occluded) == "estimate: not seen at t2 (magenta)"
    assert mask_label(occluded, label="ground truth") == "ground truth: not seen at t2 (magenta)"
    assert mask_label(np.zeros_like(occluded)) == "estimate: not seen at t2: none"
    with pytest.raises(ValueError, match="occluded of shape"):
        viz.overview_figure(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"], occluded=occluded[:-1])
    with pytest.raises(ValueError, match="bool"):
        viz.occluded_picture(c1, occluded.astype(float))


def test_overview_is_written_as_readable_png_without_leftovers(tmp_path):
    c1, c2, est, gt = _scene()
    target = tmp_path / "figs" / "overview.png"
    fig = viz.overview_figure(c1, np.stack([c2] * 3, axis=-1), est["disp1"], est["disp2"],
                              est["u"], est["v"], gt=gt, path=target, title="test scene")
    assert sorted(p.name for p in target.parent.iterdir()) == ["overview.png"]
    np.testing.assert_array_equal(iio.imread(target), fig)
    # its words in the file too (a picture's text, for readers that cannot see it)
    from PIL import Image

    with Image.open(target) as png:
        text = dict(png.text)
    assert text["Title"] == "test scene"
    # a title with a file name not in UTF-8 (its bytes as Python's stand-ins): it had failed the save
    viz.overview_figure(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"], path=target,
                        title="lfsf run: caf\udce9.npz and b.npz")
    with Image.open(target) as png:
        assert png.text["Title"] == "lfsf run: caf\\udce9.npz and b.npz"
    assert text["Comment"].startswith("panels: centre view t1, centre view t2, disp1 estimate, ")
    assert "flow EPE  mean" in text["Comment"] and "disparities in px per view step" in text["Comment"]


def test_overview_error_panels_mean_and_valid_mask():
    c1, c2, est, gt = _scene()
    valid = np.ones_like(gt["disp1"], dtype=bool)
    valid[:, :5] = False
    est["disp1"][:, :5] += 100.0  # huge errors, but outside the mask
    rows = viz._overview_panels(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"],
                                dict(gt, valid=valid), None)
    assert [len(r) for r in rows] == [2, 3, 3, 3]
    err1 = rows[3][0]
    expected = np.abs(est["disp1"] - gt["disp1"])[valid].mean()
    assert f"mean {expected:.3g}" in err1.label
    epe = np.hypot(est["u"] - gt["u"], est["v"] - gt["v"])[valid].mean()
    assert f"mean {epe:.3g}" in rows[3][2].label
    for panel in rows[3] + rows[2]:  # error and ground-truth panels: invalid is black
        assert (panel.image[:, :5] == 0).all()
        assert (panel.image[:, 5:].reshape(-1, 3) != 0).any(axis=1).all()
    # estimate and ground truth, δ1 and δ2 share one disparity scale; both flows one
    assert rows[1][0].footer == rows[2][0].footer == rows[1][1].footer == rows[2][1].footer
    assert rows[1][2].footer == rows[2][2].footer
    # … the 1st and 99th percentiles of all four maps' values, beyond which lie some: the
    # ends are marked (the huge errors outside the mask are no disparities of the truth)
    shown = [est["disp1"], est["disp2"], np.where(valid, gt["disp1"], np.nan), np.where(valid, gt["disp2"], np.nan)]
    finite = np.concatenate([m[np.isfinite(m)] for m in shown])
    assert np.allclose((rows[1][0].footer.lo, rows[1][0].footer.hi), np.percentile(finite, [1, 99]))
    assert rows[1][0].footer.below and rows[1][0].footer.above
    bar = rows[1][0].footer  # (equal by colours and numbers, on every Python: 3.13's dataclass == failed)
    assert bar == viz._ColorBar(bar.lut.copy(), bar.lo, bar.hi, bar.below, bar.above)
    assert bar != viz._ColorBar(bar.lut, bar.lo, bar.hi + 1.0, bar.below, bar.above)
    assert bar != viz._ColorBar(bar.lut[::-1], bar.lo, bar.hi, bar.below, bar.above)
    assert bar != viz._ColorBar(bar.lut, bar.lo, bar.hi, bar.below, not bar.above)


def test_overview_rejects_mismatched_shapes():
    c1, c2, est, gt = _scene()
    with pytest.raises(ValueError, match="shape"):
        viz.overview_figure(c1, c2, est["disp1"], est["disp2"][:-1], est["u"], est["v"])
    # the map of another shape is the one named, against the centre view's shape (disp1 is
    # not the measure of the others)
    with pytest.raises(ValueError, match=re.escape(f"expected disp1 of shape {c1.shape[:2]} (the centre view's), "
                                                   f"got {est['disp1'][:-1].shape}")):
        viz.overview_figure(c1, c2, est["disp1"][:-1], est["disp2"], est["u"], est["v"])
    # where the four maps agree, the centre view is the one named (disp1 was)
    with pytest.raises(ValueError, match=re.escape(f"expected centre1 of the maps' shape {est['disp1'].shape} (the "
                                                   f"views they were estimated on), got (5, 5)")):
        viz.overview_figure(np.zeros((5, 5)), c2, est["disp1"], est["disp2"], est["u"], est["v"])
    for partial in ({"u": gt["u"]}, {"valid": np.ones(c1.shape[:2], bool)}):  # half a flow; no map at all
        with pytest.raises(ValueError, match="u without v|it has \\['valid'\\]"):
            viz.overview_figure(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"], gt=partial)


def test_an_overview_against_part_of_a_ground_truth():
    """An HCI benchmark's truth is δ1 alone: its row and its error show δ1, and the
    panels of δ2 and the flow say that there is no ground truth for them."""
    c1, c2, est, gt = _scene()
    rows = viz._overview_panels(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"], {"disp1": gt["disp1"]}, None)
    assert [p.label for p in rows[2]] == ["disp1 ground truth", "disp2: no ground truth", "flow: no ground truth"]
    assert [p.label.split("  ")[0] for p in rows[3]] == ["|disp1 - GT|", "|disp2 - GT|: no ground truth",
                                                         "flow EPE: no ground truth"]
    assert f"mean {np.abs(est['disp1'] - gt['disp1']).mean():.3g}" in rows[3][0].label
    for panel in rows[2][1:] + rows[3][1:]:
        assert (panel.image == viz.NOT_ESTIMATED_GREY).all() and panel.footer is None
    # without the truth's flow, the estimate's flow is drawn on its own scale
    alone = viz._overview_panels(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"], None, None)
    assert np.array_equal(rows[1][2].image, alone[1][2].image) and rows[1][2].footer == alone[1][2].footer
    flow_only = viz._overview_panels(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"],
                                     {"u": gt["u"], "v": gt["v"]}, None)
    assert [p.label for p in flow_only[2]] == ["disp1: no ground truth", "disp2: no ground truth", "flow ground truth"]


# --------------------------------------------------------------------------- save_png


def test_save_png_converts_float_and_grey(tmp_path):
    grey = np.array([[0.0, 0.5], [1.0, 1.2]])
    viz.save_png(tmp_path / "g.png", grey)
    np.testing.assert_array_equal(iio.imread(tmp_path / "g.png"), [[0, 128], [255, 255]])
    # 16 bits written as 8; 0…255 as floats refused (it had come out an image of 255s)
    viz.save_png(tmp_path / "w.png", np.array([[0, 257], [32896, 65535]], np.uint16))
    np.testing.assert_array_equal(iio.imread(tmp_path / "w.png"), [[0, 1], [128, 255]])
    with pytest.raises(ValueError, match=r"got values 0…200: divide 8-bit values by 255"):
        viz.save_png(tmp_path / "bad.png", np.array([[0.0, 100.0], [np.nan, 200.0]]))
    rgb = np.zeros((3, 4, 3), dtype=np.uint8)
    rgb[..., 1] = 200
    viz.save_png(tmp_path / "c.png", rgb)
    np.testing.assert_array_equal(iio.imread(tmp_path / "c.png"), rgb)
    with pytest.raises(ValueError, match="shape"):
        viz.save_png(tmp_path / "bad.png", np.zeros((2, 2, 2), dtype=np.uint8))
    with pytest.raises(ValueError, match="dtype"):
        viz.save_png(tmp_path / "bad.png", np.zeros((2, 2), dtype=np.int32))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.png", "g.png", "w.png"]


@pytest.mark.parametrize("failure", [OSError("disk full"), KeyboardInterrupt()])
def test_failing_write_leaves_no_partial_or_open_file(tmp_path, monkeypatch, failure):
    """A write that fails (a full disk) or is interrupted leaves neither a partial file
    nor an open one: Pillow closes a file it opened itself on an Exception only, and an
    interrupt had left the part file open until the collector came (a ResourceWarning)."""
    target = tmp_path / "out.png"
    target.write_bytes(b"previous")
    files = []

    def broken_save(image, fp, format=None, **params):
        fp.write(b"\x89PNG half")  # a partial file, then the disk "fails"
        files.append(fp)
        raise failure

    monkeypatch.setattr(viz.Image.Image, "save", broken_save)
    with pytest.raises(type(failure)):
        viz.save_png(target, np.zeros((4, 4), dtype=np.uint8))
    with pytest.raises(type(failure)):
        viz.save_png(tmp_path / "new.png", np.zeros((4, 4), dtype=np.uint8), text={"Title": "a"})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.png"]
    assert target.read_bytes() == b"previous"
    assert len(files) == 2 and all(f.closed for f in files)


def test_a_tall_narrow_image_is_not_enlarged_into_a_huge_picture():
    c = np.random.default_rng(0).random((3000, 8)).astype(np.float32)
    img = viz.overview_figure(c, c, c, c, c, c)
    assert img.shape[0] < 3 * 3000 + 1000 and img.shape[1] < 1000


def test_odd_maps_and_titles_are_handled_quickly_or_refused_clearly():
    """A finite map spanning ±1e308 (hi − lo overflowed: an IndexError), an infinite end
    (the same), a 0×5 map (a ZeroDivisionError), a 10000-character title (33 s, shortened
    one character at a time)."""
    import signal

    # and with no range given: the percentiles' interpolation overflowed (ends inf and −inf)
    assert (viz.disparity_to_color(np.array([[-1e308, 1e308]]))
            == viz.disparity_to_color(np.array([[-1.0, 1.0]]))).all()
    rgb = viz.disparity_to_color(np.array([[-1e308, 1e308], [0.0, 1.0]]), vmin=-1e308, vmax=1e308)
    assert rgb[0, 0].tolist() == viz.disparity_to_color(np.array([[0.0, 1.0]]))[0, 0].tolist()
    assert (rgb[1, 0] == rgb[1, 1]).all()         # 0 and 1 are the same colour on that scale
    with pytest.raises(ValueError, match="expected finite ends of the colour scale, got -inf"):
        viz.disparity_to_color(np.zeros((2, 2)), vmin=-np.inf, vmax=1.0)
    empty = np.zeros((0, 5))
    with pytest.raises(ValueError, match=r"at least one pixel, got shape \(0, 5\)"):
        viz.overview_figure(empty, empty, empty, empty, empty, empty)
    maps = np.zeros((4, 5))
    short = viz.overview_figure(maps, maps, maps, maps, maps, maps, title="x" * 300)
    # (a guard against a hang, not a timing: one character at a time this took many minutes)
    previous = signal.signal(signal.SIGALRM, lambda *_: pytest.fail("still shortening the title after 120 s"))
    signal.alarm(120)
    try:
        long = viz.overview_figure(maps, maps, maps, maps, maps, maps, title="x" * 100_000)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    assert np.array_equal(short, long)                 # the same shortened title



def test_a_title_with_line_breaks_is_drawn_on_one_line():
    """A title with a newline (Pillow's "can't measure length of multiline text" ended
    SceneFlow.save with nothing written) is drawn as the same words on one line."""
    maps = np.zeros((4, 5))
    broken = viz.overview_figure(maps, maps, maps, maps, maps, maps, title="paper\nfast\t 48×40")
    assert np.array_equal(broken, viz.overview_figure(maps, maps, maps, maps, maps, maps, title="paper fast 48×40"))


def test_centre_views_beyond_0_1_are_shown_on_their_joint_scale():
    """Float views in 0…255 (which the estimator stretches for itself) were clipped to a
    white overview; they are shown on the two views' joint range, the same picture as
    the views in [0, 1]. Views in [0, 1] are shown as they are."""
    rng = np.random.default_rng(0)
    c1, c2 = rng.random((12, 16)), rng.random((12, 16))
    c1[0, 0], c2[0, 1] = 0.0, 1.0                 # (the joint range exactly 0…1)
    maps = np.zeros((12, 16))
    unit = viz.overview_figure(c1, c2, maps, maps, maps, maps)
    assert np.array_equal(viz.overview_figure(255.0 * c1, 255.0 * c2, maps, maps, maps, maps), unit)
    assert not np.array_equal(viz.overview_figure(0.5 * c1, 0.5 * c2, maps, maps, maps, maps), unit)


@pytest.mark.parametrize("name", ["x.jpg", "x", "x.png.tmp"])
def test_save_png_refuses_a_name_that_says_another_format(tmp_path, name):
    with pytest.raises(ValueError, match="must end in .png"):
        viz.save_png(tmp_path / name, np.zeros((4, 4), np.uint8))
    assert list(tmp_path.iterdir()) == []
    viz.save_png(tmp_path / "x.PNG", np.zeros((4, 4), np.uint8))
    assert (tmp_path / "x.PNG").is_file()


def test_the_overview_marks_clipped_bar_ends_and_says_its_units():
    """A bar's end reads '<=' or '>=' where values lie beyond it (drawn in its colour:
    a small near object above the 99th percentile looked like the backdrop's far end);
    the last line gives the units and what the marks mean, and with ground truth what
    black is."""
    c1, c2, est, gt = _scene()
    rows = viz._overview_panels(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"], None, None)
    bar = rows[1][0].footer
    assert bar.below and bar.above  # (noisy maps: 1 % of the values lie beyond each end)
    even = np.tile(np.linspace(0.0, 1.0, 64), (48, 1))
    rows = viz._overview_panels(c1, c2, even, even, est["u"], est["v"], None, None)
    bar = rows[1][0].footer
    assert not bar.below and not bar.above or (bar.lo, bar.hi) != (0.0, 1.0)
    assert viz._overview_notes(rows, None) == "disparities in px per view step, flow in px"
    rows = viz._overview_panels(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"], gt, None)
    assert viz._overview_notes(rows, gt) == ("disparities in px per view step, flow and its errors in px; <= or >= at "
                                             "a bar's end: values beyond it take its colour")
    # black only where the truth leaves pixels out; no flow errors without the truth's flow
    valid = np.ones(c1.shape[:2], bool)
    valid[:, :3] = False
    masked = dict(gt, valid=valid)
    rows = viz._overview_panels(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"], masked, None)
    assert viz._overview_notes(rows, masked).endswith("; hatched grey: no ground truth there")
    # … and where the estimate is not finite (it had been black, as the truth's no value, without a note)
    holed = est["disp1"].copy()
    holed[5, 5] = np.nan
    rows = viz._overview_panels(c1, c2, holed, est["disp2"], est["u"], est["v"], masked, None)
    assert viz._overview_notes(rows, masked).endswith(
        "; hatched grey: no ground truth there or the estimate not finite there")
    rows = viz._overview_panels(c1, c2, holed, est["disp2"], est["u"], est["v"], None, None)
    assert viz._overview_notes(rows, None).endswith("; hatched grey: the estimate not finite there")
    hci = {"disp1": gt["disp1"]}
    rows = viz._overview_panels(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"], hci, None)
    assert viz._overview_notes(rows, hci).startswith("disparities in px per view step, flow in px;")
    rows = viz._overview_panels(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"], gt, None)
    figure = viz.overview_figure(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"], gt=gt)
    grid = viz._compose(rows, None)
    assert figure.shape[1] == grid.shape[1] and figure.shape[0] > grid.shape[0]  # the notes, below the grid
    assert np.array_equal(figure[:grid.shape[0] - viz._MARGIN], grid[:grid.shape[0] - viz._MARGIN])


def test_the_overview_error_means_are_over_the_pixels_lfsf_eval_scores():
    """With ``border`` the error panels' means leave out the border as lfsf eval does: the
    flow EPE in the picture is the table's (the demo's overview said 0.0409 under a
    table's 0.0441: its mean took in the 8-px border), and the notes line says so."""
    from lfsf.evaluate import evaluate

    c1, c2, est, gt = _scene()
    valid = np.ones(c1.shape[:2], bool)
    valid[10:20, 10:30] = False
    truth = dict(gt, valid=valid)
    errors = evaluate(est, truth, border=8)
    rows = viz._overview_panels(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"], truth, None, border=8)
    labels = [panel.label for panel in rows[-1]]
    assert labels[2] == f"flow EPE  mean {errors['flow']['epe']:.3g}"
    inner = valid.copy()
    inner[:8], inner[-8:], inner[:, :8], inner[:, -8:] = False, False, False, False
    assert labels[0] == f"|disp1 - GT|  mean {np.abs(est['disp1'] - gt['disp1'])[inner].mean():.3g}"
    whole = viz._overview_panels(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"], truth, None)
    assert whole[-1][2].label != labels[2]  # (the border's pixels do count without it)
    assert viz._overview_notes(rows, truth, border=8).endswith(
        "; error means and scales without the 8-px border (paler), as lfsf eval")
    assert "border" not in viz._overview_notes(whole, truth)
    # the scale too: a large error in the border alone (one wrong corner of HCI's 15 px had
    # set a 2.8-px scale over errors mostly under 0.5) leaves it as it was
    corner = dict(est, disp1=est["disp1"].copy())
    corner["disp1"][:8, :8] += 50.0
    spoilt = viz._overview_panels(c1, c2, corner["disp1"], est["disp2"], est["u"], est["v"], truth, None, border=8)
    assert spoilt[-1][0].footer.hi == rows[-1][0].footer.hi and spoilt[-1][0].label == labels[0]
    # … and the border drawn paler than the same errors inside
    e = np.abs(est["disp1"] - gt["disp1"])
    picture, drawn = rows[-1][0].image, viz.error_to_color(e, rows[-1][0].footer.hi)
    assert np.array_equal(picture[inner], drawn[inner]) and (picture[:8] >= drawn[:8]).all()
    assert (picture[:8].astype(int) - drawn[:8]).mean() > 20
    # where the truth has no value the border is black, as inside (the notes' "black: no ground truth")
    holed = dict(truth, valid=valid.copy())
    holed["valid"][:4, :4] = False
    picture = viz._overview_panels(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"], holed, None,
                                   border=8)[-1][0].image
    assert (picture[:4, :4] == 0).all() and (picture[4:8, 4:8] > 0).any()
    for gt in (truth, None):  # (checked without a ground truth too)
        with pytest.raises(ValueError, match="border must be a whole number"):
            viz._overview_panels(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"], gt, None, border=-1)


def test_a_flow_only_overview_says_its_disparities_were_not_estimated():
    """disparities=False (a flow-only run: δ1, δ2 are zeros): their panels, and their
    error panels, are grey and say so, without a colour bar; the flow's are as before."""
    c1, c2, est, gt = _scene()
    zeros = np.zeros_like(est["disp1"])
    for truth, expected in ((None, [2, 3]), (gt, [2, 3, 3, 3])):
        rows = viz._overview_panels(c1, c2, zeros, zeros, est["u"], est["v"], truth, None, disparities=False)
        assert [len(r) for r in rows] == expected
        skipped = [rows[1][0], rows[1][1]] + ([rows[3][0], rows[3][1]] if truth else [])
        for panel, name in zip(skipped, ["disp1", "disp2"] * 2):
            assert panel.label == f"{name}: not estimated (flow only)" and panel.footer is None
            assert (panel.image == viz.NOT_ESTIMATED_GREY).all()
        full = viz._overview_panels(c1, c2, zeros, zeros, est["u"], est["v"], truth, None)

        def same(a, b):
            return a.label == b.label and np.array_equal(a.image, b.image) and a.footer == b.footer

        assert same(rows[1][2], full[1][2])
        if truth:
            assert rows[2][0].label == "disp1 ground truth" and same(rows[3][2], full[3][2])
    rows = viz._overview_panels(c1, c2, zeros, zeros, est["u"], est["v"], None, None, disparities=False)
    assert viz._overview_notes(rows, None, disparities=False) == "flow in px"


def test_rows_without_keys_have_no_footer_strip_and_the_wheel_is_readable():
    """The centre views' row has no keys, so no blank footer band under it (a 30-px band
    before the next row); the flow's colour wheel is _WHEEL_KEY px across (16 was too
    small to make out its directions)."""
    c1, c2, est, gt = _scene()
    fig = viz.overview_figure(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"], gt=gt)
    mask = (fig == np.array(viz._HEADER_RGB, dtype=np.uint8)).all(axis=-1)
    rows = np.flatnonzero(mask.sum(axis=1) >= 32)
    tops = rows[np.concatenate([[True], np.diff(rows) > 1])]
    assert len(tops) == 4
    pitches = np.diff(tops)
    assert pitches[1] == pitches[2] and pitches[1] - pitches[0] == viz._WHEEL_KEY + 2 * viz._PAD
    rows_ = viz._overview_panels(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"], gt, None)
    grid = viz._compose(rows_, None)
    wheel = viz.flow_wheel_legend(viz._WHEEL_KEY)
    # the wheel is pasted into the flow panel's footer, somewhere: find it exactly
    h, w = wheel.shape[:2]
    found = any(np.array_equal(grid[y:y + h, x:x + w], wheel)
                for y in range(grid.shape[0] - h) for x in range(2 * grid.shape[1] // 3, grid.shape[1] - w)
                if np.array_equal(grid[y + h // 2, x + w // 2], wheel[h // 2, w // 2]))
    assert found


def test_flow_scale_is_the_full_colour_magnitude_flow_to_color_takes():
    """viz.flow_scale (what a result's flow.png says it is drawn at) is flow_to_color's
    own default: drawing at it gives the same picture, invalid vectors left out."""
    rng = np.random.default_rng(1)
    u, v = (rng.normal(0, 2, (12, 16)).astype(np.float32) for _ in range(2))
    u[0, 0] = np.nan
    v[1, 1] = 1e10  # (unknown flow, Middlebury's marker)
    scale = viz.flow_scale(u, v)
    ok = np.isfinite(u) & (np.abs(v) < 1e9)
    assert scale == pytest.approx(float(np.hypot(u[ok].astype(np.float64), v[ok].astype(np.float64)).max()))
    assert np.array_equal(viz.flow_to_color(u, v), viz.flow_to_color(u, v, scale))
    assert viz.flow_scale(np.zeros((2, 2)), np.zeros((2, 2))) == 0.0


def test_overview_names_the_flow_component_its_ground_truth_lacks():
    """gt = {"u": …} had been refused as "missing ['disp1', 'disp2', 'v']", though only v
    was wanted (δ1 and δ2 may be absent)."""
    z = np.zeros((12, 16), np.float32)
    with pytest.raises(ValueError, match=r"^expected gt's flow as u with v; it has u without v$"):
        viz.overview_figure(z, z, z, z, z, z, gt={"u": z})
    with pytest.raises(ValueError, match=r"^expected gt with keys disp1, disp2 and/or u with v; it has \['valid'\]$"):
        viz.overview_figure(z, z, z, z, z, z, gt={"valid": z > 0})
    assert viz.overview_figure(z, z, z, z, z, z, gt={"u": z, "v": z}).ndim == 3


def test_pixels_without_a_value_are_hatched_not_black():
    """Black had meant "no ground truth" in the error panels and was near their largest
    errors' dark red for a protanope and in print (a helper's colour-vision simulation:
    ΔE 19). The pixels without a value are hatched in two greys, told apart by their
    pattern; the rest of each panel is its map's colours, unchanged."""
    import math

    c1, c2, est, gt = _scene()
    valid = np.ones(c1.shape[:2], bool)
    valid[10:30, 20:40] = False
    rows = viz._overview_panels(c1, c2, est["disp1"], est["disp2"], est["u"], est["v"], dict(gt, valid=valid), None)
    for panel in rows[2] + rows[3]:  # ground truth and errors: their hole
        assert np.array_equal(panel.missing, ~valid)
    assert not any(panel.missing.any() for panel in rows[1])
    # drawn: both greys, in stripes, over the hole and nowhere else
    s = math.ceil(viz._MIN_PANEL_WIDTH / c1.shape[1])
    big = np.repeat(np.repeat(rows[3][0].image, s, axis=0), s, axis=1)
    hole = np.repeat(np.repeat(~valid, s, axis=0), s, axis=1)
    drawn = big.copy()
    viz._hatch(drawn, hole)
    counts = [int(np.all(drawn[hole] == grey, axis=1).sum()) for grey in viz.HATCH_GREYS]
    assert sum(counts) == hole.sum() and min(counts) > 0.4 * hole.sum(), counts
    assert np.array_equal(drawn[~hole], big[~hole])
    row = drawn[hole.any(axis=1)][0][hole.any(axis=0)]  # a row of the hole: stripes 3 px wide, in turn
    runs = np.diff(np.flatnonzero(np.any(np.diff(row.astype(int), axis=0) != 0, axis=1)))
    assert len({tuple(p) for p in row}) == 2 and set(runs.tolist()) == {viz._HATCH_PERIOD // 2}, runs
    # … and in the figure: the hole of 3 ground-truth and 3 error panels
    figure = viz._compose(rows, None)
    hatch = np.zeros(figure.shape[:2], bool)
    for grey in viz.HATCH_GREYS:
        hatch |= np.all(figure == grey, axis=2)
    assert hatch.sum() >= 6 * hole.sum()


def test_the_occlusion_mask_stays_in_greyscale():
    """The mask's magenta (L* 60) had vanished in print into the dimmed view (L* 27–77):
    now every marked pixel is darker in greyscale than every pixel of the view around."""
    c1, _, _, _ = _scene()
    occluded = np.zeros(c1.shape, bool)
    occluded[10:20, 30:40] = True
    picture = viz.occluded_picture(c1, occluded).astype(float) / 255.0
    linear = np.where(picture <= 0.04045, picture / 12.92, ((picture + 0.055) / 1.055) ** 2.4)
    luminance = linear @ np.array([0.2126, 0.7152, 0.0722])
    lightness = np.where(luminance > 0.008856, 116 * np.cbrt(luminance) - 16, 903.3 * luminance)
    assert lightness[occluded].max() + 25 < lightness[~occluded].min(), (lightness[occluded].max(),
                                                                         lightness[~occluded].min())


def test_text_and_keys_grow_with_wide_panels():
    """A 640×480 input's overview is 1952 px wide; its 13-px labels read as 7 px fitted
    to a page. Wide panels now get a font and keys in proportion; small ones as before."""
    rng = np.random.default_rng(0)
    heights = {}
    for w, h in ((64, 48), (640, 480)):
        c = rng.random((h, w))
        d = rng.random((h, w))
        rows = viz._overview_panels(c, c, d, d, d, d, None, None)
        figure = viz._compose(rows, "title")
        scale = max(1, min(-(-viz._MIN_PANEL_WIDTH // w), viz._MAX_PANEL_HEIGHT // h))
        heights[w] = figure.shape[0] - 2 * scale * h  # what is not the panels: text and keys
    assert heights[640] > 1.3 * heights[64], heights


def test_a_narrow_flow_key_keeps_its_number():
    """A tall, narrow input's flow key read "full colour at |(u,v)| = .." (a helper's
    60×640 picture): the words go before the number does."""
    from PIL import Image, ImageDraw

    draw, font = ImageDraw.Draw(Image.new("RGB", (1, 1))), viz._font()
    wide = viz._wheel_label(draw, font, 9.28, 400)
    assert wide == "full colour at |(u,v)| = 9.28 px"
    narrow = viz._wheel_label(draw, font, 9.28, int(draw.textlength(wide, font=font)) - 1)
    assert narrow == "full: 9.28 px"
    assert viz._wheel_label(draw, font, 9.28, int(draw.textlength("full: 9.28 px", font=font)) - 1) == "9.28 px"


def test_a_scene_flow_shows_itself_as_a_picture_of_its_maps():
    """A notebook shows a result at a cell's end by its ``_repr_png_``: the overview's
    estimate row (δ1, δ2 on one scale, the flow, their keys) under its size, radius and
    device, without the centre views it does not hold; a flow-only result's disparities
    as not estimated."""
    import io as io_module

    from PIL import Image

    from lfsf import Params
    from lfsf.estimate import SceneFlow

    rng = np.random.default_rng(3)
    d1, d2, u, v = (rng.normal(size=(30, 40)).astype(np.float32) for _ in range(4))
    sf = SceneFlow(d1, d2, u, v, Params.preset("fast"), 2.0, "cpu")
    picture = np.asarray(Image.open(io_module.BytesIO(sf._repr_png_())).convert("RGB"))
    expected = viz.maps_figure(d1, d2, u, v, title="SceneFlow 40x30, R=2, cpu")
    np.testing.assert_array_equal(picture, expected)
    whole = viz.overview_figure(d1, d1, d1, d2, u, v)
    assert expected.shape[1] == whole.shape[1] and expected.shape[0] < whole.shape[0]
    flow_only = SceneFlow(d1 * 0, d2 * 0, u, v, Params.preset("flow"), 0.0, "cpu")
    shown = np.asarray(Image.open(io_module.BytesIO(flow_only._repr_png_())).convert("RGB"))
    assert shown.shape == expected.shape and not np.array_equal(shown, expected)
    grey = np.all(shown == viz.NOT_ESTIMATED_GREY, axis=-1)
    assert grey[:, : shown.shape[1] // 3].mean() > 0.4   # (δ1's panel: plain grey)


def test_a_light_field_shows_itself_as_its_centre_view():
    """A notebook shows a light field at a cell's end by its ``_repr_png_``: the centre
    view, 8 bits, grey or RGB; float views beyond [0, 1] from their range (not clipped to
    white), as the overview draws them."""
    import io as io_module

    from PIL import Image

    from lfsf.io import LightField

    rng = np.random.default_rng(5)
    for views in (rng.random((3, 3, 12, 16)), rng.random((3, 3, 12, 16, 3))):
        lf = LightField(views.astype(np.float32))
        shown = np.asarray(Image.open(io_module.BytesIO(lf._repr_png_())))
        np.testing.assert_array_equal(shown, np.round(lf.centre * 255).astype(np.uint8))
    counts = LightField((views * 200).astype(np.float32))          # 0…200 given as floats
    shown = np.asarray(Image.open(io_module.BytesIO(counts._repr_png_()))).astype(float)
    assert (shown == 255).mean() < 0.05 and shown.std() > 30   # (clipped, nearly all would read 255)
