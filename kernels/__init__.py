"""Warp kernels of lfsf (installed as :mod:`lfsf.kernels`).

Only ``@wp.kernel`` functions and ``@wp.func`` helpers live here, one file per part of
the algorithm; :mod:`lfsf` owns the buffers and launches them. Modules are imported by
their users (``from lfsf.kernels import render``) so that importing :mod:`lfsf` compiles
nothing.
"""

from lfsf.device import require_warp as _require_warp

_require_warp()  # (a clear error where Warp is too old for these kernels, before a decorator fails)
