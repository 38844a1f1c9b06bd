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

#: Another layout is reported where the layout as read lowers the mean matching cost
#: below that of no parallax (δ = 0, the same in every layout) by less than this share of
#: what the other layout lowers it by. The gains, not the costs, are compared: the noise's
#: share of the costs is the same in every layout (with costs compared, sensor noise had
#: brought them within 7 % of each other on weak textures). Fifty-second session, 63 light
#: fields from three renderers (clean, with noise up to σ ≈ 0.032, vignetting, a
#: Lytro-like chain of defects), HCI antinous and the Lytro scene, each as read, with
#: its columns reversed and transposed (189 cases): the layout as read gained at least
#: 1.28× the best other one's, and with an axis reversed or two swapped at most 0.78×;
#: nothing said of a layout as read, every other layout told.
ORIENTATION_RATIO = 0.85
#: ... and where the other layout lowers the cost by at least this share of no parallax's:
#: a scene without parallax reads the same in every layout, and its disparities are the
#: same too.
PARALLAX_GAIN = 0.05
#: The views are reduced (block means) to about this many pixels along the longer side.
ORIENTATION_WIDTH = 160
#: The sweep takes δ in half-pixel steps of the reduced views, at most this many either side of 0.
MAX_STEPS = 24

_LAYOUTS = {
    "reversed": ("one of the grid's axes reversed: the views beside the centre shift one way along its rows "
                 "and the other way along its columns (views numbered right to left, or bottom to top, where "
                 "lfsf reads column b growing to the right and row a downwards, MODEL.md §1); reverse one "
                 "axis (views[:, ::-1] or views[::-1]; in a folder, renumber the views)"),
    "swapped": ("two axes swapped: neighbouring views along a row of the grid differ by vertical shifts and "
                "along a column by horizontal ones (views[b, a, y, x] or views[a, b, x, y], where lfsf reads "
                "views[a, b, y, x]); transpose the grid (views.transpose(1, 0, 2, 3)) or the images"),
    "swapped and reversed": ("two axes swapped and one reversed: neighbouring views along a row of the grid "
                             "differ by vertical shifts, along a column by horizontal ones, the two of opposite "
                             "sign (views[b, a, y, x] or views[a, b, x, y] with one axis reversed, where lfsf "
                             "reads views[a, b, y, x])"),
}


def _reduce(image: np.ndarray, factor: int) -> np.ndarray:
    """Block means of ``factor`` × ``factor`` pixels (the rows and columns left over dropped)."""
    h, w = (image.shape[0] // factor) * factor, (image.shape[1] // factor) * factor
    return image[:h, :w].reshape(h // factor, factor, w // factor, factor).mean(axis=(1, 3), dtype=np.float64)


def _grey(view: np.ndarray) -> np.ndarray:
    """A view as float64 grey: colour (y, x, 3) as luma (:func:`lfsf.io.luma`)."""
    from lfsf.io import luma

    view = np.asarray(view)
    return np.asarray(luma(view) if view.ndim == 3 else view, np.float64)


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
    [a, b, y, x, 3] (colour, matched as luma);
    ``max_disparity``: the largest |δ| in pixels per view step. None where the grid has
    no views on both sides of the centre along both axes, or the views are too small."""
    rows, cols = views.shape[:2]
    ca, cb = rows // 2, cols // 2
    k = min(ca, rows - 1 - ca, cb, cols - 1 - cb, 2)  # (view steps from the centre)
    if k < 1:
        return None
    factor = max(1, int(round(max(views.shape[2:4]) / ORIENTATION_WIDTH)))
    picked = [(ca, cb), (ca, cb + k), (ca, cb - k), (ca + k, cb), (ca - k, cb)]
    centre, right, left, below, above = reduced = [_reduce(_grey(views[a, b]), factor) for a, b in picked]
    if min(centre.shape) < 16:
        return None
    # each neighbour at the centre's mean brightness (vignetting dims the views off the centre)
    for view in reduced[1:]:
        mean = float(np.mean(view))
        if mean > 0:
            view *= float(np.mean(centre)) / mean
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
    (as :func:`layout_costs` takes them) clearly better (:data:`ORIENTATION_RATIO`, :data:`PARALLAX_GAIN`),
    else None (the layout as read, or no way to tell)."""
    costs = layout_costs(views, max_disparity)
    if costs is None:
        return None
    other = min(_LAYOUTS, key=costs.__getitem__)
    best, flat = costs[other], costs["no parallax"]
    if flat - best <= PARALLAX_GAIN * flat or flat - costs["as read"] >= ORIENTATION_RATIO * (flat - best):
        return None
    return (f"{source}: the views look laid out with {_LAYOUTS[other]}; as they are, the disparities will be "
            f"wrong (matching cost {best:.3f} in that layout against {costs['as read']:.3f} as read; "
            "lfsf.orientation)")
