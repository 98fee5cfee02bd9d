"""`python -m evstream.cli ...` = `evstream ...`."""

import sys

from . import main

sys.exit(main())
