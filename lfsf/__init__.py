"""lfsf — scene flow from light fields.

Joint estimation of the disparity of the centre view at two times and its optical flow
from two 4-D light fields, with the variational method of Heber & Pock (GCPR 2014),
written as NVIDIA Warp kernels that run on the CPU and on CUDA.

Importing :mod:`lfsf` is cheap: Warp is imported, and kernels are compiled, only when
something that needs them is first used.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

# public name -> module that defines it (loaded on first use, PEP 562)
_LAZY = {
    "LightField": "lfsf.io",
    "read_lightfield": "lfsf.io",
    "write_lightfield": "lfsf.io",
    "resolve_device": "lfsf.device",
    "Params": "lfsf.params",
    "estimate_scene_flow": "lfsf.estimate",
    "SceneFlow": "lfsf.estimate",
    "predict_next": "lfsf.estimate",
    "render_scene": "lfsf.synth",
    "list_scenes": "lfsf.synth",
}

__all__ = sorted(_LAZY) + ["__version__"]

#: The submodules, reachable as attributes after ``import lfsf`` (``lfsf.synth.render_scene``),
#: each imported on first use.
SUBMODULES = ("batch", "bench", "cli", "decode", "device", "estimate", "evaluate", "gains", "io", "params",
              "peers", "solver", "synth", "viz")


def __getattr__(name: str):
    if name in SUBMODULES:
        return importlib.import_module(f"lfsf.{name}")   # (the import sets the attribute too)
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'lfsf' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return __all__ + list(SUBMODULES)
