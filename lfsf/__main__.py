"""``python -m lfsf`` is the ``lfsf`` command."""

from lfsf.cli import entry

entry()
