"""What counts as bad input, in one place."""

import argparse

class DependencyError(ImportError):
    """A package that lfsf needs is too old (or missing): the message names the package,
    the version found and the ``pip install`` that mends it."""


#: The exceptions that mean bad input (a missing, unreadable or malformed file, a wrong
#: setting, an output path that cannot be written: a file where a folder should be, a
#: name too long, no permission; and a Python without what lfsf needs, a
#: :class:`DependencyError`): the CLI reports them in one line with exit status 2,
#: and a batch reports them as a failed pair's reason, both without a traceback. Every
#: OSError names its file (``[Errno 36] File name too long: '…'``).
BAD_INPUT_ERRORS = (ValueError, OSError, DependencyError)


#: Exit status of bad input, and of an interrupt (Ctrl-C).
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130


def run_script(main, prog: str | None = None) -> int:
    """Run ``main()`` (a script's, or an ``lfsf`` command's) and return its exit status:
    bad input (a :data:`BAD_INPUT_ERRORS`) is one line ``PROG: error: …`` on stderr and
    status 2, Ctrl-C ``PROG: interrupted`` and status 130. ``prog`` defaults to the
    script's file name."""
    import os
    import sys

    prog = prog or os.path.basename(sys.argv[0]) or "script"
    try:
        return int(main() or 0)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BAD_INPUT_ERRORS as exc:
        if interrupted(exc):  # e.g. numpy's savez closing its zip file in a finally
            print(f"{prog}: interrupted", file=sys.stderr)
            return EXIT_INTERRUPTED
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT


def interrupted(exc: BaseException) -> bool:
    """Whether a KeyboardInterrupt lies behind ``exc`` (raised while handling it, or in a
    ``finally`` that ran because of it, as numpy's savez closing its zip file does)."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


class ArgumentParser(argparse.ArgumentParser):
    """argparse, with usage errors reported like every other bad input: one line
    ``PROG: error: …`` (pointing to ``--help`` for the usage) and status 2. The ``lfsf``
    commands and the scripts parse their options with it."""

    def error(self, message):
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} ({self.prog} --help lists the options)\n")
