"""``python -m avll``: the ``avll`` command."""

import sys

from .cli import main

sys.exit(main())
