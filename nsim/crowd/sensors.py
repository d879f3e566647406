"""Rendered sensor frames for a robot controller: the scenario's ``robot.sensors`` through the scene model.

A scenario on a scene checkpoint (``scene: {checkpoint: REF}``) may give its controller rendered
frames::

    robot:
      sensors: {rate_hz: 2, rig: spot, names: [frontleft, lidar], image_scale: 0.25}

``rig`` is a rig preset (``nsim/configs/robots/<name>.yaml``; default ``spot``), a rig file relative to the
scenario file, or (in the canonical scenario, where ``resolve_rig`` puts it) the resolved rig
itself (``nsim.sensors.rig.Rig.to_dict``), so the stored scenario needs no file and its digest (the
simulate stage's action key) changes with any mount, intrinsics or LiDAR pattern. ``names``: the
rig's sensors a controller may ask for; ``image_scale`` / ``lidar_azimuth_scale``: as ``nsim render``
scales them (``nsim.rendering.render_plan.adapt_rig``).

:class:`SceneSensors` loads the scene model and its occupancy grid once and renders one sensor at a
body-to-world pose with ``nsim.rendering.renderer.render_camera`` / ``render_lidar`` and the render
stage's settings (``nsim.rendering.render_plan.RenderConfig``, the render stage's ``Config``: method, marching step, chunk, depth estimate,
minimum accumulation). The frames are the scene **without people** (compositing the run's people
is ``nsim render``'s job) and without sensor noise:

camera  ``{"rgb": (H, W, 3) float32 in [0, 1]}`` (``(H, W)`` for a grey camera, the rig's exposure
        applied), plus ``"depth": (H, W) float32`` when the camera has a depth output;
depth   ``{"depth": (H, W) float32}``: the rig's depth kind (z-depth along the optical axis unless it
        says range), metres, quantised and gated as the rig says; inf = no return, NaN = invalid;
lidar   ``{"ranges": (channels, azimuth_samples) float32}``: metres along each beam, inf = no return
        or outside ``[min_range_m, max_range_m]``.

No-return pixels are rendered as the model renders them (``nsim render --set fill=none``).
"""

from __future__ import annotations

import dataclasses
import json
import re
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from nsim.errors import InputError

DEFAULT_RIG = "spot"


@dataclasses.dataclass(frozen=True)
class SensorsSpec:
    """A scenario's ``robot.sensors`` (canonical): ``rig`` the resolved rig data; ``sensors`` the names
    offered (the field names ``render_plan.adapt_rig`` reads)."""

    rate_hz: float
    rig: Mapping[str, Any]
    sensors: tuple[str, ...]
    image_scale: float = 1.0
    lidar_azimuth_scale: float = 1.0

    @classmethod
    def from_data(cls, d: Mapping[str, Any]) -> SensorsSpec:
        return cls(float(d["rate_hz"]), d["rig"], tuple(d["names"]), float(d.get("image_scale", 1.0)),
                   float(d.get("lidar_azimuth_scale", 1.0)))

    def rig_object(self):
        """The rig restricted to ``sensors`` and scaled (``nsim.rendering.render_plan.adapt_rig``)."""
        from nsim.rendering.render_plan import adapt_rig
        from nsim.sensors.rig import Rig

        return adapt_rig(Rig.from_resolved(self.rig), self)


def resolve_rig(value: Any, base_dir: Path | None, fail: Callable[[str], InputError]) -> dict[str, Any]:
    """``robot.sensors.rig`` as resolved rig data: a preset name, a rig file (relative to ``base_dir``) or
    already-resolved data (checked by reading it back). ``fail(message)`` builds the error naming the field."""
    from nsim.config import configs_dir
    from nsim.errors import NsimError
    from nsim.sensors.rig import Rig

    if isinstance(value, Mapping):
        try:
            rig = Rig.from_resolved(value)
        except (KeyError, TypeError, ValueError, NsimError) as exc:
            raise fail(f"not a resolved rig ({exc.__class__.__name__}: {exc})") from None
    else:
        preset = configs_dir() / "robots" / f"{value}.yaml"
        if re.fullmatch(r"[A-Za-z0-9_-]+", value) and preset.is_file():
            path = preset
        elif base_dir is None:
            raise fail(f"{value!r} is not a rig preset ({', '.join(rig_presets())}); a rig file is only allowed "
                       "in a scenario file")
        else:
            path = Path(value) if Path(value).is_absolute() else base_dir / value
            if not path.is_file():
                raise fail(f"{value!r} is neither a rig preset ({', '.join(rig_presets())}) nor a file ({path})")
        try:
            rig = Rig.load(path)
        except NsimError as exc:
            raise fail(str(exc)) from None
    return json.loads(json.dumps(rig.to_dict()))


