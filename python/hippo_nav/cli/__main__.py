"""`python -m hippo_nav.cli`: the `hippo-nav` command."""

import sys

from hippo_nav.cli import main

sys.exit(main())
