"""Shared test fixtures: the devices to run kernels on and the real data sets."""

from pathlib import Path

import math
import os

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
#: The real data sets: the workspace's ../shared/data, or the folder $LFSF_TEST_DATA names
#: (a clone elsewhere, say).
DATA = Path(os.environ.get("LFSF_TEST_DATA") or ROOT.parent / "shared" / "data")


def _devices():
    from lfsf.device import available_devices

    devs = ["cpu"]
    if "cuda:0" in available_devices():
        devs.append("cuda:0")
    return devs


DEVICES = _devices()


@pytest.fixture(params=DEVICES)
def device(request):
    """Every kernel test runs on the CPU, and on cuda:0 too when present."""
    return request.param


def data_path(*parts) -> Path:
    """A path under the real data's folder (:data:`DATA`); skips the test when it is absent."""
    path = DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"{path} not present (set LFSF_TEST_DATA to the folder of the real data sets)")
    return path


def load_script(name: str):
    """``scripts/<name>.py`` imported as a module (the scripts are not a package)."""
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "scripts" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"{name}_script", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def rng(seed=0):
    return np.random.default_rng(seed)


def wave_texture(seed, waves, freq, amplitude):
    """A smooth random texture T(x, y) = 0.5 + amplitude·Σ sin(k·(x, y) + phase): ``waves``
    plane waves with spatial frequencies uniform in ``freq`` (rad/px) and random
    directions and phases. Returns T as a function of (x, y) arrays."""
    r = rng(seed)
    f = r.uniform(freq[0], freq[1], waves)
    ang = r.uniform(0, 2 * math.pi, waves)
    phase = r.uniform(0, 2 * math.pi, waves)
    kx, ky = f * np.cos(ang), f * np.sin(ang)

    def t(x, y):
        x = np.asarray(x, np.float64)[..., None]
        y = np.asarray(y, np.float64)[..., None]
        return 0.5 + amplitude * np.sum(np.sin(kx * x + ky * y + phase), -1)
    return t


def arr(a, dtype, device):
    """A Warp array of float32 data with the given Warp dtype."""
    from lfsf.device import warp

    return warp().array(np.ascontiguousarray(a, np.float32), dtype=dtype, device=device)


def launch(kernel, dim, inputs, outputs, device, bands=None):
    from lfsf.device import launch_rows

    launch_rows(kernel, dim=dim, inputs=inputs, outputs=outputs, device=device, bands=bands)
