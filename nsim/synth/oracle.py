"""Ground-truth oracle of a test room: exact images, depth, rays and LiDAR scans.

``RoomOracle(spec)`` bakes the room's textures once; every query after that is a pure
function of its arguments (no hidden state, no randomness except an explicit generator).

Cameras are duck-typed on the ``nsim.geometry.cameras.Camera`` API: ``width``, ``height``
and ``unproject(uv (..., 2)) -> unit dirs in camera axes (..., 3)`` (OpenCV pixel
convention: the centre of the top-left pixel is ``(0, 0)``). Pixels a model cannot
unproject may come back NaN; they get rgb 0 and NaN depth.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from nsim.sensors.lidar import LidarConfig, beam_directions
from nsim.synth.raycast import DEFAULT_LIGHTING, Lighting, RayHits, cast
from nsim.synth.room import RoomSpec
from nsim.synth.textures import RoomTextures, bake_room_textures


class GroundTruthView(NamedTuple):
    """One rendered view (unpacks as ``rgb, depth_z, depth_range``).

    rgb: (H, W, 3) float32 in [0, 1].
    depth_z: (H, W) float32 z-depth along the camera's +z axis, metres; NaN where undefined
        (the pixel ray points sideways or backwards, e.g. fisheye beyond 90 deg, or cannot be unprojected).
    depth_range: (H, W) float32 distance from the camera centre along the pixel ray, metres.
    """

    rgb: np.ndarray
    depth_z: np.ndarray
    depth_range: np.ndarray


@dataclass(frozen=True)
class LidarScan:
    """One LiDAR revolution as a range image (rows: channels by ascending elevation, columns: azimuth).

    ranges_m: (channels, azimuth_samples) float32; inf where there is no return (outside
        [min_range_m, max_range_m]).
    points_lidar_m: (channels, azimuth_samples, 3) float32 returns in the LiDAR frame
        (x forward, y left, z up); NaN where there is no return.
    surface_id: (channels, azimuth_samples) int64 surface hit (``nsim.synth.room`` ids); -1 for none.
    """

    ranges_m: np.ndarray
    points_lidar_m: np.ndarray
    surface_id: np.ndarray


def _check_pose(name: str, pose: np.ndarray) -> np.ndarray:
    pose = np.asarray(pose, dtype=np.float64)
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise ValueError(f"{name}: expected a finite (4, 4) pose, got shape {pose.shape}")
    R = pose[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
        raise ValueError(f"{name}: rotation block is not a rotation")
    return pose


def _rotate(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``R (3, 3) @ v`` for ``v (N, 3)``: ``(N, 3)`` (einsum: numpy's BLAS matmul is slow for 3-wide operands)."""
    return np.einsum("ij,nj->ni", R, v)


def _finite_rows(v: np.ndarray) -> np.ndarray:
    """Whether every component of the vectors ``v (..., 3)`` is finite: ``(...)`` bool."""
    return np.isfinite(v[..., 0] + v[..., 1] + v[..., 2])


def _pixel_spread_rad(dirs_cam: np.ndarray) -> np.ndarray:
    """Angular size ``(H, W)`` of each pixel from neighbouring centre rays ``(H, W, 3)`` (geometric mean of x, y)."""
    H, W = dirs_cam.shape[:2]

    def step(axis: int) -> np.ndarray:
        n = dirs_cam.shape[axis]
        if n < 2:
            return np.full((H, W), np.nan)
        diff = np.linalg.norm(np.diff(dirs_cam, axis=axis), axis=-1)
        pad = [(0, 0), (0, 0)]
        pad[axis] = (0, 1)
        diff = np.pad(diff, pad, mode="edge")
        return diff

    sx, sy = step(1), step(0)
    sx = np.where(np.isfinite(sx), sx, sy)
    sy = np.where(np.isfinite(sy), sy, sx)
    spread = np.sqrt(sx * sy)
    finite = np.isfinite(spread)
    fallback = float(np.median(spread[finite])) if finite.any() else 0.0
    return np.where(finite, spread, fallback)


