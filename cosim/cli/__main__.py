"""``python -m cosim.cli ...`` runs the ``cosim`` command."""

from . import main

main()
