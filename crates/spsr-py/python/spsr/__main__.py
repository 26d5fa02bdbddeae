"""``python -m spsr``: the command line."""

from ._cli import main

main()
