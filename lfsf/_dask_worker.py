"""Preloaded into each worker process of ``lfsf batch``'s local Dask cluster.

A terminal's Ctrl-C reaches the whole process group; each worker process answered it with
its own KeyboardInterrupt traceback. Here they ignore it: the ``lfsf batch`` process
alone answers, closes the cluster and so ends them.
"""

import signal


def dask_setup(worker) -> None:  # noqa: ARG001 - the hook Dask's preload calls
    signal.signal(signal.SIGINT, signal.SIG_IGN)
