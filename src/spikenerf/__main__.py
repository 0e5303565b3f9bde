"""``python -m spikenerf`` runs the CLI."""

from spikenerf.cli import main

main()
