"""Device choice and kernel launches.

Every kernel in :mod:`lfsf.kernels` is written once and runs on the CPU and on CUDA. Warp
runs a CPU launch on a single thread, so :func:`launch_rows` splits the outer launch
dimension into row bands and launches them from a thread pool (Warp releases the GIL
while a CPU kernel runs); on CUDA it is a single launch.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import sys
import threading
from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait
from typing import Callable, Sequence

from lfsf._errors import DependencyError

ENV_DEVICE = "LFSF_DEVICE"
ENV_THREADS = "LFSF_THREADS"

_init_lock = threading.Lock()
#: Seconds between the checks of a wait for a compile (:func:`_compile`'s for its modules,
#: :func:`_wait_for_compile`'s for another thread's): an interrupt raised as a flag, not a
#: signal, is seen at the next.
COMPILE_POLL = 0.1
#: (device, names of the modules) that the thread holding _init_lock compiles
#: (:func:`_load`), or None where it compiles none.
_compiling: tuple[str, tuple[str, ...]] | None = None
_loaded: set[tuple[int, str]] = set()
_pool: ThreadPoolExecutor | None = None
_initialised = False


@contextlib.contextmanager
def _stderr_filtered(drop: str):
    """Hold back what native code writes to file descriptor 2; re-emit all but lines with ``drop``."""
    import tempfile

    if sys.stderr is not None:  # (None: pythonw, a daemon)
        sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:  # (descriptor 2 closed: nothing to hold back)
        yield
        return
    with tempfile.TemporaryFile(mode="w+b") as buf:
        os.dup2(buf.fileno(), 2)
        try:
            yield
        finally:
            if sys.stderr is not None:
                sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            buf.seek(0)
            kept = [ln for ln in buf.read().decode(errors="replace").splitlines() if drop not in ln]
            if kept and sys.stderr is not None:
                print("\n".join(kept), file=sys.stderr)


#: The oldest Warp that lfsf runs on (pyproject's ``warp-lang>=``). Its kernels use
#: ``cuda_max_registers``, new in Warp 1.17. Warp 1.14 and 1.16 fail when the kernels are
#: imported; 1.5 and 1.10 fail earlier, when Warp starts (``wp.LOG_ERROR``). The test
#: suite and ``lfsf demo`` pass on 1.17 (forty-second session).
MIN_WARP = (1, 17)


def require_warp(version: str | None = None) -> None:
    """Raise :class:`lfsf._errors.DependencyError` (an ImportError), naming the version
    found and the way to upgrade, where the installed Warp (or ``version``) is older than
    :data:`MIN_WARP`. This gives a clear message (from the CLI one line, status 2) instead
    of an error somewhere inside Warp or a kernel decorator."""
    if version is None:
        import warp

        version = getattr(warp, "__version__", None) or warp.config.version
    parts = re.match(r"(\d+)\.(\d+)", str(version))
    if parts and tuple(int(p) for p in parts.groups()) < MIN_WARP:
        least = ".".join(map(str, MIN_WARP))
        raise DependencyError(f"lfsf needs warp-lang {least} or newer, and this Python has {version}: "
                              f"pip install -U 'warp-lang>={least}'")


def warp():
    """Import and initialise Warp quietly; return the module. Warp's log level is then
    ``wp.LOG_WARNING`` for the rest of the process: at Warp's own default (info) every
    module's first load prints a line, which lfsf's commands and library calls would
    print too. Code of a user's own that wants Warp's info lines sets
    ``wp.config.log_level`` after lfsf's first call."""
    import warp as wp

    global _initialised
    if not _initialised:
        require_warp()
        with _init_lock:
            # A machine without an NVIDIA driver is normal for us (CPU runs): keep Warp's
            # start-up banner and driver warning out of the output; asking for a CUDA
            # device that is not there is still a clear error in resolve_device.
            wp.config.log_level = wp.LOG_ERROR
            if wp.config.kernel_cache_dir is None and "WARP_CACHE_PATH" not in os.environ:
                wp.config.kernel_cache_dir = _cache_without_home(wp.config.version)
            try:
                with _stderr_filtered("NVIDIA CUDA driver"):
                    wp.init()
            except OSError as exc:
                # (no errno: "[Errno 13]" had led the line, and a full disk's would read as the outputs')
                where = f" {exc.filename}" if exc.filename else ""
                raise OSError(f"Warp cannot set up its kernel cache{where} ({exc.strerror}); set WARP_CACHE_PATH to a "
                              "writable folder") from None
            wp.config.log_level = wp.LOG_WARNING
            _initialised = True
    return wp


