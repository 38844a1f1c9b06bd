"""Depth, 3-D points and 3-D scene flow for a calibrated camera (lfsf.camera, MODEL.md §7),
against the renderer's own geometry: the objects' 3-D motions of a scene."""

import json
import re
import subprocess
import sys

import numpy as np
import pytest

import lfsf
from lfsf import synth
from lfsf.camera import Camera, scene_flow_errors

BACKDROP_DEPTH, SPHERE_DEPTH = 10.0, 5.0
#: A backdrop and a sphere, each moving without turning: every point of each moves by its
#: centre's 3-D translation (the sphere also comes 0.5 nearer).
SCENE = synth.Scene("two translations", "a backdrop and a sphere, each translating", (
    synth.Primitive("plane", (0.5, 0.5), BACKDROP_DEPTH, (3.0, 3.0), synth.Texture(20, 0.5, 0.4, seed=1),
                    shift=(1.5, -0.5)),
    synth.Primitive("sphere", (0.45, 0.5), SPHERE_DEPTH, (0.15,), synth.Texture(12, 0.5, 0.45, seed=2),
                    shift=(3.0, 1.0), approach=-0.5),
))


def _translations(size):
    """Each object's 3-D translation from t1 to t2, in the renderer's world (= the centre
    camera's frame)."""
    cam = synth.CameraArray.for_size(*size)
    moves = []
    for prim in SCENE.objects:
        poses, _, _ = synth._object_poses(prim, cam)
        moves.append(poses[1][1] - poses[0][1])
    return moves


def _object_masks(gt, size, border=0):
    """The scored pixels (valid, seen at t2, inside ``border``) of the backdrop and the
    sphere, told apart by their true δ1."""
    cam = synth.CameraArray.for_size(*size)
    between = 0.5 * (cam.disparity(SPHERE_DEPTH) + cam.disparity(BACKDROP_DEPTH))
    scored = gt["valid"] & ~gt["occluded"]
    if border:
        inner = np.zeros_like(scored)
        inner[border:-border, border:-border] = True
        scored &= inner
    return scored & (gt["disp1"] < between), scored & (gt["disp1"] > between)


def test_depth_inverts_the_renderers_disparity():
    cam = synth.CameraArray.for_size(160, 120)
    camera = Camera(cam.focal, cam.baseline, cam.shift)
    depths = np.array([2.0, 4.0, 6.0, 11.0, 40.0])
    np.testing.assert_allclose(camera.depth(cam.disparity(depths)), depths, rtol=1e-6)
    np.testing.assert_allclose(camera.disparity(depths), cam.disparity(depths), rtol=1e-6)
    # δ + δ0 ≤ 0: at or beyond infinity, and no number
    assert np.isnan(camera.depth(np.array([-cam.shift, -cam.shift - 1.0, np.nan]))).all()


def test_the_ground_truths_points_move_as_their_objects():
    """X(p + (u, v), δ2) − X(p, δ1) of the exact δ1, δ2 and flow is each object's 3-D
    translation: the camera (f, b, δ0 = the renderer's shift, the principal point at the
    views' centre) and the conventions of δ2 (indexed by the t1 pixel) agree with the
    renderer's geometry."""
    size = (96, 72)
    _, _, gt = synth.render_scene(SCENE, size=size, grid=5, device="cpu")
    camera = Camera.from_truth(gt)
    points1 = camera.points(gt["disp1"])
    points2 = camera.points(gt["disp2"], gt["u"], gt["v"])
    backdrop, sphere = _object_masks(gt, size)
    assert backdrop.sum() > 3000 and sphere.sum() > 300
    for mask, move in zip((backdrop, sphere), _translations(size)):
        np.testing.assert_allclose((points2 - points1)[mask], np.broadcast_to(move, (mask.sum(), 3)), atol=1e-5)
    # the t1 points lie on the backdrop's plane, z = 10 (it is not tilted)
    np.testing.assert_allclose(points1[backdrop][:, 2], BACKDROP_DEPTH, rtol=1e-5)
    # a principal point elsewhere moves the points sideways, not their depth: the ray
    # through it is the optical axis
    moved = Camera(camera.focal, camera.baseline, camera.offset, principal=(40.0, 30.0)).points(gt["disp1"])
    np.testing.assert_array_equal(moved[..., 2], points1[..., 2])
    np.testing.assert_array_equal(moved[30, 40, :2], 0.0)
    np.testing.assert_allclose(moved[..., 0] - points1[..., 0], (47.5 - 40.0) * points1[..., 2] / camera.focal,
                               rtol=1e-5, atol=1e-6)
    assert camera.size == (96, 72)
    with pytest.raises(ValueError, match="for views of 96×72 px, the map is 48×36"):
        camera.points(gt["disp1"][::2, ::2])


