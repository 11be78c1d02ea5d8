"""``python -m avll.cli``: the ``avll`` command."""

import sys

from . import main

sys.exit(main())
