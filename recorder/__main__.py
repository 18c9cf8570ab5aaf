"""``python -m recorder`` runs ``atikt-record``."""

import sys

from recorder._cli import main

sys.exit(main())
