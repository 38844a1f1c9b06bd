"""What the research scripts in ``scripts/`` check before their first run."""
from __future__ import annotations

import os


def check_before_runs(size=None, grid: int | None = None, *, colour: bool = False, device: str | None = None,
                      output: str | os.PathLike | None = None) -> None:
    """Refuse, before any run rather than after all of them, what would fail later: a
    render of ``size`` (width, height) with ``grid`` × ``grid`` views (``colour``: RGB;
    no render checked without ``size``, and ``grid`` is needed with it), the ``device``
    (None: ``$LFSF_DEVICE`` or the default, as the runs will resolve it) and an
    ``output`` file (a report) that cannot be written (None: none). Raises ValueError
    naming the problem."""
    if size is not None:
        from lfsf import synth

        synth.check_render(tuple(size), grid, colour=colour)
    from lfsf.device import resolve_device

    resolve_device(device)
    if output:
        from lfsf._files import output_file

        output_file(output)
