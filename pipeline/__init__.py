"""The sonarmap engine: config, keys, artifact store, runner, readers/writers, CLI."""

import logging

__version__ = "0.1.0"
logging.getLogger(__name__).addHandler(logging.NullHandler())
