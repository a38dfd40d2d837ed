"""`python -m jmlgdsl` is the `jmlgdsl` command."""

import sys

from .cli import main

sys.exit(main())
