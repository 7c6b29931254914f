"""``python -m simnav.cli``."""

from simnav.cli.app import main

main()
