"""The discrete search kernels (kernels/search.py) against their NumPy references
(tests/reference_kernels.py, written from the docstrings) on tiny seeded inputs, and the
searches they make up: a plane sweep that finds a known disparity and block matching that
finds a known shift, both to sub-candidate precision."""

import math

import numpy as np
import pytest

from lfsf import device as D

import reference_kernels as ref

wp = D.warp()


from conftest import arr, launch, rng, wave_texture  # noqa: E402


def close(got, want, rtol=1e-5, atol=1e-5):
    np.testing.assert_allclose(np.asarray(got, np.float64), want, rtol=rtol, atol=atol)


# --- kernel runners ------------------------------------------------------------------------


def run_disparity_cost(samples, phis, candidates, base, offset, device, span=None):
    from lfsf.kernels import search

    _, h, w = samples.shape
    k = len(candidates)
    span = D.row_span(device, w)[0] if span is None else span
    cost = wp.zeros((k, h, w), dtype=float, device=device)
    launch(search.disparity_cost, (k * h, -(-w // span)),
           [arr(samples, float, device), arr(phis, wp.vec2, device), arr(candidates, float, device),
            arr(base, float, device), arr(offset, wp.vec4, device), span], [cost], device)
    return cost.numpy()


def run_box_sum(values, radius, device, span=None, pixel=False):
    """``span`` pixels of a row per thread (default: the device's, lfsf.device.row_span);
    ``pixel``: the instance without vector runs (CUDA's)."""
    from lfsf.kernels import search

    k, h, w = values.shape
    span = D.row_span(device, w)[0] if span is None else span
    out = wp.zeros((k, h, w), dtype=float, device=device)
    kernel = search.box_sum_pixel if pixel else search.box_sum
    launch(kernel, (k * h, -(-w // span)), [arr(values, float, device), radius, span], [out], device)
    return out.numpy()


def run_select_disparity(cost, candidates, device):
    from lfsf.kernels import search

    _, h, w = cost.shape
    best = wp.zeros((h, w), dtype=float, device=device)
    best_cost = wp.zeros((h, w), dtype=float, device=device)
    launch(search.select_disparity, (h, w), [arr(cost, float, device), arr(candidates, float, device)],
           [best, best_cost], device)
    return best.numpy(), best_cost.numpy()


def run_flow_cost(centre1, centre2, candidates, base, device, span=None):
    from lfsf.kernels import search

    h, w = centre1.shape
    k = len(candidates)
    span = D.row_span(device, w)[0] if span is None else span
    cost = wp.zeros((k, h, w), dtype=float, device=device)
    launch(search.flow_cost, (k * h, -(-w // span)),
           [arr(centre1, float, device), arr(centre2, float, device), arr(candidates, wp.vec2, device),
            arr(base, wp.vec4, device), span], [cost], device)
    return cost.numpy()


def run_flow_search(centre1, centre2, half, radius, device, span=None, distance=3, runner_up=False):
    from lfsf.kernels import search

    h, w = centre1.shape
    span = D.row_span(device, w)[0] if span is None else span
    best_cost = wp.zeros((h, w), dtype=float, device=device)
    best_k = wp.zeros((h, w), dtype=int, device=device)
    best = wp.zeros((h, w), dtype=wp.vec2, device=device)
    second_cost = wp.zeros((h, w), dtype=float, device=device)
    second_k = wp.zeros((h, w), dtype=int, device=device)
    launch(search.flow_search, (h, -(-w // span)),
           [arr(centre1, float, device), arr(centre2, float, device), half, radius, distance, span],
           [best_cost, best_k, best, second_cost, second_k], device)
    if runner_up:
        return best.numpy(), best_cost.numpy(), second_cost.numpy(), second_k.numpy()
    return best.numpy()


@pytest.mark.parametrize("h,w,half,radius", [(13, 7, 3, 1), (20, 37, 12, 2), (9, 50, 20, 0), (31, 33, 4, 5),
                                             (60, 80, 12, 2), (5, 5, 4, 2), (32, 8, 20, 2), (40, 6, 30, 3)])
def test_flow_search_rows_is_flow_search_bit_for_bit(h, w, half, radius):
    """The CPU's row kernel (the row's column sums per shift in vector code) leaves the
    same best, best cost and runner-up as :func:`flow_search`, borders and shifts off the
    image included: shifts beyond the width too (views taller than wide, where the search
    reaches past the width: it had written past the row's end, and crashed the process)."""
    from lfsf.kernels import search

    g = rng(11)
    a = g.random((h, w)).astype(np.float32)
    b = (np.roll(a, (2, 3), (0, 1)) + 0.05 * g.random((h, w))).astype(np.float32)
    expected = run_flow_search(a, b, half, radius, "cpu", runner_up=True)
    outs = [wp.zeros((h, w), dtype=t, device="cpu") for t in (float, int, wp.vec2, float, int)]
    colc = wp.empty((h, w + 2 * radius), dtype=float, device="cpu")
    launch(search.flow_search_rows, (h, 1), [arr(a, float, "cpu"), arr(b, float, "cpu"), half, radius, 3, colc],
           outs, "cpu")
    got = outs[2].numpy(), outs[0].numpy(), outs[3].numpy(), outs[4].numpy()
    for x, y in zip(expected, got):
        assert np.array_equal(x.view(np.uint8), y.view(np.uint8))


# --- against the references ----------------------------------------------------------------


def _cost_inputs(r, h, w):
    """(phis, samples, candidates, base, offset) of the disparity-cost tests: five
    samples, random views, base disparities and flow offsets (components 2, 3)."""
    phis = np.array([(0.0, 0.0), (1.0, 0.0), (-0.7, 0.7), (0.3, -1.4), (-1.5, -0.5)], np.float32)
    samples = r.random((len(phis), h, w)).astype(np.float32)
    candidates = np.array([-1.0, -0.3, 0.0, 0.45, 1.2], np.float32)
    base = r.uniform(-0.5, 0.5, (h, w)).astype(np.float32)
    offset = r.uniform(-1.5, 1.5, (h, w, 4)).astype(np.float32)
    return phis, samples, candidates, base, offset


@pytest.mark.parametrize("span", [1, 4, 9])  # a pixel per thread (CUDA), part of a row, a whole row (CPU)
def test_disparity_cost_matches_reference(device, span):
    r = rng(1)
    h, w = 7, 9
    phis, samples, candidates, base, offset = _cost_inputs(r, h, w)
    offset[..., :2] = 7.0  # components 0, 1 are not used
    offset[2, 3, 2:] = (30.0, 0.0)  # q far outside: no sample left, cost 1
    offset[5, 6, 2:] = (0.0, -0.4)
    got = run_disparity_cost(samples, phis, candidates, base, offset, device, span)
    want = ref.disparity_cost(samples, phis, candidates, base, offset)
    close(got, want, atol=2e-5)
    np.testing.assert_array_equal(got[:, 2, 3], 1.0)
    # some samples were left out at some pixels, and the costs stay in [0, 1]
    assert np.all((got >= 0) & (got <= 1))
    full = ref.disparity_cost(samples, phis, candidates, base, np.zeros_like(offset))
    assert not np.allclose(full, want)


#: (kernel, columns a thread): 64, the CPU's SWEEP_LANES, on a wider image whose middle
#: threads have every lane inside (the kernels' vector path) and whose outer ones do not
SWEEP_CASES = [("sweep_cost", 1), ("sweep_cost", 4), ("sweep_cost", 9), ("sweep_cost", 64), ("sweep_cost_pixel", 1)]


def _sweep_size(span):
    """(h, w) of the sweep tests: 7×9, or 5×150 for threads of 64 columns."""
    return (7, 9) if span < 64 else (5, 150)


@pytest.mark.parametrize("name, span", SWEEP_CASES)
def test_sweep_cost_matches_reference(device, name, span):
    """The plane sweep's cost (constant shifts per candidate and sample) is disparity_cost
    without a base disparity or a flow offset, borders and half-planes included, for
    threads of several columns (CPU) and of one (the CUDA instance)."""
    from lfsf.estimate import sweep_shifts
    from lfsf.kernels import search
    from lfsf.kernels.common import vec8

    r = rng(11)
    h, w = _sweep_size(span)
    phis = np.array([(0.0, 0.0), (1.0, 0.0), (-0.7, 0.7), (0.3, -1.4), (-1.5, -0.5), (0.0, 2.0)], np.float32)
    samples = r.random((len(phis), h, w)).astype(np.float32)
    # whole-pixel shifts (onto the last column/row exactly), fractions, far outside
    candidates = np.array([-3.0, -1.0, -0.3, 0.0, 0.45, 1.0, 1.2, 20.0 * w / 9], np.float32)
    masks = wp.empty(len(phis), dtype=vec8, device=device)
    launch(search.sample_half_planes, len(phis), [arr(phis, wp.vec2, device)], [masks], device)
    np.testing.assert_array_equal(masks.numpy().T, ref.half_plane_members(phis).astype(np.float32))
    cost = wp.zeros((len(candidates), h, w), dtype=float, device=device)
    launch(getattr(search, name), (len(candidates) * h, -(-w // span)),
           [arr(samples, float, device), arr(sweep_shifts(candidates, phis), wp.vec4, device), masks, span], [cost],
           device)
    got = cost.numpy()
    want = ref.disparity_cost(samples, phis, candidates, np.zeros((h, w), np.float32),
                              np.zeros((h, w, 4), np.float32))
    close(got, want, atol=2e-5)
    np.testing.assert_array_equal(got[-1], 1.0)  # every sample leaves the image


def _random_zbuf(r, n, h, w):
    """View z-buffers whose values sit well away from the disparities they are compared
    with (δ + margin): the visibility decisions are then the same in float32 and float64."""
    z = r.choice([-5.0, 5.0], (n, h, w)).astype(np.float32)
    z[r.random((n, h, w)) < 0.2] = -1e30  # EMPTY: nothing landed
    return z


@pytest.mark.parametrize("span", [1, 4, 9])
def test_disparity_cost_visible_matches_reference(device, span):
    from lfsf.kernels import search

    r = rng(3)
    h, w = 7, 9
    phis, samples, candidates, base, offset = _cost_inputs(r, h, w)
    offset[2, 3, 2:] = (30.0, 0.0)  # q far outside: no sample left, cost 1
    zbuf = _random_zbuf(r, len(phis), h, w)
    cost = wp.zeros((len(candidates), h, w), dtype=float, device=device)
    launch(search.disparity_cost_visible, (len(candidates) * h, -(-w // span)),
           [arr(samples, float, device), arr(phis, wp.vec2, device), arr(candidates, float, device),
            arr(base, float, device), arr(offset, wp.vec4, device), arr(zbuf, float, device), 0.25, span], [cost],
           device)
    got = cost.numpy()
    want = ref.disparity_cost_visible(samples, phis, candidates, base, offset, zbuf, 0.25)
    close(got, want, atol=2e-5)
    np.testing.assert_array_equal(got[:, 2, 3], 1.0)
    everything = ref.disparity_cost_visible(samples, phis, candidates, base, offset, np.full_like(zbuf, -1e30), 0.25)
    assert not np.allclose(everything, want)  # some samples were covered


@pytest.mark.parametrize("name, span", [(n.replace("sweep_cost", "sweep_cost_visible"), s) for n, s in SWEEP_CASES])
def test_sweep_cost_visible_matches_reference(device, name, span):
    """The plane sweep's visibility cost is disparity_cost_visible without a base
    disparity or a flow offset."""
    from lfsf.estimate import sweep_shifts
    from lfsf.kernels import search

    r = rng(12)
    h, w = _sweep_size(span)
    phis = np.array([(0.0, 0.0), (1.0, 0.0), (-0.7, 0.7), (0.3, -1.4), (-1.5, -0.5), (0.0, 2.0)], np.float32)
    samples = r.random((len(phis), h, w)).astype(np.float32)
    candidates = np.array([-3.0, -1.0, -0.3, 0.0, 0.45, 1.0, 1.2, 20.0 * w / 9], np.float32)
    zbuf = _random_zbuf(r, len(phis), h, w)
    cost = wp.zeros((len(candidates), h, w), dtype=float, device=device)
    launch(getattr(search, name), (len(candidates) * h, -(-w // span)),
           [arr(samples, float, device), arr(sweep_shifts(candidates, phis), wp.vec4, device),
            arr(candidates, float, device), arr(zbuf, float, device), 0.25, span], [cost], device)
    got = cost.numpy()
    want = ref.disparity_cost_visible(samples, phis, candidates, np.zeros((h, w), np.float32),
                                      np.zeros((h, w, 4), np.float32), zbuf, 0.25)
    close(got, want, atol=2e-5)
    np.testing.assert_array_equal(got[-1], 1.0)  # every sample leaves the image


def test_disparity_cost_of_an_exact_light_field_is_zero_at_the_true_disparity(device):
    """Whole-pixel shifts: L(x, φ) = T(x + δφ) sampled exactly, so the cost at δ is 0
    wherever the warped samples stay in the image (and at p + û with an offset)."""
    r = rng(2)
    h, w, pad = 8, 10, 6
    tex = r.random((h + 2 * pad, w + 2 * pad))
    phis = np.array([(0, 0), (1, 0), (0, 1), (-1, -1), (2, -1)], np.float32)
    delta = 2.0
    samples = np.array([tex[pad + int(delta * fy):pad + int(delta * fy) + h,
                            pad + int(delta * fx):pad + int(delta * fx) + w] for fx, fy in phis], np.float32)
    candidates = np.array([0.0, 1.0, 2.0, 3.0], np.float32)
    offset = np.zeros((h, w, 4), np.float32)
    offset[..., 2:] = (1.0, -1.0)
    got = run_disparity_cost(samples, phis, candidates, np.zeros((h, w), np.float32), offset, device)
    interior = (slice(5, h - 3), slice(4, w - 5))
    np.testing.assert_array_equal(got[2][interior], 0.0)
    assert np.all(got[[0, 1, 3]][:, interior[0], interior[1]] > 0)


#: (columns, columns a thread) of the window filters' tests: a pixel per thread (CUDA),
#: part of a row, a whole row (CPU); and rows wide enough for their vector runs
#: (BOX_LANES columns at once), whole and in parts.
BOX_SPANS = pytest.mark.parametrize("w, span", [(6, 1), (6, 4), (6, 6), (75, 75), (75, 40)])


@BOX_SPANS
@pytest.mark.parametrize("radius", [0, 1, 2])
def test_box_sum_matches_reference(radius, w, span, device):
    values = rng(3).random((3, 4, w)).astype(np.float32)
    got = run_box_sum(values, radius, device, span)
    close(got, ref.box_mean(values, radius))
    # threads of many columns (vector runs) sum as a thread per pixel does, bit for bit, and
    # as the instance without vector runs (CUDA's) does
    np.testing.assert_array_equal(got, run_box_sum(values, radius, device, 1))
    np.testing.assert_array_equal(got, run_box_sum(values, radius, device, span, pixel=True))
    if radius == 0:
        np.testing.assert_array_equal(got, values)
    # a constant is kept, borders included (the window is clamped, the mean stays a mean)
    close(run_box_sum(np.full((1, 4, w), 0.3, np.float32), radius, device, span), 0.3)


@BOX_SPANS
@pytest.mark.parametrize("radius", [0, 1, 2])
def test_box_min_matches_reference(radius, w, span, device):
    from lfsf.kernels import search

    values = rng(4).random((3, 5, w)).astype(np.float32)
    out = wp.zeros((3, 5, w), dtype=float, device=device)
    launch(search.box_min, (3 * 5, -(-w // span)), [arr(values, float, device), radius, span], [out], device)
    np.testing.assert_array_equal(out.numpy(), ref.box_min(values, radius).astype(np.float32))
    plain = wp.zeros((3, 5, w), dtype=float, device=device)  # the instance without vector runs (CUDA's)
    launch(search.box_min_pixel, (3 * 5, -(-w // span)), [arr(values, float, device), radius, span], [plain], device)
    np.testing.assert_array_equal(plain.numpy(), out.numpy())
    if radius == 0:
        np.testing.assert_array_equal(out.numpy(), values)


def test_windowed_cost_takes_the_best_window_that_holds_the_pixel(device):
    """lfsf.estimate._windowed_cost: box mean, then the least of those over the windows
    that hold the pixel (shiftable windows): next to a high-cost column the pixel takes
    the window on its own side."""
    from lfsf.estimate import _windowed_cost
    from lfsf.kernels import search

    r = rng(5)
    h, w = 6, 9
    samples = r.random((3, h, w)).astype(np.float32)
    phis = np.array([(0.0, 0.0), (1.0, 0.0), (0.0, -1.0)], np.float32)
    candidates = np.array([-0.5, 0.0, 0.7], np.float32)
    zero = np.zeros((h, w), np.float32)
    inputs = [arr(samples, float, device), arr(phis, wp.vec2, device), arr(candidates, float, device),
              arr(zero, float, device), arr(np.zeros((h, w, 4), np.float32), wp.vec4, device)]
    got = _windowed_cost(search.disparity_cost, inputs, 3, (h, w), 1, device).numpy()
    raw = ref.disparity_cost(samples, phis, candidates, zero, np.zeros((h, w, 4), np.float32))
    close(got, ref.box_min(ref.box_mean(raw, 1), 1), atol=2e-5)
    close(_windowed_cost(search.disparity_cost, inputs, 3, (h, w), 0, device).numpy(), raw, atol=2e-5)


def _costs_with_minima_everywhere(r, n, h, w):
    """Random costs whose minimum falls at the first candidate, the last and in between."""
    cost = r.random((n, h, w)).astype(np.float32)
    cost[0, 0, :] = -1.0      # minimum at the first candidate: no refinement
    cost[n - 1, 1, :] = -1.0  # at the last: no refinement
    cost[n // 2, 2, :] = -1.0
    return cost


def test_select_disparity_matches_reference(device):
    r = rng(4)
    n, h, w = 7, 6, 8
    step = 0.3
    candidates = (np.arange(n) * step - 0.8).astype(np.float32)
    cost = _costs_with_minima_everywhere(r, n, h, w)
    cost[:, 3, :4] = 0.25  # every candidate ties (a flat region): the one nearest zero, 0.1
    cost[:2, 3, 4:] = -2.0  # the first two tie: the second, nearer zero, refined half-way to the first
    best, best_cost = run_select_disparity(cost, candidates, device)
    want, want_cost = ref.select_disparity(cost, candidates)
    np.testing.assert_array_equal(best[3, :4], candidates[3])
    close(best[3, 4:], candidates[1] - 0.5 * step, atol=1e-6)
    close(best, want, atol=2e-6)
    np.testing.assert_array_equal(best_cost, np.min(cost, axis=0))
    np.testing.assert_array_equal(best_cost, want_cost.astype(np.float32))
    k = np.argmin(np.where(cost == cost.min(axis=0), np.abs(candidates)[:, None, None], np.inf), axis=0)
    np.testing.assert_array_equal(best[0], candidates[0])
    np.testing.assert_array_equal(best[1], candidates[-1])
    # the parabola moves at most half a step, towards the lower neighbour
    assert np.all(np.abs(best - candidates[k]) <= 0.5 * step + 1e-6)
    moved = np.abs(best - candidates[k]) > 1e-4
    assert moved[[2, 4, 5]].sum() > 3 * w // 2  # the rows of random costs with an inner minimum


def test_select_disparity_finds_the_vertex_of_a_sampled_parabola(device):
    """Costs sampled from a(δ − δ*)² + b on evenly spaced candidates: the refined choice is
    δ*, wherever δ* lies between candidates."""
    n, h, w = 9, 3, 5
    step = 0.25
    candidates = (np.arange(n) * step - 1.0).astype(np.float32)
    r = rng(5)
    target = r.uniform(-0.85, 0.85, (h, w))
    a = r.uniform(0.5, 3.0, (h, w))
    b = r.uniform(0.0, 0.2, (h, w))
    cost = (a * (candidates[:, None, None] - target) ** 2 + b).astype(np.float32)
    best, best_cost = run_select_disparity(cost, candidates, device)
    close(best, target, atol=2e-4)
    close(best_cost, np.min(cost, axis=0), atol=0)


@pytest.mark.parametrize("span", [1, 3, 8])
def test_flow_cost_matches_reference(device, span):
    r = rng(6)
    h, w = 6, 8
    centre1 = r.random((h, w)).astype(np.float32)
    centre2 = r.random((h, w)).astype(np.float32)
    candidates = np.concatenate([ref.flow_grid(1), [(0.4, -0.7), (-2.5, 1.5)]]).astype(np.float32)
    base = r.uniform(-1.0, 1.0, (h, w, 4)).astype(np.float32)
    base[..., :2] = 5.0  # components 0, 1 are not used
    base[1, 2, 2:] = (0.0, 0.0)
    got = run_flow_cost(centre1, centre2, candidates, base, device, span)
    want = ref.flow_cost(centre1, centre2, candidates, base)
    close(got, want, atol=2e-6)
    # where p + u_k leaves the image the cost is 1; at u = 0 it is |I1 − I2|
    outside = want == 1.0
    assert 0 < outside.sum() < outside.size // 2
    close(got[4, 1, 2], abs(float(centre1[1, 2]) - float(centre2[1, 2])), atol=1e-7)


def test_state_costs_are_the_cost_kernels_values_where_active(device):
    """The outlines' relabelling's costs of a state map: the t1 best-half cost of each
    pixel's δ1 (disparity_cost with no flow), its flow residual (flow_cost) and its t1
    cost over the visible samples (disparity_cost_visible), the same values as those
    kernels give, against their NumPy references too; 0 where not active. The z-buffers
    read (dx, dy) px further are those of the map moved as a whole by (−dx, −dy)."""
    from lfsf.kernels import search

    r = rng(39)
    h, w = 7, 9
    phis, samples, _c, base, _o = _cost_inputs(r, h, w)
    centre1, centre2 = r.random((h, w)).astype(np.float32), r.random((h, w)).astype(np.float32)
    x = r.uniform(-1.5, 1.5, (h, w, 4)).astype(np.float32)
    x[..., 0] = base
    x[2, 3, 2:] = (30.0, 0.0)  # carried out of the image: flow cost 1
    active = (r.random((h, w)) > 0.3).astype(np.float32)
    active[2, 3] = 1.0
    zbuf = _random_zbuf(r, len(phis), h, w)
    inputs = [arr(samples, float, device), arr(phis, wp.vec2, device), arr(centre1, float, device),
              arr(centre2, float, device), arr(x, wp.vec4, device), arr(active, float, device),
              arr(zbuf, float, device)]
    cost = wp.zeros((3, h, w), dtype=float, device=device)
    launch(search.state_costs, (h, w), inputs + [0, 0, 0.25, 1], [cost], device)
    got = cost.numpy()
    on = active > 0.5
    zero = np.zeros((1,), np.float32)
    still = np.zeros_like(x)
    t1 = run_disparity_cost(samples, phis, zero, base, still, device)[0]
    flow = run_flow_cost(centre1, centre2, np.zeros((1, 2), np.float32), x, device)[0]
    seen = wp.zeros((1, h, w), dtype=float, device=device)
    launch(search.disparity_cost_visible, (h, w),
           [inputs[0], inputs[1], arr(zero, float, device), arr(base, float, device), arr(still, wp.vec4, device),
            inputs[6], 0.25, 1], [seen], device)
    if D.is_cpu(device):
        np.testing.assert_array_equal(got[0][on], t1[on])
        np.testing.assert_array_equal(got[1][on], flow[on])
        np.testing.assert_array_equal(got[2][on], seen.numpy()[0][on])
    close(got[0][on], ref.disparity_cost(samples, phis, zero, base, still)[0][on], atol=2e-5)
    close(got[1][on], ref.flow_cost(centre1, centre2, np.zeros((1, 2), np.float32), x)[0][on], atol=2e-6)
    want = ref.disparity_cost_visible(samples, phis, zero, base, still, zbuf, 0.25)[0]
    close(got[2][on], want[on], atol=2e-5)
    assert got[1][2, 3] == 1.0 and not got[:, ~on].any()
    everything = ref.disparity_cost_visible(samples, phis, zero, base, still, np.full_like(zbuf, -1e30), 0.25)[0]
    assert not np.allclose(everything[on], want[on])  # some samples were covered
    # the z-buffers read moved: those of the map moved by (−dx, −dy), edge rows repeated
    for dy, dx in ((1, 0), (-2, 1), (0, -1)):
        launch(search.state_costs, (h, w), inputs + [dy, dx, 0.25, 1], [cost], device)
        moved = np.stack([ref.shifted(z, dy, dx) for z in zbuf])
        want = ref.disparity_cost_visible(samples, phis, zero, base, still, moved, 0.25)[0]
        close(cost.numpy()[2][on], want[on], atol=2e-5)
        np.testing.assert_array_equal(cost.numpy()[:2], got[:2])
    # without the visible samples (Params.visibility off): that cost 0, the z-buffers not read
    launch(search.state_costs, (h, w), inputs[:6] + [wp.empty((1, 1, 1), dtype=float, device=device), 0, 0, 0.25, 0],
           [cost], device)
    np.testing.assert_array_equal(cost.numpy()[:2], got[:2])
    assert not cost.numpy()[2].any()


def test_state_costs_read_a_moved_map_s_z_buffers_from_the_map_s_own(device):
    """The relabelling splats x's view z-buffers once: a candidate map, x moved as a whole
    (fusion.shifted by (dy, dx)), reads them (dx, dy) px further. Its visible-sample cost
    is then the one its own z-buffers give, away from the image's edges (where the moved
    map repeats its edge pixels); read unmoved, x's give another."""
    from lfsf import estimate
    from lfsf.kernels import fusion, search

    r = rng(41)
    h, w = 24, 30
    phis = (2.0 * _cost_inputs(r, h, w)[0]).astype(np.float32)
    samples = r.random((len(phis), h, w)).astype(np.float32)
    x = np.zeros((h, w, 4), np.float32)
    x[..., 0] = r.uniform(-0.8, -0.4, (h, w))                  # a backdrop ...
    x[7:17, 9:21, 0] = r.uniform(1.0, 1.4, (10, 12))            # ... and a card in front
    centre = arr(samples[0], float, device)
    phis_d, samples_d = arr(phis, wp.vec2, device), arr(samples, float, device)
    x_d = arr(x, wp.vec4, device)
    everywhere = arr(np.ones((h, w), np.float32), float, device)
    own = estimate._view_zbuffer(x_d, 0, False, phis_d, device)
    cand = wp.empty_like(x_d)
    cost = wp.zeros((3, h, w), dtype=float, device=device)

    def seen(zbuf, dy, dx):
        launch(search.state_costs, (h, w),
               [samples_d, phis_d, centre, centre, cand, everywhere, zbuf, dy, dx, 0.25, 1], [cost], device)
        return cost.numpy()[2].copy()

    for dy, dx in ((1, 0), (-2, 1), (0, -2), (2, 2)):
        launch(fusion.shifted, (h, w), [x_d, dy, dx], [cand], device)
        moved = estimate._view_zbuffer(cand, 0, False, phis_d, device)
        m = abs(dy) + abs(dx) + 5                                    # |δφ| ≤ 1.4 · 2.9: 5 px from the edges
        inner = (slice(m, h - m), slice(m, w - m))
        read = seen(own, dy, dx)
        np.testing.assert_array_equal(read[inner], seen(moved, 0, 0)[inner])
        assert not np.array_equal(read[inner], seen(own, 0, 0)[inner])


def test_relabel_active_and_dilated_match_numpy(device):
    """The pixels that may take a neighbour's state (not hidden, their flow cost above
    the floor, a neighbour within reach apart by both gaps), and a mask's dilation."""
    from lfsf.kernels import search

    r = rng(40)
    h, w = 10, 12
    x = np.zeros((h, w, 4), np.float32)
    x[:, 6:, 0] = 1.0                      # a depth edge between columns 5 and 6 ...
    x[:, 6:, 2] = 2.0                      # ... that moves apart by 2 px
    x[:5, 6:, 2] = 0.5                     # except in the upper rows (0.5 px: within the gap)
    x += r.normal(scale=0.01, size=x.shape).astype(np.float32)
    hidden = np.zeros((h, w), np.float32)
    hidden[7, 5] = 1.0
    flow_cost = r.random((h, w)).astype(np.float32)
    floor = 0.2
    out = wp.zeros((h, w), dtype=float, device=device)
    launch(search.relabel_active, (h, w), [arr(x, wp.vec4, device), arr(hidden, float, device),
                                           arr(flow_cost, float, device), floor, 0.3, 1.0, 2], [out], device)
    want = ref.relabel_active(x, hidden, flow_cost, floor, 0.3, 1.0, 2)
    np.testing.assert_array_equal(out.numpy(), want)
    # (rows 0–2 are more than 2 rows from any edge pixel that moves apart)
    assert want[5:, 3:9].any() and not want[:, :3].any() and not want[:3].any() and want[7, 5] == 0
    for radius in (0, 1, 2):
        d = wp.zeros((h, w), dtype=float, device=device)
        launch(search.dilated, (h, w), [out, radius], [d], device)
        np.testing.assert_array_equal(d.numpy(), ref.dilated(want, radius))
    assert ref.dilated(want, 2).sum() > want.sum()


def test_surface_block_cost_matches_reference(device):
    """The flow of each pixel moved as a block over the window's pixels of its own
    surface, against its NumPy reference; a window of one surface is the plain block
    cost, and a pixel's cost ignores the other surface's pixels whatever their match."""
    from lfsf.kernels import search

    def run(c1, c2, x, radius, tolerance):
        out = wp.empty(c1.shape, dtype=float, device=device)
        launch(search.surface_block_cost, c1.shape,
               [arr(c1, float, device), arr(c2, float, device), arr(x, wp.vec4, device), int(radius), float(tolerance)],
               [out], device)
        return out.numpy()

    r = rng(23)
    h, w = 7, 10
    c1 = r.random((h, w)).astype(np.float32)
    c2 = r.random((h, w)).astype(np.float32)
    x = r.uniform(-2.5, 2.5, (h, w, 4)).astype(np.float32)
    x[..., 0] = np.where(np.arange(w) < 5, 1.0, -1.0)[None, :] + r.uniform(-0.2, 0.2, (h, w))
    for radius, tolerance in ((0, 0.5), (1, 0.5), (2, 0.3), (1, 10.0), (1, 0.0)):  # (0: the pixel itself, still)
        close(run(c1, c2, x, radius, tolerance), ref.surface_block_cost(c1, c2, x, radius, tolerance), atol=2e-6)
    # the right surface's pixels (δ1 ≈ −1) change nothing of the left one's costs
    x2 = x.copy()
    x2[:, 5:, 2:] += 3.0
    c1b = c1.copy()
    c1b[:, 5:] = 0.0
    close(run(c1b, c2, x2, 2, 0.5)[:, :4], run(c1, c2, x, 2, 0.5)[:, :4], atol=0)


@pytest.mark.parametrize("slope,above,margin", [(0.0, 0.3, -1.0), (1.0, 0.05, -1.0), (2.5, 0.0, 1.0),
                                                (1.0, 0.05, 0.0)])
def test_cost_above_matches_reference(device, slope, above, margin):
    """cost > slope · (3×3 mean of |∇I|) + above, against NumPy's gradient and a padded
    mean, and 0 where p + (u, v) lies within ``margin`` of the image's edge or beyond
    (margin ≥ 0); a ramp's gradient is its slope everywhere (one-sided differences on
    the border included)."""
    from lfsf.kernels import search

    def run(cost, centre, x):
        out = wp.empty(cost.shape, dtype=float, device=device)
        launch(search.cost_above, cost.shape, [arr(cost, float, device), arr(centre, float, device), float(slope),
                                               float(above), arr(x, wp.vec4, device), float(margin)], [out], device)
        return out.numpy()

    r = rng(41)
    h, w = 7, 9
    centre = r.random((h, w)).astype(np.float32)
    cost = r.uniform(0.0, 1.2, (h, w)).astype(np.float32)
    x = r.uniform(-3.0, 3.0, (h, w, 4)).astype(np.float32)
    want = ref.cost_above(cost, centre, slope, above, x, margin)
    assert 0 < want.sum() < want.size
    np.testing.assert_array_equal(run(cost, centre, x), want)
    if margin >= 0:  # the margin leaves out some that the residual alone would flag
        assert (ref.cost_above(cost, centre, slope, above) > want).any()
    ramp = (0.3 * np.arange(w)[None, :] + 0.4 * np.arange(h)[:, None]).astype(np.float32)  # |∇I| = 0.5
    cost = np.full((h, w), 0.5 * slope + above, np.float32)
    cost[::2] += 0.01
    cost[1::2] -= 0.01
    got = run(cost, ramp, np.zeros((h, w, 4), np.float32))
    want = np.zeros((h, w), np.float32)
    want[::2] = 1.0  # the rows with the residual above the bound
    k = int(np.ceil(margin))
    if k > 0:  # a still point is within the margin on the outer k rows and columns
        want[:k] = want[h - k:] = 0.0
        want[:, :k] = want[:, w - k:] = 0.0
    np.testing.assert_array_equal(got, want)


def test_unmatched_points_are_those_whose_flow_finds_no_match_at_t2(device):
    """:func:`lfsf.estimate._unmatched`: the block residual of the surface block cost's
    NumPy reference above the trust floor and above UNMATCHED_MEDIAN × its median (no
    match), and above UNMATCHED_SLOPE × the 3×3 mean |∇I1| plus that bound (lost). A
    textured t1 moved by (2, 1) px to t2, the true flow given, except where a patch of
    t2 was painted over with another texture: the points that land there, and only
    those, have no match (besides those carried out of the image). With sensor noise
    (σ = 0.02) every residual rises above a floor of 0.1 σ(I1), and the median's bound
    keeps the points that do match out."""
    from lfsf import estimate
    from lfsf.params import Params

    h, w = 40, 48
    tex = wave_texture(31, 6, (0.3, 0.9), 0.12)
    other = wave_texture(32, 6, (0.3, 0.9), 0.12)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    c1 = tex(xx, yy).astype(np.float32)
    c2 = tex(xx - 2.0, yy - 1.0).astype(np.float32)
    c2[14:26, 20:32] = other(xx, yy)[14:26, 20:32]
    x = np.zeros((h, w, 4), np.float32)
    x[..., 0] = x[..., 1] = 0.5
    x[..., 2], x[..., 3] = 2.0, 1.0
    params = Params()
    for noise in (0.0, 0.02):
        n1 = (c1 + noise * rng(5).standard_normal((h, w))).astype(np.float32)
        n2 = (c2 + noise * rng(6).standard_normal((h, w))).astype(np.float32)
        floor = 0.1 * float(np.std(n1))
        got, lost = estimate._unmatched(arr(n1, float, device), arr(n2, float, device), arr(x, wp.vec4, device),
                                        params, device, floor)
        got, lost = got.numpy(), lost.numpy()
        cost = ref.surface_block_cost(n1, n2, x, params.search_radius, params.median_tolerance)
        noise_bound = estimate.UNMATCHED_MEDIAN * float(np.median(cost))
        limit = max(floor, noise_bound)
        near = (np.abs(cost - limit) < 1e-5 * limit)  # float32 against float64 at the bound
        np.testing.assert_array_equal((got > 0.5)[~near], (cost > limit)[~near])
        # lost: above what a flow UNMATCHED_SLOPE px off would leave, by the local gradient
        bound = estimate.UNMATCHED_SLOPE * ref.gradient_mean(n1) + noise_bound
        near = np.abs(cost - bound) < 1e-5 * bound
        edge = float(params.search_radius)  # p + (u, v) within the window's reach of the edge: never lost
        qy, qx = np.mgrid[0:h, 0:w] + np.array([1.0, 2.0])[:, None, None]
        inside = (qx >= edge) & (qy >= edge) & (qx <= w - 1 - edge) & (qy <= h - 1 - edge)
        np.testing.assert_array_equal((lost > 0.5)[~near], ((cost > bound) & inside)[~near])
        assert (cost > bound)[~inside].any()  # the edge's rule is tried
        inner = np.zeros((h, w), bool)
        inner[15:23, 20:28] = True
        assert (got > 0.5)[inner].mean() > 0.9, noise
        grown = np.zeros((h, w), bool)
        grown[11:27, 16:32] = True  # the patch and the windows that reach into it
        grown[:, w - 3:] = grown[h - 2:] = True  # the points carried out of the image, and their windows
        assert not (got > 0.5)[~grown].any(), noise
        # (noise adds to the gradient, and so to what a flow 1 px off would leave: fewer are lost)
        assert (lost > 0.5)[inner].mean() > (0.5 if noise == 0 else 0.2), noise
        assert not (lost > 0.5)[~grown].any(), noise


@pytest.mark.parametrize("span", [1, 3, 9])
@pytest.mark.parametrize("half,radius", [(1, 0), (1, 1), (2, 2), (2, 5)])
def test_flow_search_matches_reference(half, radius, span, device):
    """flow_search is flow_cost over the whole-pixel grid (base 0), then box_sum, then
    select_flow, in one pass without a cost volume. A flat patch makes every shift tie
    there: the first candidate wins and is not refined (on the grid's border)."""
    r = rng(7)
    h, w = 7, 9
    centre1 = r.random((h, w)).astype(np.float32)
    centre2 = r.random((h, w)).astype(np.float32)
    centre1[:, :2] = centre2[:, :4] = 0.25  # flat patches: every shift within them ties
    got = run_flow_search(centre1, centre2, half, radius, device, span)
    grid = ref.flow_grid(half).astype(np.float32)
    cost = ref.box_mean(ref.flow_cost(centre1, centre2, grid, np.zeros((h, w, 4), np.float32)), radius)
    want = ref.select_flow(cost, half)
    close(got, want, atol=2e-5)


@pytest.mark.parametrize("half,distance", [(2, 2), (3, 3), (4, 2)])
def test_flow_search_runner_up_matches_reference(half, distance, device):
    """flow_search's runner-up (the least cost at least ``distance`` steps from the best
    so far, in scan order) against the sequential rule in NumPy; costs are rounded to a
    16th so that ties occur and are broken the same way (first in scan order). Where it
    was not dropped on the way, it is the least cost over all shifts that far from the
    final best."""
    r = rng(17)
    h, w = 8, 11
    centre1 = (np.round(r.random((h, w)) * 16) / 16).astype(np.float32)
    centre2 = (np.round(r.random((h, w)) * 16) / 16).astype(np.float32)
    centre2[:, 5:] = centre1[:, 5:]  # half the image moves by zero: a unique best
    best, best_cost, second, second_k = run_flow_search(centre1, centre2, half, 0, device, None, distance, True)
    grid = ref.flow_grid(half).astype(np.float32)
    cost = ref.flow_cost(centre1, centre2, grid, np.zeros((h, w, 4), np.float32))
    want, want_k = ref.flow_runner_up(cost, half, distance)
    np.testing.assert_array_equal(second_k, want_k)
    close(second, want, atol=1e-6)
    close(best_cost, cost.min(0), atol=1e-6)
    # the runner-up found is never below the least cost of the shifts that far away
    side = 2 * half + 1
    kb = np.argmin(cost, 0)
    k = np.arange(side * side)[:, None, None]
    far = (np.abs(k // side - kb // side) >= distance) | (np.abs(k % side - kb % side) >= distance)
    least_far = np.where(far, cost, np.inf).min(0)
    assert np.all(second >= least_far - 1e-6)
    assert np.mean(np.isclose(second, least_far)) > 0.5


# --- the searches ----------------------------------------------------------------------------


def _texture(seed, waves=8):
    """A smooth random texture T(x, y) in [0, 1]: plane waves of wavelength 5–12 px."""
    return wave_texture(seed, waves, (0.5, 1.25), 0.45 / math.sqrt(waves))


def _circle_samples(radius, rings=(1, 8, 8)):
    """φ on circles (MODEL.md §2): M = len(rings), radii R·i/(M − 1)."""
    m = len(rings)
    phis = []
    for i, count in enumerate(rings):
        r = radius * i / (m - 1)
        for j in range(count):
            s = 2 * math.pi * j / count
            phis.append((r * math.cos(s), r * math.sin(s)))
    return np.array(phis, np.float32)


@pytest.mark.parametrize("delta", [0.35, -0.6])
def test_plane_sweep_recovers_a_constant_disparity(delta, device):
    """The light field of a fronto-parallel textured plane at disparity δ (sample φ shows
    T(x + δφ)); candidates 0.25 apart (half a pixel at the outer circle, as lfsf.estimate
    spaces them) with δ between two of them: cost → box_sum → select_disparity gives δ to
    a fraction of the candidate step, much closer than the nearest candidate."""
    h, w = 24, 30
    radius = 2.0
    phis = _circle_samples(radius)
    tex = _texture(9)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    samples = np.array([tex(xx + delta * fx, yy + delta * fy) for fx, fy in phis.astype(np.float64)],
                       np.float32)
    step = 0.5 / radius
    candidates = (np.arange(-5, 6) * step).astype(np.float32)
    cost = run_disparity_cost(samples, phis, candidates, np.zeros((h, w), np.float32),
                              np.zeros((h, w, 4), np.float32), device)
    smooth = run_box_sum(cost, 2, device)
    best, _ = run_select_disparity(smooth, candidates, device)
    margin = int(math.ceil(radius * np.max(np.abs(candidates)))) + 3
    inner = best[margin:-margin, margin:-margin]
    nearest = candidates[np.argmin(np.abs(candidates - delta))]
    wta_error = abs(nearest - delta)
    assert wta_error >= 0.35 * step
    err = np.abs(inner - delta)
    assert np.median(err) < 0.1 * step, np.median(err)
    assert np.max(err) < 0.5 * wta_error, (np.max(err), wta_error)


def _block_matching(shift, device, half=2, h=20, w=24):
    """I2 = I1 moved by a known shift u (I2(p + u) = I1(p)): flow_search over a (2n+1)²
    grid of whole-pixel candidates with 5 × 5 windows, as lfsf.estimate does.
    Returns the estimates of the pixels whose candidates all stay in the image."""
    tex = _texture(10)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    centre1 = tex(xx, yy).astype(np.float32)
    centre2 = tex(xx - shift[0], yy - shift[1]).astype(np.float32)
    best = run_flow_search(centre1, centre2, half, 2, device)
    margin = half + 3
    return best[margin:-margin, margin:-margin]


def test_block_matching_recovers_a_whole_pixel_shift(device):
    shift = (2.0, -1.0)
    err = np.abs(_block_matching(shift, device) - np.asarray(shift))
    assert np.max(np.median(err, axis=(0, 1))) < 0.03, np.median(err, axis=(0, 1))
    assert np.max(err) < 0.1, np.max(err)


@pytest.mark.parametrize("shift", [(1.35, 0.0), (-0.7, 0.0)])
def test_block_matching_recovers_a_sub_pixel_shift(shift, device):
    """A shift with a fractional x: the parabola along x recovers most of the fraction."""
    err = np.abs(_block_matching(shift, device) - np.asarray(shift))
    wta_error = abs(shift[0] - round(shift[0]))
    med = np.median(err, axis=(0, 1))
    assert med[0] < 0.4 * wta_error and med[1] < 0.15, (med, wta_error)
    assert np.max(err) < 0.3, np.max(err, axis=(0, 1))


def test_block_matching_with_two_fractional_components_is_closer_than_whole_pixels(device):
    """Both components fractional: the refinement (one parabola per axis, through the
    whole-pixel winner's row and column) is biased towards the winner, since each slice
    misses the true minimum by the other component's fraction; it still beats the nearest
    whole-pixel candidate."""
    shift = np.array([1.35, -0.6])
    got = _block_matching(tuple(shift), device)
    wta_error = np.abs(shift - np.round(shift))
    med = np.median(np.abs(got - shift), axis=(0, 1))
    assert np.all(med < 0.8 * wta_error), (med, wta_error)


def test_hidden_matches_flags_the_points_that_a_moving_square_covers():
    """A square moving 4 px right over a still background covers the 4 columns right of
    it at t2. The forward search of those points finds the square (q = p, taken at t2 by
    the square's point p − 4, which the backward search leads to and which leads back);
    they, and only they, are flagged."""
    from lfsf.estimate import _hidden_matches

    h, w = 24, 32
    forward = np.zeros((h, w, 2), np.float32)
    backward = np.zeros((h, w, 2), np.float32)
    forward[8:16, 8:16, 0] = 4.0  # the square at t1, columns 8 … 15
    backward[8:16, 12:20, 0] = -4.0  # the square at t2, columns 12 … 19
    expected = np.zeros((h, w), bool)
    expected[8:16, 16:20] = True
    np.testing.assert_array_equal(_hidden_matches(forward, backward), expected)
    # a stray pair of matches: (3, 25) finds (3, 21), which belongs to (3, 23) both ways,
    # and (3, 21) itself is left without its own match; two lone flags, not an area
    forward[3, 25] = (-4.0, 0.0)
    forward[3, 23] = (-2.0, 0.0)
    backward[3, 21] = (2.0, 0.0)
    np.testing.assert_array_equal(_hidden_matches(forward, backward), expected)
    # the same pair as a 2×2 block of them is an area, and is flagged
    forward[3:5, 24:26] = (-4.0, 0.0)
    forward[3:5, 22:24] = (-2.0, 0.0)
    backward[3:5, 20:22] = (2.0, 0.0)
    assert _hidden_matches(forward, backward)[3:5, 24:26].all()


def test_hidden_matches_of_block_matching_find_the_covered_strip(device):
    """Real searches, both ways, of a textured square moving 3 px right over a textured
    background: the flags cover most of the covered strip (the 3 columns right of the
    square), and lie nowhere else but next to the square's outline."""
    from lfsf.estimate import _flow_search, _hidden_matches

    h, w = 40, 48
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    back = wave_texture(5, 16, (0.4, 1.4), 0.05)
    front = wave_texture(9, 16, (0.4, 1.4), 0.05)
    inside = (yy >= 12) & (yy < 28) & (xx >= 14) & (xx < 26)
    centre1 = np.where(inside, front(xx, yy), back(xx, yy)).astype(np.float32)
    moved = (yy >= 12) & (yy < 28) & (xx >= 17) & (xx < 29)
    centre2 = np.where(moved, front(xx - 3.0, yy), back(xx, yy)).astype(np.float32)
    wp = D.warp()
    c1 = wp.array(centre1, dtype=float, device=device)
    c2 = wp.array(centre2, dtype=float, device=device)
    flagged = _hidden_matches(_flow_search(c1, c2, 5, 1, device), _flow_search(c2, c1, 5, 1, device))
    strip = np.zeros((h, w), bool)
    strip[12:28, 26:29] = True
    assert flagged[strip].mean() > 0.6, flagged[strip].mean()
    # elsewhere only within 2 px of the square's outline (3×3 windows straddle it there)
    outline = np.zeros((h, w), bool)
    outline[10:30, 12:31] = True
    outline[14:26, 19:24] = False  # the square's inside at both times, 2 px in
    assert not flagged[~outline].any(), np.argwhere(flagged & ~outline)


# --- fusion of the searches into the estimate (kernels/fusion.py) --------------------------


def test_fusion_plane_kernels_match_numpy(device):
    """A component of the unknowns as a map, and the unknowns with one component replaced
    (in place as well)."""
    from lfsf.kernels import fusion

    r = rng(31)
    h, w = 5, 7
    x = r.normal(size=(h, w, 4)).astype(np.float32)
    plane = r.normal(size=(h, w)).astype(np.float32)
    for k in range(4):
        out = wp.zeros((h, w), dtype=float, device=device)
        launch(fusion.unknown_plane, (h, w), [arr(x, wp.vec4, device), k], [out], device)
        np.testing.assert_array_equal(out.numpy(), x[..., k])
        xs = arr(x, wp.vec4, device)
        launch(fusion.with_plane, (h, w), [xs, k, arr(plane, float, device)], [xs], device)
        want = x.copy()
        want[..., k] = plane
        np.testing.assert_array_equal(xs.numpy(), want)


@pytest.mark.parametrize("first, count, use_hidden", [(2, 2, 1), (0, 1, 0), (1, 1, 0), (2, 2, 0)])
def test_take_better_kernel_matches_numpy(device, first, count, use_hidden):
    """Components first … first + count − 1 take the candidate's where its cost is below
    margin times the current one, and (with the mask) the pixel is not hidden."""
    from lfsf.kernels import fusion

    r = rng(32)
    h, w = 6, 9
    x = r.normal(size=(h, w, 4)).astype(np.float32)
    cand = r.normal(size=(h, w, 4)).astype(np.float32)
    new, cur = r.random((h, w)).astype(np.float32), r.random((h, w)).astype(np.float32)
    hidden = (r.random((h, w)) > 0.6).astype(np.float32)
    margin = 0.9
    xs = arr(x, wp.vec4, device)
    launch(fusion.take_better, (h, w), [arr(cand, wp.vec4, device), arr(new, float, device), arr(cur, float, device),
                                        margin, arr(hidden, float, device), use_hidden, first, count], [xs], device)
    better = new < np.float32(margin) * cur
    if use_hidden:
        better &= hidden <= 0.5
    assert 0 < better.sum() < better.size
    want = x.copy()
    want[better, first:first + count] = cand[better, first:first + count]
    np.testing.assert_array_equal(xs.numpy(), want)
    # and a mask of two tests
    a, b = r.random((h, w)).astype(np.float32), r.random((h, w)).astype(np.float32)
    out = wp.zeros((h, w), dtype=float, device=device)
    launch(fusion.either_above, (h, w), [arr(a, float, device), 0.7, arr(b, float, device), 0.8], [out], device)
    np.testing.assert_array_equal(out.numpy(), ((a > 0.7) | (b > 0.8)).astype(np.float32))
    # and a mask of well-matched points, the threshold itself included
    a[0, 0] = 0.5
    launch(fusion.at_most, (h, w), [arr(a, float, device), 0.5], [out], device)
    np.testing.assert_array_equal(out.numpy(), (a <= np.float32(0.5)).astype(np.float32))
    assert 0 < out.numpy().sum() < out.size


def test_shifted_unknowns_match_numpy(device):
    """The unknowns read at p + (dx, dy), the image's edge pixels repeated beyond it."""
    from lfsf.kernels import fusion

    x = rng(35).normal(size=(5, 7, 4)).astype(np.float32)
    out = wp.zeros((5, 7), dtype=wp.vec4, device=device)
    for dy, dx in ((0, 1), (-2, 1), (2, -2), (1, 0), (-1, -1), (6, -9)):
        launch(fusion.shifted, (5, 7), [arr(x, wp.vec4, device), dy, dx], [out], device)
        np.testing.assert_array_equal(out.numpy(), ref.shifted(x, dy, dx))
    assert not np.array_equal(ref.shifted(x, 1, 0), x)


def test_take_other_surface_matches_numpy(device):
    """The candidate's whole state where it explains the pixel better by both costs, over
    a pixel not hidden whose flow does not match, with δ1 and flow apart by the gaps, and
    a candidate behind the pixel's state by its visible samples too; a second candidate
    replaces the first only where its t1 cost is lower still."""
    from lfsf.kernels import fusion

    r = rng(36)
    h, w = 9, 11
    x = r.normal(size=(h, w, 4)).astype(np.float32)
    hidden = (r.random((h, w)) > 0.8).astype(np.float32)
    flow_cur, t1_cur, seen_cur = (r.random((h, w)).astype(np.float32) for _ in range(3))
    floor, margin, depth_gap, flow_gap = 0.1, 0.8, 0.3, 1.0
    best = np.full((h, w), np.inf, np.float32)
    out = x.copy()
    best_d, out_d = arr(best, float, device), arr(out, wp.vec4, device)

    def run(cand, flow_new, t1_new, seen_new, seen_too=1, best_d=best_d, out_d=out_d):
        launch(fusion.take_other_surface, (h, w),
               [arr(x, wp.vec4, device), arr(cand, wp.vec4, device), arr(flow_new, float, device),
                arr(flow_cur, float, device), arr(t1_new, float, device), arr(t1_cur, float, device),
                arr(seen_new, float, device), arr(seen_cur, float, device), arr(hidden, float, device), floor,
                margin, depth_gap, flow_gap, seen_too], [best_d, out_d], device)

    taken = []
    for seed in (37, 38):
        c = np.random.default_rng(seed)
        cand = (x + c.normal(scale=1.0, size=x.shape)).astype(np.float32)
        flow_new, t1_new, seen_new = ((cost * c.uniform(0.3, 1.2, (h, w))).astype(np.float32)
                                      for cost in (flow_cur, t1_cur, seen_cur))
        run(cand, flow_new, t1_new, seen_new)
        before, best_before = out.copy(), best.copy()
        best, out = ref.take_other_surface(x, cand, flow_new, flow_cur, t1_new, t1_cur, seen_new, seen_cur, hidden,
                                           floor, margin, depth_gap, flow_gap, best, out)
        np.testing.assert_array_equal(best_d.numpy(), best)
        np.testing.assert_array_equal(out_d.numpy(), out)
        taken.append(np.any(out != before, axis=-1))
        # candidates behind the pixel's state were taken, and some refused by their
        # visible samples alone
        _b, unseen = ref.take_other_surface(x, cand, flow_new, flow_cur, t1_new, t1_cur, np.zeros_like(seen_new),
                                            np.ones_like(seen_cur), hidden, floor, margin, depth_gap, flow_gap,
                                            best_before, before)
        behind = cand[..., 0] < x[..., 0]
        assert (taken[-1] & behind).any() and (np.any(unseen != out, axis=-1) & behind).any()
        # without seen_too (Params.visibility off) the visible samples' costs do not count
        blind = arr(before, wp.vec4, device)
        run(cand, flow_new, t1_new, seen_new, 0, arr(best_before, float, device), blind)
        np.testing.assert_array_equal(blind.numpy(), unseen)
    assert 0 < taken[0].sum() < h * w and taken[1].any()
    np.testing.assert_array_equal(out[hidden > 0.5], x[hidden > 0.5])
    # a third candidate that passes every test but the best so far (1 % above it): the
    # state taken stays where one was, the candidate is taken where none was
    cand = (x + 5.0).astype(np.float32)    # (δ1 and the flow apart from x's, ahead)
    t1_new = np.where(np.isfinite(best), best * np.float32(1.01), t1_cur * np.float32(0.5)).astype(np.float32)
    flow_new = (flow_cur * np.float32(0.1)).astype(np.float32)
    run(cand, flow_new, t1_new, seen_cur)
    kept = np.isfinite(best) & (t1_new < np.float32(margin) * t1_cur)
    assert kept.sum() >= 5
    np.testing.assert_array_equal(out_d.numpy()[kept], out[kept])
    best, out = ref.take_other_surface(x, cand, flow_new, flow_cur, t1_new, t1_cur, seen_cur, seen_cur, hidden, floor,
                                       margin, depth_gap, flow_gap, best, out)
    np.testing.assert_array_equal(out_d.numpy(), out)


def test_depth_nearby_matches_numpy(device):
    """1 (keep) where no pixel within the reach holds the unknown within the depth of the
    candidate, or where the keep mask says so; 0 where a candidate may be taken. Both
    unknowns, with and without the mask, at the image's edges too (reads clamped)."""
    from lfsf.kernels import fusion

    r = rng(39)
    h, w, reach, depth = 9, 12, 2, 0.3
    x = r.normal(scale=1.5, size=(h, w, 4)).astype(np.float32)
    candidate = r.normal(scale=1.5, size=(h, w)).astype(np.float32)
    keep = (r.random((h, w)) > 0.7).astype(np.float32)
    for component in (0, 1):
        for mask in (None, keep):
            out = wp.empty((h, w), dtype=float, device=device)
            launch(fusion.depth_nearby, (h, w),
                   [arr(x, wp.vec4, device), component, arr(candidate, float, device), reach, depth,
                    arr(candidate if mask is None else mask, float, device), int(mask is not None)], [out], device)
            expected = ref.depth_nearby(x, component, candidate, reach, depth, mask)
            np.testing.assert_array_equal(out.numpy(), expected)
            assert 0 < expected.sum() < h * w
    # a candidate equal to a value two pixels away is near; three away, not
    flat = np.zeros((h, w, 4), np.float32)
    flat[4, 6, 0] = 2.0
    candidate = np.full((h, w), 2.0, np.float32)
    out = wp.empty((h, w), dtype=float, device=device)
    launch(fusion.depth_nearby, (h, w), [arr(flat, wp.vec4, device), 0, arr(candidate, float, device), reach, depth,
                                         arr(candidate, float, device), 0], [out], device)
    ii, jj = np.mgrid[0:h, 0:w]
    np.testing.assert_array_equal(out.numpy() == 0, (np.abs(ii - 4) <= 2) & (np.abs(jj - 6) <= 2))


def test_hidden_or_leaving_kernel_matches_numpy(device):
    """1 where the hidden mask says so or the flow takes the pixel out of the image
    (p + (u, v) beyond [0, w − 1] × [0, h − 1]), else 0."""
    from lfsf.kernels import fusion

    r = rng(34)
    h, w = 7, 10
    x = r.normal(scale=4.0, size=(h, w, 4)).astype(np.float32)
    x[0, 0, 2:] = (0.0, 0.0)                      # the corner itself: inside
    x[h - 1, w - 1, 2:] = (0.0, 0.0)
    x[2, w - 3, 2:] = (2.0, 0.0)                  # exactly onto the last column: inside
    x[3, 1, 2:] = (-1.0001, 0.0)                  # just past the first: out
    hidden = (r.random((h, w)) > 0.8).astype(np.float32)
    out = wp.zeros((h, w), dtype=float, device=device)
    launch(fusion.hidden_or_leaving, (h, w), [arr(hidden, float, device), arr(x, wp.vec4, device)], [out], device)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    xq, yq = xx + x[..., 2], yy + x[..., 3]
    leaves = (xq < 0) | (xq > w - 1) | (yq < 0) | (yq > h - 1)
    want = ((hidden > 0.5) | leaves).astype(np.float32)
    assert 0 < leaves.sum() < leaves.size and (leaves & (hidden <= 0.5)).any()
    assert not leaves[0, 0] and not leaves[2, w - 3] and leaves[3, 1]
    np.testing.assert_array_equal(out.numpy(), want)


def test_sample_at_flow_kernel_matches_the_host_bilinear(device):
    """image(p + (u, v)), clamped, against lfsf.estimate._sample_at_flow: bit for bit on
    the CPU (float64 weights, as NumPy takes them; the estimate is sensitive to them),
    within float32 rounding on CUDA (fused multiply–adds)."""
    from lfsf.estimate import _sample_at_flow
    from lfsf.kernels import fusion

    r = rng(33)
    h, w = 23, 31
    image = r.random((h, w)).astype(np.float32)
    x = r.normal(scale=8.0, size=(h, w, 4)).astype(np.float32)  # (many positions past the edges: clamped)
    out = wp.zeros((h, w), dtype=float, device=device)
    launch(fusion.sample_at_flow, (h, w), [arr(image, float, device), arr(x, wp.vec4, device)], [out], device)
    want = _sample_at_flow(image, x)
    if D.is_cpu(device):
        np.testing.assert_array_equal(out.numpy(), want)
    else:
        close(out.numpy(), want, rtol=1e-6, atol=1e-7)
    yy, xx = np.mgrid[0:h, 0:w]
    close(want, ref.bilinear(image, xx + x[..., 2], yy + x[..., 3]))


def _fusion_inputs(device, seed=40):
    """Samples of a textured plane at disparity 0.6 (t1) and 0.8 seen moved by (1.5, −0.5)
    (t2), 5 samples on a circle, an estimate x near the truth with noise, and searched
    maps that are right at some pixels and wrong at others."""
    from lfsf.params import Params

    h, w = 24, 32
    phis, _radius = Params.preset("fast").replace(circles=2, samples=(1, 4)).sample_offsets((5, 5))
    phis = np.asarray(phis, np.float32)
    tex = wave_texture(seed, 6, (0.3, 0.9), 0.15)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    s1 = np.stack([tex(xx - 0.6 * p[0], yy - 0.6 * p[1]) for p in phis]).astype(np.float32)
    s2 = np.stack([tex(xx - 1.5 - 0.8 * p[0], yy + 0.5 - 0.8 * p[1]) for p in phis]).astype(np.float32)
    r = rng(seed)
    x = np.stack([0.6 + r.normal(0, 0.3, (h, w)), 0.8 + r.normal(0, 0.3, (h, w)),
                  1.5 + r.normal(0, 0.6, (h, w)), -0.5 + r.normal(0, 0.6, (h, w))], -1).astype(np.float32)
    good = r.random((h, w)) < 0.5
    found1 = np.where(good, 0.6, 0.6 + r.normal(0, 0.5, (h, w))).astype(np.float32)
    found2 = np.where(good, 0.8, 0.8 + r.normal(0, 0.5, (h, w))).astype(np.float32)
    fu = np.where(good, 1.5, 1.5 + r.normal(0, 1.0, (h, w))).astype(np.float32)
    fv = np.where(good, -0.5, -0.5 + r.normal(0, 1.0, (h, w))).astype(np.float32)
    hidden = (r.random((h, w)) < 0.2).astype(np.float32)
    return phis, s1, s2, x, found1, found2, fu, fv, hidden


@pytest.mark.parametrize("visibility", [True, False])
def test_disparity_fusion_on_the_device_is_the_host_rule(device, visibility):
    """lfsf.estimate._fuse_disparities against the NumPy rule it replaced: δ1 takes the
    searched value where its windowed cost (view z-buffers of the searched map, or the
    best half) is below FUSION_MARGIN times the current one; then δ2 takes the searched
    map of t2's frame read at p + (u, v) by the same rule, its costs at the fused x's
    flow. Bit for bit on the CPU; on CUDA (other rounding) at all but a few pixels."""
    from lfsf.estimate import FUSION_MARGIN, _fuse_disparities, _sample_at_flow, _view_zbuffer, _window_cost
    from lfsf.params import Params

    phis, s1, s2, x, found1, found2, _fu, _fv, _hidden = _fusion_inputs(device)
    params = Params.preset("paper").replace(visibility=visibility)
    r, margin = params.search_radius, params.occlusion_margin
    wphis, ws1, ws2 = arr(phis, wp.vec2, device), arr(s1, float, device), arr(s2, float, device)

    def cost(samples, d, offset, disparity_map):
        zbuf = None
        if visibility:
            zx = offset.copy()
            zx[..., disparity_map[0]] = disparity_map[1]
            zbuf = _view_zbuffer(arr(zx, wp.vec4, device), disparity_map[0], disparity_map[0] == 1, wphis, device)
        return _window_cost(samples, wphis, arr(d, float, device), arr(offset, wp.vec4, device), r, device, zbuf,
                            margin).numpy()

    want = x.copy()
    cur = cost(ws1, want[..., 0], np.zeros_like(x), (0, found1))
    new = cost(ws1, found1, np.zeros_like(x), (0, found1))
    want[..., 0] = np.where(new < np.float32(FUSION_MARGIN) * cur, found1, want[..., 0])
    cand2 = _sample_at_flow(found2, want)
    cur = cost(ws2, want[..., 1], want, (1, cand2))
    new = cost(ws2, cand2, want, (1, cand2))
    want[..., 1] = np.where(new < np.float32(FUSION_MARGIN) * cur, cand2, want[..., 1])

    xs = arr(x, wp.vec4, device)
    _fuse_disparities(xs, ws1, ws2, wphis, arr(found1, float, device), arr(found2, float, device), params, device)
    got = xs.numpy()
    for k in (0, 1):
        taken = want[..., k] != x[..., k]
        assert 0.02 < taken.mean() < 0.98, k  # (both outcomes occur)
    np.testing.assert_array_equal(got[..., 2:], x[..., 2:])
    if D.is_cpu(device):
        np.testing.assert_array_equal(got, want)
    else:
        assert np.mean(got != want) < 0.02


def test_flow_fusion_on_the_device_is_the_host_rule(device):
    """lfsf.estimate._fuse_flow against the NumPy rule it replaced: the flow takes the
    searched one where its windowed residual is below FUSION_MARGIN times the current
    one, but not where the point is hidden at t2 nor where the current flow takes it out
    of the image; the disparities are left alone."""
    from lfsf.estimate import FUSION_MARGIN, _fuse_flow, _window_flow_cost
    from lfsf.params import Params

    _phis, s1, s2, x, _f1, _f2, fu, fv, hidden = _fusion_inputs(device, seed=41)
    params = Params.preset("paper")
    c1, c2 = arr(s1[0], float, device), arr(s2[0], float, device)
    cand = x.copy()
    cand[..., 2], cand[..., 3] = fu, fv
    new = _window_flow_cost(c1, c2, arr(cand, wp.vec4, device), params.search_radius, device).numpy()
    cur = _window_flow_cost(c1, c2, arr(x, wp.vec4, device), params.search_radius, device).numpy()
    h, w = fu.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    xq, yq = xx + x[..., 2], yy + x[..., 3]
    leaves = (xq < 0) | (xq > w - 1) | (yq < 0) | (yq > h - 1)
    assert leaves.any() and not leaves.all()
    for mask in (np.zeros_like(hidden), hidden):
        better = (new < np.float32(FUSION_MARGIN) * cur) & ~leaves & ~(mask > 0.5)
        assert (new < np.float32(FUSION_MARGIN) * cur)[leaves].any()     # (a leaving flow it would have taken)
        want = x.copy()
        want[better, 2:] = cand[better, 2:]
        assert 0.1 < better.mean() < 0.9
        xs = arr(x, wp.vec4, device)
        _fuse_flow(xs, c1, c2, arr(fu, float, device), arr(fv, float, device), params, device,
                   arr(mask, float, device))
        if D.is_cpu(device):
            np.testing.assert_array_equal(xs.numpy(), want)
        else:
            assert np.mean(xs.numpy() != want) < 0.02


def test_flow_search_marks_flat_and_periodic_regions_ambiguous(device):
    """``_flow_search(..., ambiguity=True)``: a textured image moving (2, 1) px whose left
    third is flat and whose middle third is a checkerboard of 4-px squares (the motion
    and (4, 4) px or 8 px along an axis from it match as well). The flat and the periodic
    regions are marked ambiguous away from their edges, the textured third nowhere, and
    the search's flow there is the motion (within 0.25 px: the parabola's refinement)."""
    from lfsf.estimate import _flow_search

    h, w = 40, 72
    tex = _texture(12)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    shift = (2.0, 1.0)

    def scene(x, y):
        img = tex(x, y)
        img = np.where(x < 24, 0.5, img)
        board = 0.3 + 0.4 * ((np.floor(x / 4) + np.floor(y / 4)) % 2)
        return np.where((x >= 24) & (x < 48), board, img).astype(np.float32)

    c1, c2 = scene(xx, yy), scene(xx - shift[0], yy - shift[1])
    flow, ambiguous = _flow_search(arr(c1, float, device), arr(c2, float, device), 9, 1, device, ambiguity=True)
    inner = slice(12, h - 12)
    assert ambiguous[inner, 3:20].all()
    assert ambiguous[inner, 30:42].mean() > 0.9
    assert not ambiguous[:, 54:].any()
    np.testing.assert_allclose(flow[inner, 54:62], np.broadcast_to(shift, (h - 24, 8, 2)), atol=0.25)
