"""One build step on top of pyproject.toml: the wheel carries the presets.

The repository's ``configs/`` stays their one source (README, docs, tests and bench name
``configs/...``); a built wheel gets a copy of it as the package data ``nsim/_configs/``, which
``nsim.config.configs_dir()`` finds when nsim is installed without the repository. Editable installs
copy nothing: they read ``configs/`` beside the package. The sdist carries ``configs/`` (MANIFEST.in).
"""

from __future__ import annotations

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

CONFIGS = Path(__file__).resolve().parent / "configs"
PACKAGED = ("nsim", "_configs")  # nsim.config.PACKAGED_CONFIGS names the same folder


def config_files() -> list[Path]:
    """The files under ``configs/``, relative to it (no caches or hidden files)."""
    files = (p.relative_to(CONFIGS) for p in sorted(CONFIGS.rglob("*")) if p.is_file())
    return [p for p in files if not any(part.startswith(".") or part == "__pycache__" for part in p.parts)]


class build_py_with_configs(build_py):
    """``build_py``, then ``configs/`` copied to ``<build_lib>/nsim/_configs/`` (stale copies removed first)."""

    def run(self) -> None:
        super().run()
        if self.editable_mode:
            return
        if not CONFIGS.is_dir():
            raise SystemExit(f"{CONFIGS}: the presets folder is missing (an sdist built without MANIFEST.in?)")
        dest = Path(self.build_lib, *PACKAGED)
        shutil.rmtree(dest, ignore_errors=True)
        for rel in config_files():
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(CONFIGS / rel, dest / rel)

    def get_outputs(self, include_bytecode: bool = True) -> list[str]:
        outputs = list(super().get_outputs(include_bytecode))
        if not self.editable_mode and CONFIGS.is_dir():
            outputs += [str(Path(self.build_lib, *PACKAGED, rel)) for rel in config_files()]
        return outputs


setup(cmdclass={"build_py": build_py_with_configs})
