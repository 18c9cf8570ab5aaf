"""``python -m replay`` runs ``atikt-replay``."""

import sys

from replay.cli._main import main

sys.exit(main())
