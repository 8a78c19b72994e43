"""``python -m facecorr.cli``: the same as the ``facecorr`` command."""

import sys

from . import main

sys.exit(main())
