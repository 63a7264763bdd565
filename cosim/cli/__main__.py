"""``python -m cosim.cli ...`` runs the ``cosim`` command (and names itself so in its messages)."""

from . import main

main(prog_name="cosim")
