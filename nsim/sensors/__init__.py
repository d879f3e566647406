"""The robot's sensors: rigs (YAML, URDF links), cameras, depth cameras and spinning LiDARs.

    from nsim.sensors import Rig
    rig = Rig.load("nsim/configs/robots/spot.yaml")
    for sensor in rig:
        origins, dirs = sensor.rays(body_to_world)   # (N, 3) each, row-major over sensor.ray_shape
"""

from nsim.sensors.depth_model import DepthConfig, apply_depth_model, range_to_z_depth, z_depth_to_range
from nsim.sensors.lidar import LidarConfig, beam_azimuths_rad, beam_directions, beam_elevations_deg
from nsim.sensors.rig import (
    CameraSensor,
    LidarSensor,
    OrganizedScan,
    Rig,
    Sensor,
    load_rig,
    static_transforms,
)
from nsim.sensors.urdf import Urdf, load_urdf, rpy_to_matrix

__all__ = [
    "CameraSensor",
    "DepthConfig",
    "LidarConfig",
    "LidarSensor",
    "OrganizedScan",
    "Rig",
    "Sensor",
    "Urdf",
    "apply_depth_model",
    "beam_azimuths_rad",
    "beam_directions",
    "beam_elevations_deg",
    "load_rig",
    "load_urdf",
    "range_to_z_depth",
    "rpy_to_matrix",
    "static_transforms",
    "z_depth_to_range",
]
