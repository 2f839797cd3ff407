"""`python -m pipeline` is the same as `sonarmap`."""

from pipeline.cli import main

main()
