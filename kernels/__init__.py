"""Warp kernels of lfsf (installed as :mod:`lfsf.kernels`).

Only ``@wp.kernel`` functions and ``@wp.func`` helpers live here, one file per part of
the algorithm; :mod:`lfsf` owns the buffers and launches them. Modules are imported by
their users (``from lfsf.kernels import render``) so that importing :mod:`lfsf` compiles
nothing.

Calling one yourself: most kernels take ``row0`` first, the first row of the band of
rows they run on (:func:`lfsf.device.launch_rows` launches a kernel in bands from a thread
pool, each with its own ``row0``): give 0 and launch over the dimensions the kernel's
docstring says, e.g. ``wp.launch(median.median_flow, dim=(h, w), inputs=[0, x, 2, 0.0],
outputs=[out], device="cpu")``. Arrays of the unknowns are ``wp.vec4`` (δ1, δ2, u, v) or,
flow only, ``wp.vec2`` (u, v) (:data:`lfsf.kernels.common.UNKNOWNS`); each kernel has a
NumPy reference of the same formula in ``tests/reference_kernels.py``.
"""

from lfsf.device import require_warp as _require_warp

_require_warp()  # (a clear error where Warp is too old for these kernels, before a decorator fails)
