"""One LiDAR beam pattern: the rig, the oracle's ground truth and the renderer scan the same beams."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nsim.geometry.transforms import make_se3
from nsim.sensors.lidar import BeamPattern, LidarConfig, beam_directions, beams_and_config
from nsim.sensors.rig import LidarSensor, LidarSpec, Rig

ROBOTS = Path(__file__).resolve().parents[2] / "nsim" / "configs" / "robots"
UNEVEN_DEG = (-25.0, -10.0, -3.0, 0.0, 2.0, 15.0)
AZIMUTHS = 36


def _old_directions(elevations_deg: np.ndarray, azimuth_samples: int) -> np.ndarray:
    """The formula as ``beam_directions`` wrote it before the beam pattern (and the rig's uneven twin)."""
    phi = np.radians(90.0 - elevations_deg)[:, None]
    theta = (2.0 * np.pi * np.arange(azimuth_samples, dtype=np.float64) / azimuth_samples)[None, :]
    sin_phi = np.sin(phi)
    return np.stack(np.broadcast_arrays(np.cos(theta) * sin_phi, np.sin(theta) * sin_phi, np.cos(phi)), axis=-1)


def _uneven_rig(mount_z_m: float = 0.0, **lidar) -> LidarSensor:
    shuffled = [UNEVEN_DEG[i] for i in (4, 0, 5, 2, 3, 1)]  # any order in the file
    block = {"vertical_angles_deg": shuffled, "azimuth_samples": AZIMUTHS, "min_range_m": 0.0, **lidar}
    data = {"sensors": [{"name": "top", "type": "lidar", "mount": {"xyz_m": [0.0, 0.0, mount_z_m]}, "lidar": block}]}
    return Rig.from_data(data)["top"]


def test_default_pattern_is_unchanged():
    """Bit for bit the old formula: the paper's 16 x 1800 sensor, a LidarConfig and Spot's rig LiDAR."""
    old = _old_directions(np.linspace(-15.0, 15.0, 16, dtype=np.float64), 1800)
    cfg = LidarConfig()
    assert cfg.beams.shape == (16, 1800)
    np.testing.assert_array_equal(cfg.beams.directions(), old)
    np.testing.assert_array_equal(beam_directions(cfg), old)
    spot = Rig.load(ROBOTS / "spot.yaml")["lidar"]
    assert spot.evenly_spaced and spot.beams == cfg.beams
    np.testing.assert_array_equal(spot.dirs_sensor, old)
    odd = LidarConfig(channels=5, vertical_fov_deg=(-20.0, 10.0), azimuth_samples=12)
    np.testing.assert_array_equal(odd.beams.directions(), _old_directions(np.linspace(-20.0, 10.0, 5), 12))


def test_explicit_elevations_in_the_rig():
    s = _uneven_rig()
    assert s.beams == BeamPattern(UNEVEN_DEG, AZIMUTHS) and not s.evenly_spaced
    assert s.ray_shape == (6, AZIMUTHS) and s.config.channels == 6 and s.config.vertical_fov_deg == (-25.0, 15.0)
    np.testing.assert_array_equal(s.dirs_sensor, _old_directions(np.array(UNEVEN_DEG), AZIMUTHS))
    beams, cfg = beams_and_config(s)
    assert beams is s.beams and cfg is s.config
    assert beams_and_config(s.config)[0] != s.beams  # the config alone spreads its beams evenly: not this sensor


def test_resolved_rig_is_unchanged():
    """``Rig.to_dict`` (``rig.json``, part of the render stage's cache key) keeps its keys and values, so
    render ids stay; an uneven rig comes back from it with its beams."""
    d = Rig.load(ROBOTS / "spot.yaml").to_dict()["sensors"][5]
    assert set(d) == {"name", "type", "sensor_to_body", "lidar", "elevations_deg", "dropout_prob"}
    assert d["lidar"] == {"channels": 16, "vertical_fov_deg": [-15.0, 15.0], "azimuth_samples": 1800,
                          "min_range_m": 0.3, "max_range_m": 100.0, "range_noise_std_m": 0.0}
    assert d["elevations_deg"] == np.linspace(-15.0, 15.0, 16).tolist() and d["dropout_prob"] == 0.0
    s = _uneven_rig(dropout_prob=0.1)
    data = {"name": "u", "sensors": [{"name": "top", "type": "lidar", "sensor_to_body": np.eye(4).tolist(),
                                      "lidar": {"channels": 6, "vertical_fov_deg": [-25.0, 15.0], "azimuth_samples": AZIMUTHS,
                                                "min_range_m": 0.0, "max_range_m": 100.0, "range_noise_std_m": 0.0},
                                      "elevations_deg": list(UNEVEN_DEG), "dropout_prob": 0.1}]}
    assert Rig(name="u", sensors=(s,)).to_dict() == data
    back = Rig.from_resolved(data)["top"]
    assert back.beams == s.beams and back.config == s.config and back.dropout_prob == 0.1


def test_oracle_ground_truth_uses_the_rigs_elevations():
    """The oracle's returns sit at the rig's explicit elevations, ring by ring (the scan a render is scored on)."""
    from nsim.synth.oracle import RoomOracle
    from tests.synth.simple_room import simple_spec

    s = _uneven_rig(mount_z_m=0.25)
    body_to_world = make_se3(np.eye(3), np.array([4.0, 2.0, 0.35]))  # the LiDAR 0.6 m up, 2 m from three walls
    scan = RoomOracle(simple_spec()).lidar_gt(s.world_pose(body_to_world), s)
    assert scan.ranges_m.shape == (6, AZIMUTHS)
    assert np.isfinite(scan.ranges_m).all()  # a closed room: every beam returns
    p = scan.points_lidar_m.astype(np.float64)
    elevation = np.degrees(np.arcsin(p[..., 2] / np.linalg.norm(p, axis=-1)))
    np.testing.assert_allclose(elevation, np.broadcast_to(np.array(UNEVEN_DEG)[:, None], (6, AZIMUTHS)), atol=1e-3)
    floor = scan.ranges_m[0]  # -25 deg from 0.6 m up: the floor all around, 1.29 m out, 0.6 / sin(25 deg) away
    np.testing.assert_allclose(floor, 0.6 / np.sin(np.radians(25.0)), rtol=1e-5)
    assert np.all(scan.surface_id[0] == 0)


def _hollow_room():
    """A toy NeRF: dense everywhere outside the box [0.5, 3.5] x [0.5, 2.5] x [0.2, 1.8] (its walls)."""
    torch = pytest.importorskip("torch")
    from tests.rendering.reference import BoxField, ToyModel

    lo, hi = np.array([0.5, 0.5, 0.2]), np.array([3.5, 2.5, 1.8])
    model = ToyModel(BoxField(lo.tolist(), hi.tolist(), sigma_in=0.0, sigma_out=400.0), [[0.0, 0.0, 0.0], [4.0, 3.0, 2.0]])
    return torch, model, lo, hi


def test_renderer_rays_are_the_patterns():
    from nsim.rendering.renderer import MarchConfig, lidar_rays, render_lidar

    torch, model, lo, hi = _hollow_room()
    s = _uneven_rig()
    yaw = np.radians(30.0)
    rot = np.array([[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
    pose = s.world_pose(make_se3(rot, np.array([2.0, 1.5, 1.0])))
    rays, shape = lidar_rays(model, pose, s)
    assert shape == (6, AZIMUTHS)
    want = s.beams.directions().reshape(-1, 3) @ pose[:3, :3].T
    np.testing.assert_allclose(rays.dirs.numpy(), want, atol=1e-6)
    np.testing.assert_allclose(rays.origins.numpy(), np.broadcast_to(pose[:3, 3], want.shape), atol=1e-6)

    with torch.no_grad():
        ranges = render_lidar(model, pose, s, method="march", march_cfg=MarchConfig(step_m=0.01))
    assert ranges.shape == (6, AZIMUTHS) and np.isfinite(ranges).all()
    o = pose[:3, 3]
    with np.errstate(divide="ignore"):  # where each beam leaves the empty box: the walls along these beams
        exit_t = np.where(want > 0, (hi - o) / want, np.where(want < 0, (lo - o) / want, np.inf)).min(axis=1)
    np.testing.assert_allclose(ranges.reshape(-1), exit_t, atol=0.02)


def test_lidar_spec_is_built_on_lidar_config():
    """One set of defaults: the rig block extends LidarConfig; an empty block is the default sensor."""
    assert issubclass(LidarSpec, LidarConfig)
    assert LidarSpec().config() == LidarConfig()
    s = Rig.from_data({"sensors": [{"name": "l", "type": "lidar", "mount": {}, "lidar": {}}]})["l"]
    assert s.config == LidarConfig() and s.evenly_spaced and s.dropout_prob == 0.0
    spec = LidarSpec(vertical_angles_deg=(5.0, -5.0), azimuth_samples=4)
    assert spec.channels == 2 and spec.vertical_fov_deg == (-5.0, 5.0) and spec.beams == BeamPattern((-5.0, 5.0), 4)
    assert spec.config() == LidarConfig(channels=2, vertical_fov_deg=(-5.0, 5.0), azimuth_samples=4)


@pytest.mark.parametrize(
    ("make", "fragment"),
    [
        (lambda: BeamPattern((), 4), "at least one beam"),
        (lambda: BeamPattern((1.0, 0.0), 4), "ascending"),
        (lambda: BeamPattern((0.0, 91.0), 4), "within [-90, 90]"),
        (lambda: BeamPattern((0.0,), 0), "azimuth_samples"),
        (lambda: BeamPattern.from_angles([3.0, 1.0, 3.0], 4), "distinct"),
        (lambda: LidarSpec(vertical_angles_deg=(1.0, 2.0), channels=3), "3 channels but 2 vertical_angles_deg"),
        (lambda: LidarSensor("l", np.eye(4), LidarConfig(), np.linspace(-10.0, 10.0, 16)), "16 channels over [-15.0, 15.0]"),
        (lambda: LidarSensor("l", np.eye(4), LidarConfig(channels=4), np.linspace(-15.0, 15.0, 16)), "4 channels"),
    ],
)
def test_inconsistent_beams_are_refused(make, fragment):
    with pytest.raises(ValueError) as info:
        make()
    assert fragment in str(info.value) and "\n" not in str(info.value)


def test_sensor_keeps_the_callers_array_writable():
    el = np.linspace(-15.0, 15.0, 16)
    s = LidarSensor("l", np.eye(4), LidarConfig(), el)
    assert el.flags.writeable and not s.elevations_deg.flags.writeable
