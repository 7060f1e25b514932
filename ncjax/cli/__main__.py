"""``python -m ncjax.cli``: the ``ncjax`` command."""

import sys

from .main import main

sys.exit(main())
