"""``python -m nuav2`` runs the CLI."""

import sys

from nuav2.cli import main

sys.exit(main())
