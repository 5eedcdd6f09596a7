"""``python -m bayeshyst.cli``: the ``bayeshyst`` command."""

import sys

from bayeshyst.cli import main

sys.exit(main())
