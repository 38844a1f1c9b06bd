"""Whether a light field's views lie in its array as lfsf reads them (MODEL.md §1:
``views[a, b, y, x]``, row a of the grid growing downwards, column b to the right, a scene
point of disparity δ seen at p in the centre view seen at p − δ·(b − b_c, a − a_c) in view
(a, b)).

A grid or image pair of axes swapped (``[b, a, y, x]``, ``[a, b, x, y]``: a transposed
array, a MATLAB file read in the other order) or one axis of the grid reversed (views
numbered right to left, as some camera arrays' files are) reads without error and gives
disparities of no meaning. The parallax tells them apart: the views beside the centre
along a row must shift along x, those along a column along y, both by the same δ. Four
layouts are matched on the centre view and its four neighbours k view steps away, over a
range of δ (a plane sweep with 5×5 windows on views reduced to about 160 pixels): as
read, one axis reversed (the row neighbours' δ of the opposite sign to the column
neighbours'), the axes swapped, and swapped with one reversed. Grids reversed along both
axes match as read with every δ negated, and are not told apart from a scene of the
opposite depth order.
"""

from __future__ import annotations

import math

import numpy as np

from lfsf._filters import box_mean
from lfsf.io import block_mean, luma

#: Another layout is reported where the layout as read lowers the mean matching cost
#: below that of no parallax (δ = 0, the same in every layout) by less than this share of
#: what the other layout lowers it by. The gains, not the costs, are compared: the noise's
#: share of the costs is the same in every layout (with costs compared, sensor noise had
#: brought them within 7 % of each other on weak textures). Fifty-second session, 150
#: light fields (three renderers' scenes at both times, four scenes under each of 25
#: camera defects up to noise of σ ≈ 0.032, HCI antinous, the Lytro scene), each as
#: given, with its rows or its columns reversed, its grid transposed and its images
#: transposed: as given, the layout as read gained at least 1.28× the best other one's;
#: laid out otherwise, at most 0.78×; none of the 150 told, all 600 others. A helper's
#: own light fields: views spaced 2–3× wider down the columns than along the rows (outside
#: lfsf's model) with stripes or checks were told reversed or swapped (ratios 0.55–0.76);
#: stripes along one axis, or parallax beyond the sweep's range, tell no layout apart.
ORIENTATION_RATIO = 0.85
#: ... and where the other layout lowers the cost by at least this share of no parallax's:
#: a scene without parallax reads the same in every layout, and its disparities are the
#: same too (views of one image with independent noise of σ = 0.03: gains of 0.04 in
#: every layout, their ratios 0.9–1.1).
PARALLAX_GAIN = 0.05
#: Where the layout as read gains less than this share of the other's, a gain of
#: SMALL_PARALLAX_GAIN is enough: the Lytro scene halved, on its inner 3×3 views, gains
#: 0.02 in the layout it is given in and nothing transposed (ratio 0.00 to 0.07).
CLEAR_RATIO = 0.3
SMALL_PARALLAX_GAIN = 0.01
#: The views are reduced (block means) to about this many pixels along the longer side.
ORIENTATION_WIDTH = 160
#: The sweep takes δ in half-pixel steps of the reduced views, at most this many either side of 0.
MAX_STEPS = 24

#: Which of the two axes to reverse, the views cannot tell: the wrong one leaves both
#: reversed, every δ negated.
_WHICH = ("which one the views cannot tell: the other leaves every δ negated (a rig of parallel cameras sees "
          "every point at δ ≥ 0)")
_LAYOUTS = {
    "reversed": ("one of the grid's axes reversed: the views beside the centre shift one way along its rows "
                 "and the other way along its columns (views numbered right to left, or bottom to top, where "
                 "lfsf reads column b growing to the right and row a downwards, MODEL.md §1); reverse one "
                 f"axis (views[:, ::-1] or views[::-1]; in a folder, renumber the views), {_WHICH}"),
    "swapped": ("two axes swapped: neighbouring views along a row of the grid differ by vertical shifts and "
                "along a column by horizontal ones (views[b, a, y, x] or views[a, b, x, y], where lfsf reads "
                "views[a, b, y, x]); swap the grid's axes (np.swapaxes(views, 0, 1)) or the images' "
                "(np.swapaxes(views, 2, 3))"),
    "swapped and reversed": ("two axes swapped and one reversed: neighbouring views along a row of the grid "
                             "differ by vertical shifts, along a column by horizontal ones, the two of opposite "
                             "sign (views[b, a, y, x] or views[a, b, x, y] with one axis reversed, where lfsf "
                             "reads views[a, b, y, x]); swap the grid's axes (np.swapaxes(views, 0, 1)) and "
                             f"reverse one of them (then [:, ::-1] or [::-1]), {_WHICH}"),
}


def _grey(view: np.ndarray) -> np.ndarray:
    """A view as float32 grey: colour (y, x, 3) as luma (:func:`lfsf.io.luma`)."""
    view = np.asarray(view)
    return np.asarray(luma(view) if view.ndim == 3 else view, np.float32)


