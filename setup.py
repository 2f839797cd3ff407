"""Maps the project's top-level folders into one import name, `sonarmap`.

The folders stay where the project's layout puts them (pipeline/, stages/, schemas/,
sim/, configs/); installed, they are `sonarmap.pipeline`, `sonarmap.stages`, ... and
nothing else lands at the top of site-packages. Everything else is in pyproject.toml.
"""

from setuptools import find_namespace_packages, setup

FOLDERS = ("pipeline", "stages", "schemas", "sim", "configs")
# Folders that hold only data (configs/scenes/, schemas/msg/...) are listed as packages
# too: setuptools warns about every importable folder a package leaves out.
found = find_namespace_packages(
    include=[pattern for f in FOLDERS for pattern in (f, f"{f}.*")], exclude=["*.__pycache__"]
)

setup(
    packages=[f"sonarmap.{name}" for name in found],
    package_dir={f"sonarmap.{folder}": folder for folder in FOLDERS},
)