def _cache_without_home(version: str = "") -> str | None:
    """Where Warp's kernel cache goes: None (Warp's own choice, ``$XDG_CACHE_HOME/warp`` or
    ``~/.cache/warp``; ``~/Library/Caches/warp`` on macOS) where that can hold it (or
    holds this Warp ``version``'s already, writable or not), the home's ``.cache/warp``
    where ``XDG_CACHE_HOME`` is empty or relative (which the XDG rules say to ignore; Warp
    took it as a folder in the current one), else a folder of this user's in the temporary
    folder. With HOME unset and no passwd entry, ``~`` stays ``~``, and Warp had made a
    folder named ``~`` in the current folder, and compiled again in each new one; with
    HOME=/ (``docker run --user 12345``) it could not start. The folder must be this
    user's alone: its compiled code is loaded and run."""
    import stat
    import tempfile

    if os.name == "nt":
        return None
    macos = sys.platform == "darwin"   # (Warp's is ~/Library/Caches/warp there, XDG or not)
    xdg = None if macos else os.environ.get("XDG_CACHE_HOME")
    if xdg and os.path.isabs(xdg):
        return None
    home = os.path.expanduser("~")
    if not home.startswith("~"):
        wanted = os.path.join(home, *(("Library", "Caches") if macos else (".cache",)), "warp")
        if os.path.isdir(os.path.join(wanted, version)):
            return None if xdg is None else wanted
        existing = wanted
        while not os.path.lexists(existing) and os.path.dirname(existing) != existing:
            existing = os.path.dirname(existing)   # (a dangling link is there, and cannot be made)
        if os.path.isdir(existing) and os.access(existing, os.W_OK | os.X_OK):
            return None if xdg is None else wanted
    folder = os.path.join(tempfile.gettempdir(), f"lfsf-warp-cache-{os.getuid()}")
    where = f"there is no home folder to hold it{f' ({home} is not writable)' if not home.startswith('~') else ''}"
    try:
        os.mkdir(folder, 0o700)
    except FileExistsError:
        pass
    except OSError as exc:
        raise OSError(f"Warp cannot set up its kernel cache: {where}, and {folder} cannot be made ({exc.strerror}); "
                      "set WARP_CACHE_PATH to a writable folder") from None
    status = os.lstat(folder)
    if not stat.S_ISDIR(status.st_mode):
        raise OSError(f"Warp cannot set up its kernel cache: {where}, and {folder} is not a folder (a link, or a "
                      "file); set WARP_CACHE_PATH to a folder of your own")
    if status.st_uid != os.getuid() or status.st_mode & 0o022:
        raise OSError(f"Warp cannot set up its kernel cache: {where}, and {folder} is not this user's alone (its "
                      "compiled code would be run); set WARP_CACHE_PATH to a folder of your own")
    return folder


def available_devices() -> list[str]:
    """Names of the devices Warp can launch on, e.g. ``['cpu', 'cuda:0']``."""
    wp = warp()
    return [str(d) for d in wp.get_devices()]


def resolve_device(device: str | None = None) -> str:
    """Return the device to run on, as Warp names it.

    Order: the argument, else the ``LFSF_DEVICE`` environment variable, else ``cuda:0``
    when CUDA is present, else ``cpu``. ``"cuda"`` means the first CUDA device.

    Raises
    ------
    ValueError
        If the device named is not one Warp can use here.
    """
    if device is not None and not isinstance(device, str):
        raise ValueError(f"device must be a name such as 'cpu' or 'cuda:0', got {device!r}")
    name = device if device not in (None, "") else os.environ.get(ENV_DEVICE) or None
    wp = warp()
    devices = available_devices()
    if name is None:
        return "cuda:0" if wp.is_cuda_available() else "cpu"
    key = name.strip().lower()
    if key == "cuda":
        key = "cuda:0"
    if key not in devices:
        source = "" if device not in (None, "") else f" (from ${ENV_DEVICE})"
        if re.fullmatch(r"cuda:\d+", key):
            cuda = "" if any(d.startswith("cuda") for d in devices) else " (Warp finds no CUDA device: no NVIDIA GPU or driver)"
            raise ValueError(f"device '{name}'{source} is not on this machine, which has {', '.join(devices)}{cuda}")
        raise ValueError(f"unknown device '{name}'{source}: this machine has {', '.join(devices)}")
    return key


