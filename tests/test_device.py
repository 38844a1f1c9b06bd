"""Device choice and banded CPU launches."""

import numpy as np
import pytest

from lfsf import device as D
from lfsf import synth


def test_default_device_is_cuda_when_present(monkeypatch):
    monkeypatch.delenv(D.ENV_DEVICE, raising=False)
    want = "cuda:0" if "cuda:0" in D.available_devices() else "cpu"
    assert D.resolve_device() == want
    assert D.resolve_device("cpu") == "cpu"


def test_environment_variable_chooses_device(monkeypatch):
    monkeypatch.setenv(D.ENV_DEVICE, "cpu")
    assert D.resolve_device() == "cpu"
    monkeypatch.setenv(D.ENV_DEVICE, "cuda:7")
    with pytest.raises(ValueError, match=r"unknown device 'cuda:7' \(from \$LFSF_DEVICE\)"):
        D.resolve_device()
    assert D.resolve_device("cpu") == "cpu"  # the argument wins over the environment


@pytest.mark.parametrize("name", ["cuda:9", "gpu", "tpu:0"])
def test_unknown_device_is_a_clear_error(name):
    with pytest.raises(ValueError, match="unknown device"):
        D.resolve_device(name)


@pytest.mark.parametrize("rows,bands", [(10, 3), (2, 8), (7, 1), (100, 7)])
def test_row_bands_cover_rows_once(rows, bands):
    parts = D.row_bands(rows, bands)
    assert parts[0][0] == 0 and parts[-1][1] == rows
    assert all(a < b for a, b in parts)
    assert all(p[1] == q[0] for p, q in zip(parts, parts[1:]))
    assert len(parts) <= bands


def test_banded_and_single_launches_give_identical_results():
    from lfsf.kernels import render

    wp = D.warp()
    cam = synth.CameraArray.for_size(48, 36)
    objs, _ = synth._scene_arrays(synth.get_scene("paper"), cam, "cpu")
    wcam = synth._warp_camera(cam)
    results = []
    for bands in (1, 2, 5):
        views = wp.zeros((9, 36, 48, 1), dtype=float, device="cpu")
        D.launch_rows(render.render_views, dim=(9 * 36, 48), inputs=[wcam, objs, 3, 1.0, 1.0, 2],
                      outputs=[views], device="cpu", bands=bands)
        results.append(views.numpy())
    assert np.all(results[0] != 0)
    np.testing.assert_array_equal(results[0], results[1])
    np.testing.assert_array_equal(results[0], results[2])


def test_thread_count_from_environment(monkeypatch):
    monkeypatch.setenv(D.ENV_THREADS, "3")
    assert D.cpu_threads() == 3
    monkeypatch.setenv(D.ENV_THREADS, "many")
    with pytest.raises(ValueError, match="LFSF_THREADS"):
        D.cpu_threads()


def test_importing_lfsf_compiles_nothing_and_skips_warp():
    import subprocess
    import sys

    code = "import sys, lfsf; print('warp' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