def test_the_estimates_scene_flow_is_the_objects_motion():
    """The estimate's 3-D scene flow (default preset, 160×120, 9×9 views) against the two
    objects' translations: the sphere's (|T| = 0.51) within 2 % on the median pixel, the
    backdrop's (|T| = 0.10 across the view, 10 deep) within 25 % (its depth, 1.6 px per
    view step from δ = 0, carries a depth error of about 0.15 % that is 0.015 along z)."""
    size = (160, 120)
    lf1, lf2, gt = synth.render_scene(SCENE, size=size, grid=9, device="cpu")
    sf = lfsf.estimate_scene_flow(lf1, lf2, lfsf.Params.preset("paper"), device="cpu")
    points1, points2 = sf.points(Camera.from_truth(gt))
    backdrop, sphere = _object_masks(gt, size, border=8)
    for mask, move, bound in zip((backdrop, sphere), _translations(size), (0.25, 0.02)):
        error = np.linalg.norm((points2 - points1)[mask] - move, axis=1)
        assert np.median(error) < bound * np.linalg.norm(move), (np.median(error), np.linalg.norm(move))
    # the same through scene_flow_errors, over every scored pixel, and nothing for the truth itself
    camera = Camera.from_truth(gt)
    errors = scene_flow_errors(sf, gt, camera)
    assert errors["pixels"] > 12000 and errors["epe3d_median"] < 0.25 * np.linalg.norm(_translations(size)[0])
    assert errors["depth1_rel"] < 0.01
    true_motion = np.linalg.norm(np.array(_translations(size)), axis=1)
    assert true_motion[0] < errors["motion"] < true_motion[1]     # (most pixels are the backdrop's)
    exact = scene_flow_errors({k: gt[k] for k in ("disp1", "disp2", "u", "v")}, gt, camera)
    assert exact["epe3d"] == exact["depth1_rel"] == 0.0
    off = scene_flow_errors({**{k: gt[k] for k in ("disp1", "disp2", "u")}, "v": gt["v"] + 1.0}, gt, camera)
    # a flow 1 px off down moves every point 1 px sideways at its t2 depth: Z2 / f
    z2 = camera.depth(gt["disp2"])[8:-8, 8:-8]
    assert off["epe3d_median"] == pytest.approx(np.median(z2[(gt["valid"])[8:-8, 8:-8]]) / camera.focal, rel=0.05)


@pytest.mark.parametrize("size, k", [((64, 48), 2), ((65, 49), 2), ((64, 48), 3)])
def test_a_shrunk_cameras_points_are_the_block_means_of_the_full_ones(size, k):
    """On a fronto-parallel plane (δ constant: X linear in the pixel) the points of the views
    shrunk K times, as ``LightField.downsample`` shrinks them (K×K means, the rest of each
    side dropped), are the means of the full views' points over each block, where the
    camera knows the full views' size (K need not divide it)."""
    width, height = size
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    disp = np.full(x.shape, 1.5)
    camera = Camera(80.0, 0.2, 2.0, size=size)
    full = camera.points(disp).astype(np.float64)
    h, w = height // k, width // k
    blocks = full[:h * k, :w * k].reshape(h, k, w, k, 3).mean(axis=(1, 3))
    small_disp = disp[:h * k, :w * k].reshape(h, k, w, k).mean(axis=(1, 3)) / k
    np.testing.assert_allclose(camera.downsampled(k).points(small_disp), blocks, rtol=2e-5, atol=1e-5)


