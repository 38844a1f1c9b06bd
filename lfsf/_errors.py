"""What counts as bad input, and how a command ends on it, on memory that runs out and on
a signal, in one place."""

import argparse
import contextlib
import errno
import math
import numbers
import re
import signal
import sys
import threading


class LfsfWarning(UserWarning):
    """The category of every warning lfsf gives (``lfsf.LfsfWarning``): about its input
    (float views far outside [0, 1], views laid out otherwise, an HCI folder without its
    grid, a lenslet image without its metadata or with a clipped white image, results
    estimated on downsampled views) and about rendered ground truth beyond the
    estimator's ranges. ``warnings.filterwarnings("ignore", category=lfsf.LfsfWarning)``
    silences them, ``"error"`` makes them exceptions; the ``module`` of a filter cannot
    tell them apart, as they are raised at the caller's line. A UserWarning, so that a
    filter of those catches them too."""


def warn_at_caller(message: str, category: type[Warning] = LfsfWarning) -> None:
    """``warnings.warn`` at the line that called into lfsf: the first frame outside the
    package (a filter's ``module`` matches the user's, wherever in lfsf the warning
    arises and however many of lfsf's frames lie between)."""
    import os
    import warnings

    package = os.path.dirname(os.path.abspath(__file__)) + os.sep
    frame, level = sys._getframe(1), 2    # (level 1 is this function's)
    while frame.f_back is not None and os.path.abspath(frame.f_code.co_filename).startswith(package):
        frame, level = frame.f_back, level + 1
    warnings.warn(message, category, stacklevel=level)


class DependencyError(ImportError):
    """A package that lfsf needs is too old (Warp, :func:`lfsf.device.require_warp`): the
    message names the package, the version found and the ``pip install`` that mends it."""


class MachineError(RuntimeError):
    """Something of this machine's, not of the input, kept a run from going on (a local
    Dask cluster that did not start): the CLI reports it in one line with exit status 1,
    without a traceback."""


#: The exceptions that mean bad input (a missing, unreadable or malformed file, a wrong
#: setting, an output path that cannot be written: a file where a folder should be, a
#: name too long, no permission; and a Python without what lfsf needs, a
#: :class:`DependencyError`): the CLI reports them in one line with exit status 2,
#: and a batch reports them as a failed pair's reason, both without a traceback. Every
#: OSError names its file (``[Errno 36] File name too long: '…'``).
BAD_INPUT_ERRORS = (ValueError, OSError, DependencyError)


#: Exit status of a run that could not finish (memory ran out, the disk is full), of bad input, of an
#: interrupt (Ctrl-C), of a SIGTERM (``kill``, ``timeout``, a batch system's job limit)
#: and of a SIGHUP (the terminal or ssh session gone, without nohup): 128 + the
#: signal's number, as a shell gives.
EXIT_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 143
EXIT_HUNG_UP = 129


class Terminated(KeyboardInterrupt):
    """SIGTERM (or SIGHUP: ``signum``), raised in the main thread by the handler
    :func:`terminate_as_interrupt` sets, so that it unwinds as Ctrl-C does: temporary
    files are removed and a set of outputs is put in place whole or not at all
    (:func:`lfsf._files.interrupts_held` holds it back as it does SIGINT)."""

    def __init__(self, signum: int | None = None):
        super().__init__()
        self.signum = signum


