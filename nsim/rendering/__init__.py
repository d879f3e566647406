"""Samplers, occupancy grids, the scene model, baked surfaces and the rendering API.

Rays, samples, volume quadrature and compositing live one layer below, in ``nsim.volume``.

For later stages::

    from nsim.rendering import load_model, OccupancyGrid, render_camera, render_lidar
    model = load_model(scene_dir, device)
    grid = OccupancyGrid.load(scene_dir / "occupancy_grid.npy", device)
    view = render_camera(model, camera, cam_to_world, method="march", grid=grid, return_samples=True)
"""

import importlib

# name -> submodule; imported on first use, so that torch-free parts (engine, culling) stay light
_EXPORTS = {
    "SamplerConfig": "model", "SceneModel": "model", "load_model": "model", "save_model": "model",
    "ObstacleMap": "occupancy", "OccupancyGrid": "occupancy", "obstacle_map": "occupancy",
    "MarchConfig": "renderer", "RenderedView": "renderer", "camera_rays": "renderer", "march": "renderer",
    "render_camera": "renderer", "render_lidar": "renderer", "render_rays": "renderer",
}


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"nsim.rendering.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'nsim.rendering' has no attribute {name!r}")


__all__ = [
    "MarchConfig",
    "ObstacleMap",
    "OccupancyGrid",
    "RenderedView",
    "SamplerConfig",
    "SceneModel",
    "camera_rays",
    "load_model",
    "march",
    "obstacle_map",
    "render_camera",
    "render_lidar",
    "render_rays",
    "save_model",
]
