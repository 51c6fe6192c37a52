"""``python -m ineid.cli`` runs the ``ineid`` command."""

from ineid.cli import main

main(prog_name="ineid")