class RoomOracle:
    """Exact renderer and sensor model of a ``RoomSpec``.

    ``__init__`` bakes the textures (about 0.2-0.7 s and 60-85 MB for the presets); the
    oracle is immutable afterwards, so one instance can serve any number of queries.
    """

    def __init__(self, spec: RoomSpec, lighting: Lighting = DEFAULT_LIGHTING) -> None:
        self.spec = spec
        self.lighting = lighting
        self.textures: RoomTextures = bake_room_textures(spec)

    def cast_rays(self, origins: np.ndarray, dirs: np.ndarray,
                  footprint_rad: float | np.ndarray | None = None) -> RayHits:
        """``cast`` with this room's textures and lighting: origins, unit dirs ``(N, 3)`` world."""
        return cast(self.spec, origins, dirs, self.textures, footprint_rad=footprint_rad, lighting=self.lighting)

    def render_gt(self, camera, cam_to_world: np.ndarray, supersample: int = 1) -> GroundTruthView:
        """Render ``camera`` at ``cam_to_world (4, 4)`` (OpenCV axes).

        Colour is trilinear-filtered by each ray's footprint; with ``supersample = s > 1`` it
        is also averaged over an ``s x s`` grid of sub-pixel rays (stratified centres). Depth
        always comes from the pixel-centre ray.
        """
        if isinstance(supersample, bool) or not isinstance(supersample, (int, np.integer)) or supersample < 1:
            raise ValueError(f"render_gt: supersample must be an int >= 1, got {supersample!r}")
        pose = _check_pose("render_gt: cam_to_world", cam_to_world)
        R, centre = pose[:3, :3], pose[:3, 3]
        H, W = int(camera.height), int(camera.width)
        jj, ii = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
        uv = np.stack([jj, ii], axis=-1)  # (H, W, 2)
        dirs_cam = np.asarray(camera.unproject(uv), dtype=np.float64)  # (H, W, 3)
        valid = _finite_rows(dirs_cam)
        spread = _pixel_spread_rad(dirs_cam)  # (H, W)

        def trace(d_cam: np.ndarray, spread_rad: np.ndarray, textured: bool) -> RayHits:
            ok = _finite_rows(d_cam)
            d_world = _rotate(R, np.where(ok[:, None], d_cam, [0.0, 0.0, 1.0]))
            hits = cast(self.spec, np.broadcast_to(centre, d_world.shape), d_world,
                        self.textures if textured else None, footprint_rad=spread_rad, lighting=self.lighting)
            hits.rgb[~ok] = 0.0
            hits.t[~ok] = np.nan
            return hits

        # with supersampling the centre rays only give depth: no texture lookups
        centre_hits = trace(dirs_cam.reshape(-1, 3), spread.reshape(-1), textured=supersample == 1)
        depth_range = centre_hits.t.reshape(H, W)
        z = dirs_cam[..., 2]
        depth_z = np.where(valid & (z > 1e-9), depth_range * np.where(valid, z, 0.0), np.nan)
        if supersample == 1:
            rgb = centre_hits.rgb.reshape(H, W, 3)
        else:
            s = int(supersample)
            offsets = (np.arange(s) + 0.5) / s - 0.5
            oy, ox = np.meshgrid(offsets, offsets, indexing="ij")
            sub_uv = uv[:, :, None, :] + np.stack([ox.ravel(), oy.ravel()], axis=-1)[None, None]  # (H, W, s*s, 2)
            sub_dirs = np.asarray(camera.unproject(sub_uv), dtype=np.float64).reshape(-1, 3)
            sub_spread = np.repeat(spread.reshape(-1) / s, s * s)
            sub_hits = trace(sub_dirs, sub_spread, textured=True)
            sub_ok = _finite_rows(sub_dirs).reshape(H * W, s * s).astype(np.float32)
            sub_rgb = sub_hits.rgb.reshape(H * W, s * s, 3)
            count, total = sub_ok[:, 0].copy(), sub_rgb[:, 0].copy()
            for k in range(1, s * s):  # explicit sums: numpy is slow at reducing short inner axes
                count += sub_ok[:, k]
                total += sub_rgb[:, k]
            rgb = (total / np.maximum(count, 1.0)[:, None]).reshape(H, W, 3)
        return GroundTruthView(rgb=np.ascontiguousarray(rgb, dtype=np.float32),
                               depth_z=depth_z.astype(np.float32), depth_range=depth_range.astype(np.float32))

    def lidar_gt(self, lidar_to_world: np.ndarray, lidar: LidarConfig,
                 rng: np.random.Generator | None = None) -> LidarScan:
        """Exact scan of a LiDAR at ``lidar_to_world (4, 4)`` (LiDAR frame x fwd, y left, z up).

        With ``lidar.range_noise_std_m > 0`` Gaussian noise from ``rng`` (required then) is
        added to every range before the min/max range gate; draws do not depend on the scene.
        """
        pose = _check_pose("lidar_gt: lidar_to_world", lidar_to_world)
        dirs_lidar = beam_directions(lidar)  # (C, A, 3)
        dirs_world = _rotate(pose[:3, :3], dirs_lidar.reshape(-1, 3))
        hits = cast(self.spec, np.broadcast_to(pose[:3, 3], dirs_world.shape), dirs_world, None,
                    lighting=self.lighting)
        ranges = hits.t.reshape(lidar.channels, lidar.azimuth_samples)
        if lidar.range_noise_std_m > 0.0:
            if rng is None:
                raise ValueError("lidar_gt: range_noise_std_m > 0 needs a seeded rng (np.random.Generator)")
            ranges = ranges + rng.normal(0.0, lidar.range_noise_std_m, size=ranges.shape)
        returned = np.isfinite(ranges) & (ranges >= lidar.min_range_m) & (ranges <= lidar.max_range_m)
        ranges = np.where(returned, ranges, np.inf)
        points = np.where(returned[..., None], np.where(returned, ranges, 0.0)[..., None] * dirs_lidar, np.nan)
        surface = np.where(returned, hits.surface_id.reshape(ranges.shape), -1)
        return LidarScan(ranges_m=ranges.astype(np.float32), points_lidar_m=points.astype(np.float32),
                         surface_id=surface)
