"""`python -m tiplog`, the same as the `tiplog` command."""

import sys

from tiplog.cli import main

sys.exit(main())
