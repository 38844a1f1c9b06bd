"""Every estimator kernel against its NumPy reference (tests/reference_kernels.py) on tiny
seeded inputs, plus the identities the model relies on: adjointness of gradient and
divergence, the data term's linearisation and Kᵀ, the preconditioner as abs row/column
sums of the actual K, and the solver's energy going down. The data term's occlusion
handling is checked against its reference on random and constructed inputs, and on
synthetic depth edges, where the weights must drop exactly on the occluder's side.
(The search kernels: tests/test_search_kernels.py.)"""

import math

import numpy as np
import pytest

from lfsf import device as D

import reference_kernels as ref

wp = D.warp()

RTOL = 1e-5
ATOL = 1e-5


from conftest import arr, launch, rng, wave_texture  # noqa: E402


def close(got, want, rtol=RTOL, atol=ATOL):
    np.testing.assert_allclose(np.asarray(got, np.float64), want, rtol=rtol, atol=atol)


#: The kernels on the unknowns run on vec4 (δ1, δ2, u, v) and, flow only, on vec2 (u, v):
#: each test of one runs both, the vec2 one against the flow components of the reference.
UNKNOWNS = pytest.mark.parametrize("unknowns", ["vec4", "vec2"])


def unknowns_arr(a, unknowns, device):
    """(h, w, 4) data as the kernel's unknowns: all four, or (u, v) alone."""
    return arr(a, wp.vec4, device) if unknowns == "vec4" else arr(a[..., 2:], wp.vec2, device)


def unknowns_value(a, unknowns):
    """A value per unknown of (δ1, δ2, u, v) as the kernel's unknowns' vector."""
    return wp.vec4(*map(float, a)) if unknowns == "vec4" else wp.vec2(*map(float, a[2:]))


def unknowns_zeros(shape, unknowns, device):
    return wp.zeros(shape, dtype=wp.vec4 if unknowns == "vec4" else wp.vec2, device=device)


def flow_part(a, unknowns):
    """The components of (h, w, 4) data the ``unknowns`` hold."""
    return a if unknowns == "vec4" else a[..., 2:]


# --- sampling ------------------------------------------------------------------------------


