"""``python -m docs.gen``: see :mod:`docs.gen`."""

import sys

from docs.gen import main

sys.exit(main())
