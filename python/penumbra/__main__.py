"""``python -m penumbra``: the ``penumbra`` command (penumbra.cli)."""

import sys

from .cli import main

sys.exit(main())
