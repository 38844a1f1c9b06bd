"""The check of a light field's layout (lfsf.orientation): a grid or image pair of axes
swapped, or one axis of the grid reversed, is told; the views as lfsf reads them, and
scenes without parallax, are not."""

import warnings

import numpy as np
import pytest

import lfsf
from lfsf.orientation import ORIENTATION_RATIO, layout_costs, layout_warning
from lfsf.synth import add_noise, render_scene

from conftest import data_path

LAYOUTS = {
    "as read": lambda v: v,
    "columns reversed": lambda v: v[:, ::-1],
    "rows reversed": lambda v: v[::-1],
    "grid transposed": lambda v: v.transpose(1, 0, 2, 3),
    "images transposed": lambda v: v.transpose(0, 1, 3, 2),
    "grid transposed, columns reversed": lambda v: v.transpose(1, 0, 2, 3)[:, ::-1],
    "both axes reversed": lambda v: v[::-1, ::-1],  # (δ negated: not told apart)
}
#: What the check should say of each: the name of the layout it finds, or None.
TOLD = {"as read": None, "columns reversed": "one of the grid's axes reversed",
        "rows reversed": "one of the grid's axes reversed", "grid transposed": "two axes swapped:",
        "images transposed": "two axes swapped:", "grid transposed, columns reversed": "two axes swapped and one reversed",
        "both axes reversed": None}


@pytest.fixture(scope="module")
def scenes():
    return {name: render_scene(name, size=(96, 72))[0].views for name in ("paper", "random-3")}


@pytest.mark.parametrize("layout", list(LAYOUTS))
@pytest.mark.parametrize("scene", ["paper", "random-3"])
def test_each_layout_is_told(scenes, scene, layout):
    views = np.ascontiguousarray(LAYOUTS[layout](scenes[scene]))
    said = layout_warning(views, "lf1.npz")
    if TOLD[layout] is None:
        assert said is None
    else:
        assert said is not None and said.startswith(f"lf1.npz: the views look laid out with {TOLD[layout]}")
        costs = layout_costs(views)
        # the layout named matches far better than the views as read
        assert min(v for k, v in costs.items() if k not in ("as read", "no parallax")) < 0.5 * costs["as read"]


@pytest.mark.parametrize("scene", ["random-3", "weak_texture"])
def test_noise_and_colour(scene):
    """With sensor noise (σ = 0.02, on the weakest texture too, where the costs of every
    layout lie within 20 % of each other) and in colour: the layout as read is not told,
    a reversed axis is."""
    lf = add_noise(render_scene(scene, size=(96, 72))[0], 0.02, 5)
    views = lf.views
    assert layout_warning(views, "x") is None
    assert "reversed" in layout_warning(np.ascontiguousarray(views[:, ::-1]), "x")
    colour = np.repeat(views[..., None], 3, axis=-1) * np.array([0.9, 1.0, 1.1], np.float32)
    assert layout_warning(colour, "x") is None
    assert "two axes swapped:" in layout_warning(np.ascontiguousarray(colour.transpose(1, 0, 2, 3, 4)), "x")


@pytest.mark.parametrize("seed", range(4))
def test_noise_alone_is_no_parallax(seed):
    """Every view the same image with its own noise (σ = 0.01): each layout gains about
    as little over no parallax (2·10⁻⁴ of its cost), in ratios that are chance's; without
    the bound on the gain (PARALLAX_GAIN) three of these four had been told."""
    image = render_scene("random-3", size=(96, 72))[0].views[4, 4]
    views = image + np.random.default_rng(seed).normal(0, 0.01, (9, 9) + image.shape).astype(np.float32)
    for layout in ("as read", "grid transposed", "columns reversed"):
        assert layout_warning(np.ascontiguousarray(LAYOUTS[layout](views)), "x") is None


