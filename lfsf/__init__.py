"""lfsf — scene flow from light fields.

Joint estimation of the disparity of the centre view at two times and its optical flow
from two 4-D light fields, with the variational method of Heber & Pock (GCPR 2014),
written as NVIDIA Warp kernels that run on the CPU and on CUDA.

Importing :mod:`lfsf` is cheap: Warp is imported, and kernels are compiled, only when
something that needs them is first used.

Conventions (the docstrings' "MODEL.md §1"; MODEL.md is the project's restatement of
the paper's model, ``docs/MODEL.md`` in the source checkout, not installed):

* light fields are ``views[a, b, y, x]`` (grey) or ``views[a, b, y, x, c]`` (RGB),
  float32 in [0, 1]: ``a`` the view row, ``b`` the view column of an A×B grid, the
  centre at ``(a_c, b_c) = ((A − 1)/2, (B − 1)/2)``: the middle view, or along an
  even side the mean of the middle two (or four) views; pixel ``x`` to the right,
  ``y`` down;
* ``δ1`` (``disp1``), pixels per view step: the point seen at centre pixel ``p`` at t1
  appears in the view at angular offset ``φ = (ξ, η) = (b − b_c, a − a_c)`` at
  ``p − δ1·φ`` (as in the HCI 4D benchmark);
* the flow ``(u, v)``, pixels: that point appears in the centre view at t2 at
  ``p + (u, v)``;
* ``δ2`` (``disp2``): the disparity at t2 of that same point, indexed by its pixel
  ``p`` at t1 (not the t2 disparity map);
* ``occluded``: where the estimate does not see the point in the centre view at t2.

With a calibrated camera, :class:`lfsf.Camera` turns δ into depth, Z = f·b / (δ + δ0), and
``SceneFlow.points`` gives the 3-D points at t1 and t2, whose difference is the 3-D scene
flow (MODEL.md §7; ``lfsf points`` on the command line).
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import os
import sys
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"


class _CheckoutKernels(importlib.abc.MetaPathFinder):
    """Finds ``lfsf.kernels`` in a source checkout's ``kernels/``, beside ``lfsf/``.

    Installed, the kernels are the subpackage ``lfsf/kernels`` (pyproject.toml's
    package-dir). Imported from a checkout without an editable install, as ``python -m
    lfsf`` or ``python -m pytest`` in its root put ``./lfsf`` first on the path, nothing
    else maps them: ``lfsf.kernels`` was missing (ModuleNotFoundError), or another tree's
    (an editable install's elsewhere, a silent mix of two versions)."""

    #: (Told apart by this mark, not by class: a reload of lfsf makes a new class.)
    lfsf_checkout_kernels = True

    def __init__(self, package: str, folder: str) -> None:
        self.package = package   # the checkout's lfsf/
        self.folder = folder     # its kernels/

    def find_spec(self, name: str, path: Any = None, target: Any = None) -> Any:
        # only for the lfsf this finder came with (another copy imported later, a wheel's,
        # has kernels of its own)
        if name != __name__ + ".kernels" or not any(os.path.abspath(p) == self.package for p in path or ()):
            return None
        return importlib.util.spec_from_file_location(name, os.path.join(self.folder, "__init__.py"),
                                                      submodule_search_locations=[self.folder])


def _find_checkout_kernels() -> None:
    here = os.path.dirname(os.path.abspath(__file__))
    beside = os.path.join(os.path.dirname(here), "kernels")
    if (not os.path.isdir(os.path.join(here, "kernels")) and os.path.isfile(os.path.join(beside, "__init__.py"))
            and not any(getattr(finder, "lfsf_checkout_kernels", False) and getattr(finder, "package", None) == here
                        for finder in sys.meta_path)):
        sys.meta_path.insert(0, _CheckoutKernels(here, beside))


_find_checkout_kernels()

# public name -> module that defines it (loaded on first use, PEP 562)
_LAZY = {
    "LfsfWarning": "lfsf._errors",
    "Camera": "lfsf.camera",
    "LightField": "lfsf.io",
    "read_lightfield": "lfsf.io",
    "write_lightfield": "lfsf.io",
    "resolve_device": "lfsf.device",
    "Params": "lfsf.params",
    "estimate_scene_flow": "lfsf.estimate",
    "SceneFlow": "lfsf.estimate",
    "Note": "lfsf.estimate",
    "predict_next": "lfsf.estimate",
    "render_scene": "lfsf.synth",
    "list_scenes": "lfsf.synth",
}

# a literal list, which type checkers read (tests/test_typing.py checks it against _LAZY)
__all__ = [
    "Camera",
    "LfsfWarning",
    "LightField",
    "Note",
    "Params",
    "SceneFlow",
    "estimate_scene_flow",
    "list_scenes",
    "predict_next",
    "read_lightfield",
    "render_scene",
    "resolve_device",
    "write_lightfield",
    "__version__",
]

if TYPE_CHECKING:
    # what the lazy loading below gives, for type checkers (never run): without these every
    # name reached as ``lfsf.X`` would be typed Any
    from lfsf import (batch, bench, camera, cli, decode, device, estimate, evaluate, gains, io, params, peers, solver,
                      synth, viz)
    from lfsf._errors import LfsfWarning as LfsfWarning
    from lfsf.camera import Camera as Camera
    from lfsf.device import resolve_device as resolve_device
    from lfsf.estimate import Note as Note
    from lfsf.estimate import SceneFlow as SceneFlow
    from lfsf.estimate import estimate_scene_flow as estimate_scene_flow
    from lfsf.estimate import predict_next as predict_next
    from lfsf.io import LightField as LightField
    from lfsf.io import read_lightfield as read_lightfield
    from lfsf.io import write_lightfield as write_lightfield
    from lfsf.params import Params as Params
    from lfsf.synth import list_scenes as list_scenes
    from lfsf.synth import render_scene as render_scene

#: The submodules, reachable as attributes after ``import lfsf`` (``lfsf.synth.render_scene``),
#: each imported on first use.
SUBMODULES = ("batch", "bench", "camera", "cli", "decode", "device", "estimate", "evaluate", "gains", "io", "params",
              "peers", "solver", "synth", "viz")


def __getattr__(name: str) -> Any:
    if name in SUBMODULES:
        return importlib.import_module(f"lfsf.{name}")   # (the import sets the attribute too)
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'lfsf' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__ + list(SUBMODULES)
