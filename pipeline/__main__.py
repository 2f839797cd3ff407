"""`python -m sonarmap.pipeline` is the same as `sonarmap`."""

from sonarmap.pipeline.cli import main

if __name__ == "__main__":  # worker processes (spawned) import this module again
    main()
