"""``python -m cstorm.cli``: the ``cstorm`` command."""

import sys

from .commands import main

sys.exit(main())
