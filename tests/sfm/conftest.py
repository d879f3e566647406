"""Shared SfM fixtures: the box room rendered once per session, and one reconstruction of it."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from nsim.geometry.cameras import Camera
from nsim.sfm.colmap import SfmResult, run_sfm
from nsim.sfm.options import SfmOptions
from tests.sfm.scene import handheld_loop, render_sequence

N_VIEWS = 30
WIDTH, HEIGHT = 160, 120
HFOV_DEG = 75.0


@dataclass(frozen=True)
class Capture:
    image_dir: Path
    names: list[str]
    camera: Camera
    cam_to_world: np.ndarray  # (N, 4, 4) ground truth, OpenCV axes, metres, z up

    def gt(self, names: list[str]) -> np.ndarray:
        return self.cam_to_world[[self.names.index(n) for n in names]]


@pytest.fixture(scope="session")
def pinhole_capture(tmp_path_factory) -> Capture:
    d = tmp_path_factory.mktemp("box_room_pinhole")
    camera = Camera.pinhole_from_fov(WIDTH, HEIGHT, HFOV_DEG)
    poses = handheld_loop(N_VIEWS)
    names = render_sequence(d, camera, poses)
    return Capture(d, names, camera, poses)


@pytest.fixture(scope="session")
def pinhole_sfm_dir(tmp_path_factory) -> Path:
    """The work folder of ``pinhole_sfm`` (its COLMAP database.db stays there)."""
    return tmp_path_factory.mktemp("sfm_pinhole")


@pytest.fixture(scope="session")
def pinhole_sfm(pinhole_capture, pinhole_sfm_dir) -> SfmResult:
    """SIMPLE_RADIAL, unknown intrinsics, sequential matching with loop detection."""
    return run_sfm(pinhole_capture.image_dir, pinhole_sfm_dir, SfmOptions())


@pytest.fixture(scope="session")
def fisheye_capture(tmp_path_factory) -> Capture:
    d = tmp_path_factory.mktemp("box_room_fisheye")
    camera = Camera.fisheye_spot_like(WIDTH, HEIGHT)
    poses = handheld_loop(N_VIEWS)
    names = render_sequence(d, camera, poses)
    return Capture(d, names, camera, poses)
