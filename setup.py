"""Ship the top-level ``assets/`` and ``envs/`` folders inside the wheel as ``simn_sim/_data``.

The repository layout keeps data beside the code (``assets/``, ``envs/``); an installed package
must still find them, so the build copies them into the package. ``simn_sim.paths`` looks in
``simn_sim/_data`` first and falls back to the repository root (editable installs).
"""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).parent.resolve()


class BuildPyWithData(build_py):
    def run(self):
        super().run()
        target = Path(self.build_lib) / "simn_sim" / "_data"
        for name in ("assets", "envs"):
            src = ROOT / name
            dst = target / name
            if dst.exists():
                shutil.rmtree(dst)
            shutil.copytree(src, dst, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))


setup(cmdclass={"build_py": BuildPyWithData})
