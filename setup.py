"""The wheel carries the repository's shipped folders (pages, checkpoints, populations, example studies, sweep
files, released replays) as package data under ``colorgrid/_data/``, where ``colorgrid.resources`` finds them.

Everything else about the package is in ``pyproject.toml``; this file only adds that copy to ``build_py``.
"""

import importlib.util
import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

_spec = importlib.util.spec_from_file_location("resources", Path(__file__).parent / "colorgrid" / "resources.py")
resources = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(resources)  # the standard library only: the folder list without importing colorgrid


class BuildWithShippedFolders(build_py):
    """``build_py``, then each shipped folder copied to ``colorgrid/_data/<folder>`` in the build (not in an
    editable install, which reads the checkout's folders in place)."""

    def run(self):
        super().run()
        if self.editable_mode:
            return
        for folder in resources.SHIPPED:
            shutil.copytree(folder, Path(self.build_lib, "colorgrid", "_data", folder), dirs_exist_ok=True,
                            ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))


setup(cmdclass={"build_py": BuildWithShippedFolders})
