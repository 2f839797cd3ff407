"""CLI commands, one module each; every module exposes `register(app)`.

Modules must keep heavy imports (torch, open3d, gtsam, mcap, pyarrow) inside the
command functions so `sonarmap --help` starts fast.
"""

COMMAND_MODULES: tuple[str, ...] = (
    "run",
    "status",
    "show",
    "store_admin",
    "config_cmd",
    "simulate",
    "topics",
    "convert",
    "train",
    "label",
    "demo",
    "sweep",
    "study",
    "share",
    "view",
    "follow",
)
"""Order in which commands appear in `sonarmap --help`."""
