"""Rendering one shard of ``nsim render``: the scene NeRF and the run's people along each sensor's rays,
measured as the sensor measures, written file by file.

``ShardRenderer(job, cfg)`` is the factory's product for ``nsim.rendering.engine.run_shards``: it loads
the scene model, its occupancy grid, the rig (or the recorded streams' sensors) and the people
(``nsim.rendering.people.HumanSet``) once, then ``render_shard(i, out_dir)`` writes shard ``i``'s
frames into ``out_dir`` (the file layout is the artifact's, documented in
``nsim.rendering.render_output``) and a ``frames.json`` of per-frame statistics that
``nsim.rendering.render_output.assemble`` reads.

``job``: a ``nsim.rendering.render_job.ShardJob`` (``nsim.rendering.render_plan.shard_job``; plain,
picklable data): the folders of the scene checkpoint, the human checkpoints and the baked scene
(``method: baked``: the scene is rendered from it, ``nsim.rendering.baked``; the scene checkpoint
still gives the rays' range, the background and ``fill``), the rig (trajectory mode) or the recorded
streams (recording mode), the seed, the device and the frames of each shard.
``cfg``: the render's ``nsim.rendering.render_plan.RenderConfig``.

Measurement is the rig's (``nsim.sensors.rig``): ``CameraSensor.expose`` (exposure, grey),
``CameraSensor.measure_depth`` (the depth model: noise, quantisation, valid range) and
``LidarSensor.measure`` (range noise, dropout, range gate); with ``cfg.noise`` false, the same with
the noise terms set to zero. Noise draws come from a generator seeded by (seed, frame, sensor), so
the files do not depend on the shard size, the engine or the number of workers.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from nsim.rendering.people import CompositeConfig, HumanSet
from nsim.rendering.render_job import PoseFrame, RecordedFrame, RecordedStream, ShardJob, TickFrame

if TYPE_CHECKING:
    from nsim.rendering.render_plan import RenderConfig

log = logging.getLogger(__name__)

DEPTH_ATTRIBUTE = {
    "z": "z-depth: metres along the camera's optical (+z) axis; inf = no return; NaN = no valid measurement",
    "range": "range: metres along the pixel's ray; inf = no return; NaN = no valid measurement",
}


class ShardRenderer:
    """Holds the loaded models; renders one shard of frames into a directory (a Ray actor keeps one)."""

    def __init__(self, job: ShardJob, cfg: RenderConfig) -> None:
        """``job``: what to render (the module docstring); ``cfg``: the render's settings."""
        import torch

        from nsim.rendering.model import load_model
        from nsim.rendering.occupancy import OccupancyGrid

        self.job = job
        self.cfg = cfg
        self.compositing = CompositeConfig(method=cfg.method, march=cfg.march, chunk_rays=cfg.chunk_rays,
                                           culling=cfg.culling)
        self.device = torch.device(job.device)
        scene_dir = Path(job.scene_dir)
        self.model = load_model(scene_dir, device=self.device).eval()
        if self.cfg.background != "scene":
            self.model.sampler_cfg = dataclasses.replace(self.model.sampler_cfg, background=self.cfg.background)
        self.fill_rgb = None  # (3,) colour of no-return pixels (``fill``)
        if self.cfg.fill == "image_mean":
            mean = self.model.image_mean_rgb  # set by load_model; None for checkpoints written before it existed
            if mean is None:
                log.warning("%s: the scene checkpoint has no image_mean_rgb (written before nsim kept it); "
                            "no-return pixels are not filled", scene_dir)
            else:
                self.fill_rgb = torch.tensor(mean, dtype=torch.float32, device=self.device)
        self.grid = OccupancyGrid.load(scene_dir / "occupancy_grid.npy", device=self.device)
        self.baked = None  # method: baked, the baked scene (nsim.rendering.baked) the scene is rendered from
        if cfg.method == "baked":
            from nsim.rendering.baked import BakedScene

            self.baked = BakedScene.load(job.baked_dir, device=self.device)
            if self.baked.uses_field:
                self.baked = self.baked.with_field(self.model.field)
            if self.cfg.background != "scene":
                self.baked = dataclasses.replace(self.baked, background=self.cfg.background)
        self.rig = job.rig if job.rig is None or cfg.noise else _without_noise(job.rig)
        self.humans = None  # the run's people, each drawn by its checkpoint or the default look
        if job.trajectory_npz is not None and (job.human_dirs or job.person_model):
            from nsim.io.npz import read_npz
            from nsim.rendering.default_look import people_models

            arrays = read_npz(Path(job.trajectory_npz))
            models, person_model = people_models(job.human_dirs, job.person_model, arrays["height_m"], self.device)
            self.humans = HumanSet(models, arrays, self.device, person_model)
        self.streams = {}  # recording mode: stream key -> its CameraSensor (camera, depth) or None (LiDAR)
        for st in job.streams or ():
            self.streams[st.key] = _stream_sensor(st)

    # -- rays -> samples -> outputs
    def _render_rays(self, origins: np.ndarray, dirs: np.ndarray, valid: np.ndarray, near: float, far: float,
                     posed: list, camera=None, cam_to_world=None, colour: bool = True) -> dict[str, np.ndarray]:
        """Render world rays ``(N, 3)`` among the ``posed`` people (``HumanSet.joint_transforms``; [] for
        nobody): rgb (N, 3), range (N,), accumulation (N,), instance (N,). ``colour=False`` (a LiDAR): a baked
        scene renders depth and accumulation only (rgb then holds no colour)."""
        import torch

        from nsim.rendering.renderer import render_rays
        from nsim.volume.rays import make_rays

        cfg = self.cfg
        o = torch.as_tensor(np.array(origins, dtype=np.float32), device=self.device)
        d = torch.as_tensor(np.where(valid[:, None], dirs, [0.0, 0.0, 1.0]), dtype=torch.float32, device=self.device)
        sc = self.model.sampler_cfg
        rays = make_rays(o, d, max(near, sc.near_m), min(far, sc.far_m),
                         self.model.aabb if sc.clip_rays_to_box else None)
        people = (self.humans.visible(posed, o, d, camera, cam_to_world, cfg.culling, t_min=near, t_max=far,
                                      valid=valid) if self.humans and posed else [])
        if self.baked is not None:
            from nsim.rendering.baked import render_baked

            nerf = None
            if self.baked.falls_back:  # depth edges and what the bake lacks: from the NeRF itself
                nerf = lambda r: render_rays(self.model, r, "proposal", self.grid, cfg.march, cfg.chunk_rays)  # noqa: E731
            out = render_baked(self.baked, rays, cfg.chunk_rays, return_samples=bool(people), colour=colour,
                               fallback=nerf, may_fall_back=torch.as_tensor(valid, device=self.device))
            if people:  # the people's samples merged with the baked scene's, as with the NeRF's
                out, instance = self.humans.composite(self.model, self.grid, rays, people, self.compositing,
                                                      scene_out=out)
            else:
                instance = np.zeros(len(o), dtype=np.uint16)
        elif not people:
            out = render_rays(self.model, rays, cfg.method, self.grid, cfg.march, cfg.chunk_rays)
            instance = np.zeros(len(o), dtype=np.uint16)
        else:
            out, instance = self.humans.composite(self.model, self.grid, rays, people, self.compositing)
        r = out.depth_median if cfg.depth_estimate == "median" else out.depth
        acc = out.accumulation
        surface = acc >= cfg.min_accumulation
        r = torch.where(surface, r, torch.tensor(float("inf"), device=r.device))
        v = torch.as_tensor(valid, device=r.device)
        rgb = out.rgb
        if self.fill_rgb is not None:  # no return: the remaining light over the training images' mean colour
            rgb = torch.where(surface[:, None], rgb, rgb + (1.0 - acc)[:, None] * (self.fill_rgb - out.background))
        rgb = torch.where(v[:, None], rgb.clamp(0.0, 1.0), 0.0)
        return {"rgb": rgb.cpu().numpy(), "range": torch.where(v, r, float("nan")).cpu().numpy(),
                "acc": acc.cpu().numpy(), "instance": np.where(valid, instance, 0).astype(np.uint16)}

    def _rng(self, frame_index: int, sensor: str) -> np.random.Generator:
        digest = hashlib.sha256(f"nsim.render:{self.job.seed}:{frame_index}:{sensor}".encode()).digest()
        return np.random.default_rng(int.from_bytes(digest[:8], "little"))

    def render_shard(self, shard: int, out_dir: Path) -> dict:
        out_dir = Path(out_dir)
        stats = []
        for frame in self.job.shards[shard]:
            if isinstance(frame, RecordedFrame):
                stats.append(self._render_recording_frame(frame, out_dir))
            elif isinstance(frame, TickFrame):
                stats.append(self._render_tick(frame, out_dir))
            else:
                stats.append(self._render_pose_frame(frame, out_dir))
        (out_dir / "frames.json").write_text(json.dumps(stats, indent=1, sort_keys=True) + "\n")
        return {"frames": len(stats)}

    def _render_tick(self, frame: TickFrame, out_dir: Path) -> dict:
        from nsim.sensors.rig import CameraSensor, LidarSensor

        body = frame.body_to_world
        i = frame.index
        row: dict[str, Any] = {"index": i}
        posed = self.humans.joint_transforms(i) if self.humans else []
        for s in self.rig.sensors:
            o, d = s.rays(body)
            valid = np.isfinite(d).all(-1)
            if isinstance(s, CameraSensor):
                res = self._render_rays(o, d, valid, 0.0, float("inf"), posed, s.camera, s.world_pose(body))
                row[s.name] = self._write_camera(out_dir, s.name, i, s, res)
            elif isinstance(s, LidarSensor):
                c = s.config
                res = self._render_rays(o, d, valid, c.min_range_m, c.max_range_m, posed, colour=False)
                row[s.name] = self._write_lidar(out_dir, s, i, res)
        return row

    def _render_pose_frame(self, frame: PoseFrame, out_dir: Path) -> dict:
        from nsim.geometry.cameras import dirs_to_world, fill_invalid_dirs

        cam = frame.camera
        c2w = frame.cam_to_world
        dirs_cam = cam.pixel_dirs_cam().reshape(-1, 3)
        filled, valid = fill_invalid_dirs(dirs_cam)
        o, d = dirs_to_world(filled, c2w)
        res = self._render_rays(o, d, valid, 0.0, float("inf"), [], cam, c2w)
        h, w = cam.height, cam.width
        i = frame.index
        from nsim.io.exr import write_depth_exr
        from nsim.io.images import to_uint8, write_image

        (out_dir / "frames" / "rgb").mkdir(parents=True, exist_ok=True)
        (out_dir / "frames" / "depth").mkdir(parents=True, exist_ok=True)
        write_image(out_dir / "frames" / "rgb" / f"{i:06d}.png", to_uint8(res["rgb"].reshape(h, w, 3)))
        z = np.where(dirs_cam[:, 2] > 1e-9, res["range"] * dirs_cam[:, 2], np.nan).reshape(h, w)
        write_depth_exr(out_dir / "frames" / "depth" / f"{i:06d}.exr", z, attributes={"nsim_depth": DEPTH_ATTRIBUTE["z"]})
        return {"index": i, "frames": {"mean_accumulation": float(np.mean(res["acc"]))}}

    def _render_recording_frame(self, frame: RecordedFrame, out_dir: Path) -> dict:
        """One frame of one recorded stream, written where the recording keeps it (module docstring)."""
        from nsim.io.exr import write_depth_exr, write_points_exr
        from nsim.io.images import to_uint8, write_image

        key, i = frame.stream, frame.index
        kind, name = key.split("/", 1)
        path = out_dir / kind / name / f"{i:06d}"
        path.parent.mkdir(parents=True, exist_ok=True)
        s = self.streams[key]
        posed = self.humans.joint_transforms_at(frame.people_time_s) if self.humans else []
        if kind == "lidar":
            from nsim.io.exr import read_points_exr
            from nsim.rendering.recording import point_directions, points_from_ranges

            rec = read_points_exr(Path(self.job.recording_dir) / kind / name / f"{i:06d}.exr")
            xyz_rec = np.stack([rec[c].reshape(-1) for c in "XYZ"], axis=-1)
            dirs, valid = point_directions(xyz_rec)
            pose = frame.sensor_to_world
            o = np.broadcast_to(pose[:3, 3], dirs.shape)
            res = self._render_rays(o, dirs @ pose[:3, :3].T, valid, 0.0, float("inf"), posed, colour=False)
            xyz = points_from_ranges(dirs, res["range"]).astype(np.float32)
            write_points_exr(path.with_suffix(".exr"), {"X": xyz[None, :, 0], "Y": xyz[None, :, 1], "Z": xyz[None, :, 2],
                                                         "range": res["range"].astype(np.float32)[None, :]})
            return {"stream": key, "index": i, "points": len(xyz), "returns": int(np.isfinite(res["range"]).sum())}
        body = frame.body_to_world
        o, d = s.rays(body)
        valid = np.isfinite(d).all(-1)
        res = self._render_rays(o, d, valid, 0.0, float("inf"), posed, s.camera, s.world_pose(body))
        h, w = s.ray_shape
        if kind == "camera":
            write_image(path.with_suffix(".png"), to_uint8(s.expose(res["rgb"].reshape(h, w, 3))))
            row = {"stream": key, "index": i, "mean_accumulation": float(np.mean(res["acc"]))}
            if self.humans is not None:
                from nsim.io.coco import write_instance_mask

                (out_dir / "mask" / name).mkdir(parents=True, exist_ok=True)
                write_instance_mask(out_dir / "mask" / name / f"{i:06d}.png", res["instance"].reshape(h, w))
                row["people_px"] = int((res["instance"] > 0).sum())
            return row
        depth = s.depth_from_range(res["range"].reshape(h, w)).astype(np.float32)  # inf stays inf, NaN stays NaN
        write_depth_exr(path.with_suffix(".exr"), depth, attributes={"nsim_depth": DEPTH_ATTRIBUTE["z"],
                                                                     "nsim_sensor": name})
        return {"stream": key, "index": i, "valid_depth_fraction": float(np.isfinite(depth).mean())}

    def _write_camera(self, out_dir: Path, name: str, i: int, s, res: dict) -> dict:
        from nsim.io.exr import write_depth_exr, write_rgb_exr
        from nsim.io.images import to_uint8, write_image
        from nsim.sensors.rig import _srgb_to_linear

        h, w = s.ray_shape
        info: dict[str, Any] = {}
        if s.emits_image:
            rgb = s.expose(res["rgb"].reshape(h, w, 3))
            (out_dir / name / "rgb").mkdir(parents=True, exist_ok=True)
            write_image(out_dir / name / "rgb" / f"{i:06d}.png", to_uint8(rgb))
            if self.cfg.rgb_exr:
                (out_dir / name / "rgb_linear").mkdir(parents=True, exist_ok=True)
                lin = _srgb_to_linear(rgb)
                if lin.ndim == 2:
                    lin = np.repeat(lin[..., None], 3, axis=-1)
                write_rgb_exr(out_dir / name / "rgb_linear" / f"{i:06d}.exr", lin)
        if s.emits_depth:
            rng = self._rng(i, name) if self.cfg.noise else None  # noise off: the rig has none (_without_noise)
            depth = s.measure_depth(np.nan_to_num(res["range"].reshape(h, w), nan=np.inf), rng)
            depth = np.where(np.isfinite(res["range"].reshape(h, w)) | np.isinf(res["range"].reshape(h, w)), depth, np.nan)
            (out_dir / name / "depth").mkdir(parents=True, exist_ok=True)
            write_depth_exr(out_dir / name / "depth" / f"{i:06d}.exr", depth.astype(np.float32),
                            attributes={"nsim_depth": DEPTH_ATTRIBUTE[s.depth.kind], "nsim_sensor": name})
            info["valid_depth_fraction"] = float(np.isfinite(depth).mean())
        if self.humans is not None:
            from nsim.io.coco import write_instance_mask

            (out_dir / name / "mask").mkdir(parents=True, exist_ok=True)
            write_instance_mask(out_dir / name / "mask" / f"{i:06d}.png", res["instance"].reshape(h, w))
            info["people_px"] = int((res["instance"] > 0).sum())
        return info

    def _write_lidar(self, out_dir: Path, s, i: int, res: dict) -> dict:
        from nsim.io.lidar_exr import write_lidar_exr, write_lidar_ply

        c, a = s.ray_shape
        exact = np.nan_to_num(res["range"].reshape(c, a), nan=np.inf)
        ranges = s.measure(exact, self._rng(i, s.name) if self.cfg.noise else None)  # noise off: the range gate only
        intensity = np.where(np.isfinite(ranges), res["acc"].reshape(c, a), 0.0).astype(np.float32)
        scan = s.scan(ranges, intensity)
        (out_dir / s.name / "scan").mkdir(parents=True, exist_ok=True)
        write_lidar_exr(out_dir / s.name / "scan" / f"{i:06d}.exr", scan, sensor=s.name, elevations_deg=s.elevations_deg)
        write_lidar_ply(out_dir / s.name / "scan" / f"{i:06d}.ply", scan)
        return {"returns": int(np.isfinite(ranges).sum())}


