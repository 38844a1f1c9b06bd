"""``python -m lfsf`` is the ``lfsf`` command."""

import sys

from lfsf.cli import main

sys.exit(main())
