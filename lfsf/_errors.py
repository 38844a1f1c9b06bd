"""What counts as bad input, in one place."""

#: The exceptions that mean bad input (a missing, unreadable or malformed file, a wrong
#: setting, an output path that cannot be written: a file where a folder should be, a
#: name too long, no permission): the CLI reports them in one line with exit status 2,
#: and a batch reports them as a failed pair's reason, both without a traceback. Every
#: OSError names its file (``[Errno 36] File name too long: '…'``).
BAD_INPUT_ERRORS = (ValueError, OSError)
