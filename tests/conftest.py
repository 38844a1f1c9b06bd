"""Shared test fixtures: the devices to run kernels on and the real data sets."""

from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"


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
    """A path under ../shared/data; skips the test when it is absent."""
    path = DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"{path} not present")
    return path


def rng(seed=0):
    return np.random.default_rng(seed)


def arr(a, dtype, device):
    """A Warp array of float32 data with the given Warp dtype."""
    from lfsf.device import warp

    return warp().array(np.ascontiguousarray(a, np.float32), dtype=dtype, device=device)


def launch(kernel, dim, inputs, outputs, device, bands=None):
    from lfsf.device import launch_rows

    launch_rows(kernel, dim=dim, inputs=inputs, outputs=outputs, device=device, bands=bands)