def _shifted(image: np.ndarray, d: float, axis: int) -> np.ndarray:
    """``image`` read at (coordinate + d) along ``axis``: linear between the two pixels
    around it, the edge pixels repeated beyond the image."""
    n = image.shape[axis]
    at = np.clip(np.arange(n) + d, 0, n - 1)
    i0 = np.floor(at).astype(np.intp)
    i1 = np.minimum(i0 + 1, n - 1)
    shape = [1, 1]
    shape[axis] = n
    f = (at - i0).reshape(shape)
    a = np.take(image, i0, axis=axis)
    return a + f * (np.take(image, i1, axis=axis) - a)


def layout_costs(views: np.ndarray, max_disparity: float = 4.0) -> dict[str, float] | None:
    """Mean matching cost of each layout (module docstring) over the centre view's more
    textured half: ``"as read"``, ``"reversed"``, ``"swapped"``, ``"swapped and
    reversed"``, and ``"no parallax"`` (δ = 0 as read). ``views``: [a, b, y, x] (grey) or
    [a, b, y, x, 3] (colour, matched as luma); ``max_disparity``: the largest |δ| in pixels
    per view step. None where the grid has no views on both sides of the centre along both
    axes, or the views are too small."""
    rows, cols = views.shape[:2]
    ca, cb = rows // 2, cols // 2
    k = min(ca, rows - 1 - ca, cb, cols - 1 - cb, 2)  # (view steps from the centre)
    if k < 1:
        return None
    factor = max(1, int(round(max(views.shape[2:4]) / ORIENTATION_WIDTH)))
    if min(views.shape[2:4]) // factor < 16:  # (a strip: 2600×14 shrunk 16 times had no rows left)
        return None
    picked = [(ca, cb), (ca, cb + k), (ca, cb - k), (ca + k, cb), (ca - k, cb)]
    centre, right, left, below, above = (block_mean(_grey(views[a, b]), factor).astype(np.float64)
                                         for a, b in picked)
    if min(centre.shape) < 16:
        return None
    lo, hi = np.percentile(centre, [1, 99])
    scale = 1.0 / max(hi - lo, 1e-6)  # (costs in units of the centre view's range)
    reach = max_disparity * k / factor + 1.0  # (pixels of the reduced views at k steps)
    step = max(0.5, reach / MAX_STEPS)  # (half pixels; coarser for a wide disparity_range)
    steps = np.arange(-math.ceil(reach / step), math.ceil(reach / step) + 1) * step

    def sweep(plus, minus, axis):
        """Costs (D, h, w): the views k steps either side read at p ∓ δ along ``axis``
        (where a point of disparity δ lies in them), compared with the centre."""
        return np.stack([box_mean(scale * (np.abs(_shifted(plus, -d, axis) - centre)
                                           + np.abs(_shifted(minus, d, axis) - centre)), 5) for d in steps])

    rows_x, columns_y = sweep(right, left, 1), sweep(below, above, 0)
    rows_y, columns_x = sweep(right, left, 0), sweep(below, above, 1)
    gy, gx = np.gradient(centre)
    strength = np.hypot(gx, gy)
    inner = np.zeros(centre.shape, bool)
    margin = int(reach) + 3
    inner[margin:-margin, margin:-margin] = True
    if not inner.any():
        return None
    used = inner & (strength >= np.percentile(strength[inner], 50))
    costs = {
        "as read": np.min(rows_x + columns_y, axis=0),
        "reversed": np.min(rows_x + columns_y[::-1], axis=0),
        "swapped": np.min(rows_y + columns_x, axis=0),
        "swapped and reversed": np.min(rows_y + columns_x[::-1], axis=0),
        "no parallax": (rows_x + columns_y)[len(steps) // 2],
    }
    return {name: float(np.mean(cost[used])) for name, cost in costs.items()}


def layout_warning(views: np.ndarray, source: str, max_disparity: float = 4.0) -> str | None:
    """A sentence for the user where another layout than the one read matches ``views``
    (as :func:`layout_costs` takes them) clearly better (:data:`ORIENTATION_RATIO`,
    :data:`PARALLAX_GAIN`, :data:`CLEAR_RATIO`), else None (the layout as read, or no way
    to tell)."""
    costs = layout_costs(views, max_disparity)
    if costs is None:
        return None
    other = min(_LAYOUTS, key=costs.__getitem__)
    best, flat = costs[other], costs["no parallax"]
    gain, gain_as_read = flat - best, flat - costs["as read"]
    if not ((gain > PARALLAX_GAIN * flat and gain_as_read < ORIENTATION_RATIO * gain)
            or (gain > SMALL_PARALLAX_GAIN * flat and gain_as_read < CLEAR_RATIO * gain)):
        return None
    return (f"{source}: the views look laid out with {_LAYOUTS[other]}; as they are, the disparities will be "
            "wrong (unless the views' spacing differs between rows and columns, which lfsf's one δ a point does "
            f"not model either; mean matching cost {best:.3f} in that layout, {costs['as read']:.3f} as read, "
            f"{flat:.3f} with no parallax; lfsf.orientation)")