def shown_number(value) -> str:
    """A number for a message: a whole number of more than 12 digits as about its
    magnitude, "9.99e399" (1e300 taken as an int had filled a message with 300 digits;
    past 4300 digits ``str`` raises)."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10 ** 12:
        size = abs(value)
        exponent = int(math.log10(size))
        exponent += 10 ** (exponent + 1) <= size   # (log10 rounded up or down at the ends)
        exponent -= 10 ** exponent > size
        lead = size // 10 ** (exponent - 2)   # (three digits)
        return f"{'-' if value < 0 else ''}{lead // 100}.{lead % 100:02d}e{exponent}"
    return str(value)


def whole(value) -> int | None:
    """``value`` as an int where it is a whole number (an int, NumPy's too, or a float of
    no fraction: 2.0, as :class:`lfsf.Params` takes them), else None (a bool, 2.5, text)."""
    if isinstance(value, bool):  # (an int to Python; NumPy's bool is no number at all)
        return None
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real) and math.isfinite(value) and float(value).is_integer():
        return int(value)
    return None


def ending_signals() -> tuple:
    """The signals besides SIGINT that end a command as an interrupt does: SIGTERM, and
    SIGHUP where the system has it (the session that ran the command gone: it had left
    its temporary folders behind)."""
    return (signal.SIGTERM,) + ((signal.SIGHUP,) if hasattr(signal, "SIGHUP") else ())


@contextlib.contextmanager
def terminate_as_interrupt():
    """While the body runs, SIGTERM and SIGHUP raise :class:`Terminated` (in the main
    thread; from any other thread, or where the signal is ignored, as under ``nohup``,
    nothing changes)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        raise Terminated(signum)

    old: list = []
    try:
        for s in ending_signals():
            previous = signal.getsignal(s)
            if previous not in (signal.SIG_IGN, None):  # (ignored, or a handler set from C: left as it is)
                signal.signal(s, handler)  # (inside the try: a signal right after it still restores)
                old.append((s, previous))
        yield
    finally:
        for s, previous in reversed(old):
            signal.signal(s, previous)


#: Seconds after which a signal whose exception was lost in a ``__del__`` is sent again
#: (:func:`_interrupts_redelivered`).
REDELIVERY_DELAY = 0.01


def send_again(signum: int) -> None:
    """Deliver ``signum`` (SIGINT, SIGTERM) to this process's main thread once more: as a
    real signal on POSIX, which also wakes a main thread blocked in a wait; on Windows,
    where ``os.kill`` of any signal but the console events ends the process outright
    (TerminateProcess), as Python's simulation of one (``_thread.interrupt_main``)."""
    import _thread
    import os

    if os.name == "nt":
        _thread.interrupt_main(signum)
    else:
        os.kill(os.getpid(), signum)


class _RedeliveringHook:
    """``sys.unraisablehook`` while a body runs (:func:`_interrupts_redelivered`): a
    KeyboardInterrupt that Python dropped in a ``__del__`` is sent again a moment later
    (REDELIVERY_DELAY, :func:`send_again`, from a timer thread, once the main thread has
    left the hook: ``raise_signal`` or ``_thread.interrupt_main`` here would run the
    handler at once, inside the hook, where its exception is dropped as well), kept to be
    raised as the body ends, or handed to the command's own guard; anything else goes to
    the ``previous`` hook."""

    def __init__(self, previous, raise_lost: bool) -> None:
        self.previous = previous
        self.raise_lost = raise_lost
        self.ended = False
        self.sent = 0
        self.lost: list[KeyboardInterrupt] = []
        self.timers: list[threading.Timer] = []
        self.lock = threading.Lock()

    def __call__(self, unraisable) -> None:
        exc = unraisable.exc_value
        if not isinstance(exc, KeyboardInterrupt):
            self.previous(unraisable)
            return
        signum = getattr(exc, "signum", None) or signal.SIGINT
        pythons_own = signal.getsignal(signum) is signal.default_int_handler
        inside_command_guard = isinstance(self.previous, _RedeliveringHook) and not self.previous.raise_lost
        if self.raise_lost and not pythons_own and inside_command_guard:
            self.previous(unraisable)   # (the command's handlers: its guard sends the signal again)
            return
        exc.__traceback__ = None   # (its frames, the object being finalised among them, are not kept)
        self.lost.append(exc)
        if self.raise_lost and not pythons_own:
            return                 # (a handler of the user's, or none: raised as the body ends)
        timer = threading.Timer(REDELIVERY_DELAY, self._send_again, (signum,))
        timer.daemon = True
        self.timers.append(timer)
        timer.start()

    def _send_again(self, signum: int) -> None:
        # (under the lock, which the main thread takes as the body ends: its wait is
        # interruptible, so the signal lands within the body, not in the caller's code)
        with self.lock:
            if self.ended:
                return
            self.sent += 1
            send_again(signum)

    def end(self) -> KeyboardInterrupt | None:
        """Stop sending; the last interrupt kept and not sent again, if any."""
        self.ended = True   # (before the lock: an interrupt while waiting for it leaves no timer to send)
        for timer in self.timers:
            timer.cancel()
        with self.lock:     # (a send under way holds it: its signal lands here, within the body)
            pass
        return self.lost[-1] if len(self.lost) > self.sent else None