#: At most this many CPU threads (``$LFSF_THREADS``): more than the cores only adds
#: switching (1000 threads took a run from 4.7 s to 22.6 s on 2 cores).
MAX_THREADS = 256


def cpu_threads() -> int:
    """Threads used for banded CPU launches: ``$LFSF_THREADS`` or the usable cores."""
    env = os.environ.get(ENV_THREADS)
    if env:
        try:
            threads = int(env)
        except ValueError:
            raise ValueError(f"{ENV_THREADS} must be a whole number, got {env!r}") from None
        if not 1 <= threads <= MAX_THREADS:
            raise ValueError(f"{ENV_THREADS} must be in 1…{MAX_THREADS} (this machine has {os.cpu_count()} "
                             f"CPUs), got {threads}")
        return threads
    return usable_cpus()


def usable_cpus() -> int:
    """The CPUs this process may run on (its affinity: a container's or ``taskset``'s
    share, not the machine's count), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        count = getattr(os, "process_cpu_count", os.cpu_count)()   # (Python ≥ 3.13: the affinity's too)
        return max(1, count or 1)


def thread_pool() -> ThreadPoolExecutor:
    """The pool of :func:`cpu_threads` threads that banded CPU launches run on (made once
    per process: a child forked from a process that had one makes its own)."""
    global _pool
    with _init_lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(max_workers=cpu_threads(), thread_name_prefix="lfsf-band")
        return _pool


def _forked_child() -> None:
    """In a child forked from this process (``multiprocessing``'s "fork" start, the
    default on Linux before Python 3.14): the parent's pool is forgotten, whose threads
    the child does not have (its launches waited for them for ever), and so is the
    lock, which a thread of the parent may have held at the fork."""
    global _pool, _init_lock, _compiling
    _pool = None
    _init_lock = threading.Lock()
    _compiling = None


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forked_child)


def _wait_for_compile(device, announce: Callable[[list[str]], None] | None) -> float:
    """Where another thread holds the lock of :func:`_load`, wait for it, with
    ``announce`` told of the modules that thread compiles for the same ``device`` (once
    it knows them); the seconds it waited where there was such a compile, else 0. The
    wait polls (COMPILE_POLL), so that an interrupt raised as a flag is seen. The lock is
    not kept: :func:`_load` takes it again."""
    import time

    if _init_lock.acquire(blocking=False):
        _init_lock.release()
        return 0.0
    start = time.perf_counter()
    told = False
    while True:
        # (the names the other thread compiles, which it sets under the lock once it knows
        # them, read again at every poll: asking the cache here, as the compile goes on,
        # would hash Warp's modules outside the lock)
        compiling = _compiling
        if not told and compiling is not None and compiling[0] == str(device) and compiling[1]:
            told = True
            if announce is not None:
                announce(list(compiling[1]))
        if _init_lock.acquire(timeout=COMPILE_POLL):
            break
    _init_lock.release()
    return time.perf_counter() - start if told else 0.0


def _load(modules: Sequence, device, announce: Callable[[list[str]], None] | None = None) -> float:
    """Compile or load the Warp modules ``modules`` on ``device`` (a Warp device), those
    not loaded yet in this process, several at once, under a lock, so that threads do
    not race to compile a module. Returns the seconds spent waiting for another thread's
    compile for this device plus compiling or loading what was still missing (0 where
    all were loaded). ``announce`` is given the names of the modules that the kernel
    cache holds no build of, before they are compiled, or while this thread waits, those
    that another thread compiles (:func:`_wait_for_compile`)."""
    global _compiling
    if all((id(m), str(device)) in _loaded for m in modules):
        return 0.0
    wp = warp()
    waited = _wait_for_compile(device, announce)
    with _init_lock:
        todo = [m for m in modules if (id(m), str(device)) not in _loaded]
        if not todo:
            return waited
        cache = wp.config.kernel_cache_dir
        cold = _cold(todo, device) if wp.config.cache_kernels else []
        # (set before the checks and the announcement, which a waiting thread would otherwise
        # sit through in silence; cleared in the finally below, whatever ends them)
        _compiling = (str(device), tuple(m.name for m in cold)) if cold else None
        try:
            if cold:
                _check_cache_room(cache)
                _remove_dead_builds(cache)
                if announce is not None:
                    announce([m.name for m in cold])
            return waited + _compile_or_load(wp, todo, cold, device, cache)
        finally:
            _compiling = None


def _compile_or_load(wp, todo: list, cold: list, device, cache: str) -> float:
    """:func:`_load`'s compile or load of ``todo`` (of which the cache holds no build of
    ``cold``) under its lock: marks them loaded and returns the seconds; Warp's errors
    from the cache become an OSError naming it."""
    import time

    start = time.perf_counter()
    try:
        _compile(wp, todo, device)
    except OSError as exc:   # (the message had named a build folder of Warp's, or blamed the outputs)
        if exc.errno not in _CACHE_ERRNOS or not _within(exc.filename, cache):
            raise
        # (a folder of the user's own: in a shared cache with the sticky bit, as /tmp, the
        # folder is writable and the entries of another user's are not)
        raise OSError(f"Warp's kernel cache {cache}: {exc.strerror} ({exc.filename}) while compiling lfsf's "
                      f"kernels into it: set WARP_CACHE_PATH to a folder of your own, writable, with room "
                      f"({CACHE_ROOM >> 20} MB)") from None
    except UnicodeError as exc:   # (Warp hands the path to its compiler as UTF-8: the C locale's undecoded bytes fail)
        raise OSError(f"Warp's kernel cache {cache}: its path cannot be handed to Warp's compiler ({exc.reason}); "
                      "set WARP_CACHE_PATH to a folder whose path is ASCII, or use a UTF-8 locale") from None
    except Exception as exc:  # noqa: BLE001 - narrowed below to a cache entry that does not read
        import json

        # (a .meta that is no JSON, an object file that LLVM does not take; not the
        # codegen's own errors, some ValueErrors, which a damaged cache does not cause)
        # (nor a module compiled just now, which no deleting mends)
        failed = re.match(r"Failed to load CPU module '([^']+)'", str(exc))
        # (a cache filled on a machine of another CPU: the module's folder is there, with
        # no object of this CPU's in it; Warp could not add this one, which it had compiled)
        module = next((m for m in cold if failed and m.name == failed.group(1)), None)
        folder, binary = (None, None) if module is None else _build(module, device)
        if binary is not None and os.path.isdir(folder) and not os.path.exists(binary):
            raise OSError(f"Warp's kernel cache {cache}: its entry {folder} holds lfsf's kernels built for "
                          f"another CPU, and this CPU's could not be added to it (it is another user's, or "
                          f"not writable): set WARP_CACHE_PATH to a folder of your own") from None
        if not (isinstance(exc, json.JSONDecodeError) or failed and failed.group(1) not in {m.name for m in cold}):
            raise
        raise OSError(f"Warp's kernel cache {cache} holds a damaged entry of lfsf's kernels ({exc}): delete "
                      f"them (rm -r {os.path.join(cache, 'wp_lfsf.kernels.*')}), and they are compiled "
                      "again") from None
    _loaded.update((id(m), str(device)) for m in todo)
    return time.perf_counter() - start


def _compile(wp, modules: Sequence, device) -> None:
    """Warp's ``force_load`` of the ``modules`` on ``device``, several at once on
    :func:`cpu_threads` threads. A Ctrl-C (or a module that fails) cancels the modules not
    begun: Warp's own pool went on to compile every one of them, so a Ctrl-C during a
    first run's compile took 12.7 s to end it (12 modules, 2 cores); now it waits only for
    the modules being compiled."""
    # (one thread a block on the CPU, as a launch there compiles it: Warp 1.17 preloaded
    # its modules' default of 256 otherwise, a build that no launch used)
    block_dim = 1 if device.is_cpu else None
    workers = min(len(modules), cpu_threads())
    if workers <= 1:
        wp.force_load(device=device, modules=list(modules), max_workers=1, block_dim=block_dim)
        return
    pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="lfsf-compile")
    try:
        futures = [pool.submit(wp.force_load, device=device, modules=[m], max_workers=1, block_dim=block_dim)
                   for m in modules]
        # (any module's error, not only once those before it ended; in short waits, so that an
        # interrupt that comes as a flag, not a signal, _thread.interrupt_main's, is not held
        # until every module is compiled)
        while True:
            done, running = wait(futures, timeout=COMPILE_POLL, return_when=FIRST_EXCEPTION)
            if not running or any(f.exception() is not None for f in done if not f.cancelled()):
                break
        for future in futures:
            if future.done():
                future.result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


#: A build folder of Warp's older than this, whose process is not running here, is a
#: killed compile's (a module's compile takes seconds; another machine's, on a cache that
#: machines share, is not asked after by its process id alone).
DEAD_BUILD_AGE = 3600.0


def _remove_dead_builds(cache: str) -> None:
    """Remove the build folders of lfsf's modules that Warp compiles into (the module's
    folder name and ``_pPID_tTHREAD``) and renames into place, where the process is gone:
    a process killed outright during its compile (SIGKILL, the out-of-memory killer) had
    left them in the cache for good, two a kill (a helper's). Only those older than
    :data:`DEAD_BUILD_AGE` and of no process running here."""
    import shutil
    import time

    from lfsf._files import gone

    now = time.time()
    with contextlib.suppress(OSError):
        for entry in os.scandir(cache):
            made = re.fullmatch(r"wp_lfsf\.kernels\.[A-Za-z0-9_]+_[0-9a-f]+_p(\d+)_t\d+", entry.name)
            with contextlib.suppress(OSError):
                if (made and entry.is_dir(follow_symlinks=False) and now - entry.stat().st_mtime > DEAD_BUILD_AGE
                        and gone(int(made[1]))):
                    shutil.rmtree(entry.path, ignore_errors=True)


def remove_warp_temporaries() -> None:
    """Remove the folders that Warp keeps in the temporary folder for the life of the
    process (``wp_pch_*``, the CPU compiler's precompiled headers, 4.6 MB each) and
    removes at the interpreter's exit: a command ended at once by a signal
    (``os._exit``) had left them, 8.9 MB a first run. Nothing where Warp was not
    imported, or where this Warp keeps no such folders."""
    context = sys.modules.get("warp._src.context") or sys.modules.get("warp.context")
    folders = getattr(getattr(context, "runtime", None), "_pch_dirs", None)
    if not isinstance(folders, dict):
        return
    for folder in list(folders.values()):
        with contextlib.suppress(Exception):
            folder.cleanup()


def _within(path, folder: str) -> bool:
    """Whether the file ``path`` (None: no file) lies in ``folder``."""
    if path is None:
        return False
    folder = os.path.realpath(folder)
    try:
        return os.path.commonpath([os.path.realpath(os.fsdecode(path)), folder]) == folder
    except ValueError:   # (Windows: on another drive)
        return False


#: Free space the kernel cache needs for lfsf's modules to be compiled into it: they take
#: about 4 MB, and their build folders and objects more while they compile (a 200-KB
#: folder had LLVM end the process with its own "IO failure on output stream").
CACHE_ROOM = 64 << 20

#: What a kernel cache that cannot take the compiled modules says: full, or not writable.
_CACHE_ERRNOS = tuple(getattr(errno, name) for name in ("ENOSPC", "EDQUOT", "EACCES", "EPERM", "EROFS")
                      if hasattr(errno, name))


def _build(module, device) -> tuple[str, str | None]:
    """Where the kernel cache keeps the Warp ``module``'s build for the Warp ``device``'s
    kind of launch: the folder that Warp names by the module's hash (for one thread a
    block on the CPU, as a launch there compiles it, and the module's own block size on
    CUDA), and the object file in it of this CPU's target (or this GPU's architecture),
    None where this Warp does not say."""
    block_dim = 1 if device.is_cpu else module.options["block_dim"]
    folder = os.path.join(warp().config.kernel_cache_dir, module.get_module_identifier(block_dim=block_dim))
    try:  # (Warp's own name for it: a folder of a cache shared by machines holds one for each CPU)
        name = module._get_compile_output_name(device, block_dim=block_dim)
    except Exception:  # noqa: BLE001 - another Warp's; the folder alone then
        name = None
    return folder, None if not isinstance(name, str) else os.path.join(folder, name)


def _built(module, device) -> bool | None:
    """Whether the kernel cache holds the Warp ``module``'s build for ``device`` (its
    folder, and in it the object file of this CPU or GPU where Warp names it); None where
    this Warp names its folders otherwise."""
    try:
        folder, binary = _build(module, device)
    except (AttributeError, KeyError, TypeError):
        return None
    return os.path.isdir(folder) and (binary is None or os.path.exists(binary))


def _cold(modules, device) -> list:
    """The Warp ``modules`` of which the kernel cache holds no build for the Warp
    ``device`` (:func:`_built`: a folder of another machine's CPU's alone, in a cache that
    machines share, counts as none); [] where this Warp names its folders otherwise."""
    return [m for m in modules if _built(m, device) is False]


def cold_modules(modules, device) -> list[str]:
    """The names of the Python modules of kernels among ``modules`` (e.g.
    :mod:`lfsf.kernels.tgv`) that Warp's kernel cache holds no build of for ``device``
    (of this CPU's target, or this GPU's architecture, where Warp names its objects so):
    the ones that :func:`preload` would compile."""
    wp = warp()
    return [m.name for m in _cold([wp.get_module(m.__name__) for m in modules], wp.get_device(device))]


def _check_cache_room(cache: str) -> None:
    """An OSError naming the kernel cache where its file system has less than
    :data:`CACHE_ROOM` free: the compiler would end the process with a line of its own."""
    import shutil

    try:
        free = shutil.disk_usage(cache).free
    except OSError:
        return
    if free < CACHE_ROOM:
        raise OSError(f"Warp's kernel cache {cache}: {free >> 10} KB free, where lfsf's kernels need about "
                      f"{CACHE_ROOM >> 20} MB to be compiled into it (once): free some, or set WARP_CACHE_PATH "
                      "to a folder with room")


def preload(modules: Sequence, device, announce: Callable[[list[str]], None] | None = None) -> float:
    """Compile the Warp kernels of the Python ``modules`` (e.g. :mod:`lfsf.kernels.tgv`)
    for ``device``, or load them from Warp's kernel cache, several modules at once, and
    return the seconds it took. Modules already loaded in this process are skipped;
    ``announce`` is given the names of those to be compiled (:func:`cold_modules`),
    before the compile.

    Without this, Warp loads a module the first time one of its kernels is launched, so
    the modules compile one after another. With a cold kernel cache, the estimator's
    eleven modules took 13.7 s to compile one at a time and 8.2 s two at a time, on
    this project's 2-core CPU. On a machine with more cores, the largest module's
    compile time is the floor (`data_groups`, 2.8 s). With a warm cache, loading
    them takes about 0.1 s either way.

    Modules are loaded on :func:`cpu_threads` threads: the compiler runs in native code
    and releases the GIL."""
    wp = warp()
    return _load([wp.get_module(m.__name__) for m in modules], wp.get_device(device), announce)


def vector_view(array, dtype, shape):
    """The memory of a contiguous Warp ``array`` seen as an array of ``dtype`` (e.g. the
    vectors of several floats that the lanes kernels read) with ``shape``. The view does
    not own the memory; it holds a reference to ``array`` (``_ref``, as Warp's own views
    do), so the memory lives as long as either."""
    wp = warp()
    view = wp.array(ptr=array.ptr, dtype=dtype, shape=shape, device=array.device, capacity=array.capacity)
    view._ref = array
    return view


class RecordedRows:
    """A :func:`launch_rows` call recorded once (arguments packed, ``wp.Launch`` objects
    per band) and replayed by calling it: for launches repeated with the same arrays and
    values, such as the solver's iterations. A plain launch of a kernel with generic
    arguments spends about 85 µs in Python choosing its overload and packing its
    arguments; a recorded one about 7 µs (20×15 pixels, CPU). ``single`` says whether it
    is one launch (CUDA, or one band), which a graph can capture (:class:`CapturedLoop`)."""

    def __init__(self, kernel, dim, inputs: Sequence = (), outputs: Sequence = (), device: str | None = None,
                 bands: int | None = None):
        wp = warp()
        dims = (dim,) if isinstance(dim, int) else tuple(dim)
        dev = wp.get_device(device)
        parts = [(0, dims[0])] if dev.is_cuda else row_bands(dims[0], bands or cpu_threads())
        _load([kernel.module], dev)  # (once, before the bands' threads race to)
        self.launches = [
            wp.launch(kernel=kernel, dim=(stop - start, *dims[1:]), inputs=[start, *inputs],
                      outputs=list(outputs), device=dev, record_cmd=True)
            for start, stop in parts
        ]

    @property
    def single(self) -> bool:
        return len(self.launches) == 1

    def __call__(self) -> None:
        if self.single:
            self.launches[0].launch()
            return
        pool = thread_pool()
        for f in [pool.submit(launch.launch) for launch in self.launches]:
            f.result()


class CapturedLoop:
    """Steps (callables that launch kernels, e.g. :class:`RecordedRows`) run ``n`` times
    in order. On CUDA, where every step is a single launch, the sequence is captured once
    as a graph (``wp.ScopedCapture``) and replayed with ``wp.capture_launch``; otherwise
    the steps are called in turn.

    Not on the CPU: there a capture records every launch and copy of the process, from
    any thread (Warp's CPU capture is process-wide), so estimates in two threads crashed
    or mixed their maps (a helper, forty-ninth session: segmentation faults, δ1 off by
    3.8 px), and a Ctrl-C inside Warp's ``capture_begin`` left it open for every later
    call. Nor did it pay: the steps called in turn took 0.92–0.97 of the time
    (:data:`CPU_CAPTURE` measurements). On CUDA a loop is captured only where no other
    thread of the process (beyond lfsf's launch pool) could launch meanwhile, with
    Ctrl-C held back, and a capture that fails is closed."""

    def __init__(self, steps: Sequence[Callable[[], None]], device: str | None = None):
        self.steps = list(steps)
        self.device = device
        self.graph = None
        self._tried = (not all(getattr(step, "single", False) for step in self.steps)
                       or (is_cpu(warp().get_device(device)) and not CPU_CAPTURE))

    def _capture(self) -> None:
        self._tried = True
        if not _alone():  # (another thread's launches would go into the graph, or break it)
            return
        from lfsf._files import interrupts_held

        wp = warp()
        with interrupts_held():  # (a Ctrl-C inside capture_begin had left the capture open)
            try:
                # the steps' modules are loaded (RecordedRows); loading every module first,
                # the default, would compile all of lfsf's kernels for the device
                with wp.ScopedCapture(device=self.device, force_module_load=False) as capture:
                    for step in self.steps:
                        step()
                self.graph = capture.graph
            except Exception:  # capture unsupported here: replay the steps one by one
                self.graph = None
                with contextlib.suppress(Exception):  # (closed, where the failure left it open)
                    if wp.get_device(self.device).is_capturing:
                        wp.capture_end(device=self.device)

    def run(self, n: int) -> None:
        if n <= 0:
            return
        if not self._tried:
            self._capture()  # the capture records without running
        wp = warp()
        for _ in range(n):
            if self.graph is not None:
                wp.capture_launch(self.graph)
            else:
                for step in self.steps:
                    step()


#: Paired medians of the estimator's time with the CPU loops called in turn over the time
#: with them captured as graphs (forty-ninth session, this 2-core CPU, `paper`'s scene,
#: alternating runs in one process): 160×120 `paper` 0.971, `fast` 0.956; 320×240
#: `paper` 0.929; 640×480 `paper` 0.941, `flow` 0.915. The CPU no longer captures.
CPU_CAPTURE = False


def _alone() -> bool:
    """Whether the calling thread is the only one of the process that could launch
    kernels now: every other live thread is one of lfsf's launch pool (``lfsf-band``),
    which only runs the caller's bands."""
    me = threading.current_thread()
    return all(t is me or t.name.startswith("lfsf-band") or not t.is_alive() for t in threading.enumerate())


#: Images of fewer pixels than this are better launched in one piece on the CPU, without
#: the thread pool: an iteration (3 launches) on a 20×15 level took 0.97 ms in bands and
#: 0.12 ms in one piece.
SMALL_IMAGE = 1 << 14


def is_cpu(device) -> bool:
    """Whether ``device`` (a name such as ``cpu`` or ``cuda:0``, or a Warp device) is the
    CPU: the kernels that take groups of pixels in vector registers, or walk whole rows
    per thread, run there; CUDA takes a thread per pixel."""
    return str(device).startswith("cpu")


def row_span(device: str, width: int) -> tuple[int, int]:
    """(span, threads per row) for kernels that walk ``span`` pixels of a row per thread:
    the whole row on the CPU, where one thread per pixel costs more than a light stencil
    (ROF: 2.5× slower measured), one pixel on CUDA."""
    span = max(1, int(width)) if is_cpu(device) else 1
    return span, -(-int(width) // span)


def row_bands(rows: int, bands: int) -> list[tuple[int, int]]:
    """Split ``range(rows)`` into at most ``bands`` contiguous, near-equal ``(start, stop)``."""
    bands = max(1, min(bands, rows))
    edges = [rows * i // bands for i in range(bands + 1)]
    return [(a, b) for a, b in zip(edges[:-1], edges[1:]) if b > a]


_overloads: dict = {}


def _type_key(value):
    dtype = getattr(value, "dtype", None)
    return (type(value), dtype, getattr(value, "ndim", None)) if dtype is not None else type(value)


def resolved_kernel(kernel, args: Sequence):
    """``kernel``'s overload for the types of ``args`` (its inputs then outputs), found
    once per kernel and types and then looked up: a launch of a generic kernel (arrays of
    ``dtype=Any``, lfsf.kernels.common.overload_unknowns) otherwise infers the types and
    builds the overload's signature every time, 64 µs of Python against 27 µs for the
    launch of its overload (CPU, 8×8 pixels); a run at 640×480 makes about 1,300
    launches. A kernel that is not generic is returned as it is; so is a generic one
    where this Warp has no type inference to ask (the launch then infers)."""
    if not getattr(kernel, "is_generic", False):
        return kernel
    key = (kernel, tuple(_type_key(a) for a in args))
    found = _overloads.get(key)
    if found is None:
        try:
            found = kernel.add_overload(kernel.infer_argument_types(list(args)))
        except (AttributeError, TypeError):  # (another Warp's API: let wp.launch infer)
            found = kernel
        _overloads[key] = found
    return found


def launch_rows(
    kernel,
    dim: int | Sequence[int],
    inputs: Sequence = (),
    outputs: Sequence = (),
    device: str | None = None,
    bands: int | None = None,
) -> None:
    """Launch ``kernel`` over ``dim``, in row bands on the CPU.

    The kernel's first parameter must be ``row0: int``, the first row (index along
    ``dim[0]``) of the band it is launched on; it adds ``row0`` to its first thread index.
    ``inputs`` are the remaining inputs. On CUDA (or with one band) this is one launch with
    ``row0 = 0``; on the CPU the rows are split into ``bands`` bands (default: one per
    thread of :func:`cpu_threads`) launched concurrently, and the call returns when all are
    done. Results are identical to a single launch: each thread's work depends only on its
    own index.
    """
    wp = warp()
    dims = (dim,) if isinstance(dim, int) else tuple(dim)
    dev = wp.get_device(device)
    kernel = resolved_kernel(kernel, [0, *inputs, *outputs])
    if dev.is_cuda:
        wp.launch(kernel=kernel, dim=dims, inputs=[0, *inputs], outputs=list(outputs), device=dev)
        return
    parts = row_bands(dims[0], bands or cpu_threads())
    if len(parts) <= 1:
        wp.launch(kernel=kernel, dim=dims, inputs=[0, *inputs], outputs=list(outputs), device=dev)
        return
    _load([kernel.module], dev)  # (once, before the bands' threads race to)
    pool = thread_pool()
    futures = [
        pool.submit(
            wp.launch,
            kernel=kernel,
            dim=(stop - start, *dims[1:]),
            inputs=[start, *inputs],
            outputs=list(outputs),
            device=dev,
        )
        for start, stop in parts
    ]
    for f in futures:
        f.result()
