"""What counts as bad input, in one place."""

#: The exceptions that mean bad input (a missing, unreadable or malformed file, a wrong
#: setting): the CLI reports them in one line with exit status 2, and a batch reports them
#: as a failed pair's reason, both without a traceback.
BAD_INPUT_ERRORS = (ValueError, FileNotFoundError, IsADirectoryError, NotADirectoryError, PermissionError)