@contextlib.contextmanager
def _interrupts_redelivered(raise_lost: bool = False):
    """While the body runs, a KeyboardInterrupt (or :class:`Terminated`) that Python
    could not raise, because its handler ran inside a ``__del__`` (a Warp array freed as
    the signal that :func:`lfsf._files.interrupts_held` held back came through), is not
    lost with "Exception ignored in …" and a traceback (status 0) (:class:`_RedeliveringHook`).
    Main thread only (``sys.unraisablehook`` is the process's).

    Parameters
    ----------
    raise_lost : bool
        False (a command's guard, :func:`run_script`): sent again; one not yet sent when
        the body ends is dropped (the command ended first, as with a signal after its
        end). True (a library call's, :func:`interrupts_kept`): sent again where the
        signal's handler is Python's own (``signal.default_int_handler``: a script, a
        notebook's cell); inside a command's guard, whose handlers are lfsf's, handed to
        that guard; else (a handler of the user's, which is not run a second time, or an
        ignored signal) raised as the body ends, as is one not yet sent.
    """
    hook = _RedeliveringHook(sys.unraisablehook, raise_lost)
    sys.unraisablehook = hook
    try:
        yield
    finally:
        sys.unraisablehook = hook.previous
        lost = hook.end()
    # (only where the body ended without an exception: one in flight goes on as it is)
    if raise_lost and lost is not None:
        raise lost


@contextlib.contextmanager
def interrupts_kept():
    """A long library call's body (:func:`lfsf.estimate_scene_flow`) with a Ctrl-C that
    Python dropped in a ``__del__`` during it raised after all
    (:func:`_interrupts_redelivered`): in a notebook or a script, one in some 75 during an
    estimate had been lost, the call running on to its end with "Exception ignored in:
    <function array.__del__ …> KeyboardInterrupt" on stderr. In another thread than the
    main one (which alone gets signals), the body runs as it is; inside an lfsf command,
    the command's guard sends the signal again. (A context, not a decorator: a wrapper's
    frame would hold the call's arguments, the light fields that the estimate frees once
    sampled.)"""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    with _interrupts_redelivered(raise_lost=True):
        yield


def quiet_interrupts_in_finalisers(unraisable) -> None:
    """A ``sys.unraisablehook`` for a command's process once its work is over: a Ctrl-C
    (or SIGTERM) whose handler ran inside a ``__del__`` of what the command left (Warp
    arrays freed after it) is dropped without the traceback Python prints for it; any
    other exception goes to Python's own hook."""
    if not isinstance(unraisable.exc_value, KeyboardInterrupt):
        sys.__unraisablehook__(unraisable)


