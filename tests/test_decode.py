"""Decoding raw lenslet images (lfsf.decode, kernels/decode.py, `lfsf decode`).

Every decode kernel against a NumPy reference on tiny inputs; the lattice and view
conventions; calibration accuracy over the whole sensor; decoded views against the
known light field of synthetic lenslet images (hexagonal and rectangular lattices,
a few mrad of rotation, non-integer pitch and offset, vignetting, noise, with and
without a Bayer mosaic); scene flow from decoded views against that from the source
views; and the faults that must end in one clear message (exit status 2)."""

import contextlib
import json
import math
import re

import numpy as np
import pytest

import lfsf
from lfsf import cli
from lfsf._errors import LfsfWarning
from lfsf import decode as D
from lfsf.decode import Lattice, calibrate, decode, synthetic_lenslet
from lfsf.device import warp

from conftest import arr, launch, rng, wave_texture

wp = warp()


def close(got, want, atol=1e-5):
    np.testing.assert_allclose(np.asarray(got, np.float64), want, rtol=1e-5, atol=atol)


# --- NumPy references ----------------------------------------------------------------------


def ref_bilinear(img, x, y):
    h, w = img.shape
    x = np.clip(x, 0, w - 1)
    y = np.clip(y, 0, h - 1)
    j0 = np.minimum(np.floor(x).astype(int), max(w - 2, 0))
    i0 = np.minimum(np.floor(y).astype(int), max(h - 2, 0))
    j1, i1 = np.minimum(j0 + 1, w - 1), np.minimum(i0 + 1, h - 1)
    fx, fy = x - j0, y - i0
    return ((1 - fy) * ((1 - fx) * img[i0, j0] + fx * img[i0, j1])
            + fy * ((1 - fx) * img[i1, j0] + fx * img[i1, j1]))


def ref_demosaic(mosaic, pattern, channel):
    h, w = mosaic.shape
    out = np.zeros_like(mosaic, dtype=np.float64)
    for i in range(h):
        for j in range(w):
            if pattern[2 * (i % 2) + j % 2] == channel:
                out[i, j] = mosaic[i, j]
                continue
            total = weight = 0.0
            for di in (-1, 0, 1):
                for dj in (-1, 0, 1):
                    ii, jj = min(max(i + di, 0), h - 1), min(max(j + dj, 0), w - 1)
                    if pattern[2 * (ii % 2) + jj % 2] == channel:
                        k = (2 - abs(di)) * (2 - abs(dj))
                        total += k * mosaic[ii, jj]
                        weight += k
            out[i, j] = total / weight if weight else 0.0
    return out


