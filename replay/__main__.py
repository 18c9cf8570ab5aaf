"""``python -m replay`` runs ``atikt-replay``."""

import sys

from replay._cli import main

sys.exit(main())