def run_script(main, prog: str | None = None) -> int:
    """Run ``main()`` (a script's, or an ``lfsf`` command's) and return its exit status:
    bad input (a :data:`BAD_INPUT_ERRORS`) is one line ``PROG: error: …`` on stderr and
    status 2; memory that ran out, a full disk, or a :class:`MachineError`, one line and
    status 1; Ctrl-C ``PROG: interrupted`` and status 130, SIGTERM ``PROG: terminated`` and 143, SIGHUP ``PROG: hung up
    (SIGHUP)`` and 129, each after the temporary files are removed
    (:func:`terminate_as_interrupt`). ``prog`` defaults to the script's file
    name."""
    import os

    prog = prog or os.path.basename(sys.argv[0]) or "script"
    try:
        with terminate_as_interrupt(), _interrupts_redelivered():
            return int(main() or 0)
    except KeyboardInterrupt as exc:
        return _stopped(prog, exc)
    except BAD_INPUT_ERRORS as exc:
        cause = interrupted(exc)
        if cause is not None:  # e.g. numpy's savez closing its zip file in a finally
            return _stopped(prog, cause)
        if isinstance(exc, OSError) and exc.errno in _FULL:  # (not bad input: the same run goes through elsewhere)
            where = f"{exc.filename}: " if exc.filename else ""
            # (what a command writes to files is written whole or not at all; its printed output is not)
            kept = ("what was printed may be cut short" if str(exc.filename).startswith("<")
                    else "nothing was left half-written")
            print(f"{prog}: error: {where}no space left on the device ({exc.strerror}): free some, or write "
                  f"the outputs elsewhere ({kept})", file=sys.stderr)
            return EXIT_FAILED
        if isinstance(exc, OSError) and exc.errno == errno.EFBIG:  # (a limit of this machine, not bad input)
            where = f"{exc.filename}: " if exc.filename else ""
            print(f"{prog}: error: {where}file too large ({exc.strerror}): beyond the file system's or this "
                  "process's file-size limit (ulimit -f); write the outputs elsewhere (nothing was left "
                  "half-written)", file=sys.stderr)
            return EXIT_FAILED
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except MachineError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except (MemoryError, RuntimeError) as exc:
        if not out_of_memory(exc):
            raise
        print(f"{prog}: error: out of memory ({str(exc).rstrip('.') or type(exc).__name__}): free memory, or give "
              f"smaller light fields (lfsf run with the paper's setting takes about 0.9 GB at 640×480, 2.6 GB at "
              f"1280×960: 0.3 GB and 1.9 KB a pixel; --downsample 2 about a third)", file=sys.stderr)
        return EXIT_FAILED


#: The errno values of a full disk (or a quota reached): the run could not finish, status 1.
_FULL = tuple(getattr(errno, name) for name in ("ENOSPC", "EDQUOT") if hasattr(errno, name))


def out_of_memory(exc: BaseException) -> bool:
    """Whether ``exc`` says that memory ran out: numpy's (or Python's) MemoryError, or
    the RuntimeError of a Warp allocation that failed."""
    return isinstance(exc, MemoryError) or (isinstance(exc, RuntimeError)
                                            and str(exc).startswith("Failed to allocate"))


def _stopped(prog: str, exc: KeyboardInterrupt) -> int:
    if isinstance(exc, Terminated):
        if exc.signum == getattr(signal, "SIGHUP", None):
            print(f"{prog}: hung up (SIGHUP)", file=sys.stderr)
            return EXIT_HUNG_UP
        print(f"{prog}: terminated", file=sys.stderr)
        return EXIT_TERMINATED
    print(f"{prog}: interrupted", file=sys.stderr)
    return EXIT_INTERRUPTED


def interrupted(exc: BaseException) -> KeyboardInterrupt | None:
    """The KeyboardInterrupt (or :class:`Terminated`) that lies behind ``exc`` (raised
    while handling it, or in a ``finally`` that ran because of it, as numpy's savez
    closing its zip file does), or None."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


class ArgumentParser(argparse.ArgumentParser):
    """argparse, with usage errors reported like every other bad input: one line
    ``PROG: error: …`` (pointing to ``--help`` for the usage) and status 2. The ``lfsf``
    commands and the scripts parse their options with it. A value such as ``-1e-3`` or
    ``-.5`` is a negative number, not an unknown option, as from Python 3.13 on (3.11 took
    only ``-1`` and ``-0.5`` for numbers: ``--camera 100 0.1 -1e-3`` was refused)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(r"-\.?\d")  # (argparse's own, 3.13)

    def error(self, message):
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} ({self.prog} --help lists the options)\n")