def test_vignetting_does_not_count():
    """Views dimmed towards the grid's rim (to 0.3 of the centre's brightness at the
    corners): each layout's costs rise alike, the gains over no parallax tell them apart."""
    views = render_scene("random-3", size=(96, 72))[0].views
    a = (np.arange(9) - 4)[:, None] / 4
    b = (np.arange(9) - 4)[None, :] / 4
    dimmed = views * (1 - 0.7 * (a ** 2 + b ** 2) / 2).astype(np.float32)[:, :, None, None]
    assert layout_warning(dimmed, "x") is None
    assert "two axes swapped:" in layout_warning(np.ascontiguousarray(dimmed.swapaxes(0, 1)), "x")
    assert "reversed" in layout_warning(np.ascontiguousarray(dimmed[:, ::-1]), "x")


def test_nothing_to_tell():
    """No parallax (every view the same image), a single row of views, views too small:
    nothing said, whatever the layout."""
    views = render_scene("random-3", size=(96, 72))[0].views
    flat = np.broadcast_to(views[4, 4], views.shape)
    assert layout_warning(np.ascontiguousarray(flat.transpose(0, 1, 3, 2)), "x") is None
    assert layout_costs(views[4:5]) is None and layout_costs(views[:, 3:5]) is None
    assert layout_costs(views[:, :, :12, :12]) is None


@pytest.mark.parametrize("scene", ["hci-antinous", "lytro-illum-2067"])
def test_real_data(scene):
    """The real light fields as read are not told; with their columns reversed, they are."""
    views = lfsf.read_lightfield(data_path(scene)).grey().views
    assert layout_warning(views, scene) is None
    assert "one of the grid's axes reversed" in layout_warning(np.ascontiguousarray(views[:, ::-1]), scene)
    costs = layout_costs(np.ascontiguousarray(views.transpose(1, 0, 2, 3)))
    flat = costs["no parallax"]
    assert flat - costs["as read"] < ORIENTATION_RATIO * (flat - costs["swapped"])
    if scene == "lytro-illum-2067":
        # halved, its inner 3×3 views: little parallax (a gain of 2 % over none), but none
        # at all transposed (CLEAR_RATIO)
        small = np.ascontiguousarray(lfsf.LightField(views).downsample(2).views[3:6, 3:6])
        assert layout_warning(small, scene) is None
        assert "two axes swapped:" in layout_warning(np.ascontiguousarray(small.swapaxes(0, 1)), scene)


def test_estimate_warns_of_each_light_field_once(scenes):
    """estimate_scene_flow warns once of each light field laid out otherwise, naming it (a
    t2 transposed had gone unsaid: its centre view is t1's layout's), and its pilots
    (exposure, view gains) do not warn again; a light field given twice (stereo) is told
    once; flow only (one circle) is not checked."""
    good = scenes["random-3"]
    views = np.ascontiguousarray(good.transpose(1, 0, 2, 3))
    dimmer = (good * np.float32(0.8)).astype(np.float32)  # (the exposure's pilot runs too)
    params = lfsf.Params.preset("fast").replace(warps=1, iterations=5, final_iterations=5)

    def said(lf1, lf2, preset=params):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            lfsf.estimate_scene_flow(lf1, lf2, preset)
        assert all(w.category is lfsf.LfsfWarning for w in caught if "laid out" in str(w.message))
        return [str(w.message) for w in caught if "laid out" in str(w.message)]

    told = said(lfsf.LightField(views, source="t1.npz"), dimmer)
    assert len(told) == 1 and told[0].startswith("t1.npz: the views look laid out with two axes swapped"), told
    told = said(dimmer, lfsf.LightField(views, source="t2.npz"))
    assert len(told) == 1 and told[0].startswith("t2.npz: the views look laid out with two axes swapped"), told
    one = lfsf.LightField(views, source="lf.npz")
    assert len(said(one, one)) == 1
    assert said(views, views, "flow") == []
    # the sweep covers the estimate's disparity_range (its figures are the check's at 12)
    wide = params.replace(disparity_range=12.0)
    assert said(one, one, wide) == [layout_warning(views, "lf.npz", 12.0)] != [layout_warning(views, "lf.npz")]