# a pixel per thread (CUDA), part of a row, a whole row (CPU); 37 columns: two chunks of 16
# (sampling.CHUNK) and the rest one by one, a span of 20 one chunk and the rest
@pytest.mark.parametrize("w, span", [(9, 1), (9, 4), (9, 9), (37, 1), (37, 20), (37, 37)])
@pytest.mark.parametrize("grid", [(5, 5), (4, 6), (3, 2)])
def test_sample_subaperture_matches_reference(grid, w, span, device):
    from lfsf.kernels import sampling

    assert sampling.CHUNK == 16
    rows, cols = grid
    h = 7
    views = rng(1).random((rows, cols, h, w)).astype(np.float32)
    ac, bc = (rows - 1) / 2, (cols - 1) / 2
    phis = np.array([
        (0.0, 0.0),
        (0.37, -0.81),            # between four views
        (-1.2, 0.6),
        (bc - math.floor(bc), ac - math.floor(ac)),   # onto view (ceil(a_c), ceil(b_c))
        (-bc, -ac),               # the corner view (0, 0)
        (bc, ac),                 # the last view
        (10.0, -10.0),            # clamped: view (0, cols − 1)
        (-3.3, 7.5),              # clamped: view (rows − 1, 0)
    ], np.float32)
    out = wp.empty((len(phis), h, w), dtype=float, device=device)
    launch(sampling.sample_subaperture, (len(phis) * h, -(-w // span)),
           [arr(views.reshape(rows * cols, h, w), float, device), rows, cols, arr(phis, wp.vec2, device), span],
           [out], device)
    got = out.numpy()
    close(got, ref.sample_subaperture(views, phis))
    # CUDA's kernel, a pixel of every sample a thread: the same sums
    pixel = wp.empty((len(phis), h, w), dtype=float, device=device)
    launch(sampling.sample_subaperture_pixel, (h, w),
           [arr(views.reshape(rows * cols, h, w), float, device), rows, cols, arr(phis, wp.vec2, device)],
           [pixel], device)
    close(pixel.numpy(), ref.sample_subaperture(views, phis))
    if device == "cpu":  # (CUDA may contract the products and sums into fused ones either way)
        np.testing.assert_array_equal(pixel.numpy(), got)
    # angular positions on a view give that view exactly
    exact = {
        3: (math.ceil(ac), math.ceil(bc)), 4: (0, 0), 5: (rows - 1, cols - 1),
        6: (0, cols - 1), 7: (rows - 1, 0),
    }
    for s, (a, b) in exact.items():
        np.testing.assert_array_equal(got[s], views[a, b], err_msg=f"phi={phis[s]} should be view {(a, b)}")
    if rows % 2 and cols % 2:
        np.testing.assert_array_equal(got[0], views[rows // 2, cols // 2])


def test_sample_subaperture_integer_offsets_are_views(device):
    from lfsf.kernels import sampling

    rows, cols, h, w = 5, 7, 4, 6
    views = rng(2).random((rows, cols, h, w)).astype(np.float32)
    ab = [(a, b) for a in range(rows) for b in range(cols)]
    phis = np.array([(b - 3, a - 2) for a, b in ab], np.float32)
    out = wp.empty((len(phis), h, w), dtype=float, device=device)
    span, per_row = D.row_span(device, w)
    launch(sampling.sample_subaperture, (len(phis) * h, per_row),
           [arr(views.reshape(rows * cols, h, w), float, device), rows, cols, arr(phis, wp.vec2, device), span],
           [out], device)
    got = out.numpy()
    for s, (a, b) in enumerate(ab):
        np.testing.assert_array_equal(got[s], views[a, b])


# --- ROF -----------------------------------------------------------------------------------


@pytest.mark.parametrize("span", [1, 4, 9])  # a pixel per thread (CUDA), part of a row, a whole row (CPU)
def test_rof_dual_step_matches_reference(device, span):
    from lfsf.kernels import rof

    r = rng(3)
    n, h, w = 2, 7, 9
    u_bar = r.random((n, h, w)).astype(np.float32)
    p = (r.standard_normal((n, h, w, 2)) * 0.6).astype(np.float32)
    sigma = 0.9
    p_wp = arr(p, wp.vec2, device)
    launch(rof.rof_dual_step, (n * h, -(-w // span)), [arr(u_bar, float, device), sigma, span], [p_wp], device)
    got = p_wp.numpy()
    want = ref.rof_dual_step(u_bar, p, sigma)
    close(got, want)
    assert np.all(np.linalg.norm(got, axis=-1) <= 1 + 1e-6)
    unprojected = p + sigma * np.stack(
        [np.moveaxis(g, -1, 0) for g in ref.grad(np.moveaxis(u_bar.astype(np.float64), 0, -1))], -1)
    assert np.any(np.linalg.norm(unprojected, axis=-1) > 1)  # the projection was exercised
    assert np.any(np.linalg.norm(unprojected, axis=-1) < 1)


@pytest.mark.parametrize("relax", [1.0, 0.4])  # plain over-relaxation, and a step of the accelerated one
@pytest.mark.parametrize("span", [1, 4, 9])
def test_rof_primal_step_matches_reference(device, span, relax):
    from lfsf.kernels import rof

    r = rng(4)
    n, h, w = 2, 7, 9
    f = r.random((n, h, w)).astype(np.float32)
    u = r.random((n, h, w)).astype(np.float32)
    p = (r.standard_normal((n, h, w, 2)) * 0.5).astype(np.float32)
    tau, mu = 0.3, 0.125
    u_wp = arr(u, float, device)
    ub_wp = wp.zeros((n, h, w), dtype=float, device=device)
    launch(rof.rof_primal_step, (n * h, -(-w // span)), [arr(f, float, device), arr(p, wp.vec2, device), tau, mu,
                                                        relax, span], [u_wp, ub_wp], device)
    want_u, want_ub = ref.rof_primal_step(f, p, u, tau, mu, relax)
    close(u_wp.numpy(), want_u)
    close(ub_wp.numpy(), want_ub)


def _rof_lanes(a: np.ndarray, rows: int) -> np.ndarray:
    """(n, h, w) images in rows of ``rows`` values (zeros past w), as (n, h, rows / 8, 8)."""
    n, h, w = a.shape
    out = np.zeros((n, h, rows), np.float32)
    out[..., :w] = a
    return out.reshape(n, h, rows // 8, 8)


@pytest.mark.parametrize("w, rows", [(9, 16), (16, 16), (5, 8)])  # lanes past the row's end, none, most
def test_rof_lanes_steps_match_reference(device, w, rows):
    """The ROF steps on groups of 8 pixels (the CPU's) against the reference, with rows
    longer than the images: the lanes past the width take no part in any stencil."""
    from lfsf.kernels import rof

    assert rof.ROF_LANES == 8
    r = rng(5)
    n, h = 2, 7
    u_bar = r.random((n, h, w)).astype(np.float32)
    p = (r.standard_normal((n, h, w, 2)) * 0.6).astype(np.float32)
    sigma = 0.9
    lanes = (rows // 8, 8)
    px = arr(_rof_lanes(p[..., 0], rows), rof.rof_lane, device)
    py = arr(_rof_lanes(p[..., 1], rows), rof.rof_lane, device)
    garbage = _rof_lanes(u_bar, rows)
    garbage.reshape(n, h, rows)[..., w:] = 7.0  # whatever lies past the width is not read
    launch(rof.rof_dual_lanes, (n * h, 1), [arr(garbage, rof.rof_lane, device), w, sigma], [px, py], device)
    got = np.stack([px.numpy().reshape(n, h, rows)[..., :w], py.numpy().reshape(n, h, rows)[..., :w]], -1)
    close(got, ref.rof_dual_step(u_bar, p, sigma))

    f = r.random((n, h, w)).astype(np.float32)
    u = r.random((n, h, w)).astype(np.float32)
    p = (r.standard_normal((n, h, w, 2)) * 0.5).astype(np.float32)
    tau, mu, relax = 0.3, 0.125, 0.4
    px_np = _rof_lanes(p[..., 0], rows)
    px_np.reshape(n, h, rows)[..., w:] = 5.0  # p past the width is not read either
    u_wp = arr(_rof_lanes(u, rows), rof.rof_lane, device)
    ub_wp = wp.zeros((n, h, *lanes[:1]), dtype=rof.rof_lane, device=device)
    launch(rof.rof_primal_lanes, (n * h, 1), [arr(_rof_lanes(f, rows), rof.rof_lane, device),
                                              arr(px_np, rof.rof_lane, device),
                                              arr(_rof_lanes(p[..., 1], rows), rof.rof_lane, device), w, tau, mu,
                                              relax], [u_wp, ub_wp], device)
    want_u, want_ub = ref.rof_primal_step(f, p, u, tau, mu, relax)
    close(u_wp.numpy().reshape(n, h, rows)[..., :w], want_u)
    close(ub_wp.numpy().reshape(n, h, rows)[..., :w], want_ub)


def test_rof_denoise_is_the_same_on_groups_of_pixels():
    """The estimator's ROF on the CPU (groups of 8 pixels a step, rows padded to a multiple
    of 8) gives the same structure part, bit for bit, as the one-pixel steps (CUDA's)."""
    from lfsf import estimate
    from lfsf.kernels import rof

    r = rng(6)
    n, h, w = 3, 11, 21
    f = r.random((n, h, w)).astype(np.float32)
    rows = estimate._rof_rows(w, "cpu")
    assert rows == 24
    u = estimate.rof_denoise(arr(_rof_lanes(f, rows).reshape(n, h, rows), float, "cpu"), 0.1, 12, "cpu", width=w)
    # the one-pixel steps, as on CUDA
    u1, ub1 = arr(f, float, "cpu"), arr(f, float, "cpu")
    p = wp.zeros((n, h, w), dtype=wp.vec2, device="cpu")
    tau = sigma = 1.0 / np.sqrt(8.0)
    for _ in range(12):
        relax = 1.0 / np.sqrt(1.0 + 2.0 * tau / 0.1)
        launch(rof.rof_dual_step, (n * h, w), [ub1, float(sigma), 1], [p], "cpu")
        launch(rof.rof_primal_step, (n * h, w), [arr(f, float, "cpu"), p, float(tau), 0.1, float(relax), 1],
               [u1, ub1], "cpu")
        tau, sigma = relax * tau, sigma / relax
    np.testing.assert_array_equal(u.numpy()[..., :w], u1.numpy())
    # a stack of rows 21 long is copied into rows of 24 and back
    np.testing.assert_array_equal(estimate.rof_denoise(arr(f, float, "cpu"), 0.1, 12, "cpu").numpy(), u1.numpy())
    # … and so is one that is not contiguous, even with rows of a multiple of 8
    wide = np.zeros((n, h, 2 * rows), np.float32)
    wide[..., :w] = f
    part = arr(wide, float, "cpu")[:, :, :rows]
    assert not part.is_contiguous
    got = estimate.rof_denoise(part, 0.1, 12, "cpu", width=w).numpy()
    np.testing.assert_array_equal(got[..., :w], u1.numpy())
    with pytest.raises(ValueError, match="wide"):
        estimate.rof_denoise(arr(_rof_lanes(f, rows).reshape(n, h, rows), float, "cpu"), 0.1, 1, "cpu", width=rows + 1)


def test_texture_part_matches_reference(device):
    from lfsf.kernels import rof

    r = rng(5)
    n, h, w = 3, 7, 9
    f = r.random((n, h, w)).astype(np.float32)
    s = r.random((n, h, w)).astype(np.float32)
    out = wp.empty((n, h, w), dtype=float, device=device)
    launch(rof.texture_part, (n * h, w), [arr(f, float, device), arr(s, float, device), 0.95, 0], [out], device)
    close(out.numpy(), f.astype(np.float64) - 0.95 * s)
    # a padded structure image: read 2 px down and right
    sp = r.random((n, h + 4, w + 4)).astype(np.float32)
    launch(rof.texture_part, (n * h, w), [arr(f, float, device), arr(sp, float, device), 0.5, 2], [out], device)
    close(out.numpy(), f.astype(np.float64) - 0.5 * sp[:, 2:-2, 2:-2])


def test_scale_values_matches_numpy(device):
    """The contrast normalisation's in-place scaling: float32 products, as NumPy's."""
    from lfsf.kernels import rof

    f = rng(6).random((3, 5, 7)).astype(np.float32)
    a = arr(f, float, device)
    launch(rof.scale_values, (3 * 5, 7), [float(np.float32(1.7))], [a], device)
    np.testing.assert_array_equal(a.numpy(), f * np.float32(1.7))


@pytest.mark.parametrize("pad", [1, 3, 6])
def test_pad_odd_matches_numpy(device, pad):
    from lfsf.kernels import rof

    n, h, w = 2, 7, 9
    f = rng(51).random((n, h, w)).astype(np.float32)
    out = wp.empty((n, h + 2 * pad, w + 2 * pad), dtype=float, device=device)
    launch(rof.pad_odd, (n * (h + 2 * pad), w + 2 * pad), [arr(f, float, device), pad], [out], device)
    want = np.pad(f.astype(np.float64), ((0, 0), (pad, pad), (pad, pad)), mode="reflect", reflect_type="odd")
    close(out.numpy(), want)


def test_structure_texture_keeps_a_ramp_up_to_the_border(device):
    """ROF of a linear ramp on the odd-reflected image is the ramp itself up to the border
    (TV and fidelity both vanish on the continued ramp), so its texture part is (1 − θ)
    times the ramp; with the Neumann boundary alone the ramp's ends flatten."""
    from lfsf import estimate
    from lfsf.params import Params

    h, w = 24, 40
    ramp = np.tile(0.01 * np.arange(w, dtype=np.float32), (h, 1))[None]
    params = Params.preset("paper").replace(rof_iterations=300)
    texture = estimate._structure_texture(arr(ramp, float, device), params, device).numpy()[0]
    close(texture, (1.0 - params.texture_theta) * ramp[0], rtol=0, atol=2e-4)
    old = estimate.ROF_PAD
    try:
        estimate.ROF_PAD = 0
        flat = estimate._structure_texture(arr(ramp, float, device), params, device).numpy()[0]
    finally:
        estimate.ROF_PAD = old
    assert np.abs(flat - (1.0 - params.texture_theta) * ramp[0]).max() > 0.01


def _rof_kernel_solve(f, mu, iterations, device):
    from lfsf.estimate import rof_denoise

    return rof_denoise(arr(f, float, device), mu, iterations, device).numpy().astype(np.float64)


def test_rof_converges_to_the_rof_minimiser(device):
    """lfsf.estimate.rof_denoise (the accelerated primal–dual ROF) follows the float64
    reference of the same iterations, converges to the minimiser (optimality of a long
    solve, energies), and is nearer to it after 60 steps than fixed steps are."""
    r = rng(6)
    n, h, w = 2, 7, 9
    f = r.random((n, h, w)).astype(np.float32)
    f[1, :, :4] += 1.0  # an edge
    mu = 0.125
    tau = sigma = 1.0 / math.sqrt(8.0)
    u = _rof_kernel_solve(f, mu, 60, device)
    want_u, _ = ref.rof_solve(f, mu, 60, tau, sigma, accelerate=True)
    close(u, want_u, rtol=1e-4, atol=1e-4)
    # optimality of the minimiser: u = f + μ div p with |p| ≤ 1 and p = ∇u/|∇u| where ∇u ≠ 0
    long_u, long_p = ref.rof_solve(f, mu, 3000, tau, sigma, accelerate=True)
    residual = long_u - (f + mu * ref.stack_div(long_p))
    assert np.max(np.abs(residual)) < 1e-4, np.max(np.abs(residual))
    gx, gy = ref.grad(np.moveaxis(long_u, 0, -1))
    g = np.stack([np.moveaxis(gx, -1, 0), np.moveaxis(gy, -1, 0)], -1)
    tv = np.sum(np.linalg.norm(g, axis=-1))
    assert abs(np.sum(long_p * g) - tv) < 1e-2 * max(tv, 1e-3)
    # energy decreases, ends within a hair of the minimiser's, nearer than fixed steps get
    e_f = ref.rof_energy(f.astype(np.float64), f, mu)
    e_10 = ref.rof_energy(_rof_kernel_solve(f, mu, 10, device), f, mu)
    e_end = ref.rof_energy(u, f, mu)
    e_min = ref.rof_energy(long_u, f, mu)
    e_fixed = ref.rof_energy(ref.rof_solve(f, mu, 60, tau, sigma)[0], f, mu)
    assert e_end < e_10 < e_f
    assert e_end - e_min < 1e-3 * e_min
    assert e_end - e_min < 0.5 * (e_fixed - e_min), (e_end - e_min, e_fixed - e_min)


# --- pyramid -------------------------------------------------------------------------------


@pytest.mark.parametrize("fine,coarse,sigma", [((9, 11), (5, 6), 0.6), ((8, 8), (4, 4), 0.8), ((7, 9), (3, 4), 1.0)])
def test_downsample_matches_reference(fine, coarse, sigma, device):
    from lfsf.kernels import pyramid

    radius = int(math.ceil(3 * sigma))
    img = rng(7).random((2, *fine)).astype(np.float32)
    out = wp.empty((2, *coarse), dtype=float, device=device)
    launch(pyramid.downsample, (2 * coarse[0], coarse[1]), [arr(img, float, device), sigma, radius], [out], device)
    close(out.numpy(), ref.downsample(img, coarse, sigma, radius))
    # a constant stays constant (weights renormalised at the borders)
    const = np.full((1, *fine), 0.3, np.float32)
    out1 = wp.empty((1, *coarse), dtype=float, device=device)
    launch(pyramid.downsample, (coarse[0], coarse[1]), [arr(const, float, device), sigma, radius], [out1], device)
    close(out1.numpy(), 0.3)


@pytest.mark.parametrize("fine,coarse", [((480, 640), (240, 320)), ((75, 101), (38, 51)), ((33, 47), (9, 12)),
                                         ((17, 23), (3, 4))])
def test_downsample_rows_is_downsample_bit_for_bit(fine, coarse):
    """The CPU's row kernel (the window's weights kept along the row) gives the per-pixel
    kernel's values exactly: whole and fractional ratios, and windows beyond MEMO_SIDE."""
    from lfsf.kernels import pyramid

    ratio = max(fine[0] / coarse[0], fine[1] / coarse[1])
    sigma = max(ratio / 3.0, 0.5)
    radius = int(math.ceil(3.0 * sigma))
    img = arr(rng(8).random((2, *fine)).astype(np.float32), float, "cpu")
    a = wp.empty((2, *coarse), dtype=float, device="cpu")
    b = wp.empty((2, *coarse), dtype=float, device="cpu")
    launch(pyramid.downsample, (2 * coarse[0], coarse[1]), [img, sigma, radius], [a], "cpu")
    launch(pyramid.downsample_rows, (2 * coarse[0], 1), [img, sigma, radius, coarse[1]], [b], "cpu")
    assert np.array_equal(a.numpy().view(np.uint32), b.numpy().view(np.uint32))


@pytest.mark.parametrize("coarse,fine,scale", [((4, 5), (9, 11), 2.25), ((3, 3), (6, 6), 2.0), ((5, 6), (7, 9), 1.0)])
def test_upsample_matches_reference(coarse, fine, scale, device):
    from lfsf.kernels import pyramid

    img = rng(8).random((2, *coarse)).astype(np.float32)
    out = wp.empty((2, *fine), dtype=float, device=device)
    launch(pyramid.upsample, (2 * fine[0], fine[1]), [arr(img, float, device), scale], [out], device)
    close(out.numpy(), ref.upsample(img, fine, scale))
    # constant → scale·constant
    const = np.full((1, *coarse), 0.7, np.float32)
    out1 = wp.empty((1, *fine), dtype=float, device=device)
    launch(pyramid.upsample, (fine[0], fine[1]), [arr(const, float, device), scale], [out1], device)
    close(out1.numpy(), 0.7 * scale)


@pytest.mark.parametrize("vec, carried", [(wp.vec4, 4), (wp.vec4, 2), (wp.vec2, 4), (wp.vec2, 3)])
@pytest.mark.parametrize("coarse,fine", [((4, 5), (9, 11)), ((5, 6), (7, 9))])
def test_upsample_unknowns_matches_the_planes_upsampled(coarse, fine, vec, carried, device):
    """The unknowns (vec4 (δ1, δ2, u, v), or flow only vec2 (u, v)) upsampled in place:
    component k < ``carried`` of the vec4 form is scales[k] times the plane upsampled
    (the reference), the others keep the fine array's values."""
    from lfsf.kernels import pyramid

    n = 4 if vec == wp.vec4 else 2
    src = rng(9).normal(size=(*coarse, n)).astype(np.float32)
    before = rng(10).normal(size=(*fine, n)).astype(np.float32)
    scales = (1.5, 0.5, 2.25, 1.75)
    out = arr(before, vec, device)
    launch(pyramid.upsample_unknowns, fine, [arr(src, vec, device), wp.vec4(*scales), carried], [out], device)
    want = before.copy()
    for c in range(n):
        k = c + 4 - n  # (the component of (δ1, δ2, u, v))
        if k < carried:
            want[..., c] = ref.upsample(src[None, ..., c], fine, scales[k])[0]
    close(out.numpy(), want)


def test_upsample_reproduces_a_linear_ramp_in_the_interior(device):
    from lfsf.kernels import pyramid

    hc, wc, h, w = 4, 5, 9, 11
    yc, xc = np.mgrid[0:hc, 0:wc].astype(np.float64)
    ramp = (0.3 * xc - 0.2 * yc + 0.1)[None].astype(np.float32)
    out = wp.empty((1, h, w), dtype=float, device=device)
    launch(pyramid.upsample, (h, w), [arr(ramp, float, device), 1.5], [out], device)
    x = ref.coarse_centre(np.arange(w), w, wc)
    y = ref.coarse_centre(np.arange(h), h, hc)
    want = 1.5 * (0.3 * x[None, :] - 0.2 * y[:, None] + 0.1)
    interior = ((y >= 0) & (y <= hc - 1))[:, None] & ((x >= 0) & (x <= wc - 1))[None, :]
    assert interior.sum() > 20
    close(out.numpy()[0][interior], want[interior])


# --- data term -----------------------------------------------------------------------------


def _data_inputs(seed, h=7, w=9):
    r = rng(seed)
    phis = np.array([(0.0, 0.0), (1.5, -0.7), (-2.0, 1.0)], np.float32)
    s = len(phis)
    samples1 = r.random((s, h, w)).astype(np.float32)
    samples2 = r.random((s, h, w)).astype(np.float32)
    weights = r.uniform(0.5, 2.0, (s, 3)).astype(np.float32)
    weights[0, :2] = 0.0
    x_hat = np.stack([
        r.uniform(-1.0, 1.0, (h, w)),
        r.uniform(-1.0, 1.0, (h, w)),
        r.uniform(-2.0, 2.0, (h, w)),
        r.uniform(-2.0, 2.0, (h, w)),
    ], -1).astype(np.float32)
    x_hat[0, 0] = (3.0, -4.0, 0.3, 0.2)  # warps that leave the image
    x_hat[3, 4] = (0.1, 0.2, 20.0, 0.0)
    return samples1, samples2, phis, weights, x_hat


def _run_data_coefficients(samples1, samples2, phis, weights, x_hat, device, occlusion_ratio=0.0, hidden2=None,
                           zbufs=None, cubic=False):
    """The kernel's coefficients as (S, h, w, 12) with the row weights w_k in [9:12] (w_k
    is λ_k where the kernel's row flag is set, else 0), and the column sums.
    ``zbufs``: (Z1, Z2) view z-buffers (S, h, w) to decide visibility by (margin
    VIEW_MARGIN), else the best half."""
    from lfsf.kernels import data_groups, data_term

    s, h, w = samples1.shape
    hidden2 = np.zeros((h, w), np.float32) if hidden2 is None else hidden2
    no_zbuf = np.zeros((1, 1, 1), np.float32)
    z1, z2 = (no_zbuf, no_zbuf) if zbufs is None else zbufs
    from lfsf.solver import from_lanes, unpack_coefficients, unpack_flags

    results = []
    # the device's kernel and storage (on the CPU, groups of 8 pixels in vector code), and the
    # kernel of a thread per pixel with a pixel's values together and with CUDA's groups of 32
    for lanes in dict.fromkeys((data_term.data_lanes(device), 1, data_term.CUDA_LANES)):
        kernel, columns = data_groups.coefficients_kernel(w, lanes)
        coef, _ = _lane_buffer(np.zeros((h, w, s, data_term.COEFFICIENTS), np.float32), device, lanes)
        words = data_term.pixel_flag_words(s)
        flags, _ = _lane_buffer(np.full((h, w, 1, words), -1, np.int32), device, lanes)  # every bit set before
        grad_j2, _ = _lane_buffer(np.zeros((h, w, 1, 2), np.float32), device, lanes)
        colsum = wp.zeros((h, w), dtype=wp.vec4, device=device)
        q_before = rng(99).uniform(-1.0, 1.0, (h, w, s, 3)).astype(np.float32)  # the duals of the last warp
        q, _ = _lane_buffer(q_before, device, lanes)
        launch(kernel, (h, columns),
               [arr(samples1, float, device), arr(samples2, float, device), arr(phis, wp.vec2, device),
                arr(weights, wp.vec3, device), arr(x_hat, wp.vec4, device), float(occlusion_ratio),
                arr(hidden2, float, device), arr(z1, float, device), arr(z2, float, device), VIEW_MARGIN,
                0 if zbufs is None else 1, lanes, int(cubic)],
               [coef, flags, grad_j2, colsum, q], device)
        # (h, w, S, 12): the seven stored, A8 and A9 rebuilt from ∇J2 as the kernels do, and the
        # row weights of the flags
        a = unpack_coefficients(from_lanes(coef.numpy(), w, lanes, data_term.COEFFICIENTS),
                                from_lanes(grad_j2.numpy(), w, lanes, 2)[:, :, 0])
        on = unpack_flags(from_lanes(flags.numpy(), w, lanes, words)[:, :, 0], s)
        got = np.concatenate([a, np.where(on, np.asarray(weights, np.float32)[None, None], 0.0)], -1)
        # the duals of rows left out are zeroed, the others kept as they were
        np.testing.assert_array_equal(from_lanes(q.numpy(), w, lanes, 3), np.where(got[..., 9:] > 0, q_before, 0.0))
        results.append((got, colsum.numpy()))
    (got, colsum), *others = results
    for got_1, colsum_1 in others:
        np.testing.assert_array_equal(got, got_1)  # the same values, however stored
        np.testing.assert_array_equal(colsum, colsum_1)
    # sample-major (S, h, w, 12) here, as the reference
    return got.transpose(2, 0, 1, 3).astype(np.float64), colsum.astype(np.float64)


DATA_EPS = 1e-6
VIEW_MARGIN = 0.25


def _check_data_coefficients(samples1, samples2, phis, weights, x_hat, occlusion_ratio, device, hidden2=None,
                             zbufs=None, cubic=False):
    """Kernel vs reference: A1…A9, the rows left out (exactly, from the row flags) and the
    column sums. Returns (kernel coef with the row weights in [9:12], reference W,
    reference occlusion details)."""
    coef, colsum = _run_data_coefficients(samples1, samples2, phis, weights, x_hat, device, occlusion_ratio,
                                          hidden2, zbufs, cubic)
    details = {}
    A, W, want_colsum = ref.data_coefficients(samples1, samples2, phis, weights, x_hat, occlusion_ratio, details,
                                              hidden2, zbufs, VIEW_MARGIN, cubic)
    for k in range(9):
        close(coef[..., k], A[k], atol=2e-5)
    for k in range(3):
        np.testing.assert_array_equal(coef[..., 9 + k] > 0, W[k] > 0, err_msg=f"rows of w{k + 1} left out")
        close(coef[..., 9 + k], W[k], atol=1e-6)
    close(colsum, want_colsum, atol=5e-5)
    if occlusion_ratio > 0:  # the input decides the occlusion tests with a margin
        for name in ("t1", "t2"):
            _assert_decisions_robust(details[name], occlusion_ratio)
        assert np.all(np.abs(details["centre_margin"]) > 1e-5), np.argwhere(np.abs(details["centre_margin"]) <= 1e-5)
    return coef, W, details


def test_data_coefficients_centre_view_alone_keeps_its_flow_row(device):
    """With the centre view alone (M = 1, flow only) there are no side views at t2 to
    judge whether the centre view is occluded: the flow row is kept wherever both ends
    are in the image, however large |I1 − J2| (before, any residual over OCCLUSION_FLOOR
    dropped it, and flow-only lost most of its data rows on real texture)."""
    samples1, samples2, phis, weights, x_hat = _data_inputs(14)
    one = slice(0, 1)
    coef, W, details = _check_data_coefficients(samples1[one], samples2[one], phis[one], weights[one], x_hat, 0.7,
                                                device)
    h, w = samples1.shape[1:]
    py, px = np.mgrid[0:h, 0:w]
    in_j = ref.inside((h, w), px + x_hat[..., 2], py + x_hat[..., 3])
    assert not in_j.all() and in_j.any()
    i1 = samples1[0]
    j2 = ref.bilinear(samples2[0], px + x_hat[..., 2], py + x_hat[..., 3])
    assert np.sum((np.abs(i1 - j2) > 0.1) & in_j) > 10  # large residuals, which the old test dropped
    np.testing.assert_array_equal(W[2, 0] > 0, in_j)
    assert not details["centre_occluded"].any()


def _splat_views(x, component, flow, phis, device, span=1):
    """``splat_views`` with each thread walking ``span`` points of a row (the last thread
    of a row fewer where the width is not a multiple)."""
    from lfsf.kernels import occlusion

    h, w = x.shape[:2]
    zbuf = wp.full((len(phis), h, w), occlusion.EMPTY, dtype=float, device=device)
    launch(occlusion.splat_views, (len(phis), h, -(-w // span)), [arr(x, wp.vec4, device), component, flow,
                                                                  arr(phis, wp.vec2, device), span], [zbuf], device)
    return zbuf.numpy()


@pytest.mark.parametrize("flow", [0, 1])
def test_splat_views_matches_reference(device, flow):
    samples1, samples2, phis, weights, x_hat = _data_inputs(21)
    width = x_hat.shape[1]
    for component, span in ((0, 1), (1, 1), (0, 4), (1, width)):  # one point, a part or a whole row a thread
        got = _splat_views(x_hat, component, flow, phis, device, span)
        want = ref.splat_views(x_hat, component, bool(flow), phis)
        np.testing.assert_array_equal(np.isinf(want), got < -1e29)  # EMPTY where nothing lands
        np.testing.assert_array_equal(np.where(np.isinf(want), 0.0, want), np.where(got < -1e29, 0.0, got))
        assert np.isinf(want).any() and np.isfinite(want).any()


def test_splat_views_cover_the_background_behind_a_near_square():
    """A near square (δ = 1, columns 6–9, rows 3–6) over a far background (δ = −1): in
    the view at φ = (2, 0) the square lands 2 px left of itself (columns 4–7, whole
    positions: no wider) and the background 2 px right, so the square covers the
    background points 4 px to its left, and nothing else; a quarter-pixel shift widens
    the footprint by one column."""
    h, w = 10, 16
    x = np.zeros((h, w, 4), np.float32)
    x[..., :2] = -1.0
    x[3:7, 6:10, :2] = 1.0
    phis = np.array([(0.0, 0.0), (2.0, 0.0)], np.float32)
    z = ref.splat_views(x, 0, False, phis)
    seen = ref.visible(z[1], np.arange(w)[None, :] + 2.0 + 0.0 * x[..., 0], np.arange(h)[:, None] + 0.0 * x[..., 0],
                       x[..., 0], 0.25)
    hidden = np.zeros((h, w), bool)
    hidden[3:7, 2:6] = True  # j + 2 on the square's columns 4–7
    np.testing.assert_array_equal(~seen, hidden)
    z = ref.splat_views(x, 0, False, np.array([(0.0, 0.0), (2.125, 0.0)], np.float32))
    assert np.all(z[1][3:7, 3:8] == 1.0)  # at 3.875 … 6.875: columns 3–7
    assert np.all(z[1][3:7, 2] == -1.0) and np.all(z[1][3:7, 8] == -1.0)
    assert ref.visible(z[0], np.arange(w)[None, :] + 0.0 * x[..., 0], np.arange(h)[:, None] + 0.0 * x[..., 0],
                       x[..., 0], 0.25).all()  # the centre view sees every point


def test_visible_asks_every_pixel_the_lookup_reads(device):
    """A sample is hidden where a depth edge runs through its bilinear lookup and any of
    the pixels it reads (non-zero weight) holds a nearer point, not only the pixel
    nearest to it: at x = 2.3 the lookup reads columns 2 and 3, so a near point on column
    3 hides it; at the whole x = 2 it reads column 2 alone. On one slanted surface (no
    edge under the lookup) the least value decides: its own neighbours, a little nearer,
    do not hide it. The kernel (through disparity_cost_visible) and the reference agree."""
    from lfsf.kernels import search

    h, w = 4, 6
    edge = np.full((h, w), -1.0, np.float32)
    edge[1, 3] = 2.0  # a near point on row 1, column 3
    ramp = np.tile(0.3 * np.arange(w, dtype=np.float32), (h, 1))  # a slanted surface
    cases = [(edge, 2.3, 1.0, 0.0, False), (edge, 2.0, 1.0, 0.0, True), (edge, 3.7, 1.0, 0.0, False),
             (edge, 4.0, 1.0, 0.0, True), (edge, 2.3, 0.4, 0.0, False), (edge, 2.3, 2.0, 0.0, True),
             (ramp, 2.5, 1.0, 0.6, True), (ramp, 2.5, 1.0, 0.3, False)]
    for z, x, y, d, seen in cases:
        assert bool(ref.visible(z, x, y, d, 0.25)) == seen, (x, y, d)
    # the same decisions in the kernel: one side sample (φ = (−1, 0)) read at q = (x, y)
    # from every pixel at disparity d; it matches the centre (cost 0) where it is seen,
    # and the cost is 1 where no sample is left
    samples = np.zeros((2, h, w), np.float32)
    phis = np.array([(0.0, 0.0), (-1.0, 0.0)], np.float32)
    for z, x, y, d, seen in cases:
        zbuf = np.stack([np.full((h, w), -1e30, np.float32), z])
        offset = np.zeros((h, w, 4), np.float32)
        offset[..., 2] = x - d - np.arange(w)[None, :]  # q − δφ = (x, y)
        offset[..., 3] = y - np.arange(h)[:, None]
        cost = wp.zeros((1, h, w), dtype=float, device=device)
        launch(search.disparity_cost_visible, (h, 1),
               [arr(samples, float, device), arr(phis, wp.vec2, device), arr(np.array([d], np.float32), float, device),
                arr(np.zeros((h, w), np.float32), float, device), arr(offset, wp.vec4, device),
                arr(zbuf, float, device), 0.25, w], [cost], device)
        np.testing.assert_array_equal(cost.numpy()[0], 0.0 if seen else 1.0, err_msg=f"{(x, y, d)}")


@pytest.mark.parametrize("cubic", [False, True])
def test_data_coefficients_with_view_zbuffers_match_reference(device, cubic):
    """With view z-buffers the samples a nearer point covers are left out, instead of the
    worse half: kernel and reference agree on every row, and the decision differs from
    the best half's on some."""
    samples1, samples2, phis, weights, x_hat = _data_inputs(22)
    zbufs = tuple(np.where(np.isinf(z), -1e30, z).astype(np.float32)
                  for z in (ref.splat_views(x_hat, 0, False, phis), ref.splat_views(x_hat, 1, True, phis)))
    coef, W, _ = _check_data_coefficients(samples1, samples2, phis, weights, x_hat, 0.7, device, zbufs=zbufs,
                                          cubic=cubic)
    _, W_half, _ = ref.data_coefficients(samples1, samples2, phis, weights, x_hat, 0.7)
    assert np.any((W[0] > 0) != (W_half[0] > 0)) and np.any((W[1] > 0) != (W_half[1] > 0))
    assert 0.2 < np.mean(W[0, 1:] > 0) < 1.0


def test_data_coefficients_leave_out_hidden_points(device):
    """Where the geometric test says the point is hidden at t2 (hidden2 = 1), every row
    involving t2 is off (w2 = w3 = 0), and nothing else changes."""
    samples1, samples2, phis, weights, x_hat = _data_inputs(13)
    h, w = samples1.shape[1:]
    hidden2 = (np.random.default_rng(5).random((h, w)) < 0.3).astype(np.float32)
    coef, W, _ = _check_data_coefficients(samples1, samples2, phis, weights, x_hat, 0.0, device, hidden2)
    coef0, _ = _run_data_coefficients(samples1, samples2, phis, weights, x_hat, device, 0.0)
    hid = hidden2 > 0.5
    assert hid.any() and (~hid).any()
    assert np.all(coef[:, hid, 10:] == 0) and np.any(coef0[:, hid, 10:] != 0)
    np.testing.assert_array_equal(coef[:, ~hid], coef0[:, ~hid])
    np.testing.assert_array_equal(coef[..., :10], coef0[..., :10])


@pytest.mark.parametrize("cubic", [False, True])
def test_data_coefficients_match_reference(device, cubic):
    samples1, samples2, phis, weights, x_hat = _data_inputs(9)
    coef, W, _ = _check_data_coefficients(samples1, samples2, phis, weights, x_hat, 0.0, device, cubic=cubic)
    # the rows whose warps leave the image are switched off
    assert np.all(coef[1:, 0, 0, 9] == 0) and np.all(coef[1:, 0, 0, 11] == 0)
    assert np.all(coef[:, 3, 4, 10] == 0)
    assert 0.2 < np.mean(W[2, 1:] > 0) < 1.0
    # φ = 0: the stereo residuals vanish identically, ρ3 = I1(p) − I2(p + u)
    close(coef[0, ..., 1], 0.0)
    close(coef[0, ..., 3], 0.0)
    close(coef[0, ..., 0], 0.0)
    close(coef[0, ..., 2], 0.0)


def test_data_coefficients_row_flags_of_many_samples_match_reference(device):
    """With 40 samples each row's flags take two words (bits 0 … 30 and 0 … 8): the rows
    left out, decoded from the kernels' words, are the reference's, for samples on both
    sides of the words' seam (warps that leave the image, points hidden at t2, the centre
    view at t2 outside the image)."""
    samples1, samples2, _phis, _weights, x_hat = _data_inputs(31)
    r = rng(32)
    s = 40
    h, w = samples1.shape[1:]
    phis = np.concatenate([[(0.0, 0.0)], r.uniform(-3.0, 3.0, (s - 1, 2))]).astype(np.float32)
    samples1, samples2 = (r.random((s, h, w)).astype(np.float32) for _ in range(2))
    weights = np.tile(np.float32([10.0 / s, 10.0 / s, 30.0 / s]), (s, 1))
    hidden2 = (r.random((h, w)) < 0.2).astype(np.float32)
    coef, W, _ = _check_data_coefficients(samples1, samples2, phis, weights, x_hat, 0.0, device, hidden2)
    for k in range(3):  # rows in and out on both sides of the seam, in every row
        for part in (W[k, :31], W[k, 31:]):
            assert np.any(part > 0) and np.any(part == 0), k


def _consecutive_share(x_hat, phis, lanes=8):
    """The share of the whole groups of ``lanes`` pixels whose lookups at t1 and t2 (each
    sample's) read consecutive pixels of one row, where
    :func:`lfsf.kernels.data_groups.lookup_lanes` loads its taps contiguously (lanes out
    of the unclamped interior read at (1, 1), as there)."""
    h, w = x_hat.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    whole = w // lanes * lanes
    shares = []
    for phi in np.asarray(phis, np.float32):
        for d, dx, dy in ((x_hat[..., 0], 0.0, 0.0), (x_hat[..., 1], x_hat[..., 2], x_hat[..., 3])):
            x = xx + dx - d * phi[0]
            y = yy + dy - d * phi[1]
            inner = (x >= 1) & (y >= 1) & (x < w - 2) & (y < h - 2)
            o = np.where(inner, np.floor(np.where(inner, y, 1)) * w + np.floor(np.where(inner, x, 1)), w + 1)
            o = o[:, :whole].reshape(h, -1, lanes) - np.arange(lanes)
            shares.append(np.all(o == o[..., :1], -1))
    return float(np.mean(shares))


@UNKNOWNS
@pytest.mark.parametrize("h, w, samples", [(11, 37, (1, 8, 8)), (4, 16, (1, 8, 8)), (3, 8, (1, 8, 8)),
                                           (7, 45, (1, 8, 8)), (11, 37, (1, 16, 24))])
@pytest.mark.parametrize("use_zbuf, ratio", [(0, 0.0), (0, 0.7), (1, 0.0), (1, 0.7)])
@pytest.mark.parametrize("fields", ["random", "smooth"])
@pytest.mark.parametrize("cubic", [0, 1])
def test_data_coefficients_groups_equal_pixel_by_pixel(h, w, samples, use_zbuf, ratio, fields, cubic, unknowns):
    """On the CPU the coefficients run a group of 8 pixels at once in vector code
    (:data:`lfsf.kernels.data_groups.data_coefficients_groups`); groups cut by the row's
    end, and views of fewer than 4 rows, pixel by pixel. Every output (coefficients, row
    flags, ∇J2, column sums, duals) has the same bits as the kernel of a thread per
    pixel, the same lane storage: with warps that leave the image and lookups within a
    pixel of the border, hidden points, both occlusion tests, flow only, and 41 samples
    (two words of row flags a row). With random unknowns a group's lookups scatter
    (gathers); with smooth ones most groups read consecutive pixels (contiguous loads),
    and some straddle a whole-pixel step."""
    from lfsf.kernels import data_groups, data_term
    from lfsf.params import Params

    r = rng(40 + w)
    phis, _radius = Params.preset("paper").replace(samples=samples).sample_offsets((9, 9))
    phis = np.asarray(phis, np.float32)
    if unknowns == "vec2":
        phis = phis[:1]
    n = len(phis)
    samples1, samples2 = (r.random((n, h, w)).astype(np.float32) for _ in range(2))
    weights = np.tile(np.float32([10.0 / n, 10.0 / n, 30.0 / n]), (n, 1))
    x_hat = np.concatenate([r.uniform(-1.0, 1.0, (h, w, 1)) + r.uniform(-0.2, 0.2, (h, w, 2)),
                            r.uniform(-2.0, 2.0, (h, w, 2))], -1).astype(np.float32)
    if fields == "smooth":
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        x_hat = np.stack([0.3 + 0.02 * xx, 0.25 + 0.015 * xx + 0.01 * yy, 1.3 + 0.03 * xx, 0.6 - 0.02 * yy],
                         -1).astype(np.float32)
        if h >= 7:  # (4 rows or fewer leave almost no unclamped interior)
            share = _consecutive_share(x_hat, phis)
            assert 0.1 < share < 1.0, share
    x_hat[0, 0] = (3.0, -4.0, 0.3, 0.2)  # warps that leave the image
    x_hat[min(3, h - 1), min(4, w - 1)] = (0.1, 0.2, 20.0, 0.0)
    # lookups exactly on the bounds of the unclamped interior (x = 1, w − 2; y = 1, h − 2)
    # and on whole pixels (δ = 0 in every view)
    for j, (x, y) in enumerate([(1.0, 1.0), (w - 2.0, h - 2.0), (1.0, h - 2.0), (w - 2.0, 1.0), (0.0, 0.0)]):
        i = (2 * j + 1) % h
        x_hat[i, j] = (0.0, 0.0, x - j, y - i)
    x_in = arr(x_hat, wp.vec4, "cpu") if unknowns == "vec4" else arr(x_hat[..., 2:], wp.vec2, "cpu")
    hidden2 = (r.random((h, w)) > 0.9).astype(np.float32)
    zbufs = [r.uniform(-3.0, 1.0, (n, h, w)).astype(np.float32) for _ in range(2)]
    q_before = r.uniform(-1.0, 1.0, (h, w, n, 3)).astype(np.float32)
    lanes = data_term.DATA_LANES
    runs = []
    for kernel, columns in (data_groups.coefficients_kernel(w, lanes), data_groups.coefficients_kernel(w, 1)):
        coef, _ = _lane_buffer(np.full((h, w, n, data_term.COEFFICIENTS), 7.0, np.float32), "cpu", lanes)
        flags, _ = _lane_buffer(np.full((h, w, 1, data_term.pixel_flag_words(n)), 7, np.int32), "cpu", lanes)
        grad_j2, _ = _lane_buffer(np.full((h, w, 1, 2), 7.0, np.float32), "cpu", lanes)
        q, _ = _lane_buffer(q_before, "cpu", lanes)
        colsum = wp.zeros((h, w), dtype=getattr(wp, unknowns), device="cpu")
        launch(kernel, (h, columns),
               [arr(samples1, float, "cpu"), arr(samples2, float, "cpu"), arr(phis, wp.vec2, "cpu"),
                arr(weights, wp.vec3, "cpu"), x_in, ratio, arr(hidden2, float, "cpu"), arr(zbufs[0], float, "cpu"),
                arr(zbufs[1], float, "cpu"), VIEW_MARGIN, use_zbuf, lanes, cubic],
               [coef, flags, grad_j2, colsum, q], "cpu")
        runs.append([a.numpy() for a in (coef, flags, grad_j2, colsum, q)])
    assert data_groups.coefficients_kernel(w, lanes)[0] is data_groups.data_coefficients_groups
    assert data_groups.coefficients_kernel(w, 1)[0] is data_term.data_coefficients
    for name, got, want in zip(("coef", "flags", "grad_j2", "colsum", "q"), *runs):
        np.testing.assert_array_equal(got.view(np.uint32), want.view(np.uint32), err_msg=name)
    # the inputs reach what they are meant to: rows left out (flags cleared) and kept, duals
    # zeroed, both kinds of group
    flags_got = runs[0][1]
    assert np.any(flags_got != 7) and np.any(runs[0][4] == 0.0) and np.any(runs[0][4] != 0.0)


# --- data term: occlusion handling ------------------------------------------------------------


RING = np.array([(0.0, 0.0)] + [(1.2 * math.cos(a), 1.2 * math.sin(a)) for a in np.arange(8) * math.pi / 4],
                np.float32)  # the centre and 8 samples at multiples of 45° (on half-plane borders)


def _assert_decisions_robust(occ, ratio, tol=1e-5):
    """The test input must not sit on a knife edge of the occlusion test (float32 kernel vs
    float64 reference): where an occlusion is found, no other half-plane that keeps other
    samples comes within ``tol`` of the best mean (but exact matches, mean 0, tie
    exactly: the first half-plane wins in both); and the ratio and floor rules decide
    with a margin of at least ``tol``."""
    means, mean_all, members, best = occ["means"], occ["mean_all"], occ["members"], occ["best"]
    m_best = np.argmin(means, axis=0)
    best_mean = np.take_along_axis(means, m_best[None], 0)[0]
    live = (occ["count"] > 0) & np.isfinite(best_mean)
    differ = np.any(members[:, None, :] != members[None, :, :], axis=-1)  # (8, 8)
    with np.errstate(invalid="ignore"):
        exact_zero = (means == 0) & (best_mean[None] == 0)  # exact matches tie exactly
        near = (np.abs(means - best_mean[None]) < tol) & ~exact_zero
    fragile = np.any(near & differ[m_best].transpose(2, 0, 1), axis=0) & (best >= 0)
    with np.errstate(invalid="ignore"):
        by_ratio = ratio * mean_all - best_mean              # > 0: the ratio rule says occluded
        by_floor = mean_all - best_mean - ref.OCCLUSION_FLOOR  # ≥ 0: the floor rule says occluded
    robust = (by_ratio < -tol) | (by_floor < -tol) | ((by_ratio > tol) & (by_floor > tol))
    fragile |= ~robust
    assert not np.any(fragile & live), np.argwhere(fragile & live)


def _occlusion_random_inputs(seed, h=7, w=9):
    """Random images and linearisation point with 11 samples: the occlusion test decides
    both ways at random pixels, on warps partly outside the image too."""
    r = rng(seed)
    phis = np.concatenate([RING, np.array([(0.4, -1.9), (-1.7, 0.3)], np.float32)])
    s = len(phis)
    samples1 = r.random((s, h, w)).astype(np.float32)
    samples2 = r.random((s, h, w)).astype(np.float32)
    weights = r.uniform(0.5, 2.0, (s, 3)).astype(np.float32)
    x_hat = np.stack([r.uniform(-1.0, 1.0, (h, w)), r.uniform(-1.0, 1.0, (h, w)),
                      r.uniform(-1.5, 1.5, (h, w)), r.uniform(-1.5, 1.5, (h, w))], -1).astype(np.float32)
    x_hat[0, 0] = (3.0, -4.0, 0.3, 0.2)
    x_hat[3, 4] = (0.1, 0.2, 20.0, 0.0)  # p + û outside: the t2 test sees no sample
    return samples1, samples2, phis, weights, x_hat


def _texture(seed, waves=6):
    """A smooth random texture T(x, y) in [0, 1]: a sum of plane waves (wavelengths 6–15 px)."""
    return wave_texture(seed, waves, (0.4, 1.0), 0.4 / waves)


def _occlusion_constructed_inputs(h=9, w=13):
    """The light fields of a smooth texture at disparity 0.6 (t2: moved by û = (0.7, −0.4)),
    with a block of each stack made to disagree by +0.5 in the samples with φ_x > 0 only."""
    tex = _texture(31)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    phis = RING
    delta, u, v = 0.6, 0.7, -0.4
    samples1 = np.array([tex(xx + delta * fx, yy + delta * fy) for fx, fy in phis.astype(np.float64)])
    samples2 = np.array([tex(xx - u + delta * fx, yy - v + delta * fy) for fx, fy in phis.astype(np.float64)])
    right = phis[:, 0] > 1e-3
    samples1[np.ix_(right, range(1, 8), range(1, 5))] += 0.5
    samples2[np.ix_(right, range(1, 7), range(8, 12))] += 0.5
    weights = rng(32).uniform(0.5, 2.0, (len(phis), 3)).astype(np.float32)
    x_hat = np.broadcast_to(np.array([delta, delta, u, v], np.float32), (h, w, 4)).copy()
    return samples1.astype(np.float32), samples2.astype(np.float32), phis, weights, x_hat


def test_data_coefficients_occlusion_matches_reference_random(device):
    ratio = 0.8
    samples1, samples2, phis, weights, x_hat = _occlusion_random_inputs(33)
    _, W, details = _check_data_coefficients(samples1, samples2, phis, weights, x_hat, ratio, device)
    for name in ("t1", "t2"):
        occ = details[name]
        # the input exercises both outcomes, and several different half-planes
        best = occ["best"]
        assert 0.1 < np.mean(best >= 0) < 0.9, (name, np.mean(best >= 0))
        assert len(np.unique(best[best >= 0])) >= 3, (name, np.unique(best))
    assert details["t2"]["count"][3, 4] == 0 and details["t2"]["best"][3, 4] == -1
    # the centre view at t2 is found occluded at some pixels (|I1 − J2| large against the
    # kept t2 samples): no t2 stereo row there, nor the centre's flow row; the flow rows
    # of the side views stay wherever t1 and t2 both keep the sample
    occ_c = details["centre_occluded"]
    assert 0 < occ_c.sum() < occ_c.size // 2
    assert np.all(W[1][:, occ_c] == 0) and np.all(W[2][0, occ_c] == 0)
    assert np.any(W[2][1:, occ_c] > 0)
    assert np.any(W[1][:, ~occ_c] > 0)
    # ratio 0 disables the test: every sample kept, as without occlusion handling
    _, W0, d0 = _check_data_coefficients(samples1, samples2, phis, weights, x_hat, 0.0, device)
    assert np.all(d0["t1"]["best"] == -1) and np.all(d0["t2"]["best"] == -1)
    assert np.all(W <= W0) and np.any(W < W0)


def test_data_coefficients_occlusion_matches_reference_constructed(device):
    """Samples with φ_x > 0 disagree strongly with the centre in a block: there, the
    kernel and the reference leave out exactly those samples (half-plane m = 4, normal
    (−1, 0)), in the t1 rows (w1, w3) and, for the t2 block, in the t2 rows (w2, w3)."""
    ratio = 0.7
    samples1, samples2, phis, weights, x_hat = _occlusion_constructed_inputs()
    coef, _, details = _check_data_coefficients(samples1, samples2, phis, weights, x_hat, ratio, device)
    right = phis[:, 0] > 1e-3
    lam = weights.astype(np.float32)
    # t1: pixel (4, 3) warps into the t1 block from every sample (and the t2 light field is
    # clean there); t2: (4, 9) + û = (9.7, 3.6) warps into the t2 block (and t1 is clean).
    for (i, j), name, row in (((4, 3), "t1", 0), ((4, 9), "t2", 1)):
        assert details[name]["best"][i, j] == 4, (name, details[name]["best"])
        got = coef[:, i, j, 9 + row]
        np.testing.assert_array_equal(got[right], 0.0, err_msg=name)
        np.testing.assert_array_equal(got[~right], lam[~right, row], err_msg=name)
        np.testing.assert_array_equal(coef[right, i, j, 11], 0.0, err_msg=name)
    assert details["t1"]["best"][4, 9] == -1 and details["t2"]["best"][4, 3] == -1
    np.testing.assert_array_equal(coef[:, 4, 3, 10], lam[:, 1])
    np.testing.assert_array_equal(coef[:, 4, 9, 9], lam[:, 0])
    # away from the blocks, every sample is kept: the interpolation errors there are far
    # below OCCLUSION_FLOOR, which overrules the ratio rule at some pixels
    for name in ("t1", "t2"):
        occ = details[name]
        best = occ["best"]
        assert np.sum(best == 4) >= 12 and np.sum(best == -1) >= 30, (name, best)
        by_ratio_only = (np.min(occ["means"], axis=0) < ratio * occ["mean_all"]) & (best < 0)
        assert np.any(by_ratio_only), name


OCCLUDER_SIDES = {"left": (-1, 0), "right": (1, 0), "above": (0, -1), "below": (0, 1)}
NEIGHBOURS = [(a, b) for b in (-1, 0, 1) for a in (-1, 0, 1) if (a, b) != (0, 0)]


def _depth_edge_scene(normal, phis, h=14, w=16, d_front=3, d_back=1, flow=(2, 1), front_flow=None, seed=34):
    """Two light fields of a straight depth edge through the image centre (at half-integer
    coordinates e): a random-textured bright front plane (disparity ``d_front``) on the side
    (P − e)·n > 0 of the edge, a random-textured dark back plane (``d_back``) elsewhere. From
    t1 to t2 the back plane moves by ``flow`` and the front plane by ``front_flow`` (default
    the same), whole pixels. With whole-pixel φ every shift is whole pixels, so every
    visible sample matches exactly. Returns samples1, samples2, the correct x̂, the side
    (P − e)·n of each pixel and the occlusion geometry: hidden1, hidden2 (S, h, w), true
    where the t1 (t2) light field's sample s of the back-plane point at p shows the front."""
    r = rng(seed)
    pad = 10
    front = 0.6 + 0.4 * r.random((h + 2 * pad, w + 2 * pad))  # differs from the back by ≥ 0.2
    back = 0.4 * r.random((h + 2 * pad, w + 2 * pad))
    front_flow = flow if front_flow is None else front_flow
    e = np.array([w / 2 - 0.5, h / 2 - 0.5])
    n = np.asarray(normal, np.float64)
    yy, xx = np.mgrid[0:h, 0:w]

    def stack(tf, tb):
        out = []
        for fx, fy in np.asarray(phis).astype(int):
            # the view at φ shows at pixel x the point whose centre pixel is x + δφ (at t1:
            # minus the plane's motion)
            xf, yf = xx - tf[0] + d_front * fx, yy - tf[1] + d_front * fy
            xb, yb = xx - tb[0] + d_back * fx, yy - tb[1] + d_back * fy
            is_front = (xf - e[0]) * n[0] + (yf - e[1]) * n[1] > 0
            out.append(np.where(is_front, front[yf + pad, xf + pad], back[yb + pad, xb + pad]))
        return np.array(out, np.float32)

    side = (xx - e[0]) * n[0] + (yy - e[1]) * n[1]
    is_front = side > 0
    disparity = np.where(is_front, d_front, d_back).astype(np.float32)
    x_hat = np.stack([disparity, disparity,
                      np.where(is_front, front_flow[0], flow[0]), np.where(is_front, front_flow[1], flow[1])], -1)
    # a back-plane point at p, seen in view φ, lies behind the front plane's point at
    # p + (d_front − d_back)φ (+ the planes' relative motion at t2)
    rel = np.asarray(flow, np.float64) - np.asarray(front_flow, np.float64)
    phi_n = np.asarray(phis, np.float64) @ n
    hidden1 = ~is_front[None] & (side[None] + (d_front - d_back) * phi_n[:, None, None] > 0)
    hidden2 = ~is_front[None] & (side[None] + rel @ n + (d_front - d_back) * phi_n[:, None, None] > 0)
    return stack((0, 0), (0, 0)), stack(front_flow, flow), x_hat.astype(np.float32), side, hidden1, hidden2


def _interior(x_hat, phis):
    """Pixels where every warped position of both light fields lies in the image."""
    h, w = x_hat.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    interior = np.ones((h, w), bool)
    for fx, fy in phis:
        for t, (dx, dy) in ((0, (0.0, 0.0)), (1, (x_hat[..., 2], x_hat[..., 3]))):
            x = xx + dx - x_hat[..., t] * fx
            y = yy + dy - x_hat[..., t] * fy
            interior &= (x >= 0) & (y >= 0) & (x <= w - 1) & (y <= h - 1)
    return interior


@pytest.mark.parametrize("side", list(OCCLUDER_SIDES))
def test_occlusion_weights_drop_on_the_occluders_side(side, device):
    """Both planes move alike: next to the edge, the back-plane points are hidden from the
    three samples towards the occluder (φ·n = 1), in both light fields; exactly those
    samples lose their weights there, and only there (interior pixels)."""
    normal = OCCLUDER_SIDES[side]
    phis = np.array([(0, 0)] + NEIGHBOURS, np.float32)
    samples1, samples2, x_hat, where, hidden1, hidden2 = _depth_edge_scene(normal, phis)
    s, h, w = samples1.shape
    weights = np.tile(np.array([1.0, 2.0, 3.0], np.float32), (s, 1))
    ratio = 0.7
    coef, _, details = _check_data_coefficients(samples1, samples2, phis, weights, x_hat, ratio, device)
    band = (where < 0) & (where > -2)  # d_front − d_back = 2
    np.testing.assert_array_equal(hidden1, hidden2)
    np.testing.assert_array_equal(np.any(hidden1, 0), band)
    assert band.sum() == 2 * (h if normal[1] == 0 else w)
    interior = _interior(x_hat, phis)
    assert np.sum(band & interior) >= 8
    occluder_side = (phis @ np.asarray(normal, np.float32)) > 0  # the 3 samples towards the occluder
    np.testing.assert_array_equal(hidden1[:, band], np.broadcast_to(occluder_side[:, None], (s, band.sum())))
    kept = np.where(hidden1, 0.0, 1.0)
    for k in range(3):
        got = coef[..., 9 + k][:, interior]
        np.testing.assert_array_equal(got, weights[0, k] * kept[:, interior], err_msg=f"w{k + 1}")
    # the kept half is the one facing away from the occluder
    m_away = int(round(math.degrees(math.atan2(-normal[1], -normal[0])) / 45.0)) % 8
    for name in ("t1", "t2"):
        best = details[name]["best"]
        np.testing.assert_array_equal(best[interior], np.where(band, m_away, -1)[interior], err_msg=name)
    assert not np.any(details["centre_occluded"][interior])
    # occlusion_ratio = 0: every weight back
    coef0, _ = _run_data_coefficients(samples1, samples2, phis, weights, x_hat, device, 0.0)
    for k in range(3):
        np.testing.assert_array_equal(coef0[..., 9 + k][:, interior], weights[0, k], err_msg=f"w{k + 1}")


@pytest.mark.parametrize("side", ["left", "below"])
def test_occlusion_of_the_centre_view_at_t2(side, device):
    """The front plane moves one pixel over the back plane from t1 to t2: next to the edge
    the back-plane point is hidden at t2 in the centre view and in the views towards the
    occluder, but seen by the views away from it. There the t2 stereo rows (which compare
    with J2) are all dropped, and the flow rows are carried by the views that see the
    point in both light fields (φ·n < 0) alone; the centre's flow row is dropped too."""
    normal = np.asarray(OCCLUDER_SIDES[side])
    # no sample with φ·n = 0 but the centre: the hidden views then form a half-plane
    phis = np.array([(0, 0)] + [p for p in NEIGHBOURS if np.dot(p, normal) != 0], np.float32)
    flow = (2, 1)
    samples1, samples2, x_hat, where, hidden1, hidden2 = _depth_edge_scene(
        normal, phis, flow=flow, front_flow=tuple(np.asarray(flow) - normal))
    s, h, w = samples1.shape
    weights = np.tile(np.array([1.0, 2.0, 3.0], np.float32), (s, 1))
    coef, _, details = _check_data_coefficients(samples1, samples2, phis, weights, x_hat, 0.7, device)
    interior = _interior(x_hat, phis)
    centre_hidden = hidden2[0]
    np.testing.assert_array_equal(centre_hidden, (where < 0) & (where > -1))  # the column/row next to the edge
    assert np.sum(centre_hidden & interior) >= 4
    np.testing.assert_array_equal(details["centre_occluded"][interior], centre_hidden[interior])
    away = (phis @ normal.astype(np.float32)) < 0
    np.testing.assert_array_equal(hidden2[:, centre_hidden], np.broadcast_to(~away[:, None], (s, centre_hidden.sum())))
    keep1 = ~hidden1
    keep2 = ~hidden2 & ~centre_hidden[None]  # a hidden centre view spoils every t2 stereo row
    want = [keep1, keep2, keep1 & ~hidden2]
    for k in range(3):
        np.testing.assert_array_equal(coef[..., 9 + k][:, interior], weights[0, k] * want[k][:, interior],
                                      err_msg=f"w{k + 1}")
    got_w3 = coef[..., 11][:, centre_hidden & interior]
    np.testing.assert_array_equal(got_w3[away], weights[0, 2])
    np.testing.assert_array_equal(got_w3[~away], 0.0)


def _smooth_view(s, t):
    """A smooth analytic image per sample s and time t, L_s^t(x, y)."""
    c = 0.9 * s + 1.7 * t

    def f(x, y):
        return (0.5 + 0.25 * np.sin(0.23 * x + 0.11 * y + c) * np.cos(0.19 * y - 0.07 * x + 2 * c)
                + 0.15 * np.sin(0.17 * (x + y) + 3 * c))
    return f


def _exact_residuals(views1, views2, phis, x):
    """ρ1, ρ2, ρ3 of MODEL.md §3 by actually warping the analytic views. (3, S, h, w)."""
    h, w = x.shape[:2]
    py, px = np.mgrid[0:h, 0:w].astype(np.float64)
    d1, d2, u, v = (x[..., k].astype(np.float64) for k in range(4))
    out = []
    for s, (xi, eta) in enumerate(phis.astype(np.float64)):
        i1 = views1[0](px, py)
        w1 = views1[s](px - d1 * xi, py - d1 * eta)
        j2 = views2[0](px + u, py + v)
        w2 = views2[s](px + u - d2 * xi, py + v - d2 * eta)
        out.append((i1 - w1, j2 - w2, w1 - w2))
    return np.moveaxis(np.array(out), 1, 0)


def test_data_linearisation_is_first_order_accurate(device):
    """ρ_k(x̂ + Δ) − ρ_k(x̂), from warping the (smooth) images, ≈ the linear part of the
    linearised ρ_k with the kernel's coefficients: checks every sign and coefficient."""
    h, w = 24, 32
    phis = np.array([(0.0, 0.0), (1.5, -0.7), (-2.0, 1.0), (0.6, 1.8)], np.float32)
    s = len(phis)
    views1 = [_smooth_view(k, 0) for k in range(s)]
    views2 = [_smooth_view(k, 1) for k in range(s)]
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    samples1 = np.array([v(xx, yy) for v in views1], np.float32)
    samples2 = np.array([v(xx, yy) for v in views2], np.float32)
    weights = np.ones((s, 3), np.float32)
    r = rng(10)
    x_hat = np.stack([
        0.6 + 0.2 * np.sin(0.3 * xx), -0.4 + 0.2 * np.cos(0.2 * yy),
        1.1 + 0.3 * np.sin(0.2 * yy), -0.8 + 0.2 * np.cos(0.25 * xx),
    ], -1).astype(np.float32)
    coef, _ = _run_data_coefficients(samples1, samples2, phis, weights, x_hat, device, 0.0)
    A = np.moveaxis(coef[..., :9], -1, 0)
    base = _exact_residuals(views1, views2, phis, x_hat)
    interior = np.zeros((h, w), bool)
    interior[6:-6, 6:-6] = True  # all warped positions stay ≥ 2 px inside
    names = ["δ1", "δ2", "u", "v"]
    for k in range(4):
        delta = np.zeros((h, w, 4))
        delta[..., k] = r.uniform(-0.05, 0.05, (h, w))
        exact = _exact_residuals(views1, views2, phis, x_hat + delta) - base
        linear = ref.data_residuals(A, delta) - ref.data_residuals(A, np.zeros_like(delta))
        for part in range(3):
            e = exact[part][:, interior]
            lin = linear[part][:, interior]
            scale = np.linalg.norm(e)
            err = np.linalg.norm(lin - e)
            assert err <= 0.05 * scale + 1e-6, (
                f"ρ{part + 1} w.r.t. {names[k]}: |linearised − exact| = {err:.3g}, |exact change| = {scale:.3g}")


def _lane_buffer(values: np.ndarray, device, lanes: int):
    """(h, w, S, k) values in the data term's lane storage: (float store, vector view);
    int32 values as row-flag words."""
    from lfsf.solver import lane_storage, to_lanes

    h, w, n, k = values.shape
    store, view = lane_storage(h, w, n, k, lanes, device, flags=values.dtype == np.int32)
    store.assign(to_lanes(values, lanes))
    return store, view


def test_lane_storage_views_keep_their_memory_alive():
    """The vector view of the data term's lane storage outlives the float array it was
    made from (the solver's recorded launches hold only views)."""
    import gc

    from lfsf.solver import from_lanes, lane_storage, to_lanes

    store, view = lane_storage(3, 10, 2, 3, 8, "cpu")
    values = rng(7).standard_normal((3, 10, 2, 3)).astype(np.float32)
    store.assign(to_lanes(values, 8))
    del store
    gc.collect()
    _junk = [np.ones(1 << 16) for _ in range(64)]  # reuse freed memory, were it freed
    np.testing.assert_array_equal(from_lanes(view.numpy().reshape(3, 2, -1), 10, 8, 3), values)


# a pixel per thread on storage of 1 or of 32 pixels a group (CUDA's), groups of 8 pixels
# one or two a thread (the CPU); 9 columns leave 7 lanes of the second group of 8 empty
# (23 of 32); 40 samples take two words of row flags a row
@UNKNOWNS
@pytest.mark.parametrize("lanes, groups, s", [(1, None, 3), (32, None, 3), (8, 1, 3), (8, 2, 3), (1, None, 40),
                                              (32, None, 40), (8, 2, 40)])
def test_dual_data_step_matches_reference(device, lanes, groups, s, unknowns):
    """The kernel's scaled duals q̃ = w q against the reference's q, and Kᵀq, with the dual
    steps σ̃ computed from the coefficients and the row flags. On vec2 (flow only) δ1,
    δ2 are 0 and Kᵀq has the flow's components."""
    from lfsf.kernels import data_term
    from lfsf.solver import from_lanes, pack_coefficients, pack_flags

    r = rng(11)
    h, w = 7, 9
    A = r.standard_normal((9, s, h, w)).astype(np.float32)
    grad_j2 = r.standard_normal((h, w, 2)).astype(np.float32)  # ∇J2: A8, A9 = ∇J2 − (A5, A6), as stored
    A[7] = grad_j2[None, :, :, 0] - A[4]
    A[8] = grad_j2[None, :, :, 1] - A[5]
    lam = r.uniform(0.2, 1.5, (s, 3)).astype(np.float32)  # λ_k of each sample
    W = lam.T[:, :, None, None] * (r.random((3, s, h, w)) > 0.2)
    A = A.astype(np.float64)  # the float32 values the kernel sees
    W = W.astype(np.float32).astype(np.float64)
    coef = pack_coefficients(A.transpose(2, 3, 1, 0).astype(np.float32), grad_j2)
    flags = pack_flags((W > 0).transpose(2, 3, 1, 0))[:, :, None, :]  # (h, w, 1, 3 words)
    x_bar = r.standard_normal((h, w, 4)).astype(np.float32)
    x_hat = r.standard_normal((h, w, 4)).astype(np.float32)
    if unknowns == "vec2":
        x_bar[..., :2] = x_hat[..., :2] = 0.0
    q = r.uniform(-1, 1, (3, s, h, w))
    coef_wp = _lane_buffer(coef, device, lanes)
    flags_wp = _lane_buffer(flags, device, lanes)
    grad_j2_wp = _lane_buffer(grad_j2[:, :, None, :], device, lanes)
    q_wp = _lane_buffer((W * q).transpose(2, 3, 1, 0).astype(np.float32), device, lanes)
    q_store = q_wp[0]
    grad_wp = unknowns_zeros((h, w), unknowns, device)
    kernel = data_term.dual_data_kernel(lanes)
    assert (kernel is data_term.dual_data_step_pixel) == (groups is None)
    if groups is None:  # a pixel per thread reads the stores
        columns, (coef_wp, flags_wp, grad_j2_wp, q_wp), last = w, (a[0] for a in (coef_wp, flags_wp, grad_j2_wp, q_wp)), lanes
    else:  # a group per thread, the vector views
        columns = -(-coef_wp[1].shape[1] // groups)
        (coef_wp, flags_wp, grad_j2_wp, q_wp), last = (a[1] for a in (coef_wp, flags_wp, grad_j2_wp, q_wp)), groups
    launch(kernel, (h, columns),
           [coef_wp, flags_wp, arr(lam, wp.vec3, device), grad_j2_wp, unknowns_arr(x_bar, unknowns, device),
            unknowns_arr(x_hat, unknowns, device), DATA_EPS, 1.0, last],
           [q_wp, grad_wp], device)
    want_q, want_grad = ref.dual_data_step(A, W, q, x_bar, x_hat, DATA_EPS)
    want_grad = flow_part(want_grad, unknowns)
    got_q = from_lanes(q_store.numpy(), w, lanes, 3).astype(np.float64).transpose(3, 2, 0, 1)  # q̃, (3, S, h, w)
    close(got_q, W * want_q, atol=1e-4)
    close(grad_wp.numpy(), want_grad, atol=1e-4)
    assert np.any(np.abs(want_q) == 1.0) and np.any(np.abs(want_q) < 1.0)  # clipping exercised
    # rows left out (w_k = 0) have q̃ = 0
    off = W == 0
    assert off.any() and np.all(got_q[off] == 0)
    got_q = np.where(off, 0.0, got_q / np.where(off, 1.0, W))  # back to q for the identity below

    # Kᵀ by the adjoint identity ⟨K Δ, q⟩ = ⟨Δ, Kᵀ q⟩, K Δ from the linear parts of w_k ρ_k
    delta = r.standard_normal((h, w, 4))
    if unknowns == "vec2":
        delta[..., :2] = 0.0
    k_delta = W * (ref.data_residuals(A, delta) - ref.data_residuals(A, np.zeros_like(delta)))
    lhs = np.sum(k_delta * got_q)
    rhs = np.sum(flow_part(delta, unknowns) * grad_wp.numpy())
    assert abs(lhs - rhs) <= 1e-4 * (np.sum(np.abs(k_delta * got_q)) + 1.0), (lhs, rhs)


# --- TGV -----------------------------------------------------------------------------------


def _image_with_flat_patch(seed, h=7, w=9, patch=(3, 4)):
    img = rng(seed).random((h, w)).astype(np.float32)
    img[:patch[0], :patch[1]] = 0.4  # ∇I = 0 inside the patch (but its last row and column)
    return img


def _run_tensor(img, gamma, beta, device):
    from lfsf.kernels import tgv

    h, w = img.shape
    out = wp.zeros((h, w), dtype=wp.vec3, device=device)
    launch(tgv.diffusion_tensor, (h, w), [arr(img, float, device), gamma, beta], [out], device)
    return out.numpy().astype(np.float64)


@pytest.mark.parametrize("gamma,beta", [(5.0, 0.7), (4.0, 1.0)])
def test_diffusion_tensor_matches_reference(gamma, beta, device):
    img = _image_with_flat_patch(12)
    got = _run_tensor(img, gamma, beta, device)
    want = ref.tensor_components(ref.diffusion_tensor(img, gamma, beta))
    close(got, want)
    # identity where ∇I = 0
    close(got[:2, :3], np.broadcast_to([1.0, 0.0, 1.0], (2, 3, 3)))
    # symmetric positive definite, eigenvalues e = exp(−γ|∇I|^β) (along n) and 1
    gx, gy = ref.grad(img)
    mag = np.hypot(gx, gy)
    e = np.exp(-gamma * mag**beta)
    mats = np.stack([got[..., 0], got[..., 1], got[..., 1], got[..., 2]], -1).reshape(*img.shape, 2, 2)
    eig = np.linalg.eigvalsh(mats)
    assert np.all(eig > 0)
    close(eig[..., 0], np.minimum(e, 1.0), atol=2e-5)
    close(eig[..., 1], 1.0, atol=2e-5)
    # the e-eigenvector is ∇I
    g = np.stack([gx, gy], -1)
    close(np.einsum("...ij,...j->...i", mats, g), e[..., None] * g, atol=2e-5)


def test_diffusion_tensor_frees_the_jump_across_the_image_edge_only(device):
    """A vertical step edge between columns 3 and 4: Γ weighs the forward difference
    x(p + e_x) − x(p), so it must be small (exp(−γ|∇I|^β) across the edge) at column 3
    alone; at columns 2 and 4, whose forward differences do not cross the edge, Γ is the
    identity (central differences made it small at both)."""
    img = np.zeros((5, 8), np.float32)
    img[:, 4:] = 1.0
    got = _run_tensor(img, 10.0, 0.7, device)
    close(got[:, 3], np.broadcast_to([np.exp(-10.0), 0.0, 1.0], (5, 3)), atol=1e-6)
    for col in (0, 1, 2, 4, 5, 6, 7):
        close(got[:, col], np.broadcast_to([1.0, 0.0, 1.0], (5, 3)))


@pytest.mark.parametrize("weight", [0.0, 0.5, 3.0])
def test_joint_diffusion_tensor_matches_reference(weight, device):
    """Γ of the guide (I, c·δ1): the eigen-decomposition by NumPy; with c = 0 it is the
    plain image tensor."""
    from lfsf.kernels import tgv

    h, w = 7, 9
    img = _image_with_flat_patch(31, h, w)
    x_hat = np.zeros((h, w, 4), np.float32)
    x_hat[..., 0] = rng(32).uniform(-2, 2, (h, w))
    x_hat[:3, :4, 0] = 0.5  # flat image and flat disparity on [:2, :3]: identity there
    x_hat[..., 1:] = rng(33).standard_normal((h, w, 3))  # ignored
    out = wp.zeros((h, w), dtype=wp.vec3, device=device)
    launch(tgv.joint_diffusion_tensor, (h, w), [arr(img, float, device), arr(x_hat, wp.vec4, device),
                                                float(weight), 5.0, 0.7], [out], device)
    got = out.numpy().astype(np.float64)
    close(got, ref.tensor_components(ref.joint_diffusion_tensor(img, x_hat[..., 0], weight, 5.0, 0.7)), atol=2e-5)
    close(got[:2, :3], np.broadcast_to([1.0, 0.0, 1.0], (2, 3, 3)), atol=1e-6)
    if weight == 0.0:
        close(got, _run_tensor(img, 5.0, 0.7, device), atol=1e-6)
    # flow only (vec2 unknowns): δ1 is 0, the plain image tensor
    out2 = wp.zeros((h, w), dtype=wp.vec3, device=device)
    launch(tgv.joint_diffusion_tensor, (h, w), [arr(img, float, device), unknowns_arr(x_hat, "vec2", device),
                                                float(weight), 5.0, 0.7], [out2], device)
    close(out2.numpy(), _run_tensor(img, 5.0, 0.7, device), atol=1e-6)


def _run_colour_tensor(planes, gamma, beta, device):
    from lfsf.kernels import tgv

    _, h, w = planes.shape
    out = wp.zeros((h, w), dtype=wp.vec3, device=device)
    launch(tgv.colour_diffusion_tensor, (h, w), [arr(np.ascontiguousarray(planes), float, device), gamma, beta],
           [out], device)
    return out.numpy().astype(np.float64)


def test_colour_diffusion_tensor_matches_reference(device):
    """Γ of a colour image (Di Zenzo): the eigen-decomposition of the channels' mean ∇I∇Iᵀ
    by NumPy; identity where all three channels are flat."""
    h, w = 7, 9
    img = np.stack([_image_with_flat_patch(40 + k, h, w) for k in range(3)], -1)
    got = _run_colour_tensor(np.moveaxis(img, -1, 0), 5.0, 0.7, device)
    close(got, ref.tensor_components(ref.colour_diffusion_tensor(img, 5.0, 0.7)), atol=2e-5)
    close(got[:2, :3], np.broadcast_to([1.0, 0.0, 1.0], (2, 3, 3)), atol=1e-6)


def test_colour_diffusion_tensor_of_a_grey_image_is_the_grey_tensor(device):
    """R = G = B = I gives :func:`diffusion_tensor`'s Γ of I (the channel mean keeps the
    gradient's size), so grey content behaves as before."""
    img = _image_with_flat_patch(44)
    got = _run_colour_tensor(np.stack([img] * 3), 5.0, 0.7, device)
    close(got, _run_tensor(img, 5.0, 0.7, device), atol=1e-6)


def test_colour_diffusion_tensor_sees_an_edge_of_equal_brightness(device):
    """Red beside green of the same luma: the grey tensor is the identity everywhere, the
    colour tensor stops the diffusion across the edge (columns 3 → 4) alone."""
    h, w = 5, 8
    img = np.zeros((h, w, 3), np.float32)
    img[:, :4] = (0.6, 0.3, 0.3)
    img[:, 4:] = (0.3, 0.6 * 0.299 / 0.587 + 0.3 - 0.3 * 0.299 / 0.587, 0.3)
    luma = img @ np.array([0.299, 0.587, 0.114], np.float32)
    assert np.ptp(luma) < 1e-6  # one brightness: the luma's Γ is the identity (but for rounding)
    got = _run_colour_tensor(np.moveaxis(img, -1, 0), 10.0, 0.7, device)
    m = np.sqrt(np.sum((img[0, 4] - img[0, 3]) ** 2) / 3.0)
    close(got[:, 3], np.broadcast_to([np.exp(-10.0 * m**0.7), 0.0, 1.0], (h, 3)), atol=1e-6)
    for col in (0, 1, 2, 4, 5, 6, 7):
        close(got[:, col], np.broadcast_to([1.0, 0.0, 1.0], (h, 3)), atol=1e-6)


@UNKNOWNS
def test_warp_by_flow_matches_reference(device, unknowns):
    from lfsf.kernels import sampling

    h, w = 6, 8
    img = rng(34).random((h, w)).astype(np.float32)
    x_hat = rng(35).uniform(-3, 3, (h, w, 4)).astype(np.float32)
    out = wp.zeros((h, w), dtype=float, device=device)
    launch(sampling.warp_by_flow, (h, w), [arr(img, float, device), unknowns_arr(x_hat, unknowns, device)], [out],
           device)
    py, px = np.mgrid[0:h, 0:w].astype(np.float64)
    close(out.numpy(), ref.bilinear(img, px + x_hat[..., 2], py + x_hat[..., 3]), atol=1e-6)


from lfsf.kernels.common import bilinear_with_gradient, lookup_with_gradient  # noqa: E402


@wp.kernel
def _value_and_gradient(row0: int, img: wp.array2d(dtype=float), xs: wp.array(dtype=wp.vec2),
                        out: wp.array(dtype=wp.vec3)):
    k = wp.tid() + row0
    v, g = bilinear_with_gradient(img, xs[k][0], xs[k][1])
    out[k] = wp.vec3(v, g[0], g[1])


@wp.kernel
def _lookup(row0: int, img: wp.array2d(dtype=float), xs: wp.array(dtype=wp.vec2), cubic: int,
            out: wp.array(dtype=wp.vec3)):
    k = wp.tid() + row0
    v, g = lookup_with_gradient(img, xs[k][0], xs[k][1], cubic)
    out[k] = wp.vec3(v, g[0], g[1])


def _lookup_points(h, w, seed):
    """Positions (x, y) to look an h × w image up at: anywhere (outside included), in the
    unclamped interior, and on its bounds."""
    r = rng(seed)
    return np.concatenate([
        r.uniform(-1.5, [w + 0.5, h + 0.5], (200, 2)),           # everywhere, outside included
        r.uniform(1.0, [w - 2.0, h - 2.0], (100, 2)),            # the interior (the fast path, 4 × 4 pixels)
        [(1.0, 1.0), (w - 2.0, 3.0), (3.0, h - 2.0), (w - 2.0001, h - 2.0001), (0.0, 0.0), (w - 1.0, h - 1.0),
         (2.0, 3.0)],                                            # the interior's bounds, corners, a whole pixel
    ]).astype(np.float32)


@pytest.mark.parametrize("cubic", [0, 1])
def test_lookup_with_gradient_matches_reference(device, cubic):
    """The data term's lookup (``Params.cubic``): Catmull–Rom's value where its 4 × 4
    pixels lie in the image, the clamped bilinear one elsewhere, and always the
    central differences of bilinear samples, against the NumPy reference (a Hermite form
    of the same cubic)."""
    h, w = 7, 9
    img = rng(38).random((h, w)).astype(np.float32)
    pts = _lookup_points(h, w, 39)
    out = wp.zeros(len(pts), dtype=wp.vec3, device=device)
    launch(_lookup, len(pts), [arr(img, float, device), arr(pts, wp.vec2, device), cubic], [out], device)
    want = ref.lookup_with_gradient(img, pts[:, 0], pts[:, 1], bool(cubic))
    for k in range(3):
        close(out.numpy()[:, k], want[k], atol=3e-6)
    if cubic:  # (and it is not the bilinear value)
        assert np.abs(out.numpy()[:, 0] - ref.bilinear(img, pts[:, 0], pts[:, 1])).max() > 0.01


def test_cubic_lookup_reproduces_quadratics(device):
    """Catmull–Rom interpolation reproduces polynomials of degree 2 in each coordinate
    (Keys 1981) wherever it reads 4 × 4 pixels; bilinear interpolation does not (it is
    exact only for bilinear functions)."""
    h, w = 8, 10
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)

    def f(x, y):
        return 0.02 * x * x - 0.03 * x * y + 0.05 * y * y + 0.1 * x - 0.2 * y + 0.001 * x * x * y * y

    img = f(xx, yy).astype(np.float32)
    pts = rng(40).uniform(1.0, [w - 2.0, h - 2.0], (300, 2)).astype(np.float32)
    want = f(pts[:, 0].astype(np.float64), pts[:, 1].astype(np.float64))
    out = wp.zeros(len(pts), dtype=wp.vec3, device=device)
    for cubic in (1, 0):
        launch(_lookup, len(pts), [arr(img, float, device), arr(pts, wp.vec2, device), cubic], [out], device)
        err = np.abs(out.numpy()[:, 0].astype(np.float64) - want).max()
        if cubic:
            assert err < 2e-5, err
        else:
            assert err > 1e-3, err


def test_bilinear_with_gradient_is_bilinear_and_its_gradient(device):
    """The fused lookup of the data term (shared weights away from the borders, the
    clamped functions within a pixel of one) gives the bilinear value and the central
    differences of the interpolant, in the interior, at the borders and outside."""
    h, w = 6, 8
    img = rng(36).random((h, w)).astype(np.float32)
    pts = _lookup_points(h, w, 37)
    out = wp.zeros(len(pts), dtype=wp.vec3, device=device)
    launch(_value_and_gradient, len(pts), [arr(img, float, device), arr(pts, wp.vec2, device)], [out], device)
    got = out.numpy()
    x, y = pts[:, 0].astype(np.float64), pts[:, 1].astype(np.float64)
    gx, gy = ref.bilinear_gradient(img, x, y)
    close(got[:, 0], ref.bilinear(img, x, y), atol=2e-6)
    close(got[:, 1], gx, atol=2e-6)
    close(got[:, 2], gy, atol=2e-6)


def _tgv_setting(seed, h=4, w=5):
    """Three different tensors: for δ1, for δ2, and for u and v."""
    t1 = ref.tensor_components(ref.diffusion_tensor(_image_with_flat_patch(seed, h, w, (2, 2)), 5.0, 0.7))
    t2 = ref.tensor_components(ref.diffusion_tensor(rng(seed + 100).random((h, w)), 3.0, 1.0))
    t3 = ref.tensor_components(ref.diffusion_tensor(rng(seed + 200).random((h, w)), 8.0, 0.5))
    return t1.astype(np.float32), t2.astype(np.float32), t3.astype(np.float32)


@UNKNOWNS
@pytest.mark.parametrize("step_ratio", [1.0, 0.25])  # Pock–Chambolle's; τ·c and σ/c
def test_tgv_preconditioner_is_abs_sums_of_K(device, unknowns, step_ratio):
    from lfsf.kernels import tgv

    h, w = 4, 5
    alpha0, alpha1, eps = np.array([2.0, 1.5, 0.8, 1.2]), 0.7, 1e-6  # α0 of each unknown
    t1, t2, t3 = _tgv_setting(13, h, w)
    assert np.any(t1[..., 1] < 0) and np.any(t1[..., 1] > 0)
    data_colsum = rng(14).uniform(0.0, 3.0, (h, w, 4)).astype(np.float32)
    outs = [unknowns_zeros((h, w), unknowns, device) for _ in range(4)]
    launch(tgv.tgv_preconditioner, (h, w),
           [unknowns_arr(data_colsum, unknowns, device), arr(t1, wp.vec3, device), arr(t2, wp.vec3, device), arr(t3, wp.vec3, device),
            unknowns_value(alpha0, unknowns), alpha1, eps, step_ratio], outs, device)
    want, zrows = ref.tgv_preconditioner(data_colsum.astype(np.float64), t1.astype(np.float64),
                                         t2.astype(np.float64), alpha0, alpha1, eps, t3.astype(np.float64))
    for name, got in zip(("tau_x", "tau_w0", "tau_w1", "sigma_y"), outs):
        scale = step_ratio if name.startswith("tau") else 1.0 / step_ratio
        np.testing.assert_allclose(got.numpy(), scale * flow_part(want[name], unknowns), rtol=1e-5, err_msg=name)
    # σ_z = 1/(2α0) (the solver's constant) is 1/row sum of every nonzero z row
    for k in range(4):
        nonzero = zrows[..., k][zrows[..., k] > 0]
        close(nonzero, 2.0 * alpha0[k])
        assert np.all((zrows[..., k] == 0) | (np.abs(zrows[..., k] - 2 * alpha0[k]) < 1e-12))


def _tgv_fields(seed, h, w, scale=1.0):
    r = rng(seed)
    return [(scale * r.standard_normal((h, w, 4))).astype(np.float32) for _ in range(9)]


def _tensor_entries(t1, t2, t3, unknowns, device):
    """Γ00, Γ01, Γ11 per unknown, as the TGV steps take them, made by expand_tensor and
    checked against the reference's Γ of each unknown."""
    from lfsf.kernels import tgv

    h, w = t1.shape[:2]
    out = [unknowns_zeros((h, w), unknowns, device) for _ in range(3)]
    launch(tgv.expand_tensor, (h, w), [arr(t1, wp.vec3, device), arr(t2, wp.vec3, device), arr(t3, wp.vec3, device)],
           out, device)
    want = np.stack([ref.per_unknown(t1, t2, k, t3) for k in range(4)], -2)  # (h, w, 4 unknowns, 3 entries)
    for e, got in enumerate(out):
        np.testing.assert_array_equal(got.numpy(), flow_part(want[..., e], unknowns))
    return out


#: (rows, columns, columns a thread) of the TGV step tests: a pixel per thread (CUDA),
#: part of a row, a whole row (CPU); and rows wide enough for the steps' vector path
#: (TGV_FLOATS floats at once: 8 pixels of vec4, 16 of vec2), whole and in parts.
TGV_SPANS = pytest.mark.parametrize("h, w, span", [(4, 5, 1), (4, 5, 2), (4, 5, 5), (5, 41, 41), (5, 41, 19)])


@UNKNOWNS
@TGV_SPANS
def test_tgv_dual_step_matches_reference(device, h, w, span, unknowns):
    from lfsf.kernels import tgv

    alpha0, alpha1 = 2.0, 0.7
    t1, t2, t3 = _tgv_setting(15, h, w)
    x_bar, w0_bar, w1_bar, y0, y1, z00, z01, z10, z11 = _tgv_fields(16, h, w, 0.5)
    r = rng(17)
    sigma_y = r.uniform(0.1, 0.8, (h, w, 4)).astype(np.float32)
    sigma_z = 1.0 / (2.0 * alpha0)
    duals = [unknowns_arr(a, unknowns, device) for a in (y0, y1, z00, z01, z10, z11)]
    launch(tgv.tgv_kernels(device)[0], (h, -(-w // span)),
           [unknowns_arr(x_bar, unknowns, device), unknowns_arr(w0_bar, unknowns, device),
            unknowns_arr(w1_bar, unknowns, device), *_tensor_entries(t1, t2, t3, unknowns, device),
            unknowns_arr(sigma_y, unknowns, device),
            sigma_z, alpha0, alpha1, span], duals, device)
    want = ref.tgv_dual_step(x_bar, w0_bar, w1_bar, t1, t2, sigma_y, sigma_z, alpha0, alpha1,
                             y0, y1, z00, z01, z10, z11, t3)
    for name, got, exp in zip(("y0", "y1", "z00", "z01", "z10", "z11"), duals, want):
        np.testing.assert_allclose(got.numpy(), flow_part(exp, unknowns), rtol=1e-5, atol=1e-5, err_msg=name)
    # both projections were exercised, and hold
    y = np.hypot(want[0], want[1])
    z = np.sqrt(sum(a * a for a in want[2:]))
    assert np.any(np.isclose(y, 1.0)) and np.any(y < 0.99) and np.all(y <= 1 + 1e-9)
    assert np.any(np.isclose(z, 1.0)) and np.any(z < 0.99) and np.all(z <= 1 + 1e-9)


@UNKNOWNS
@TGV_SPANS
def test_tgv_primal_step_matches_reference(device, h, w, span, unknowns):
    from lfsf.kernels import tgv

    alpha0, alpha1 = np.array([2.0, 1.5, 0.8, 1.2]), 0.7  # α0 of each unknown
    t1, t2, t3 = _tgv_setting(18, h, w)
    x, w0, w1, y0, y1, z00, z01, z10, z11 = _tgv_fields(19, h, w, 0.5)
    r = rng(20)
    data_grad = r.standard_normal((h, w, 4)).astype(np.float32)
    tau_x, tau_w0, tau_w1 = (r.uniform(0.05, 0.5, (h, w, 4)).astype(np.float32) for _ in range(3))
    prim = [unknowns_arr(a, unknowns, device) for a in (x, w0, w1)]
    bars = [unknowns_zeros((h, w), unknowns, device) for _ in range(3)]
    launch(tgv.tgv_kernels(device)[1], (h, -(-w // span)),
           [unknowns_arr(data_grad, unknowns, device)]
           + [unknowns_arr(a, unknowns, device) for a in (y0, y1, z00, z01, z10, z11)]
           + _tensor_entries(t1, t2, t3, unknowns, device)
           + [unknowns_arr(a, unknowns, device) for a in (tau_x, tau_w0, tau_w1)]
           + [unknowns_value(alpha0, unknowns), alpha1, span],
           prim + bars, device)
    want = ref.tgv_primal_step(data_grad, y0, y1, z00, z01, z10, z11, t1, t2, tau_x, tau_w0, tau_w1,
                               alpha0, alpha1, x, w0, w1, t3)
    for name, got, exp in zip(("x", "w0", "w1", "x_bar", "w0_bar", "w1_bar"), prim + bars, want):
        np.testing.assert_allclose(got.numpy(), flow_part(exp, unknowns), rtol=1e-5, atol=1e-5, err_msg=name)


@UNKNOWNS
@pytest.mark.parametrize("h, w, span", [(5, 41, 41), (5, 41, 19), (1, 40, 40), (3, 19, 19)])
def test_tgv_steps_vector_path_equals_pixel_by_pixel(h, w, span, unknowns):
    """On the CPU the TGV steps take 32 floats at once where they fit (the vector path);
    their CUDA instances go pixel by pixel. Both give the same bits, steps chained over a
    few iterations (here both on the CPU)."""
    from lfsf.kernels import tgv

    t1, t2, t3 = _tgv_setting(30, h, w)
    fields = _tgv_fields(31, h, w, 0.5)
    r = rng(32)
    data_grad = r.standard_normal((h, w, 4)).astype(np.float32)
    steps_ = [r.uniform(0.05, 0.5, (h, w, 4)).astype(np.float32) for _ in range(4)]
    runs = []
    for dual, primal in ((tgv.tgv_dual_step, tgv.tgv_primal_step), (tgv.tgv_dual_step_pixel, tgv.tgv_primal_step_pixel)):
        g = _tensor_entries(t1, t2, t3, unknowns, "cpu")
        x, w0, w1, y0, y1, z00, z01, z10, z11 = (unknowns_arr(a, unknowns, "cpu") for a in fields)
        bars = [unknowns_arr(a, unknowns, "cpu") for a in fields[:3]]
        sy, tx, tw0, tw1 = (unknowns_arr(a, unknowns, "cpu") for a in steps_)
        for _ in range(3):
            launch(dual, (h, -(-w // span)), [*bars, *g, sy, 0.25, 2.0, 0.5, span], [y0, y1, z00, z01, z10, z11], "cpu")
            launch(primal, (h, -(-w // span)),
                   [unknowns_arr(data_grad, unknowns, "cpu"), y0, y1, z00, z01, z10, z11, *g, tx, tw0, tw1,
                    unknowns_value([2.0, 1.5, 0.8, 1.2], unknowns), 0.5, span], [x, w0, w1, *bars], "cpu")
        runs.append([a.numpy() for a in (x, w0, w1, y0, y1, z00, z01, z10, z11, *bars)])
    for got, want in zip(*runs):
        np.testing.assert_array_equal(got.view(np.uint32), want.view(np.uint32))


def test_tgv_gradient_and_divergence_are_negative_adjoints(device):
    """⟨α1Γ∇x, y⟩ = −⟨x, α1 div(Γy)⟩ and ⟨∇w, z⟩ = −⟨w, div z⟩, with the gradient taken from
    the dual step and the divergence from the primal step, both checked against the
    forward-difference matrix and its transpose."""
    from lfsf.kernels import tgv

    h, w = 5, 6
    alpha1 = 0.8
    r = rng(21)
    t1, t2, t3 = _tgv_setting(22, h, w)
    zeros = np.zeros((h, w, 4), np.float32)
    ones = np.ones((h, w, 4), np.float32)

    # gradient: one dual step from y = 0, z = 0 with σ small enough that nothing is projected
    x = r.standard_normal((h, w, 4)).astype(np.float32)
    wf = r.standard_normal((h, w, 4)).astype(np.float32)
    step = 1e-2
    duals = [wp.zeros((h, w), dtype=wp.vec4, device=device) for _ in range(6)]
    span, per_row = D.row_span(device, w)
    launch(tgv.tgv_kernels(device)[0], (h, per_row),
           [arr(x, wp.vec4, device), arr(zeros, wp.vec4, device), arr(wf, wp.vec4, device),
            *_tensor_entries(t1, t2, t3, "vec4", device), arr(step * ones, wp.vec4, device),
            step, 1.0, alpha1, span], duals, device)
    ky0, ky1, gw00, gw01, gw10, gw11 = (d.numpy().astype(np.float64) / step for d in duals)
    # with w0 = 0, w1 = wf: z00, z01 = 0 and (z10, z11) = ∇wf
    close(gw00, 0.0)
    close(gw01, 0.0)
    dx, dy = ref.gradient_matrix(h, w)
    for k in range(4):
        close(gw10[..., k].ravel(), dx @ wf[..., k].ravel(), atol=1e-4)
        close(gw11[..., k].ravel(), dy @ wf[..., k].ravel(), atol=1e-4)

    # divergence: one primal step at τ = 1, zero data gradient
    y0, y1, z0, z1 = (r.standard_normal((h, w, 4)).astype(np.float32) for _ in range(4))
    prim = [arr(x, wp.vec4, device), arr(zeros, wp.vec4, device), arr(zeros, wp.vec4, device)]
    bars = [wp.zeros((h, w), dtype=wp.vec4, device=device) for _ in range(3)]
    launch(tgv.tgv_kernels(device)[1], (h, per_row),
           [arr(zeros, wp.vec4, device), arr(y0, wp.vec4, device), arr(y1, wp.vec4, device),
            arr(z0, wp.vec4, device), arr(z1, wp.vec4, device), arr(zeros, wp.vec4, device),
            arr(zeros, wp.vec4, device), *_tensor_entries(t1, t2, t3, "vec4", device),
            arr(ones, wp.vec4, device), arr(ones, wp.vec4, device), arr(ones, wp.vec4, device), wp.vec4(1.0), alpha1,
            span],
           prim + bars, device)
    div_gy = prim[0].numpy().astype(np.float64) - x        # α1 div(Γy)
    w0_change = prim[1].numpy().astype(np.float64)          # α1 (Γy)_0 + div(z00, z01)

    for k in range(4):
        g = ref.per_unknown(t1, t2, k, t3).astype(np.float64)
        gy0 = g[..., 0] * y0[..., k] + g[..., 1] * y1[..., k]
        gy1 = g[..., 1] * y0[..., k] + g[..., 2] * y1[..., k]
        # adjoint identity with the kernels' own gradient and divergence
        lhs = np.sum(ky0[..., k] * y0[..., k] + ky1[..., k] * y1[..., k])   # ⟨α1 Γ(∇x − w), y⟩, w = (0, wf)
        lhs_w = -alpha1 * np.sum(gy1 * wf[..., k])                           # its −w part
        rhs = -np.sum(x[..., k] * div_gy[..., k])
        assert abs((lhs - lhs_w) - rhs) < 1e-3 * (1 + abs(rhs)), (k, lhs - lhs_w, rhs)
        # divergence = −(∇ᵀ) of the forward-difference matrix
        want_div = -alpha1 * (dx.T @ gy0.ravel() + dy.T @ gy1.ravel())
        close(div_gy[..., k].ravel(), want_div, atol=1e-4)
        want_w0 = alpha1 * gy0.ravel() - (dx.T @ z0[..., k].ravel() + dy.T @ z1[..., k].ravel())
        close(w0_change[..., k].ravel(), want_w0, atol=1e-4)
        # the dual step's α1 Γ(∇x − w) from the forward-difference matrix
        r0 = (dx @ x[..., k].ravel()).reshape(h, w)
        r1 = (dy @ x[..., k].ravel()).reshape(h, w) - wf[..., k]
        close(ky0[..., k], alpha1 * (g[..., 0] * r0 + g[..., 1] * r1), atol=1e-4)
        close(ky1[..., k], alpha1 * (g[..., 1] * r0 + g[..., 2] * r1), atol=1e-4)
        # ⟨∇w, z⟩ = −⟨w, div z⟩ with the kernels' ∇ (dual step) and div (primal step)
        div_z = w0_change[..., k] - alpha1 * gy0
        lhs_z = np.sum(gw10[..., k] * z0[..., k] + gw11[..., k] * z1[..., k])
        rhs_z = -np.sum(wf[..., k] * div_z)
        assert abs(lhs_z - rhs_z) < 1e-3 * (1 + abs(rhs_z)), (k, lhs_z, rhs_z)


# --- median --------------------------------------------------------------------------------


@UNKNOWNS
@pytest.mark.parametrize("radius", [1, 2, 3, 4])  # 4: the path that reads the image per comparison
@pytest.mark.parametrize("tolerance", [0.0, 0.6])
def test_median_flow_matches_reference(radius, tolerance, device, unknowns):
    from lfsf.kernels import median

    h, w = 7, 9
    r = rng(23)
    x = r.standard_normal((h, w, 4)).astype(np.float32)
    x[..., 3] = np.round(x[..., 3] * 2) / 2  # many ties
    x[:3, :4, 2] = 0.25  # a constant patch: every value ties
    if unknowns != "vec4":
        x[..., :2] = 0  # flow only: δ1 reads as 0, every pixel takes part
    out = unknowns_zeros((h, w), unknowns, device)
    launch(median.median_flow, (h, w), [unknowns_arr(x, unknowns, device), radius, tolerance], [out], device)
    got = out.numpy()
    want = ref.median_flow(x, radius, tolerance)
    np.testing.assert_array_equal(got, flow_part(want, unknowns).astype(np.float32))
    if unknowns == "vec4":
        np.testing.assert_array_equal(got[..., :2], x[..., :2])


@UNKNOWNS
@pytest.mark.parametrize("radius", [1, 2, 3])
@pytest.mark.parametrize("size", [(7, 9), (9, 4), (1, 1), (12, 15)])
@pytest.mark.parametrize("tolerance", [0.0, 0.6])
def test_flow_median_pairs_match_reference(radius, size, tolerance, device, unknowns):
    """The median from sorted columns (two passes, a thread for two pixels) is the NumPy
    median of every window's pixels on the centre's surface (equal values: −0 and +0 are
    not told apart): odd and even
    widths (a last pair of one pixel), images narrower and shorter than the window, ties,
    and δ1 with depth edges (the windows that straddle one take the gathered median)."""
    from lfsf.kernels import median

    h, w = size
    r = rng(29)
    x = r.standard_normal((h, w, 4)).astype(np.float32)
    x[..., 3] = np.round(x[..., 3] * 2) / 2  # many ties
    x[: h // 2, : w // 2, 2] = 0.25  # a constant patch
    x[..., 0] = np.where(np.arange(w) < w // 2, 0.0, 1.0)[None] + 0.1 * r.standard_normal((h, w))  # a depth edge
    if unknowns != "vec4":
        x[..., :2] = 0
    arr = unknowns_arr(x, unknowns, device)
    columns = [wp.empty((h, w, 2 * radius + 1), dtype=float, device=device) for _ in range(2)]
    depth = wp.empty((h, w), dtype=wp.vec2, device=device)
    launch(median.sorted_flow_columns, (h, w), [arr, radius], [*columns, depth], device)
    out = unknowns_zeros((h, w), unknowns, device)
    launch(median.flow_median_pairs, (h, (w + 1) // 2), [arr, radius, tolerance, *columns, depth], [out], device)
    got = out.numpy()
    want = ref.median_flow(x, radius, tolerance)
    np.testing.assert_array_equal(got, flow_part(want, unknowns).astype(np.float32))
    if unknowns == "vec4":
        np.testing.assert_array_equal(got[..., :2], x[..., :2])


@pytest.mark.parametrize("radius", [1, 2, 3])
def test_guided_median_edges_matches_reference(radius, device):
    """δ1 and δ2 take the colour-weighted median at their depth edges where the colours
    of the two depth groups differ, and keep their values elsewhere; the flow is copied."""
    from lfsf.kernels import median

    h, w = 14, 12
    r = rng(31)
    x = r.standard_normal((h, w, 4)).astype(np.float32) * 0.1
    x[:, 6:, 0] += 2.0  # a depth edge in δ1 down the middle, and a blob in δ2
    x[2:6, 3:8, 1] += 1.5
    colours = r.uniform(0.33, 0.37, (h, w, 3)).astype(np.float32)
    colours[:, 5:] += np.float32([0.3, 0.0, -0.2])  # the colour edge one column off the depth edge
    colours[7:, :, :] = 0.35  # bottom rows: one colour on both sides of the depth edge
    out = arr(np.zeros((h, w, 4)), wp_vec4(), device)
    for sigma, jump, separation in ((0.05, 0.5, 1.0), (0.2, 0.5, 2.0), (0.05, 5.0, 1.0)):
        launch(median.guided_median_edges, (h, w), [arr(x, wp_vec4(), device), arr(colours, wp_vec3(), device),
                                                    radius, sigma, jump, separation], [out], device)
        got = out.numpy()
        want = ref.guided_median_edges(x, colours, radius, sigma, jump, separation)
        close(got, want, atol=1e-6)
        np.testing.assert_array_equal(got[..., 2:], x[..., 2:])
        if jump > 4.0:  # no window spans more than the jump: nothing moves
            np.testing.assert_array_equal(got, x)
    # the colour edge wins: column 5 (δ1 near 0, colour of the right side) takes the right's δ1
    # (a 3×3 window weighs its own column most, and keeps it)
    launch(median.guided_median_edges, (h, w), [arr(x, wp_vec4(), device), arr(colours, wp_vec3(), device),
                                                radius, 0.05, 0.5, 1.0], [out], device)
    got = out.numpy()
    if radius > 1:
        assert (got[:7 - radius, 5, 0] > 1.5).all(), got[:7 - radius, 5, 0]
    # where the colours do not separate the depth groups (bottom rows), δ1 stays as it was
    np.testing.assert_array_equal(got[7 + radius:, :, 0], x[7 + radius:, :, 0])
    assert np.abs(got[7 + radius:, 5:7, 0] - x[7 + radius:, 5:7, 0]).max() == 0


def test_guided_median_edges_radius_outside_its_window_buffer(device):
    """r < 1 copies x; r above LOCAL_RADIUS (the window buffer's) is taken as LOCAL_RADIUS
    instead of writing past the buffer."""
    from lfsf.kernels import median

    h, w = 12, 10
    r = rng(32)
    x = r.standard_normal((h, w, 4)).astype(np.float32) * 0.1
    x[:, 5:, 0] += 2.0
    colours = r.uniform(0.33, 0.37, (h, w, 3)).astype(np.float32)
    colours[:, 4:] += np.float32([0.3, 0.0, -0.2])
    most = int(median.LOCAL_RADIUS)

    def run(radius):
        out = arr(np.zeros((h, w, 4)), wp_vec4(), device)
        launch(median.guided_median_edges, (h, w), [arr(x, wp_vec4(), device), arr(colours, wp_vec3(), device),
                                                    radius, 0.05, 0.5, 1.0], [out], device)
        return out.numpy()

    np.testing.assert_array_equal(run(0), x)
    at_most = run(most)
    assert not np.array_equal(at_most, x)  # the step acts here
    np.testing.assert_array_equal(run(most + 2), at_most)


def wp_vec3():
    from lfsf.device import warp

    return warp().vec3


def wp_vec4():
    from lfsf.device import warp

    return warp().vec4


@pytest.mark.parametrize("radius", [2, 3])
def test_remove_speckles_matches_reference(radius, device):
    """δ1 and δ2 take the window's median where too few pixels around share their depth
    (a few pixels' blob, stray values), keep it on surfaces and along a 2-pixel line;
    the flow is copied. At the image's edges the window reads clamped."""
    from lfsf.kernels import median

    h, w = 16, 15
    r = rng(41)
    x = r.standard_normal((h, w, 4)).astype(np.float32) * 0.05
    x[:, 8:, 0] += 2.0   # a depth edge: both sides keep their values
    x[3:5, 2, 0] = 3.0   # a 2-pixel speckle in δ1
    x[0, 0, 1] = -4.0    # a speckle in δ2 at the corner
    x[:, 11:13, 1] += 1.0   # a line two pixels wide in δ2 (one pixel wide would go: 7 of 49)
    x[10:, 3:6, 1] += 30 * r.standard_normal((6, 3)).astype(np.float32)  # stray values
    out = arr(np.zeros((h, w, 4)), wp_vec4(), device)
    depth, support = 0.3, 8
    launch(median.remove_speckles, (h, w), [arr(x, wp_vec4(), device), radius, depth, support], [out], device)
    got = out.numpy()
    np.testing.assert_array_equal(got, ref.remove_speckles(x, radius, depth, support))
    assert abs(got[3, 2, 0]) < 0.3 and abs(got[0, 0, 1]) < 0.3       # the speckles are gone
    np.testing.assert_array_equal(got[:, 8:11, 0], x[:, 8:11, 0])      # the surfaces kept
    np.testing.assert_array_equal(got[2:14, 11:13, 1], x[2:14, 11:13, 1])    # the line kept
    np.testing.assert_array_equal(got[..., 2:], x[..., 2:])


def test_median_keeps_to_the_centre_pixels_surface(device):
    """Across a depth edge, the median takes the flow of the centre pixel's own surface:
    a near object (δ1 = 1) moving by 3 px whose window is mostly background (δ1 = −1,
    moving by 1 px) keeps its 3 px with a tolerance, and loses it to the background's
    1 px without one."""
    from lfsf.kernels import median

    h, w = 9, 9
    x = np.zeros((h, w, 4), np.float32)
    x[..., 0] = -1.0
    x[..., 2] = 1.0
    x[3:6, 3:6, 0] = 1.0  # a 3×3 near object, 9 of the centre's 25 window pixels
    x[3:6, 3:6, 2] = 3.0
    for tolerance, want in ((0.5, 3.0), (0.0, 1.0)):
        out = unknowns_zeros((h, w), "vec4", device)
        launch(median.median_flow, (h, w), [unknowns_arr(x, "vec4", device), 2, tolerance], [out], device)
        got = out.numpy()
        assert got[4, 4, 2] == want and got[3, 3, 2] == want
        assert got[0, 0, 2] == 1.0  # the background keeps its own flow either way


def test_median_networks_select_the_median_and_match_their_generator():
    """The selection networks (kernels/median_networks.py) are what
    scripts/gen_median_networks.py generates, and select the median of random, tied and
    0/1 inputs (its check, NumPy on the same operations)."""
    from pathlib import Path

    from conftest import load_script

    root = Path(__file__).resolve().parents[1]
    gen = load_script("gen_median_networks")
    text = (root / "kernels" / "median_networks.py").read_text()
    for n in gen.SIZES:
        gen.check(n)
        code, _ = gen.emit(n)
        assert code in text, f"kernels/median_networks.py is stale for n = {n}: run scripts/gen_median_networks.py"
    for r in gen.PAIR_LAYOUTS:  # (the sorted-column networks of the plain median; r = 3's proof takes 30 s: --check)
        gen.check_pair(r)
        if r < 3:
            gen.check_pair_exhaustively(r)
        for code in (gen.emit_column(r), gen.emit_pair(r)[0]):
            assert code in text, f"kernels/median_networks.py is stale for radius {r}: run scripts/gen_median_networks.py"


# --- solver energy -------------------------------------------------------------------------


def _level_solver(size, grid, params, device, level_scale=1.0):
    """A LevelSolver for the finest level of a small synthetic pair, built as
    lfsf.estimate does (sampling, texture split), started at x = 0 (``level_scale``: as if
    it were a coarser level of a larger image)."""
    from lfsf import synth
    from lfsf.estimate import _structure_texture
    from lfsf.kernels import sampling
    from lfsf.solver import LevelSolver

    lf1, lf2, _ = synth.render_scene("paper", size=size, grid=grid, supersample=1, device=device)
    rows, cols = lf1.grid
    h, w = lf1.height, lf1.width
    phis, _ = params.sample_offsets((rows, cols))
    n = len(phis)
    weights = np.tile(np.array([params.lambda1, params.lambda2, params.lambda3], np.float32) / n, (n, 1))
    weights[0, :2] = 0.0
    wp_phis = arr(phis, wp.vec2, device)
    stacks = []
    for lf in (lf1, lf2):
        views = arr(lf.grey().views.reshape(rows * cols, h, w), float, device)
        out = wp.empty((n, h, w), dtype=float, device=device)
        launch(sampling.sample_subaperture, (n * h, 1), [views, rows, cols, wp_phis, w], [out], device)
        stacks.append(out)
    centres = [wp.clone(s[0]) for s in stacks]
    textures = [_structure_texture(s, params, device) for s in stacks]
    solver = LevelSolver(textures[0], textures[1], centres[0], centres[1], wp_phis,
                         arr(weights, wp.vec3, device), params, device, level_scale=level_scale)
    solver.set_state(np.zeros((h, w, 4), np.float32))
    return solver


@pytest.mark.parametrize("preset", ["fast", "flow"])
def test_take_coarse_upsamples_w_and_the_disparity_duals_on_the_device(device, preset):
    """``take_coarse``: after set_state, w0 and w1 become the coarser level's upsampled
    (every component, unscaled: the pyramid's upsampling of each plane), and with
    ``duals`` the (δ1, δ2) parts of the TGV duals become its upsampled ones, the flow's
    parts staying 0; without ``duals`` they all stay 0. Flow only, w's held (δ1, δ2)
    parts stay 0 and no dual is carried. Solvers of other unknowns are refused. (The
    duals are the set_state's zeros where nothing is carried, though the fine solver had
    iterated before.)"""
    from reference_kernels import upsample

    from lfsf.params import Params
    from lfsf.solver import TGV_DUALS

    params = Params.preset(preset).replace(rof_iterations=10)
    coarse = _level_solver((16, 12), 5, params, device)
    coarse.linearise()
    coarse.iterate(20)
    _x, cw0, cw1 = coarse.state()
    cduals = coarse.tgv_duals()
    assert np.any(cw0 != 0) and np.any(cw1 != 0)
    fine = _level_solver((32, 24), 5, params, device)
    h, w = fine.shape
    fine.linearise()
    fine.iterate(10)  # (duals not 0: set_state must reset them)
    assert any(np.any(d != 0) for d in fine.tgv_duals())

    def up(field):
        return np.stack([upsample(field[..., c][None], (h, w), 1.0)[0] for c in range(field.shape[-1])], -1)

    for duals in (True, False):
        fine.set_state(np.zeros((h, w, 4), np.float32))
        fine.take_coarse(coarse, duals)
        _x, w0, w1 = fine.state()
        np.testing.assert_allclose(w0, up(cw0), rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(w1, up(cw1), rtol=1e-5, atol=1e-6)
        np.testing.assert_array_equal(fine.w0_bar.numpy(), fine.w0.numpy())
        for name, got, was in zip(TGV_DUALS, fine.tgv_duals(), cduals):
            if duals and preset != "flow":
                np.testing.assert_allclose(got[..., :2], up(was)[..., :2], rtol=1e-5, atol=1e-6, err_msg=name)
                assert np.all(got[..., 2:] == 0) and np.any(got[..., :2] != 0), name
            else:
                assert np.all(got == 0), name
    if preset == "flow":
        assert np.all(w0[..., :2] == 0) and np.any(w0[..., 2:] != 0)
    other = _level_solver((16, 12), 5, Params.preset("flow" if preset == "fast" else "fast"), device)
    with pytest.raises(ValueError, match="other unknowns"):
        fine.take_coarse(other, True)


@pytest.mark.parametrize("preset", ["fast", "flow"])
def test_set_state_takes_the_unknowns_on_the_device(device, preset):
    """set_state from a vec4 device array gives the state that the same array from the
    host gives (flow only: (δ1, δ2) held on the host, (u, v) iterated); another shape or
    type is refused."""
    from lfsf.params import Params

    params = Params.preset(preset).replace(rof_iterations=10)
    solver = _level_solver((32, 24), 5, params, device)
    h, w = solver.shape
    x = rng(14).normal(size=(h, w, 4)).astype(np.float32)
    solver.set_state(x)
    want = [a.copy() for a in solver.state()]
    solver.linearise()
    solver.iterate(5)
    solver.set_state(arr(x, wp.vec4, device))
    for got, expected in zip(solver.state(), want):
        np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(solver.x_bar.numpy(), solver.x.numpy())
    with pytest.raises(ValueError, match="vec4 array of shape"):
        solver.set_state(arr(x[:-1], wp.vec4, device))
    with pytest.raises(ValueError, match="vec4 array of shape"):
        solver.set_state(arr(x[..., :2], wp.vec2, device))


def test_view_visibility_margin_scales_with_the_level(device):
    """``occlusion_margin`` is in px per view step at full resolution, and disparities
    shrink with the level: a step of 0.2 (level px per view step) hides no background
    sample on the full-resolution level (margin 0.25) but does on a level of half the
    width (margin 0.125)."""
    from lfsf.params import Params

    params = Params.preset("fast").replace(radius=2.0, rof_iterations=20)
    x = np.zeros((30, 40, 4), np.float32)
    x[10:20, 15:25, :2] = 0.2  # a near square, at t1 and t2
    background = x[..., 0] == 0
    kept = {}
    for name, scale, state in (("flat", 1.0, np.zeros_like(x)), ("full", 1.0, x), ("half", 0.5, x)):
        solver = _level_solver((40, 30), 5, params, device, level_scale=scale)
        solver.set_state(state)
        solver.linearise()
        _, (w1, _, _) = solver.data_rows()
        kept[name] = int((w1[:, background] > 0).sum())
    assert kept["full"] == kept["flat"]
    assert kept["half"] < kept["full"]


def test_remove_speckles_keeps_a_pixel_with_exactly_the_support_asked(device):
    """A pixel keeps its depth when ``support`` pixels of its window (itself counted)
    share it, and only with fewer: a line of three pixels at δ1 = 5 among zeros, radius
    1, support 3, keeps its middle pixel (3 near) and loses its ends (2 near)."""
    from lfsf.kernels import median

    x = np.zeros((7, 9, 4), np.float32)
    x[3, 3:6, 0] = 5.0
    out = arr(np.zeros((7, 9, 4)), wp_vec4(), device)
    launch(median.remove_speckles, (7, 9), [arr(x, wp_vec4(), device), 1, 0.3, 3], [out], device)
    got = out.numpy()
    np.testing.assert_array_equal(got, ref.remove_speckles(x, 1, 0.3, 3))
    assert got[3, 4, 0] == 5.0 and got[3, 3, 0] == 0.0 and got[3, 5, 0] == 0.0


def test_contrast_is_normalised_by_the_t1_centre_view():
    """The texture stack is scaled by one factor, so that its first image (the t1 centre
    view) has the mean absolute gradient ``contrast``, whatever the others have."""
    from lfsf import device
    from lfsf.estimate import _mean_gradient, _normalise_contrast
    from lfsf.params import Params

    wp = device.warp()
    r = rng(7)
    images = np.stack([0.1 * r.standard_normal((20, 24)), 0.7 * r.standard_normal((20, 24))]).astype(np.float32)
    stack = wp.array(images.copy(), dtype=float, device="cpu")
    out = _normalise_contrast(stack, Params(contrast=0.02), "cpu").numpy()
    assert _mean_gradient(out[0]) == pytest.approx(0.02, rel=1e-5)
    np.testing.assert_allclose(out / images, out[0, 0, 0] / images[0, 0, 0], rtol=1e-5)  # one factor for all


def test_flow_median_tolerance_scales_with_the_level(device):
    """``median_tolerance`` is in px per view step at full resolution: the per-warp median
    of the flow takes a window's pixel only where its δ1 is within the tolerance scaled to
    the level. A spike of u at δ1 = 0.4 among pixels at δ1 = 0 shares its surface with them
    on the full-resolution level (τ = 0.5) and is filtered away, but stands alone on a
    level of half the width (τ = 0.25) and is kept."""
    from lfsf.params import Params

    params = Params.preset("fast").replace(radius=2.0, rof_iterations=20, median_radius=1, median_tolerance=0.5)
    x = np.zeros((30, 40, 4), np.float32)
    x[15, 20, 0] = 0.4
    x[15, 20, 2] = 1.0
    kept = {}
    for name, scale in (("full", 1.0), ("half", 0.5)):
        solver = _level_solver((40, 30), 5, params, device, level_scale=scale)
        assert solver.median_radius() == 1
        solver.set_state(x)
        solver.median()
        kept[name] = float(solver.unknowns()[15, 20, 2])
    assert kept == {"full": 0.0, "half": 1.0}, kept


def _linearised_problem(solver):
    p = solver.params
    a, weights = solver.data_rows()
    return ref.LinearisedProblem(a, weights,
                                 solver.linearisation_point(), solver.tensor1.numpy(), solver.tensor2.numpy(),
                                 np.array([p.alpha0, p.alpha0, p.flow_alpha0, p.flow_alpha0]), p.alpha1,
                                 solver.tensor3.numpy())


def test_level_solver_energy_decreases(device):
    from lfsf.params import Params

    params = Params.preset("fast").replace(radius=2.0, rof_iterations=20)
    solver = _level_solver((40, 30), 5, params, device)
    solver.linearise()
    e0 = solver.energy()
    solver.iterate(10)
    e10 = solver.energy()
    solver.iterate(190)
    e200 = solver.energy()
    assert np.isfinite(e200)
    assert e200 < e10 and e200 < e0, (e0, e10, e200)
    # LevelSolver.energy is the linearised energy of MODEL.md (independent NumPy build)
    problem = _linearised_problem(solver)
    assert abs(problem.energy(*solver.state()) - e200) < 1e-4 * e200


@pytest.fixture(scope="module")
def small_params():
    from lfsf.params import Params

    # α0 fixed (not the default, which tuning moves): NumPy's scalar-step reference
    # needs more iterations the larger α0 is
    return Params.preset("fast").replace(radius=1.0, rof_iterations=10, lambda1=20.0, lambda2=20.0,
                                         lambda3=20.0, alpha0=2.0, alpha0_flow=1.0)


@pytest.mark.parametrize("circles,step_ratio", [(2, 1.0), (1, 1.0), (2, 0.25)])  # 1: flow only, on vec2 (u, v)
def test_level_solver_iterates_the_preconditioned_primal_dual(device, small_params, circles, step_ratio):
    """LevelSolver.iterate (all kernels together) equals the diagonally preconditioned
    Chambolle–Pock of MODEL.md §5 in NumPy, with τ, σ from the abs sums of the actual K
    (τ·c and σ/c for a step ratio c). Flow only, the solver iterates (u, v) alone; the
    four-unknown NumPy iteration leaves δ1, δ2 at their start (0) there."""
    params = small_params.replace(step_ratio=step_ratio)
    if circles == 1:
        params = params.replace(circles=1, samples=(1,))
    solver = _level_solver((14, 12), 3, params, device)
    assert solver.flow_only == (circles == 1)
    solver.linearise()
    problem = _linearised_problem(solver)
    steps = problem.preconditioners(small_params.eps, step_ratio)
    close(solver.tau_x.numpy(), steps["tau_x"][..., 4 - len(solver.vec()):], rtol=1e-5, atol=0)
    solver.iterate(200)
    want = problem.solve(200, steps)
    for name, got, exp in zip(("x", "w0", "w1"), solver.state(), want):
        np.testing.assert_allclose(got, exp, rtol=0, atol=2e-3, err_msg=name)
    e_kernel, e_numpy = solver.energy(), problem.energy(*want)
    assert abs(e_kernel - e_numpy) < 1e-4 * e_numpy, (e_kernel, e_numpy)


@pytest.mark.parametrize("visibility", [True, False])  # the view z-buffers' rows, or the best half's
def test_level_solver_reaches_the_minimum_of_the_linearised_energy(device, small_params, visibility):
    """The preconditioned kernels and a plain scalar-step Chambolle–Pock in NumPy, on the
    same linearised problem, end at the same energy (within 10⁻⁴). Both components of
    each y(p) must share one step: with σ_y0 ≠ σ_y1 (each row's own sum) the projection
    onto |y| ≤ 1 is not the prox in the preconditioned metric, and the kernels settled
    0.3 % above the minimum however long they ran (238.94 against 238.07 here)."""
    solver = _level_solver((14, 12), 3, small_params.replace(visibility=visibility), device)
    solver.linearise()
    problem = _linearised_problem(solver)
    e_start = solver.energy()
    solver.iterate(2000)
    e_kernel = solver.energy()
    e_numpy = problem.energy(*problem.solve(12000))
    assert e_kernel < e_start
    assert abs(e_kernel - e_numpy) < 1e-4 * e_numpy, (e_start, e_kernel, e_numpy)


# --- geometric occlusion at t2 -------------------------------------------------------------------


def _hidden(x, margin, device, reach=0, outside=0.0):
    from lfsf.kernels import occlusion

    h, w = x.shape[:2]
    xa = arr(x, wp.vec4, device)
    zbuf = wp.full((h, w), occlusion.EMPTY, dtype=float, device=device)
    launch(occlusion.splat_depth, (h, w), [xa], [zbuf], device, bands=1)
    hidden = wp.zeros((h, w), dtype=float, device=device)
    launch(occlusion.hidden_at_t2, (h, w), [xa, zbuf, float(margin), float(outside)], [hidden], device)
    out = wp.zeros((h, w), dtype=float, device=device)
    launch(occlusion.spread_hidden, (h, w), [xa, hidden, float(margin), int(reach)], [out], device)
    return out.numpy()


def test_hidden_at_t2_matches_reference(device):
    rng = np.random.default_rng(11)
    h, w = 9, 12
    x = np.zeros((h, w, 4), np.float32)
    x[..., :2] = rng.uniform(-2, 2, (h, w, 2))
    x[..., 2:] = rng.uniform(-3, 3, (h, w, 2))
    x[0, 0, 2] = 40.0  # lands outside: never hidden
    for reach in (0, 1, 2):
        want = ref.hidden_at_t2(x, 0.3, reach)
        got = _hidden(x, 0.3, device, reach)
        np.testing.assert_array_equal(got, want)
        assert 0 < want.sum() < h * w
        assert reach > 0 or got[0, 0] == 0  # lands outside: hidden only by spreading
    # the points not seen at t2: landing outside counts (SceneFlow.occluded)
    want = ref.hidden_at_t2(x, 0.3, 0, outside=1.0)
    np.testing.assert_array_equal(_hidden(x, 0.3, device, 0, outside=1.0), want)
    assert want[0, 0] == 1 and want.sum() > ref.hidden_at_t2(x, 0.3, 0).sum()


def test_fill_takes_for_hidden_the_points_that_land_behind_a_surface_close_in_depth(device):
    """A far strip (δ 1.0) whose right part lands, by a wrong flow of +4 px, on a nearer
    square only 0.2 px per view step in front (within ``occlusion_margin``, 0.25): the
    linearisation's test misses those points, the fill's (``FILL_MARGIN``, the same
    z-buffer test of x, not spread: :func:`ref.hidden_at_t2`) takes them, and gives them
    the flow of their own strip's seen points (+3) more than the square's (0), where they
    had kept the flow that hid them."""
    from lfsf.params import Params
    from lfsf.solver import FILL_MARGIN

    params = Params.preset("fast")
    solver = _level_solver((24, 18), 3, params, device)
    h, w = solver.shape
    x = np.zeros((h, w, 4), np.float32)
    x[5:13, 3:9, :2] = 1.0
    x[5:13, 3:6, 2] = 3.0  # lands on 6…8, which the strip's own right part leaves
    x[5:13, 6:9, 2] = 4.0  # lands on 10…12, on the square
    x[5:13, 9:15, :2] = 1.2
    solver.set_state(x)
    solver.linearise()
    assert not (solver.hidden2.numpy() > 0.5)[5:13, 6:9].any()  # the geometric test's margin
    want = (solver.hidden2.numpy() > 0.5) | (ref.hidden_at_t2(x, FILL_MARGIN, 0) > 0.5)
    solver.fill_hidden()
    got = solver.hidden2.numpy() > 0.5
    np.testing.assert_array_equal(got, want)
    assert got[5:13, 6:9].all() and not got[5:13, 9:15].any() and not got[5:13, 3:6].any()
    u = solver.unknowns()[5:13, 6:9, 2]
    assert np.abs(u - 3.0).max() < 0.8, u


def test_fill_takes_the_points_given_as_hidden(device):
    """``fill_hidden(hidden=…)``: points the caller calls hidden at t2 (the estimator's
    points whose flow is lost) join ``hidden2`` and take the flow of their own strip's
    other points (+3), where they held a wrong one (+7) that hid nothing; points left
    alone keep theirs. As a bool array or a float device array alike."""
    from lfsf.params import Params

    params = Params.preset("fast")
    for as_device in (False, True):
        solver = _level_solver((24, 18), 3, params, device)
        h, w = solver.shape
        x = np.zeros((h, w, 4), np.float32)
        x[5:13, 3:15, :2] = 1.0
        x[5:13, 3:15, 2] = 3.0
        x[5:13, 8:10, 2] = 7.0  # lands on background pixels that no nearer point takes
        solver.set_state(x)
        solver.linearise()
        before = solver.hidden2.numpy() > 0.5
        assert not before[5:13, 8:10].any()
        lost = np.zeros((h, w), bool)
        lost[5:13, 8:10] = True
        solver.fill_hidden(hidden=wp.array(lost.astype(np.float32), dtype=float, device=device) if as_device else lost)
        got = solver.hidden2.numpy() > 0.5
        assert got[lost].all()
        u = solver.unknowns()[..., 2]
        assert np.abs(u[5:13, 8:10] - 3.0).max() < 0.3, u[5:13, 8:10]
        np.testing.assert_array_equal(u[~got], x[..., 2][~got])


def _square_moving_right(device):
    """(params, a `fast` LevelSolver of 24×18, x): a nearer square (δ 1.5) moving 3 px
    right over a still background at δ 0."""
    from lfsf.params import Params

    params = Params.preset("fast")
    solver = _level_solver((24, 18), 3, params, device)
    x = np.zeros(solver.shape + (4,), np.float32)
    x[6:12, 6:12, 0] = x[6:12, 6:12, 1] = 1.5
    x[6:12, 6:12, 2] = 3.0
    return params, solver, x


def test_solver_hidden_at_t2_is_the_geometric_test_of_the_estimate_given(device):
    """LevelSolver.hidden_at_t2(x) marks what :func:`ref.hidden_at_t2` marks for that x
    (margin ``occlusion_margin``, spread ``occlusion_reach``), whatever the solver's own
    state, and the next linearisation still tests the solver's own x̂."""
    params, solver, x = _square_moving_right(device)
    h, w = solver.shape
    want = ref.hidden_at_t2(x, params.occlusion_margin, params.occlusion_reach) > 0.5
    assert want[6:12, 12:15].all() and want.sum() < h * w // 4
    np.testing.assert_array_equal(solver.hidden_at_t2(x), want)
    solver.linearise()  # the solver's x is 0: nothing hidden
    assert not (solver.hidden2.numpy() > 0.5).any()


def test_solver_occluded_at_marks_the_hidden_and_the_leaving_points(device):
    """LevelSolver.occluded_at(x), the estimate's mask of the points not seen at t2: the
    geometric test of :func:`ref.hidden_at_t2` without its spread (reach 0), and every
    point whose flow carries it out of the image (its nearest t2 pixel outside it, as
    the synthetic ground truth's ``occluded`` counts them: beyond the pixels' edges,
    not their centres)."""
    params, solver, x = _square_moving_right(device)
    h, w = solver.shape
    x[:, -2:, 2] = 2.6  # the last two columns move out of the image
    x[:, -3, 2] = 1.4  # the one before them stays in it (to w − 1.6)
    x[:, -4, 2] = 0.3  # and, in the next column to the left, the part that moves less …
    x[10:, -2:, 2] = 0.3  # … as do the lower rows of the last two: within half a pixel of the edge
    x[2, 2, 3] = -2.8  # one point up, out of the top row (to row −0.8)
    x[3, 3, 3] = -3.4  # and one just not (to row −0.4)
    hidden = ref.hidden_at_t2(x, params.occlusion_margin, 0) > 0.5
    jj, ii = np.meshgrid(np.arange(w), np.arange(h))
    leaving = (jj + x[..., 2] >= w - 0.5) | (ii + x[..., 3] < -0.5)
    assert hidden[6:12, 12:15].all() and not hidden[6:12, 15:].any() and leaving.sum() == 2 * 10 + 1
    got = solver.occluded_at(x)
    np.testing.assert_array_equal(got, hidden | leaving)
    np.testing.assert_array_equal(got, ref.hidden_at_t2(x, params.occlusion_margin, 0, outside=1.0) > 0.5)
    assert not got[10:, -1].any()  # 0.3 px from the last pixel centre: still in the image
    solver.linearise()  # the solver's own x̂ is tested again
    assert not (solver.hidden2.numpy() > 0.5).any()


def _fill_hidden(x, hidden, sigma, radius, device, depth_sigma=0.0, flagged=None):
    from lfsf.kernels import occlusion

    xa = arr(x, wp.vec4, device)
    xb = arr(x + 5.0, wp.vec4, device)  # x̄: its δ2 and flow are set where hidden, the rest kept
    ha = arr(hidden, float, device)
    fa = arr(np.zeros_like(hidden) if flagged is None else flagged, float, device)
    launch(occlusion.fill_hidden_motion, hidden.shape, [ha, fa, float(sigma), float(depth_sigma), int(radius)],
           [xa, xb], device)
    return xa.numpy(), xb.numpy()


def test_surface_motion_fit_matches_reference(device):
    """The affine fit of each pixel's surface motion from its trusted neighbours, against
    its NumPy reference (strides 1 and 2, with and without the depth weight); and on a
    surface whose flow is exactly affine (a plane turning and receding), the fit gives a
    point whose own flow is wrong (``untrusted``) its surface's flow back, not its
    neighbour surface's."""
    from lfsf.kernels import occlusion

    def fit(x, good, sigma, depth_sigma, radius, stride, ridge):
        out = wp.empty(good.shape, dtype=wp.vec4, device=device)
        launch(occlusion.surface_motion_fit, good.shape,
               [arr(x, wp.vec4, device), arr(1.0 - good, float, device), float(sigma), float(depth_sigma), int(radius),
                int(stride), float(ridge)], [out], device)
        return out.numpy()

    r = rng(11)
    h, w = 11, 14
    x = r.uniform(-2, 2, (h, w, 4)).astype(np.float32)
    good = (r.random((h, w)) < 0.6).astype(np.float32)
    good[:, 10:] = 0.0  # a strip with no trusted pixel within radius 1: x kept there
    for sigma, depth_sigma, radius, stride, ridge in ((1.5, 0.0, 2, 1, 0.5), (2.0, 0.8, 3, 1, 4.0),
                                                       (1.0, 0.5, 2, 2, 1.0), (1.0, 0.0, 1, 1, 0.25)):
        got = fit(x, good, sigma, depth_sigma, radius, stride, ridge)
        want = ref.surface_motion_fit(x, 1.0 - good, sigma, depth_sigma, radius, stride, ridge)
        close(got, want, atol=2e-4)
        np.testing.assert_array_equal(got[..., 0], x[..., 0])
    np.testing.assert_array_equal(fit(x, good, 1.0, 0.0, 1, 1, 0.25)[:, 12], x[:, 12])
    # two surfaces side by side: the left one (δ1 = 1) turns and recedes, u = 0.3 − 0.2·(j − 5),
    # v = 0.1·(i − 6), D = −0.5 + 0.01·j; the right one (δ1 = −1) moves by (2, 0). The left
    # surface's rim (columns 7, 8) has wrong flows, and is not trusted.
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    left = xx < 9
    x = np.stack([np.where(left, 1.0, -1.0), np.where(left, 0.5 + 0.01 * xx, -1.0),
                  np.where(left, 0.3 - 0.2 * (xx - 5), 2.0), np.where(left, 0.1 * (yy - 6), 0.0)], -1).astype(np.float32)
    truth = x.copy()
    x[:, 7:9, 2:] = (2.0, 0.0)  # the rim dragged along with the neighbour surface
    x[:, 7:9, 1] = -1.0
    good = np.ones((h, w), np.float32)
    good[:, 7:9] = 0.0
    got = fit(x, good, 3.0, 0.1, 6, 1, 1e-4)
    close(got[:, 7:9], truth[:, 7:9], atol=1e-3)
    close(got[:, 10:], truth[:, 10:], atol=1e-3)


def test_fill_hidden_motion_matches_reference(device):
    """δ2 = δ1 + the weighted depth change, (u, v) the weighted flow of the visible pixels
    nearby, where hidden; every other value as it was (x and x̄), δ1 everywhere."""
    r = rng(5)
    h, w = 9, 13
    x = r.uniform(-2, 2, (h, w, 4)).astype(np.float32)
    hidden = (r.random((h, w)) < 0.3).astype(np.float32)
    hidden[:, 9:] = 1.0  # a block wider than the radius: its middle column sees nothing
    on = hidden > 0.5
    for sigma, radius, depth_sigma in ((1.0, 2, 0.0), (2.5, 3, 0.0), (2.5, 3, 0.7)):
        got, got_bar = _fill_hidden(x, hidden, sigma, radius, device, depth_sigma)
        want = ref.fill_hidden_motion(x, hidden, sigma, depth_sigma, radius)
        close(got, want, atol=1e-5)
        np.testing.assert_array_equal(got[~on], x[~on])
        np.testing.assert_array_equal(got[..., 0], x[..., 0])
        np.testing.assert_array_equal(got_bar[..., 1:][on], got[..., 1:][on])
        np.testing.assert_array_equal(got_bar[..., 0], x[..., 0] + 5.0)
        np.testing.assert_array_equal(got_bar[~on], x[~on] + 5.0)
    # radius 2: column 11 is 3 px from the last visible column (8): δ2 = δ1, flow kept
    got, _ = _fill_hidden(x, hidden, 1.0, 2, device)
    np.testing.assert_array_equal(got[:, 11, 1], x[:, 11, 0])
    np.testing.assert_array_equal(got[:, 11, 2:], x[:, 11, 2:])
    # flagged points: δ2 alone, and they give no depth change
    flagged = ((r.random((h, w)) < 0.3) & ~on).astype(np.float32)
    flagged[0, 0] = 1.0
    hidden[0, 0] = 1.0  # both
    on = hidden > 0.5
    got, got_bar = _fill_hidden(x, hidden, 2.5, 3, device, 0.7, flagged)
    close(got, ref.fill_hidden_motion(x, hidden, 2.5, 0.7, 3, flagged), atol=1e-5)
    only = (flagged > 0.5) & ~on
    assert only.sum() > 5
    np.testing.assert_array_equal(got[..., 2:][only], x[..., 2:][only])
    assert np.abs(got[..., 1][only] - x[..., 1][only]).min() > 0
    untouched = ~on & ~(flagged > 0.5)
    np.testing.assert_array_equal(got[untouched], x[untouched])


def test_fill_hidden_motion_carries_the_background_motion(device):
    """A background receding by 0.3 (δ2 = δ1 − 0.3) and moving 2 px right, partly hidden
    at t2 by a nearer occluder moving 5 px left: the hidden points get the background's
    change and flow, whatever the iterations had left there (here the occluder's). The
    occluder's visible pixels lie next to them, nearer than the background's: without
    the depth weight their motion leaks in."""
    h, w = 8, 16
    x = np.zeros((h, w, 4), np.float32)
    x[..., 0], x[..., 1], x[..., 2] = -1.0, -1.3, 2.0
    x[:, :4] = (1.0, 1.0, -5.0, 0.0)  # the occluder, visible
    hidden = np.zeros((h, w), np.float32)
    hidden[:, 4:8] = 1.0
    x[:, 4:8, 1:3] = (1.0, -5.0)  # the occluder's δ2 and flow reached over
    got, _ = _fill_hidden(x, hidden, 2.0, 6, device, depth_sigma=0.1)
    close(got[:, 4:, 1], np.full((h, w - 4), -1.3), atol=1e-6)
    close(got[:, 4:, 2], np.full((h, w - 4), 2.0), atol=1e-6)
    close(got[..., 3], np.zeros((h, w)), atol=1e-6)
    mixed, _ = _fill_hidden(x, hidden, 2.0, 6, device)
    assert (mixed[:, 4, 2] < 1.0).all()  # the occluder's −5 pulls the first hidden column


def test_hidden_at_t2_finds_the_covered_background(device):
    """A near square (δ1 = 1) moving 3 px right over a still far background (δ1 = −1)
    covers the 3 background columns to its right, and nothing else; ``reach`` widens the
    band over the background only. Still scenes (stereo) hide nothing."""
    h, w = 12, 16
    x = np.zeros((h, w, 4), np.float32)
    x[..., :2] = -1.0
    x[3:8, 4:9, :2] = 1.0
    x[3:8, 4:9, 2] = 3.0
    want = np.zeros((h, w))
    want[3:8, 9:12] = 1.0
    np.testing.assert_array_equal(_hidden(x, 0.25, device), want)
    wide = np.zeros((h, w))
    wide[2:9, 8:13] = 1.0  # one pixel around the band
    wide[3:8, 4:9] = 0.0  # but not on the square (another surface)
    np.testing.assert_array_equal(_hidden(x, 0.25, device, reach=1), wide)
    # with a margin above the depth difference nothing is hidden
    assert _hidden(x, 2.5, device, reach=1).sum() == 0
    # no motion: depth edges alone hide nothing
    x[..., 2:] = 0.0
    assert _hidden(x, 0.25, device, reach=3).sum() == 0


def test_linearise_restarts_the_over_relaxation_and_builds_the_tensors_at_x_hat(device):
    """At every linearisation (MODEL.md §6) the over-relaxed x̄ and w̄ start again from x
    and w, and Γ_uv is rebuilt at x̂: the t1 centre view's tensor with δ̂1 as a second
    channel of weight ``flow_edge_weight``. Γ_t2, made at the level's start, is the
    tensor of the t2 centre view warped to the t1 grid by û (``warp_tensor2``), or of the
    view as it is without it. Against NumPy (:mod:`reference_kernels`), on a state with a
    depth edge and a flow of a few pixels."""
    from lfsf.params import Params

    params = Params.preset("fast").replace(radius=2.0, rof_iterations=10)
    solver = _level_solver((40, 30), 5, params, device)
    h, w = solver.shape
    state = np.zeros((h, w, 4), np.float32)
    state[:, w // 2:, 0] = 1.5  # a depth edge in δ1
    state[..., 1] = 0.5
    state[..., 2] = 2.3  # û
    state[..., 3] = -1.2  # v̂
    solver.set_state(state)
    solver.linearise()
    solver.iterate(7)
    x, w0, w1 = (a.numpy().copy() for a in (solver.x, solver.w0, solver.w1))
    assert not np.array_equal(solver.x_bar.numpy(), x)  # (over-relaxed after iterating)
    solver.linearise()
    np.testing.assert_array_equal(solver.x_hat.numpy(), x)
    for bar, plain in ((solver.x_bar, x), (solver.w0_bar, w0), (solver.w1_bar, w1)):
        np.testing.assert_array_equal(bar.numpy(), plain)
    centre1 = solver.centre1.numpy().astype(np.float64)
    want3 = ref.tensor_components(ref.joint_diffusion_tensor(centre1, x[..., 0], params.flow_edge_weight,
                                                             params.gamma, params.beta))
    close(solver.tensor3.numpy().astype(np.float64), want3, atol=2e-5)
    assert np.abs(want3 - ref.tensor_components(ref.diffusion_tensor(centre1, params.gamma, params.beta))).max() > 0.1
    # Γ_t2 (made by set_state at x̂ = the state)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    centre2 = solver.centre2.numpy().astype(np.float64)
    warped = ref.bilinear(centre2, xx + state[..., 2], yy + state[..., 3])
    close(solver.tensor2.numpy().astype(np.float64),
          ref.tensor_components(ref.diffusion_tensor(warped, params.gamma, params.beta)), atol=2e-5)
    unwarped = _level_solver((40, 30), 5, params.replace(warp_tensor2=False), device)
    unwarped.set_state(state)
    close(unwarped.tensor2.numpy().astype(np.float64),
          ref.tensor_components(ref.diffusion_tensor(centre2, params.gamma, params.beta)), atol=2e-5)


def test_fill_hidden_reaches_three_sigma(device, monkeypatch):
    """``LevelSolver.fill_hidden`` hands the fill kernel a window of ⌈3σ⌉ px
    (``hidden_fill_sigma`` σ): the Gaussian weights beyond are under 1 %. (A window of
    ⌈2σ⌉ changed some 3 700 δ2 pixels of `random-2` at 160×120.)"""
    from lfsf.kernels import occlusion
    from lfsf.params import Params

    params = Params.preset("fast").replace(radius=2.0, rof_iterations=10, hidden_fill_sigma=2.6)
    solver = _level_solver((40, 30), 5, params, device)
    solver.linearise()
    seen = []
    launch_ = solver._launch

    def spy(kernel, inputs, outputs):
        if kernel is occlusion.fill_hidden_motion:
            seen.append(inputs)
        return launch_(kernel, inputs=inputs, outputs=outputs)

    monkeypatch.setattr(solver, "_launch", spy)
    solver.fill_hidden()
    assert len(seen) == 1 and seen[0][2] == 2.6 and seen[0][4] == 8, seen  # ⌈3 · 2.6⌉