def test_a_camera_of_shrunk_views_gives_the_same_depths():
    camera = Camera(320.0, 0.1, 2.0, principal=(161.5, 118.5))
    small = camera.downsampled(2)
    assert (small.focal, small.baseline, small.offset) == (160.0, 0.1, 1.0)
    assert small.principal == (80.5, 59.0)  # (pixel 2i, 2i + 1 → i: centre (2i + 0.5) → i)
    disp = np.array([[0.5, -1.0], [3.0, 1.5]], np.float32)
    np.testing.assert_allclose(small.depth(disp / 2), camera.depth(disp), rtol=1e-6)
    with pytest.raises(ValueError, match="whole number"):
        camera.downsampled(1.5)


def test_a_ground_truths_camera_numbers_may_be_arrays_of_one(tmp_path):
    """np.savez(focal=[f]) writes an array of one: read as f (it had been a TypeError's
    traceback from float()); an array of two, or of text, names the key."""
    gt = {"focal": np.array([100.0]), "baseline": np.float32(0.5), "shift": np.array([[0.25]])}
    assert Camera.from_truth(gt) == Camera(100.0, 0.5, 0.25)
    for value, said in ((np.array([1.0, 2.0]), "2 values, shape (2,)"), (np.array(["100"]), "dtype <U3")):
        np.savez(tmp_path / "gt.npz", **{**gt, "focal": value})
        with pytest.raises(ValueError, match=re.escape(f"gt.npz: 'focal' must be one number, got {said}")):
            Camera.from_file(tmp_path / "gt.npz")


def test_the_hci_camera_is_focused_at_its_focus_distance():
    parameters = {"intrinsics": {"focal_length_mm": 100, "sensor_size_mm": 35, "image_resolution_x_px": 512,
                                 "image_resolution_y_px": 512},
                  "extrinsics": {"baseline_mm": 90.0, "focus_distance_m": 8.0, "num_cams_x": 9}}
    camera = Camera.from_hci(parameters)
    assert camera.focal == pytest.approx(100 / 35 * 512) and camera.size == (512, 512)
    wide = Camera.from_hci({**parameters, "intrinsics": {**parameters["intrinsics"], "image_resolution_y_px": 384}})
    assert wide.focal == camera.focal and wide.size == (512, 384)      # f from the larger side
    assert camera.depth(np.zeros(1))[0] == pytest.approx(8000.0)          # δ = 0 at the focus distance, in mm
    assert camera.depth(np.ones(1))[0] < 8000.0                          # δ > 0: nearer (the HCI sign)
    with pytest.raises(ValueError, match="focus_distance_m"):
        Camera.from_hci({"intrinsics": parameters["intrinsics"], "extrinsics": {"baseline_mm": 90.0}})


@pytest.mark.parametrize("args, message", [
    ((0.0, 1.0), "focal must be positive"),
    ((100.0, -1.0), "baseline must be positive"),
    ((100.0, 1.0, float("nan")), "offset must be finite"),
    ((100.0, 1.0, 0.0, (1.0,)), "principal must be"),
    (("100", 1.0), "focal must be a real number"),
])
def test_a_camera_refuses_impossible_values(args, message):
    with pytest.raises(ValueError, match=message):
        Camera(*args)