def ref_resample(lens_values, lattice, first_row, first_col, u0, v0, height, width):
    """Independent of the kernel's oblique frame: the three lens centres nearest to the
    point (a lattice triangle's vertices on a hexagonal lattice), barycentric weights from
    a 3×3 solve; bilinear over the enclosing cell on a rectangular lattice."""
    views, rows, cols = lens_values.shape
    out = np.zeros((views, height, width))
    ii, jj = np.meshgrid(np.arange(first_row, first_row + rows), np.arange(first_col, first_col + cols),
                         indexing="ij")
    pu, pv = lattice.plane_position(ii, jj)
    pts = np.stack([pu.ravel(), pv.ravel()], 1)
    for y in range(height):
        for x in range(width):
            q = np.array([u0 + x, v0 + y])
            if lattice.kind == "rect":
                i0, j0 = int(np.floor(q[1])), int(np.floor(q[0]))
                fa, fb = q[0] - j0, q[1] - i0
                r, c = i0 - first_row, j0 - first_col
                vals = lens_values[:, r:r + 2, c:c + 2]
                out[:, y, x] = ((1 - fb) * ((1 - fa) * vals[:, 0, 0] + fa * vals[:, 0, 1])
                                + fb * ((1 - fa) * vals[:, 1, 0] + fa * vals[:, 1, 1]))
                continue
            d = np.sum((pts - q) ** 2, 1)
            near = np.argsort(d)[:3]
            a = np.vstack([pts[near].T, np.ones(3)])
            wts = np.linalg.solve(a, np.array([q[0], q[1], 1.0]))
            assert wts.min() > -1e-6, "the three nearest lenses must enclose the point"
            out[:, y, x] = lens_values[:, near // cols, near % cols] @ wts
    return out


# --- kernels against references ------------------------------------------------------------


def test_devignette_matches_reference(device):
    from lfsf.kernels import decode as K

    raw = rng(1).random((7, 9)).astype(np.float32)
    white = rng(2).random((7, 9)).astype(np.float32)
    white[2, 3] = 0.0
    out = wp.empty((7, 9), dtype=float, device=device)
    launch(K.devignette, (7, 9), [arr(raw, float, device), arr(white, float, device), 0.05, 0.8], [out], device)
    close(out.numpy(), 0.8 * raw / np.maximum(white, 0.05))


@pytest.mark.parametrize("bayer", ["RGGB", "BGGR", "GRBG", "GBRG"])
def test_demosaic_matches_reference(bayer, device):
    from lfsf.kernels import decode as K

    mosaic = rng(3).random((6, 7)).astype(np.float32)
    pattern = D.BAYER_PATTERNS[bayer]
    for channel in range(3):
        out = wp.empty((6, 7), dtype=float, device=device)
        launch(K.demosaic_bilinear, (6, 7), [arr(mosaic, float, device), wp.vec4i(*pattern), channel], [out],
               device)
        close(out.numpy(), ref_demosaic(mosaic, pattern, channel))
    # a scene of one colour everywhere demosaics to that colour everywhere
    colour = np.array([0.2, 0.5, 0.9], np.float32)
    flat = colour[np.array(pattern).reshape(2, 2)[np.arange(8)[:, None] % 2, np.arange(10)[None, :] % 2]]
    close(D.demosaic(flat, bayer, device=device), np.broadcast_to(colour, (8, 10, 3)))


@pytest.mark.parametrize("kind", ["hex", "rect"])
def test_sample_micro_images_matches_reference(kind, device):
    from lfsf.kernels import decode as K

    image = rng(4).random((40, 50)).astype(np.float32)
    lattice = Lattice.regular(kind, 6.3, 0.02, (21.4, 18.9))
    first_row, first_col, rows, cols = -3, -4, 6, 8      # negative indices: odd rows below zero
    offsets = np.array([(0.0, 0.0), (1.3, -0.7), (-2.1, 2.4)], np.float32)
    out = wp.empty((3, rows, cols), dtype=float, device=device)
    m = lattice.m
    launch(K.sample_micro_images, (3 * rows, cols),
           [arr(image, float, device), wp.vec2(*lattice.origin), wp.vec2(m[0, 0], m[1, 0]),
            wp.vec2(m[0, 1] * lattice.row_height, m[1, 1] * lattice.row_height), lattice.row_shift,
            first_row, first_col, arr(offsets, wp.vec2, device)], [out], device)
    ii, jj = np.meshgrid(np.arange(first_row, first_row + rows), np.arange(first_col, first_col + cols),
                         indexing="ij")
    cx, cy = lattice.centres(ii, jj)
    want = np.stack([ref_bilinear(image.astype(np.float64), cx + dx, cy + dy) for dx, dy in offsets])
    close(out.numpy(), want, atol=1e-4)


@pytest.mark.parametrize("kind", ["hex", "rect"])
def test_resample_lattice_matches_reference(kind, device):
    from lfsf.kernels import decode as K

    lattice = Lattice.regular(kind, 10.0)
    first_row, first_col, rows, cols = -3, -3, 10, 10
    values = rng(5).random((2, rows, cols)).astype(np.float32)
    u0, v0, height, width = -1.13, -0.87, 5, 6     # generic: no point on a lattice edge
    out = wp.empty((2, height, width), dtype=float, device=device)
    launch(K.resample_lattice, (2 * height, width),
           [arr(values, float, device), lattice.row_shift, lattice.row_height, first_row, first_col, u0, v0],
           [out], device)
    close(out.numpy(), ref_resample(values.astype(np.float64), lattice, first_row, first_col, u0, v0,
                                    height, width), atol=1e-5)
    # interpolation reproduces a linear function of the lattice-plane position exactly
    ii, jj = np.meshgrid(np.arange(first_row, first_row + rows), np.arange(first_col, first_col + cols),
                         indexing="ij")
    pu, pv = lattice.plane_position(ii, jj)
    linear = (0.3 + 0.05 * pu - 0.02 * pv)[None].astype(np.float32)
    out1 = wp.empty((1, height, width), dtype=float, device=device)
    launch(K.resample_lattice, (height, width),
           [arr(linear, float, device), lattice.row_shift, lattice.row_height, first_row, first_col, u0 + 0.37,
            v0 + 0.21], [out1], device)
    y, x = np.mgrid[0:height, 0:width]
    close(out1.numpy()[0], 0.3 + 0.05 * (x + u0 + 0.37) - 0.02 * (y + v0 + 0.21), atol=1e-5)


# --- conventions ---------------------------------------------------------------------------


def test_lattice_conventions():
    hexa = Lattice.regular("hex", 10.0, 0.0, (100.0, 50.0))
    u, v = hexa.plane_position(np.array([0, 1, 2, -1]), np.array([0, 0, 3, 0]))
    close(u, [0.0, 0.5, 3.0, 0.5])
    close(v, [0.0, math.sqrt(3) / 2, math.sqrt(3), -math.sqrt(3) / 2])
    close(np.array(hexa.centres(1, 2)), [125.0, 50.0 + 5 * math.sqrt(3)])
    rect = Lattice.regular("rect", 8.0, 0.01, (3.0, 4.0))
    assert abs(rect.pitch - 8.0) < 1e-12 and abs(rect.rotation - 0.01) < 1e-12
    i, j = rng(6).integers(-20, 20, (2, 50))
    for lattice in (hexa, rect):
        x, y = lattice.centres(i, j)
        ni, nj = lattice.nearest_lens(x + 0.3, y - 0.2)
        np.testing.assert_array_equal(ni, i)
        np.testing.assert_array_equal(nj, j)
    # N views span one pitch, along the sensor's axes; flip negates
    off = D.view_offsets(rect, 5)
    close(off[0], np.array([-2.0, -2.0]) * 8.0 / 5)
    close(off[1], np.array([-1.0, -2.0]) * 8.0 / 5)      # view (a, b) = (0, 1): ξ = −1
    close(D.view_offsets(rect, 5, flip=True), -off)


@pytest.mark.parametrize("kind, rotation", [("hex", 0.0), ("rect", 0.01), ("hex", -0.004)])
def test_the_output_grid_is_the_largest_a_pitch_inside_the_whole_micro_images(kind, rotation):
    """The decoded views' grid (lattice-plane points u0 … u0 + width − 1, v0 … v0 + height
    − 1) keeps every point at least one pitch inside the region whose micro-images lie
    wholly on the sensor, and is the largest such grid: one more column or row on any
    side would leave it (flooring u0 gave a row and a column nearer the border)."""
    shape = (230, 310)
    lattice = Lattice.regular(kind, 9.6, rotation, (6.0, 7.0))
    u0, v0, width, height, *_ = D._output_grid(lattice, shape)
    h, w = shape
    m = lattice.pitch / 2.0 + 1.0
    u, v = lattice.to_plane(np.array([m, w - 1 - m, m, w - 1 - m]), np.array([m, m, h - 1 - m, h - 1 - m]))
    u_lo, u_hi, v_lo, v_hi = max(u[0], u[2]), min(u[1], u[3]), max(v[0], v[1]), min(v[2], v[3])
    assert u0 == int(u0) and v0 == int(v0) and width > 10 and height > 10
    assert u_lo + 1.0 <= u0 and u0 + width - 1 <= u_hi - 1.0
    assert v_lo + 1.0 <= v0 and v0 + height - 1 <= v_hi - 1.0
    assert u0 - 1 < u_lo + 1.0 and u0 + width > u_hi - 1.0
    assert v0 - 1 < v_lo + 1.0 and v0 + height > v_hi - 1.0


@pytest.mark.parametrize("flip", [False, True])
def test_view_axes_are_the_sensor_axes(flip):
    """Decoded view (a, b) holds the light field at (ξ, η) = (b − c, a − c): a pixel right
    of (below) a lens centre goes to a view right of (below) the centre, no inversion —
    unless the optics invert (flip), and then decoding with flip undoes it."""
    lattice = Lattice.regular("rect", 9.4, 0.003, (4.2, 3.7))

    def field(u, v, xi, eta):
        return 0.5 + 0.04 * xi + 0.02 * eta + 0.0 * u

    raw, white = synthetic_lenslet(field, lattice, (200, 150), views=5, flip=flip)
    lf = decode(raw, white, views=5, flip=flip, device="cpu")
    inner = lf.views[1:4, 1:4, 2:-2, 2:-2].mean(axis=(2, 3))
    a, b = np.mgrid[1:4, 1:4]
    # (relative to the white's bright level, D.white_level: 0.994 here)
    close(inner, D.white_level(white) * (0.5 + 0.04 * (b - 2) + 0.02 * (a - 2)), atol=2e-3)
    wrong = decode(raw, white, views=5, flip=not flip, device="cpu")
    assert wrong.views[1, 3].mean() < wrong.views[1, 1].mean()


# --- calibration ---------------------------------------------------------------------------


def _texture_field(seed, colour=False, disparity=0.4):
    """A light field of one fronto-parallel textured plane, L(u, v, ξ, η) = T(u + δξ, v + δη):
    a point at centre pixel p appears at p − δφ in view φ (MODEL.md §1)."""
    textures = [wave_texture(seed + k, 6, (0.2, 0.7), 0.08) for k in range(3 if colour else 1)]

    def field(u, v, xi, eta):
        planes = [t(u + disparity * xi, v + disparity * eta) for t in textures]
        return np.stack(planes, -1) if colour else planes[0]
    return field


CASES = {
    "hex": Lattice.regular("hex", 11.37, 0.004, (5.3, 7.8)),
    "rect": Lattice.regular("rect", 10.83, -0.003, (3.6, 6.1)),
}


@pytest.mark.parametrize("kind", ["hex", "rect"])
def test_calibration_is_subpixel_over_the_whole_sensor(kind):
    true = CASES[kind]
    raw, white = synthetic_lenslet(_texture_field(1), true, (520, 400), views=9, vignetting=0.5, noise=0.003,
                                   white_noise=0.002)
    est = calibrate(white)
    assert est.kind == kind
    assert abs(est.pitch - true.pitch) < 0.01
    assert abs(est.rotation - true.rotation) < 5e-4
    i, j = D._lens_grid(est, white.shape, est.pitch / 2)
    x, y = est.centres(i, j)
    ti, tj = true.nearest_lens(x, y)
    tx, ty = true.centres(ti, tj)
    err = np.hypot(x - tx, y - ty)
    assert err.max() < 0.1, f"lens centres off by up to {err.max():.3f} px"


@pytest.mark.parametrize("kind, pitch", [("rect", 7.0), ("rect", 14.0), ("hex", 8.0)])
def test_the_white_level_does_not_depend_on_a_whole_number_pitch(kind, pitch):
    """The white's level (its bright end) was read from every 7th row and column, which a
    pitch of 7 px lines up with: the same dark place of every lens, a level of 0.052 for
    0.998, and views 19 times too dark (a helper's decode)."""
    lattice = Lattice.regular(kind, pitch, 0.0, (3.0, 3.0))
    _, white = synthetic_lenslet(_texture_field(1), lattice, (int(37.2 * pitch), int(29.2 * pitch)), views=9,
                                 vignetting=0.4, white_noise=0.001)
    level = D.white_level(white)
    top = float(np.percentile(white, 99.9))
    assert abs(level - top) < 0.02 * top, (level, top)


@pytest.mark.parametrize("white_of, said", [
    ((11.37, (5.3, 7.8)), None),                          # the raw's own white
    ((11.37, (10.3, 10.8)), "does not fit it"),           # the lattice shifted
    ((11.37 * 1.01, (5.3, 7.8)), "does not fit it"),      # another zoom: 1 % of pitch
    ((11.37 * 1.007, (5.3, 7.8)), "fits part of the sensor only"),
])
def test_a_white_image_of_another_camera_setting_is_refused_or_warned_of(white_of, said):
    """A white of another zoom, focus or camera had been decoded without a word into views
    at 9–20 dB (a helper's raws): the raw must be darker at the rims of the white's
    micro-images, as the white is."""
    import warnings

    pitch, origin = white_of
    raw, _ = synthetic_lenslet(_texture_field(1), CASES["hex"], (520, 400), views=9, vignetting=0.5, noise=0.003,
                               white_noise=0.002)
    _, white = synthetic_lenslet(_texture_field(1), Lattice.regular("hex", pitch, 0.004, origin), (520, 400), views=9,
                                 vignetting=0.5, white_noise=0.002)
    raw, white = D.RawImage(raw, None, "raw.png"), D.RawImage(white, None, "white.png")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if said == "does not fit it":
            with pytest.raises(ValueError, match=r"^raw\.png: the white image white\.png does not fit it: the raw is "
                                                 r"not darker at the rims of the white's micro-images"):
                D._check_white_fits(raw, white, calibrate(white))
        else:
            D._check_white_fits(raw, white, calibrate(white))
    messages = [str(w.message) for w in caught]
    assert (messages == []) == (said != "fits part of the sensor only"), messages
    assert all("fits part of the sensor only" in m for m in messages)


def test_a_black_part_of_the_scene_is_no_white_of_another_setting():
    """A raw black in one ninth of the sensor (a dark object: noise, no light, so no rims
    darker than the rest) with its own white: the test of fit leaves out the parts of the
    raw without light, and says nothing (a ratio of −42 % there had read as a white of
    another zoom)."""
    import warnings

    raw, white = synthetic_lenslet(_texture_field(1), CASES["hex"], (520, 400), views=9, vignetting=0.5, noise=0.003,
                                   white_noise=0.002)
    h, w = raw.shape[:2]
    raw = raw.copy()
    raw[:h // 3, :w // 3] = np.abs(np.random.default_rng(0).normal(0.004, 0.003, raw[:h // 3, :w // 3].shape))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        D._check_white_fits(D.RawImage(raw, None, "raw.png"), D.RawImage(white, None, "white.png"), calibrate(white))


def test_a_lattice_turned_far_from_the_sensors_rows_is_refused():
    """A hexagonal lattice with its rows down the sensor (found turned by 30°) gave views of
    12×4 px with status 0 (a helper)."""
    lattice = Lattice.regular("hex", 11.37, math.radians(90.0), (5.3, 7.8))
    raw, white = synthetic_lenslet(_texture_field(1), lattice, (400, 320), views=9, white_noise=0.002)
    with pytest.raises(ValueError, match=r"white: the micro-lens lattice is turned by -?30\.0° from the sensor's rows; "
                                         r"lfsf decode takes lattices within 10°"):
        decode(D.RawImage(raw, None, "raw"), D.RawImage(white, None, "white"), device="cpu")


@pytest.mark.parametrize("change, said", [(lambda w: w / 64.0, "(data of 6 bits fewer than the file holds"),
                                          (lambda w: np.minimum(1.6 * w, 1.0), "of the white image is at full scale")])
def test_a_white_image_of_few_bits_or_clipped_is_warned_of(change, said):
    """10-bit values in a 16-bit file decoded into views 64 times too dark, and a clipped
    white into poor views, without a word (a helper)."""
    raw, white = synthetic_lenslet(_texture_field(1), CASES["hex"], (400, 320), views=9, white_noise=0.002)
    white = change(white)
    with pytest.warns(LfsfWarning, match=re.escape(said)):
        decode(D.RawImage(raw * float(np.max(white)), None, "raw"), D.RawImage(white, None, "white"), views=7,
               device="cpu")


# --- decoded views against the source light field ------------------------------------------


def _psnr_inner(lf, true, field, views, inner=7):
    """PSNR (dB) of the inner inner×inner views against the source light field sampled
    at the decoded pixels' positions. The decoded grid's origin is aligned with the
    source's by the lattice vector from the true lens (0, 0) to the decoded lens (0, 0)
    (the best alignment; its residual, the calibration error, is returned too)."""
    est = lf.meta["lattice"]
    u0, v0 = lf.meta["plane_origin"]
    ii, jj = true.nearest_lens(*est.origin)
    su, sv = true.plane_position(ii, jj)
    tu, tv = true.to_plane(*est.origin)
    y, x = np.mgrid[0:lf.height, 0:lf.width]
    c, k = (views - 1) / 2, (views - inner) // 2
    errors = []
    for a in range(k, views - k):
        for b in range(k, views - k):
            want = field(x + u0 + su, y + v0 + sv, b - c, a - c)
            errors.append(np.mean((lf.views[a, b] - want) ** 2))
    return 10 * np.log10(1.0 / np.mean(errors)), math.hypot(tu - su, tv - sv)


@pytest.mark.parametrize("bayer", [None, "GRBG"])
@pytest.mark.parametrize("kind", ["hex", "rect"])
def test_decoded_views_match_the_source(kind, bayer, device):
    true = CASES[kind]
    field = _texture_field(3, colour=bayer is not None)
    raw, white = synthetic_lenslet(field, true, (520, 400), views=9, vignetting=0.4, noise=0.003,
                                   white_noise=0.001, bayer=bayer)
    lf = decode(raw, white, views=9, bayer=bayer, device=device)
    assert lf.grid == (9, 9) and lf.is_colour == (bayer is not None)
    assert lf.width >= 38 and lf.height >= 28
    psnr, misfit = _psnr_inner(lf, true, field, 9)
    assert misfit < 0.01, f"decoded origin {misfit:.4f} pitches off a lens"
    assert psnr >= 30.0, f"{kind}, bayer {bayer}: {psnr:.1f} dB"


@pytest.mark.parametrize("bayer", [None, "GRBG"])
def test_a_white_taken_at_a_lower_exposure_decodes_the_same(bayer, device):
    """The white image is taken relative to its bright level: the same white at half or
    a quarter of the scale (a lower exposure) gives the same views, where dividing by its
    absolute level doubled them and clipped every pixel brighter than half to 1; the
    views still match the source (PSNR as in the test above)."""
    true = CASES["hex"]
    field = _texture_field(3, colour=bayer is not None)
    raw, white = synthetic_lenslet(field, true, (520, 400), views=9, vignetting=0.4, noise=0.003,
                                   white_noise=0.001, bayer=bayer)
    lattice = calibrate(D.RawImage(white, bayer, "<white>"))
    full = decode(raw, white, views=9, bayer=bayer, lattice=lattice, device=device)
    for scale in (0.5, 0.25):
        dim = decode(raw, white * np.float32(scale), views=9, bayer=bayer, lattice=lattice, device=device)
        np.testing.assert_allclose(dim.views, full.views, atol=2e-6, err_msg=f"white × {scale}")
    assert np.mean(full.views >= 1.0) < 0.01  # (half the pixels were 1 with the half-scale white)
    psnr, _misfit = _psnr_inner(full, true, field, 9)
    assert psnr >= 30.0, psnr


def test_scene_flow_from_decoded_views_matches_source_views():
    """A textured plane with disparity 0.6 at t1, moved by (1.5, −0.8) with disparity 0.4
    at t2: scene flow from the decoded inner 7×7 views is close to that from the source
    views sampled at the same positions, and both are close to the truth."""
    from lfsf import Params, estimate_scene_flow

    texture = wave_texture(7, 8, (0.25, 0.9), 0.06)
    true = Lattice.regular("hex", 11.3, 0.003, (4.6, 5.2))
    decoded, source = [], []
    for d, (fu, fv) in ((0.6, (0.0, 0.0)), (0.4, (1.5, -0.8))):
        def field(u, v, xi, eta, d=d, fu=fu, fv=fv):
            return texture(u - fu + d * xi, v - fv + d * eta)

        raw, white = synthetic_lenslet(field, true, (700, 540), views=9, noise=0.002, white_noise=0.001)
        lf = decode(raw, white, views=9, device="cpu")
        est = lf.meta["lattice"]
        u0, v0 = lf.meta["plane_origin"]
        su, sv = true.plane_position(*true.nearest_lens(*est.origin))
        y, x = np.mgrid[0:lf.height, 0:lf.width]
        a, b = np.mgrid[0:7, 0:7]
        views = field((x + u0 + su)[None, None], (y + v0 + sv)[None, None], (b - 3)[..., None, None],
                      (a - 3)[..., None, None])
        source.append(lfsf.LightField(views.astype(np.float32)))
        decoded.append(lfsf.LightField(lf.views[1:-1, 1:-1]))
    params = Params.preset("fast").replace(iterations=80, warps=4, median_radius=1)
    from_source = estimate_scene_flow(source[0], source[1], params, device="cpu")
    from_decoded = estimate_scene_flow(decoded[0], decoded[1], params, device="cpu")
    truth = {"disp1": 0.6, "disp2": 0.4, "u": 1.5, "v": -0.8}
    for name, value in truth.items():
        s = getattr(from_source, name)[5:-5, 5:-5]
        d = getattr(from_decoded, name)[5:-5, 5:-5]
        tol = 0.01 if name.startswith("disp") else 0.05
        assert np.median(np.abs(d - s)) < tol, f"{name}: decoded vs source {np.median(np.abs(d - s)):.4f}"
        assert np.median(np.abs(d - value)) < tol, f"{name}: decoded vs truth {np.median(np.abs(d - value)):.4f}"


# --- files, CLI and faults -----------------------------------------------------------------


def _write_png16(path, image):
    from lfsf.io import write_png

    write_png(path, np.rint(np.clip(image, 0, 1) * 65535).astype(np.uint16))


@pytest.fixture(scope="module")
def lenslet_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("lenslet")
    field = _texture_field(5, colour=True)
    raw, white = synthetic_lenslet(field, CASES["rect"], (420, 330), views=7, noise=0.002, bayer="RGGB")
    _write_png16(folder / "raw.png", raw)
    _write_png16(folder / "white.png", white)
    return folder


def test_cli_decode_writes_a_light_field(lenslet_files, tmp_path, capsys):
    out = tmp_path / "views"
    rc = cli.main(["decode", str(lenslet_files / "raw.png"), "--white", str(lenslet_files / "white.png"),
                   "--out", str(out), "--views", "7", "--bayer", "rggb", "--device", "cpu", "--quiet"])
    assert rc == 0
    lf = lfsf.read_lightfield(out)                      # the HCI layout
    npz = lfsf.read_lightfield(out / "views.npz")
    assert lf.grid == (7, 7) and lf.is_colour and npz.shape == lf.shape
    assert np.abs(lf.views - npz.views).max() <= 0.5 / 65535 + 1e-6
    report = json.loads((out / "decode.json").read_text())
    assert report["lattice"]["kind"] == "rect" and abs(report["lattice"]["pitch"] - 10.83) < 0.02
    assert report["bayer"] == "RGGB"
    # read with its report: the estimator keeps off the micro-images' rims (the views.npz alone has none)
    assert lf.meta["decode"] == report and lf.meta["lattice"] == report["lattice"] and "lattice" not in npz.meta
    assert lf.meta["lens_views"] == report["views"] == 7 and "lens_views" not in npz.meta
    white = D.read_raw(lenslet_files / "white.png", role="white").data
    assert report["white_level"] == pytest.approx(D.white_level(white), rel=1e-6) and 0.5 < report["white_level"] <= 1
    assert not list(out.glob(".*part*"))
    # the grid is given in parameters.cfg, in place of an earlier one that gave another (the
    # folder had not read back: "parameters.cfg gives a grid of 9×9 views … but there are 49")
    assert "num_cams_x = 7" in (out / "parameters.cfg").read_text()
    (out / "parameters.cfg").write_text("[extrinsics]\nnum_cams_x = 9\nnum_cams_y = 9\n")
    assert cli.main(["decode", str(lenslet_files / "raw.png"), "--white", str(lenslet_files / "white.png"),
                     "--out", str(out), "--views", "7", "--bayer", "rggb", "--device", "cpu", "--quiet"]) == 0
    assert lfsf.read_lightfield(out).grid == (7, 7)
    assert not [p.name for p in out.iterdir() if p.name.startswith(".")]


def test_cli_decode_says_when_it_took_the_sensor_for_grey(lenslet_files, tmp_path, capsys):
    """A mosaic decoded without --bayer (a PNG has no metadata) came out grey, the filters'
    pattern in every view, and only the missing '(RGB)' in the summary hinted at it."""
    hint = "grey: no Bayer pattern was given (--bayer) or found in the file's metadata"
    for extra, said in (([], True), (["--bayer", "none"], False), (["--bayer", "RGGB"], False)):
        out = tmp_path / f"v{len(extra)}{extra[-1] if extra else ''}"
        assert cli.main(["decode", str(lenslet_files / "raw.png"), "--white", str(lenslet_files / "white.png"),
                         "--out", str(out), "--views", "5", "--device", "cpu", *extra]) == 0
        assert (hint in capsys.readouterr().err) == said, extra


def _fails(argv, capsys, *names):
    rc = cli.main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and err[0].startswith("lfsf decode: error:"), err
    for name in names:
        assert name in err[0], err[0]
    return err[0]


@pytest.mark.parametrize("kind", ["uniform", "noise", "smooth"])
def test_white_without_lattice_fails_clearly(kind, lenslet_files, tmp_path, capsys):
    y, x = np.mgrid[0:330, 0:420]
    white = {"uniform": np.full((330, 420), 0.7),
             "noise": rng(8).random((330, 420)),
             "smooth": 0.8 - 0.3 * ((x - 210) ** 2 + (y - 165) ** 2) / 210 ** 2}[kind]
    with pytest.raises(ValueError, match="no micro-lens lattice"):
        calibrate(white.astype(np.float32), source="white")
    path = tmp_path / "white.png"
    _write_png16(path, white)
    line = _fails(["decode", str(lenslet_files / "raw.png"), "--white", str(path), "--out",
                   str(tmp_path / "out"), "--device", "cpu"], capsys, str(path))
    assert "no micro-lens lattice" in line
    assert not (tmp_path / "out").exists()


def test_raw_and_white_swapped_fail_clearly(lenslet_files, tmp_path, capsys, monkeypatch):
    """The white image given as RAW and the raw as --white decoded, exit status 0, into
    views of ~1.0 everywhere (the ratio clipped). The raw's micro-images differ from lens
    to lens, as no white image's do; where they did not (a flat scene), the views say it."""
    raw, white = str(lenslet_files / "raw.png"), str(lenslet_files / "white.png")
    line = _fails(["decode", white, "--white", raw, "--out", str(tmp_path / "out"), "--views", "7",
                   "--device", "cpu"], capsys, white, raw)
    assert "not a white image: its neighbouring micro-images differ" in line
    assert "were RAW (" in line and ") and --white swapped, or a scene given as --white?" in line, line
    assert not (tmp_path / "out").exists()
    monkeypatch.setattr(D, "WHITE_LENS_STEP", 1.0)  # (the views' test, behind it)
    line = _fails(["decode", white, "--white", raw, "--out", str(tmp_path / "out"), "--views", "7",
                   "--device", "cpu"], capsys, white, raw)
    share = int(re.search(r"(\d+) % of the decoded views' values are at full scale", line).group(1))
    assert share > 50 and "were RAW and --white swapped, or is the raw overexposed?" in line, line
    assert not (tmp_path / "out").exists()
    # the right way round, few are
    views = decode(D.read_raw(raw), D.read_raw(white), views=7, bayer="RGGB", device="cpu").views
    assert np.mean(views >= D.SATURATED) < 0.05


def test_size_mismatch_fails_clearly(lenslet_files, tmp_path, capsys):
    from lfsf.io import read_image

    small = tmp_path / "small.png"
    _write_png16(small, read_image(lenslet_files / "white.png")[:300, :400] / 65535.0)
    with pytest.raises(ValueError, match="420×330"):
        decode(np.zeros((330, 420), np.float32), np.zeros((300, 400), np.float32))
    _fails(["decode", str(lenslet_files / "raw.png"), "--white", str(small), "--out", str(tmp_path / "o")],
           capsys, "raw.png", "small.png", "420×330", "400×300")


def test_unreadable_and_truncated_files_fail_clearly(lenslet_files, tmp_path, capsys):
    truncated = tmp_path / "raw.png"
    truncated.write_bytes((lenslet_files / "raw.png").read_bytes()[:5000])
    garbage = tmp_path / "shot.raw"
    garbage.write_bytes(b"not a raw image" * 100)
    lytro = tmp_path / "shot.lfr"
    lytro.write_bytes(b"\x89LFP" + b"\0" * 200)
    white = str(lenslet_files / "white.png")
    for path in (truncated, garbage, lytro):
        with pytest.raises(ValueError, match=str(path.name)):
            D.read_raw(path)
        _fails(["decode", str(path), "--white", white, "--out", str(tmp_path / "o")], capsys, str(path))
    _fails(["decode", str(tmp_path / "missing.png"), "--white", white, "--out", str(tmp_path / "o")], capsys,
           "missing.png")
    assert not (tmp_path / "o").exists()


def test_a_raw_image_of_wide_integers_is_refused(tmp_path):
    """A 16-bit sensor image saved as int32 had been scaled by int32's maximum: views of
    1e-5, without a word (views and textures were refused so already)."""
    import tifffile

    tifffile.imwrite(tmp_path / "wide.tif", np.full((12, 16), 40000, np.int32))
    with pytest.raises(ValueError, match=r"wide.tif: integer pixels of dtype int32 .* save the sensor image with 8 "
                                         r"or 16 bits"):
        D.read_raw(tmp_path / "wide.tif")
    tifffile.imwrite(tmp_path / "ok.tif", np.full((12, 16), 40000, np.uint16))
    assert D.read_raw(tmp_path / "ok.tif").data.max() == pytest.approx(40000 / 65535)


def test_a_stack_of_images_is_not_taken_for_channels(tmp_path):
    """A TIFF of two pages reads as (2, H, W): the message gives the shape and says what
    it may be (it said "got W channels")."""
    import tifffile

    stack = tmp_path / "stack.tif"
    tifffile.imwrite(stack, np.zeros((2, 12, 16), np.uint16))
    with pytest.raises(ValueError, match=re.escape(f"{stack}: expected a grey or RGB image, got an array of shape "
                                                   "(2, 12, 16): 16 channels, or a stack of images (pages of a TIFF)")):
        D.read_raw(stack)


def test_lytro_metadata_gives_pattern_and_levels(tmp_path):
    meta = {"image": {"rawDetails": {"mosaic": {"tile": "r,gr:gb,b", "upperLeftPixel": "gr"}},
                      "pixelFormat": {"black": {"r": 64, "gr": 64, "gb": 64, "b": 64},
                                      "white": {"r": 1023, "gr": 1023, "gb": 1023, "b": 1023}}}}
    assert D._lytro_bayer(meta) == "GRBG"
    assert D._lytro_bayer({"mosaic": {"tile": "r,gr:gb,b", "upperLeftPixel": "b"}}) == "BGGR"
    assert D._lytro_bayer({"camera": {"model": "B01"}}) is None
    black, white = D._lytro_levels(meta, 1023.0)
    assert abs(black - 64 / 1023) < 1e-9 and white == 1.0
    assert D._lytro_levels({}, 1023.0) == (0.0, 1.0)
    # a Lytro F01 .raw (told by its size) with its metadata beside it, read by imageio's plugin
    path = tmp_path / "white.raw"
    path.write_bytes(bytes(3280 * 3280 * 12 // 8))
    (tmp_path / "white.txt").write_text(json.dumps({"mosaic": {"tile": "r,gr:gb,b", "upperLeftPixel": "b"}}))
    image = D.read_raw(path)
    assert image.data.shape == (3280, 3280) and image.bayer == "BGGR"
    # without it: one warning of ours naming the file and what is assumed; imageio's own
    # log line ("No metadata file found …", twice, unprefixed, even with --quiet) silenced
    (tmp_path / "white.txt").unlink()
    with pytest.warns(LfsfWarning, match=r"white.raw: no metadata file beside it \(white.txt or .json\): black "
                                         r"level 0, white level full scale, Bayer pattern BGGR") as caught:
        with capture_logs("imageio") as logged:
            image = D.read_raw(path)
    assert image.bayer == "BGGR" and len(caught) == 1 and caught[0].filename == __file__ and logged == []


@contextlib.contextmanager
def capture_logs(name: str):
    """The messages logged under ``name`` (at any level that passes) while the block runs."""
    import logging

    messages: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record):
            messages.append(record.getMessage())

    logger, handler = logging.getLogger(name), Keep()
    logger.addHandler(handler)
    try:
        yield messages
    finally:
        logger.removeHandler(handler)


def test_16_bit_tiff_decodes_like_the_png(lenslet_files, tmp_path):
    """A 16-bit TIFF raw reads to the same values as the PNG and decodes the same."""
    import imageio.v3 as iio
    from lfsf.io import read_image

    tif = tmp_path / "raw.tif"
    iio.imwrite(tif, read_image(lenslet_files / "raw.png"))
    png_raw, tif_raw = D.read_raw(lenslet_files / "raw.png"), D.read_raw(tif)
    np.testing.assert_array_equal(tif_raw.data, png_raw.data)
    white = D.read_raw(lenslet_files / "white.png")
    a = decode(png_raw, white, views=7, bayer="RGGB", device="cpu")
    b = decode(tif_raw, white, views=7, bayer="RGGB", device="cpu")
    np.testing.assert_array_equal(a.views, b.views)


def _decode_argv(lenslet_files, out, *extra):
    return ["decode", str(lenslet_files / "raw.png"), "--white", str(lenslet_files / "white.png"),
            "--out", str(out), "--device", "cpu", "--quiet", *extra]


def _leftovers(out):
    """Views and hidden (temporary) entries in ``out``."""
    return sorted(p.name for p in out.iterdir() if p.name.startswith((".", "input_Cam")))


def test_interrupted_decode_writes_nothing(lenslet_files, tmp_path, monkeypatch, capsys):
    """An interruption part-way through writing the views leaves no views, no views.npz
    and no temporary files: a partial set of 25 of 49 views would read as a wrong 5×5
    light field. An earlier complete decode in the folder is left as it was."""
    import lfsf.io

    real_write_png = lfsf.io.write_png
    calls = []

    def interrupted(path, image):
        calls.append(path)
        if len(calls) > 5:
            raise KeyboardInterrupt
        real_write_png(path, image)

    monkeypatch.setattr(lfsf.io, "write_png", interrupted)
    out = tmp_path / "views"
    with pytest.raises(KeyboardInterrupt):
        D.decode_files(lenslet_files / "raw.png", lenslet_files / "white.png", out, views=7, bayer="RGGB",
                       device="cpu")
    assert len(calls) > 5
    assert not out.exists() or list(out.iterdir()) == []
    calls.clear()
    assert cli.main(_decode_argv(lenslet_files, out, "--views", "7")) == 130
    assert not out.exists() or list(out.iterdir()) == []

    monkeypatch.setattr(lfsf.io, "write_png", real_write_png)
    assert cli.main(_decode_argv(lenslet_files, out, "--views", "7")) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert len(before) == 49 + 3  # (the views, parameters.cfg, views.npz, decode.json)
    monkeypatch.setattr(lfsf.io, "write_png", interrupted)
    calls.clear()
    assert cli.main(_decode_argv(lenslet_files, out, "--views", "7", "--bayer", "none")) == 130
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    # the refusal to mix these views with an earlier decode's of another grid stays
    monkeypatch.setattr(lfsf.io, "write_png", real_write_png)
    capsys.readouterr()
    _fails(_decode_argv(lenslet_files, out, "--views", "5"), capsys, str(out), "input_Cam025.png")
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    # … and with --views given it comes before the decode (it came after it: 10-16 s on an Illum's sensor)
    monkeypatch.setattr(D, "decode", lambda *a, **k: pytest.fail("decoded before the refusal"))
    _fails(_decode_argv(lenslet_files, out, "--views", "5"), capsys, str(out), "input_Cam025.png")


@pytest.mark.parametrize("name", ["views.npz", "decode.json", "input_Cam003.png"])
def test_output_name_that_is_a_folder_fails_before_any_work(name, lenslet_files, tmp_path, capsys):
    out = tmp_path / "views"
    (out / name).mkdir(parents=True)
    line = _fails(_decode_argv(lenslet_files, out, "--views", "7"), capsys, str(out / name))
    assert "part" not in line
    assert _leftovers(out) == ([name] if name.startswith("input") else [])
    assert sorted(p.name for p in out.iterdir()) == [name]


def test_bayer_none_means_grey(lenslet_files, tmp_path, capsys):
    """``--bayer none`` (any case), as documented: a grey sensor, whatever the metadata say."""
    out = tmp_path / "views"
    assert cli.main(_decode_argv(lenslet_files, out, "--views", "7", "--bayer", "None")) == 0
    lf = lfsf.read_lightfield(out / "views.npz")
    assert lf.grid == (7, 7) and not lf.is_colour
    assert json.loads((out / "decode.json").read_text())["bayer"] is None
    raw = D.read_raw(lenslet_files / "raw.png")
    white = D.read_raw(lenslet_files / "white.png")
    tagged = D.RawImage(raw.data, "RGGB", raw.source)
    assert decode(tagged, white, views=7, device="cpu").is_colour
    grey = decode(tagged, white, views=7, bayer="NONE", device="cpu")
    assert not grey.is_colour
    np.testing.assert_array_equal(grey.views, lf.views)
    with pytest.raises(ValueError, match="none"):
        decode(raw, white, views=7, bayer="RGBG", device="cpu")


def test_views_are_bounded_by_the_pitch(lenslet_files, tmp_path, capsys):
    """N views span one lens pitch: more than the pixels across a micro-image (the pitch
    rounded up) would only interpolate, and their number grows as N² (`--views 3000`
    once asked for 87 GB). Such an N is a clear error before any work."""
    lattice = Lattice.regular("rect", 9.4, 0.003, (4.2, 3.7))
    raw, white = synthetic_lenslet(lambda u, v, xi, eta: 0.5 + 0.0 * u, lattice, (200, 150), views=5)
    assert decode(raw, white, views=10, lattice=lattice, device="cpu").grid == (10, 10)
    with pytest.raises(ValueError, match=r"at most 10 views .* 9\.40 px.* got 11"):
        decode(raw, white, views=11, lattice=lattice, device="cpu")
    with pytest.raises(ValueError, match="at least 1"):
        decode(raw, white, views=0, lattice=lattice, device="cpu")
    for n in ("12", "3000"):
        out = tmp_path / f"views{n}"
        _fails(_decode_argv(lenslet_files, out, "--views", n), capsys, "raw.png", "at most 11 views", f"got {n}")
        assert not out.exists()


def test_missing_white_is_named_as_the_white_image(lenslet_files, tmp_path, capsys):
    missing = tmp_path / "missing_white.png"
    with pytest.raises(FileNotFoundError, match="no such white image file"):
        D.decode_files(lenslet_files / "raw.png", missing, tmp_path / "o")
    line = _fails(["decode", str(lenslet_files / "raw.png"), "--white", str(missing), "--out", str(tmp_path / "o")],
                  capsys, str(missing), "no such white image file")
    assert "raw image" not in line
    with pytest.raises(ValueError, match="expected a white image file, got a folder"):
        D.decode_files(lenslet_files / "raw.png", tmp_path, tmp_path / "o")
    assert not (tmp_path / "o").exists()


def test_a_sensor_smaller_than_one_lens_is_refused():
    """(0, 0) returned (None, None) and a 1×1 sensor NaN."""
    lattice = Lattice.regular("hex", 9.6, 0.0, (5.0, 5.0))
    for sensor in ((0, 0), (1, 1)):
        with pytest.raises(ValueError, match="holds no whole micro-image"):
            synthetic_lenslet(np.zeros((9, 9, 8, 8), np.float32), lattice, sensor, views=9)


def test_images_outside_the_unit_range_are_refused():
    """A float white in counts (0…65535) decoded to views of ~1e-5, and a negative white
    clipped 99.7 % of them, both with status 0."""
    lattice = Lattice.regular("hex", 9.6, 0.0, (5.0, 5.0))
    raw, white = synthetic_lenslet(np.full((9, 9, 16, 16), 0.5, np.float32), lattice, (200, 180), views=9)
    for bad, needle in ((white * 65535, "values run from"), (white - 1.0, "values run from")):
        with pytest.raises(ValueError, match=f"white: the white image's {needle}"):
            decode(raw, bad, views=9, device="cpu")
    # a blank raw (the lens cap on): it had decoded with status 0 into a black light field
    with pytest.raises(ValueError, match=r"^raw: every pixel of the raw image is 0: a blank image"):
        decode(np.zeros_like(raw), white, views=9, device="cpu")



def test_the_default_view_count_takes_a_pitch_fitted_a_hair_under_a_whole_number():
    assert [D._default_views(p) for p in (2.9994, 3.0, 4.98, 4.995, 9.6, 14.29, 2.5)] == [3, 3, 3, 5, 9, 13, 1]


def test_a_raw_and_white_of_different_sizes_are_told_apart():
    """Arrays' roles are their names: "the white image white is 420×320" named it twice."""
    lattice = Lattice.regular("hex", 9.6, 0.0, (5.0, 5.0))
    raw, white = synthetic_lenslet(np.full((9, 9, 16, 16), 0.5, np.float32), lattice, (200, 180), views=9)
    with pytest.raises(ValueError, match=r"^raw: the raw image is 200×178 pixels but the white image is 200×180; "
                                         r"they must come from the same camera$"):
        decode(raw[:-2], white, views=9, device="cpu")