@pytest.mark.parametrize("as_read, other, told", [
    (0.60, 0.50, True),     # the layout as read gains 0.40, the other 0.50: ratio 0.80 < 0.85
    (0.55, 0.50, False),    # ratio 0.90: within ORIENTATION_RATIO
    (0.98, 0.96, False),    # the other gains 0.04 of no parallax's 1.0, ratio 0.5: under PARALLAX_GAIN,
                            # and not under CLEAR_RATIO either
    (0.99, 0.97, False),    # gains 0.01 and 0.03: ratio 0.33, just over CLEAR_RATIO
    (0.995, 0.97, True),    # ratio 0.17 on a gain of 0.03 (> SMALL_PARALLAX_GAIN): told
    (1.0, 0.992, False),    # a gain of 0.008 is no parallax, whatever the ratio
])
def test_the_rule_on_the_gains(monkeypatch, as_read, other, told):
    """The bounds of lfsf.orientation's rule, each on either side, with the costs given
    (no parallax 1.0): a gain over no parallax of PARALLAX_GAIN with the layout as read
    under ORIENTATION_RATIO of it, or of SMALL_PARALLAX_GAIN under CLEAR_RATIO."""
    from lfsf import orientation

    costs = {"as read": as_read, "reversed": 1.0, "swapped": other, "swapped and reversed": 1.0,
             "no parallax": 1.0}
    monkeypatch.setattr(orientation, "layout_costs", lambda views, max_disparity=4.0: costs)
    said = orientation.layout_warning(np.zeros((3, 3, 4, 4), np.float32), "x")
    assert (said is not None) == told, said
    if told:
        assert said.startswith("x: the views look laid out with two axes swapped:")
        assert f"mean matching cost {other:.3f} in that layout, {as_read:.3f} as read, 1.000 with no parallax" in said


def _no_parallax_reference(views: np.ndarray) -> float:
    """layout_costs' "no parallax" by another route: the four views two steps from the
    centre, each reduced by block means to about 160 px along the longer side, their
    absolute differences from the centre view in 5×5 means, in units of the centre's
    1st–99th percentile range, averaged over the more textured half of the pixels at
    least reach + 3 px inside (reach = 4 · 2 / factor + 1)."""
    from lfsf._filters import box_mean
    from lfsf.io import block_mean

    factor = max(1, round(max(views.shape[2:]) / 160))
    c = views.shape[0] // 2
    reduce = lambda a, b: block_mean(views[a, b].astype(np.float64), factor)  # noqa: E731
    centre = reduce(c, c)
    lo, hi = np.percentile(centre, [1, 99])
    diff = sum(np.abs(reduce(a, b) - centre) for a, b in ((c, c + 2), (c, c - 2), (c + 2, c), (c - 2, c)))
    cost = box_mean(diff / (hi - lo), 5)
    margin = int(4.0 * 2 / factor + 1.0) + 3
    gy, gx = np.gradient(centre)
    strength = np.hypot(gx, gy)[margin:-margin, margin:-margin]
    inner = cost[margin:-margin, margin:-margin]
    return float(np.mean(inner[strength >= np.median(strength)]))


@pytest.mark.parametrize("size", [(96, 72), (480, 200)])
def test_the_costs_are_those_of_the_textured_half_of_reduced_views(size):
    """The cost with no parallax against a reference: over the centre view's more
    textured half (all of it had weighed flat areas in, the warning's figures 20 % lower),
    on views reduced along their longer side (480×200: by 3, not by the shorter side's 1)."""
    views = render_scene("random-3", size=size, grid=5)[0].views
    assert layout_costs(views)["no parallax"] == pytest.approx(_no_parallax_reference(views), rel=1e-6)


def test_a_strip_of_views_is_not_checked():
    """Views far wider than tall (a reviewer's 2600×14): the check reduces both axes by a
    factor of the longer side, which left no rows (an error from block_mean, status 2);
    it now leaves such views unchecked, as it does views too small."""
    views = np.random.default_rng(0).random((3, 3, 14, 2600), dtype=np.float32)
    assert layout_costs(views) is None
    assert layout_costs(np.random.default_rng(0).random((3, 3, 40, 320), dtype=np.float32)) is not None
