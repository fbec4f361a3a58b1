"""``python -m mcverify``: the command line (``mcverify.gate.cli``)."""

import sys

from mcverify.gate.cli import main

sys.exit(main())
