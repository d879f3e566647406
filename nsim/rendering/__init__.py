"""Rays, samplers, volume rendering, occupancy grids, the scene model and the rendering API.

For later stages::

    from nsim.rendering import load_model, OccupancyGrid, render_camera, render_lidar
    model = load_model(scene_dir, device)
    grid = OccupancyGrid.load(scene_dir / "occupancy_grid.npy", device)
    view = render_camera(model, camera, cam_to_world, method="march", grid=grid, return_samples=True)
"""

from nsim.rendering.model import (
    RaySamples,
    RenderOutput,
    SamplerConfig,
    SceneModel,
    composite,
    load_model,
    save_model,
)
from nsim.rendering.occupancy import ObstacleMap, OccupancyGrid, obstacle_map
from nsim.rendering.rays import PoseRefinement, Rays, make_rays, se3_exp
from nsim.rendering.renderer import (
    MarchConfig,
    RenderedView,
    camera_rays,
    march,
    render_camera,
    render_lidar,
    render_rays,
)

__all__ = [
    "MarchConfig",
    "ObstacleMap",
    "OccupancyGrid",
    "PoseRefinement",
    "RaySamples",
    "Rays",
    "RenderOutput",
    "RenderedView",
    "SamplerConfig",
    "SceneModel",
    "camera_rays",
    "composite",
    "load_model",
    "make_rays",
    "march",
    "obstacle_map",
    "render_camera",
    "render_lidar",
    "render_rays",
    "save_model",
    "se3_exp",
]