def rig_presets() -> list[str]:
    from nsim.config import configs_dir

    return sorted(p.stem for p in (configs_dir() / "robots").glob("*.yaml"))


class SceneSensors:
    """Renders the rig's sensors in a scene checkpoint (the module docstring); counts the frames.

    ``scene_dir``: the scene-checkpoint artifact's folder; ``spec``: the scenario's sensors;
    ``render_cfg``: the render stage's ``Config`` (its method, march, chunk_rays, depth_estimate,
    min_accumulation are used); ``device``: the run's (``RunContext.device``). A call is
    ``(sensor_name, body_to_world (4, 4), time_s) -> dict``; the scene is static, so time is unused.
    """

    def __init__(self, scene_dir: str | Path, spec: SensorsSpec, render_cfg, device: str = "cpu",
                 where: str = "robot.sensors") -> None:
        import torch

        from nsim.rendering.model import load_model
        from nsim.rendering.occupancy import OccupancyGrid

        scene_dir = Path(scene_dir)
        self.spec = spec
        self.cfg = render_cfg
        self.where = where
        self.rig = spec.rig_object()
        self.model = load_model(scene_dir, device=torch.device(device)).eval()
        self.grid = OccupancyGrid.load(scene_dir / "occupancy_grid.npy", device=torch.device(device))
        self.frames_rendered: dict[str, int] = {name: 0 for name in spec.sensors}

    def hook(self):
        """The ``nsim.crowd.controllers.SensorHook`` that offers these frames at the scenario's rate."""
        from nsim.crowd.controllers import SensorHook

        return SensorHook(self, self.spec.rate_hz)

    def __call__(self, name: str, body_to_world: np.ndarray, time_s: float = 0.0) -> dict[str, np.ndarray]:
        if name not in self.frames_rendered:
            raise InputError(f"{self.where}: the controller asked for sensor {name!r}, not one of names "
                             f"({', '.join(self.spec.sensors)})")
        out = self.render(name, body_to_world)
        self.frames_rendered[name] += 1
        return out

    def render(self, name: str, body_to_world: np.ndarray) -> dict[str, np.ndarray]:
        """Sensor ``name`` at ``body_to_world (4, 4)`` (body: x forward, y left, z up), as described above."""
        from nsim.rendering.renderer import render_camera, render_lidar
        from nsim.sensors.depth_model import apply_depth_model
        from nsim.sensors.rig import CameraSensor

        cfg = self.cfg
        s = self.rig[name]
        pose = s.world_pose(np.asarray(body_to_world, dtype=np.float64))
        median = cfg.depth_estimate == "median"
        if not isinstance(s, CameraSensor):
            return {"ranges": render_lidar(self.model, pose, s, cfg.method, self.grid, cfg.march, cfg.chunk_rays,
                                           cfg.min_accumulation, use_median=median)}
        view = render_camera(self.model, s.camera, pose, cfg.method, self.grid, cfg.march, cfg.chunk_rays)
        out: dict[str, np.ndarray] = {}
        if s.emits_image:
            out["rgb"] = s.expose(view.rgb)
        if s.emits_depth:
            z = view.depth_median_z if median else view.depth_z
            z = np.where(view.accumulation >= cfg.min_accumulation, z, np.where(np.isnan(z), np.nan, np.inf))
            with np.errstate(invalid="ignore", divide="ignore"):
                exact = z if s.depth.kind == "z" else z / s.dirs_sensor[..., 2]
            noiseless = dataclasses.replace(s.depth, noise_abs_std_m=0.0, noise_rel_std=0.0)
            out["depth"] = apply_depth_model(exact, noiseless)
        return out


def scene_sensors(sc, store, device: str = "cpu") -> SceneSensors | None:
    """The renderer of scenario ``sc``'s ``robot.sensors`` in its scene checkpoint (``store``: the workspace
    holding it) with ``nsim render``'s default settings (``nsim.rendering.render_plan.RenderConfig``),
    or None when the scenario has none."""
    from nsim.rendering.render_plan import RenderConfig

    spec = sc.robot.sensors
    if spec is None:
        return None
    if sc.scene_id is None:  # parse_scenario refuses sensors on any other scene
        raise InputError(f"{sc.source}: robot.sensors: rendered sensor frames need a scene checkpoint")
    return SceneSensors(store.get(sc.scene_id).path, spec, RenderConfig(), device, where=f"{sc.source}: robot.sensors")
