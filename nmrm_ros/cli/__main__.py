"""`python -m nmrm_ros.cli`: the `nmrm` command."""

from . import main

main()
