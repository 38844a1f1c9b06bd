"""What the research scripts in ``scripts/`` check before their first run."""
from __future__ import annotations

import os


#: The smallest views a script that scores its runs takes: the scores leave out an 8-px
#: border (lfsf.evaluate.SYNTH_BORDER), and 16 px left nothing to score after the work
#: (as ``lfsf demo`` and ``lfsf bench``).
MIN_SCORED_SIZE = 17


def check_before_runs(size=None, grid: int | None = None, *, colour: bool = False, device: str | None = None,
                      output: str | os.PathLike | None = None, scored: bool = True) -> None:
    """Refuse, before any run rather than after all of them, what would fail later: a
    render of ``size`` (width, height) with ``grid`` × ``grid`` views (``colour``: RGB;
    no render checked without ``size``, and ``grid`` is needed with it), the ``device``
    (None: ``$LFSF_DEVICE`` or the default, as the runs will resolve it) and an
    ``output`` file (a report) that cannot be written (None: none); ``scored``: the runs
    are scored against the truth, so each side of ``size`` must be at least
    MIN_SCORED_SIZE. Raises ValueError naming the problem."""
    if size is not None:
        from lfsf import synth

        synth.check_render(tuple(size), grid, colour=colour)
        if scored and min(size) < MIN_SCORED_SIZE:
            raise ValueError(f"--size must be at least {MIN_SCORED_SIZE} {MIN_SCORED_SIZE} (the scores leave out an "
                             f"8-px border), got {size[0]} {size[1]}")
    from lfsf.device import resolve_device

    resolve_device(device)
    if output:
        from lfsf._files import output_file

        output_file(output)