def _stream_sensor(stream: RecordedStream):
    """A recorded camera or depth stream as the rig's ``CameraSensor`` (its rays, grey conversion and
    z-depth are the rig's); None for a LiDAR stream (its rays are its recorded points)."""
    from nsim.sensors.depth_model import DepthConfig
    from nsim.sensors.rig import CameraSensor

    if stream.kind == "lidar":
        return None
    return CameraSensor(name=stream.name, sensor_to_body=stream.sensor_to_body, camera=stream.camera,
                        kind=stream.kind, color=stream.color,
                        depth=DepthConfig(kind="z") if stream.kind == "depth" else None)



def _without_noise(rig):
    """The rig with its noise terms zeroed (``noise: false``): depth cameras without Gaussian noise
    (quantisation and valid range stay), LiDARs without range noise and dropout (the range gate
    stays), so that ``measure_depth`` and ``measure`` need no generator."""
    from nsim.sensors.rig import CameraSensor, LidarSensor

    sensors = []
    for s in rig.sensors:
        if isinstance(s, CameraSensor) and s.depth is not None:
            s = dataclasses.replace(s, depth=dataclasses.replace(s.depth, noise_abs_std_m=0.0, noise_rel_std=0.0))
        elif isinstance(s, LidarSensor):
            s = dataclasses.replace(s, config=dataclasses.replace(s.config, range_noise_std_m=0.0), dropout_prob=0.0)
        sensors.append(s)
    return dataclasses.replace(rig, sensors=tuple(sensors))