def _read_ply(path):
    """A binary little-endian PLY's vertex properties, read by the format's rules."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    assert header[:2] == ["ply", "format binary_little_endian 1.0"]
    count = next(int(line.split()[2]) for line in header if line.startswith("element vertex"))
    kinds = {"float": "<f4", "uchar": "u1"}
    fields = [(line.split()[2], kinds[line.split()[1]]) for line in header if line.startswith("property")]
    body = np.frombuffer(data[end:], dtype=fields)
    assert body.size == count
    return body


def _lfsf(*args):
    return subprocess.run([sys.executable, "-m", "lfsf", *map(str, args)], capture_output=True, text=True)


@pytest.fixture(scope="module")
def small_result(tmp_path_factory):
    root = tmp_path_factory.mktemp("points")
    assert _lfsf("synth", "paper", "--size", 64, 48, "--grid", 5, "--out", root / "s", "--quiet").returncode == 0
    run = _lfsf("run", root / "s/lf1.npz", root / "s/lf2.npz", "--out", root / "r", "--preset", "fast", "--quiet")
    assert run.returncode == 0, run.stderr
    return root


def test_lfsf_points_writes_the_results_points(small_result):
    root = small_result
    gt = np.load(root / "s/gt.npz")
    camera = Camera.from_truth(gt)
    points1, points2 = lfsf.SceneFlow.load(root / "r").points(camera)
    done = _lfsf("points", root / "r", "--camera", gt["focal"], gt["baseline"], gt["shift"], "--out",
                 root / "p.npz")
    assert done.returncode == 0, done.stderr
    assert "3072 points of 64×48" in done.stderr
    saved = np.load(root / "p.npz")
    np.testing.assert_allclose(saved["points1"], points1, rtol=1e-6)
    np.testing.assert_allclose(saved["scene_flow"], points2 - points1, rtol=1e-5, atol=1e-7)
    assert json.loads(str(saved["camera"]))["offset"] == pytest.approx(float(gt["shift"]))
    # the same from the gt.npz, as a coloured point cloud
    done = _lfsf("points", root / "r", "--camera", root / "s/gt.npz", "--colour", root / "s/lf1.npz", "--out",
                 root / "p.ply", "--quiet")
    assert done.returncode == 0 and done.stderr == ""
    done = _lfsf("points", root / "r", "--camera", root / "s/gt.npz", "--out", root / "q.npz", "--gt",
                 root / "s/gt.npz", "--quiet")
    expected = scene_flow_errors(lfsf.SceneFlow.load(root / "r"), gt, camera)
    assert done.returncode == 0 and f"end-point error mean {expected['epe3d']:.4g}," in done.stdout, done.stdout
    body = _read_ply(root / "p.ply")
    assert body.size == 64 * 48
    np.testing.assert_allclose(np.stack([body["x"], body["y"], body["z"]], 1), points1.reshape(-1, 3), rtol=1e-6)
    np.testing.assert_allclose(body["flow_z"], (points2 - points1)[..., 2].ravel(), rtol=1e-5, atol=1e-7)
    centre = lfsf.read_lightfield(root / "s/lf1.npz").centre
    np.testing.assert_array_equal(body["red"], np.round(np.clip(centre, 0, 1) * 255).astype(np.uint8).ravel())
    np.testing.assert_array_equal(saved["depth2"], points2[..., 2])
    np.testing.assert_array_equal(saved["occluded"], lfsf.SceneFlow.load(root / "r").occluded)


def test_lfsf_points_keeps_the_colours_and_flows_of_the_points_it_writes(small_result, tmp_path):
    """A camera that puts part of the points beyond infinity (δ0 = −the median δ1): the
    .ply holds the others, each with its own RGB colour and 3-D flow; --principal moves
    the optical axis onto that pixel."""
    root = small_result
    sf = lfsf.SceneFlow.load(root / "r")
    offset = -float(np.median(sf.disp1))
    camera = Camera(64.0, 0.375, offset, principal=(10.0, 20.0))
    points1, points2 = sf.points(camera)
    kept = np.isfinite(points1).all(-1) & np.isfinite(points2).all(-1)
    assert 0.3 < kept.mean() < 0.7
    rgb = np.random.default_rng(1).random((5, 5, 48, 64, 3)).astype(np.float32)
    np.savez(tmp_path / "rgb.npz", views=rgb)
    done = _lfsf("points", root / "r", "--camera", 64, 0.375, f"{offset:.9f}", "--principal", 10, 20, "--colour",
                 tmp_path / "rgb.npz", "--out", tmp_path / "c.ply")
    assert done.returncode == 0 and f"{int(kept.sum())} points of 64×48" in done.stderr, done.stderr
    body = _read_ply(tmp_path / "c.ply")
    assert body.size == kept.sum()
    for k, name in enumerate(("red", "green", "blue")):
        np.testing.assert_array_equal(body[name], np.round(rgb[2, 2][kept][:, k] * 255).astype(np.uint8))
    np.testing.assert_allclose(body["x"], points1[kept][:, 0], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(body["flow_y"], (points2 - points1)[kept][:, 1], rtol=1e-4, atol=1e-6)
    np.testing.assert_array_equal(camera.points(np.ones((48, 64)))[20, 10, :2], 0.0)


@pytest.mark.parametrize("extra, message", [
    (["--camera", "100"], "give the focal length f (px) and the baseline b"),
    (["--camera", "{root}/missing.npz"], "no such file"),
    (["--camera", "100", "x"], "as numbers"),
    (["--camera", "-5", "1"], "focal must be positive"),
    (["--camera", "1", "2", "3", "4"], "three numbers at most"),
    (["--camera", "100", "1", "--out", "{root}/p.txt"], "a .ply"),
    (["--camera", "{root}/s/lf1.npz"], "lacks focal, baseline, shift"),
    (["--camera", "100", "1", "--colour", "{root}/missing"], "missing"),
    (["--camera", "100", "1", "-50"], "no point lies in front of this camera"),
    (["--camera", "100", "1", "--principal", "nan", "3"], "--principal nan 3: c_x must be finite"),
    (["--camera", "100", "1", "--colour", "{root}/s/lf1.npz", "--out", "{root}/p.npz"], "holds no colours"),
    (["--camera", "{root}/s/gt.npz", "--out", "{root}/s/gt.npz"], "would replace an input"),
])
def test_lfsf_points_refuses_bad_input(small_result, extra, message):
    root = small_result
    extra = [e.format(root=root) for e in extra]
    out = [] if "--out" in extra else ["--out", root / "bad.ply"]
    done = _lfsf("points", root / "r", *extra, *out)
    assert done.returncode == 2 and message in done.stderr, done.stderr
    assert "Traceback" not in done.stderr
    assert not (root / "bad.ply").exists()


def test_lfsf_points_refuses_a_flow_only_result(small_result, tmp_path):
    root = small_result
    run = _lfsf("run", root / "s/lf1.npz", root / "s/lf2.npz", "--out", tmp_path / "f", "--preset", "flow",
                "--quiet")
    assert run.returncode == 0, run.stderr
    done = _lfsf("points", tmp_path / "f", "--camera", 100, 1, "--out", tmp_path / "f.ply")
    assert done.returncode == 2 and "flow-only" in done.stderr
    assert not (tmp_path / "f.ply").exists()


def test_lfsf_points_of_a_shrunk_result_takes_the_full_views_camera(small_result, tmp_path):
    """A result of ``lfsf run --downsample 2`` is in pixels of half the size: ``lfsf
    points`` given the full views' camera shrinks it alike, so the depths stay those of
    the scene (here against the full-size result's)."""
    root = small_result
    run = _lfsf("run", root / "s/lf1.npz", root / "s/lf2.npz", "--out", tmp_path / "r2", "--preset", "fast",
                "--downsample", 2, "--quiet")
    assert run.returncode == 0, run.stderr
    for result, out in ((root / "r", tmp_path / "full.npz"), (tmp_path / "r2", tmp_path / "half.npz")):
        done = _lfsf("points", result, "--camera", root / "s/gt.npz", "--out", out, "--quiet")
        assert done.returncode == 0, done.stderr
    full, half = np.load(tmp_path / "full.npz"), np.load(tmp_path / "half.npz")
    assert half["depth1"].shape == (24, 32)
    assert json.loads(str(half["camera"]))["focal"] == pytest.approx(json.loads(str(full["camera"]))["focal"] / 2)
    assert np.median(half["depth1"]) == pytest.approx(np.median(full["depth1"]), rel=0.03)
    assert np.median(half["points1"][..., 0]) == pytest.approx(np.median(full["points1"][..., 0]), abs=0.05)
    # in Python, the result loaded knows its K and the light fields' size: the full camera
    # given, a camera of numbers alone (no size) too, and the folder holding the gt.npz
    gt = np.load(root / "s/gt.npz")
    shrunk = lfsf.SceneFlow.load(tmp_path / "r2")
    for camera in (Camera.from_truth(gt), Camera(float(gt["focal"]), float(gt["baseline"]), float(gt["shift"]))):
        points1, _ = shrunk.points(camera)
        np.testing.assert_allclose(points1, half["points1"], rtol=1e-6, atol=1e-7)
    done = _lfsf("points", tmp_path / "r2", "--camera", root / "s", "--out", tmp_path / "dir.npz", "--quiet")
    assert done.returncode == 0, done.stderr
    np.testing.assert_array_equal(np.load(tmp_path / "dir.npz")["points1"], half["points1"])
    # --gt on it: the truth shrunk alike, the camera shrunk once (it had been twice, and refused)
    from lfsf.evaluate import downsample_truth, load_ground_truth

    truth, _ = load_ground_truth(root / "s/gt.npz")
    expected = scene_flow_errors(shrunk, downsample_truth(truth, 2), Camera.from_truth(gt), border=4)
    for camera_args in ([root / "s/gt.npz"], [gt["focal"], gt["baseline"], gt["shift"]]):
        done = _lfsf("points", tmp_path / "r2", "--camera", *camera_args, "--gt", root / "s/gt.npz", "--out",
                     tmp_path / "gt.npz", "--quiet")
        assert done.returncode == 0, done.stderr
        assert f"(border 4 px" in done.stdout and f"error mean {expected['epe3d']:.4g}," in done.stdout, done.stdout


def test_numbers_beyond_a_floats_range_are_one_line_errors_naming_their_magnitude(tmp_path):
    """A 400-digit focal or size (a parameters.cfg's, a result's recorded --downsample) had
    been an OverflowError's traceback, or a message of 400 digits."""
    with pytest.raises(ValueError, match=r"^Camera: focal must be finite, got 1.00e400$"):
        Camera(10 ** 400, 1.0, 0.0)
    with pytest.raises(ValueError, match=r"size must be \(W, H\), two whole numbers 1…1048576, or None, got "
                                         r"\(1.00e400, 5\)"):
        Camera(1.0, 1.0, 0.0, size=(10 ** 400, 5))
    cfg = tmp_path / "parameters.cfg"
    cfg.write_text("[intrinsics]\nfocal_length_mm=50\nsensor_size_mm=36\nimage_resolution_x_px=" + "9" * 400
                   + "\nimage_resolution_y_px=48\n[extrinsics]\nbaseline_mm=1\nfocus_distance_m=1\n")
    with pytest.raises(ValueError, match=r"parameters.cfg: no camera in these parameters: image_resolution_x_px"):
        Camera.from_file(cfg)
    with pytest.raises(ValueError, match=r"views of 64×48 cannot be shrunk 1000 times"):
        Camera(1.0, 1.0, 0.0, size=(64, 48)).downsampled(1000)
    from lfsf.estimate import SceneFlow

    maps = np.zeros((12, 16), np.float32)
    sf = SceneFlow(maps, maps, maps, maps, lfsf.Params.preset("fast"), 2.0, "cpu",
                   inputs={"downsample": 4, "views": [10 ** 400, 48]})
    with pytest.raises(ValueError, match=r"got \(1.00e400, 48\); from what this result records of its light fields"):
        sf.maps_camera(Camera(1.0, 1.0, 0.0))
    from lfsf.evaluate import downsample_of

    assert downsample_of({"downsample": 10 ** 400}) == 1 and downsample_of({"downsample": 4}) == 4
