"""A hand-checkable room for exact tests: 6 x 4 x 2.5 m, one 1 m cube at x, y in [1, 2]."""

from __future__ import annotations

from nsim.synth.room import Box, Material, RoomSpec

MAT = Material("gravel", 0.005)
CUBE = Box((1.0, 1.0, 0.0), (2.0, 2.0, 1.0), Material("coffee", 0.004), "cube")


def simple_spec(**overrides) -> RoomSpec:
    """The simple room; keyword arguments replace RoomSpec fields."""
    fields = dict(
        name="simple", seed=0, size_xyz_m=(6.0, 4.0, 2.5), surfaces=(MAT,) * 6, boxes=(CUBE,),
        posters=(), walk_loop_xy_m=(4.0, 2.0, 0.8, 0.6),
    )
    fields.update(overrides)
    return RoomSpec(**fields)
