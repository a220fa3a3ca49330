"""``python -m nuav2`` runs the CLI."""

from nuav2.entry import run

run()
