"""Maps the project's top-level folders into one import name, `sonarmap`.

The folders stay where the project's layout puts them (pipeline/, stages/, schemas/,
sim/, configs/); installed, they are `sonarmap.pipeline`, `sonarmap.stages`, ... and
nothing else lands at the top of site-packages. Everything else is in pyproject.toml.
"""

from setuptools import find_packages, setup

FOLDERS = ("pipeline", "stages", "schemas", "sim", "configs")

setup(
    packages=[
        f"sonarmap.{name}"
        for name in find_packages(include=[f"{folder}*" for folder in FOLDERS])
    ],
    package_dir={f"sonarmap.{folder}": folder for folder in FOLDERS},
)
