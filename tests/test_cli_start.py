"""A fast CLI: ``nsim --help``, ``nsim ls`` and commands failing on their arguments load none of the heavy
libraries (torch, scipy, pycolmap, OpenCV, Ray, matplotlib, rosbags), so they answer in well under a second.

Held by what a fresh interpreter has imported when the command returns, not by a wall-clock limit (which a busy
machine breaks)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

HEAVY = ("torch", "scipy", "pycolmap", "cv2", "ray", "matplotlib", "rosbags", "trimesh", "skimage", "OpenEXR")

SCRIPT = """
import json, sys
from nsim.cli import main
try:
    code = main(sys.argv[1:])
except SystemExit as exc:
    code = exc.code
print(json.dumps({"code": code, "heavy": [m for m in HEAVY_NAMES if m in sys.modules]}))
""".replace("HEAVY_NAMES", repr(HEAVY))


@pytest.mark.parametrize("args", [
    ["--help"],
    ["ls"],
    ["import-log", "{tmp}/nowhere"],
    ["reconstruct", "{tmp}/nowhere"],
    ["render", "--poses", "nope"],
    ["simulate", "--scenario", "{tmp}/nowhere.json"],
    ["train-scene", "nope"],
    ["train-human", "nope"],
    ["evaluate", "nope"],
    ["bake", "nope"],
    ["export", "nope"],
    ["register-log", "nope", "--poses", "nope"],
])
def test_cli_answers_without_heavy_imports(tmp_path, args):
    argv = ["--workspace", str(tmp_path / "ws"), *(a.format(tmp=tmp_path) for a in args)]
    proc = subprocess.run([sys.executable, "-c", SCRIPT, *argv], capture_output=True, text=True, timeout=600)
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["code"] == (0 if args[0] == "--help" else 2), proc.stderr  # ls: no workspace there yet
    assert result["heavy"] == [], f"nsim {' '.join(args)} imported {result['heavy']}"
