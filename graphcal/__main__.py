"""``python -m graphcal``: the command line."""

from graphcal.cli.app import main

main()
