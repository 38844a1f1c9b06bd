"""What counts as bad input, in one place."""

#: The exceptions that mean bad input (a missing, unreadable or malformed file, a wrong
#: setting, an output path that cannot be written: a file where a folder should be, a
#: name too long, no permission): the CLI reports them in one line with exit status 2,
#: and a batch reports them as a failed pair's reason, both without a traceback. Every
#: OSError names its file (``[Errno 36] File name too long: '…'``).
BAD_INPUT_ERRORS = (ValueError, OSError)


def run_script(main, argv=None) -> int:
    """Run a script's ``main(argv)`` as the ``lfsf`` commands run: bad input (a
    :data:`BAD_INPUT_ERRORS`) is one line on stderr and exit status 2, Ctrl-C status 130."""
    import os
    import sys

    prog = os.path.basename(sys.argv[0]) or "script"
    try:
        return int(main(argv) or 0)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except BAD_INPUT_ERRORS as exc:
        if interrupted(exc):
            print(f"{prog}: interrupted", file=sys.stderr)
            return 130
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2


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
