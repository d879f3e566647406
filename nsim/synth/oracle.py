"""Ground-truth oracle of a test room: exact images, depth, rays and LiDAR scans.

``RoomOracle(spec)`` bakes the room's textures once; every query after that is a pure
function of its arguments (no hidden state, no randomness except an explicit generator).

Cameras are duck-typed on the ``nsim.geometry.cameras.Camera`` API: ``width``, ``height``
and ``unproject(uv (..., 2)) -> unit dirs in camera axes (..., 3)`` (OpenCV pixel
convention: the centre of the top-left pixel is ``(0, 0)``). Pixels a model cannot
unproject may come back NaN; they get rgb 0 and NaN depth.

People: ``render_gt`` and ``lidar_gt`` take ``actors``, a sequence of ``PlacedActor`` (or
``(Actor, joint_transforms)`` pairs): articulated ``nsim.synth.actor.Actor`` bodies posed by
joint-to-world transforms ``(J, 4, 4)`` (``nsim.human.skeleton.forward_kinematics``). They are
ray cast exactly along the same rays as the room and the nearest surface wins, so actors
occlude the room and furniture occludes actors. Without actors (None or empty) every output
is bit-identical to the room-only rendering.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from nsim.sensors.lidar import LidarConfig, beams_and_config
from nsim.synth.actor import Actor, ActorHits, composite_actors
from nsim.synth.raycast import DEFAULT_LIGHTING, Lighting, RayHits, cast
from nsim.synth.room import RoomSpec
from nsim.synth.textures import RoomTextures, bake_room_textures

if TYPE_CHECKING:
    from nsim.sensors.rig import LidarSensor


@dataclass(frozen=True, eq=False)
class GroundTruthView:
    """One rendered view (unpacks as ``rgb, depth_z, depth_range``, like the 3-tuple it used to be).

    rgb: (H, W, 3) float32 in [0, 1].
    depth_z: (H, W) float32 z-depth along the camera's +z axis, metres; NaN where undefined
        (the pixel ray points sideways or backwards, e.g. fisheye beyond 90 deg, or cannot be unprojected).
    depth_range: (H, W) float32 distance from the camera centre along the pixel ray, metres.
    instance_mask: (H, W) int32 instance id of the actor the pixel-centre ray sees (the ray that
        gives depth), 0 for the room and for undefined pixels. Ids are ``PlacedActor.instance_id``
        (default: position in ``actors`` + 1).
    part_id: (H, W) int32 index into that actor's ``part_names`` at the pixel centre; -1 where no actor.
    soft_masks: (K, H, W) float32, one per actor in ``actors`` order: the fraction of the pixel's
        colour rays (the ``s x s`` sub-pixel grid; the centre ray when ``supersample = 1``) that
        see actor k. ``(0, H, W)`` without actors.
    room_rgb: (H, W, 3) float32, the room alone (what is behind the actors), filtered like ``rgb``;
        ``rgb`` itself without actors.
    """

    rgb: np.ndarray
    depth_z: np.ndarray
    depth_range: np.ndarray
    instance_mask: np.ndarray
    part_id: np.ndarray
    soft_masks: np.ndarray
    room_rgb: np.ndarray

    def __iter__(self) -> Iterator[np.ndarray]:
        return iter((self.rgb, self.depth_z, self.depth_range))


@dataclass(frozen=True, eq=False)
class PlacedActor:
    """An actor at one pose.

    joint_transforms: (J, 4, 4) joint-to-world transforms (``forward_kinematics`` of ``actor.skeleton``).
    instance_id: its value in ``instance_mask`` / ``LidarScan.instance_id`` (>= 1, unique in a
        query); None means its position in the ``actors`` sequence + 1.
    """

    actor: Actor
    joint_transforms: np.ndarray
    instance_id: int | None = None


@dataclass(frozen=True)
class LidarScan:
    """One LiDAR revolution as a range image (rows: channels by ascending elevation, columns: azimuth).

    ranges_m: (channels, azimuth_samples) float32; inf where there is no return (outside
        [min_range_m, max_range_m]).
    points_lidar_m: (channels, azimuth_samples, 3) float32 returns in the LiDAR frame
        (x forward, y left, z up); NaN where there is no return.
    surface_id: (channels, azimuth_samples) int64 surface hit (``nsim.synth.room`` ids); -1 for none
        and where the return comes from an actor.
    instance_id: (channels, azimuth_samples) int32 instance id of the actor a return comes from
        (see ``PlacedActor``); 0 for room returns and no return.
    """

    ranges_m: np.ndarray
    points_lidar_m: np.ndarray
    surface_id: np.ndarray
    instance_id: np.ndarray


def _check_pose(name: str, pose: np.ndarray) -> np.ndarray:
    pose = np.asarray(pose, dtype=np.float64)
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise ValueError(f"{name}: expected a finite (4, 4) pose, got shape {pose.shape}")
    R = pose[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
        raise ValueError(f"{name}: rotation block is not a rotation")
    return pose


def _placed_actors(actors, where: str) -> list[tuple[Actor, np.ndarray, int]]:
    """``actors`` (None, ``PlacedActor``s or ``(Actor, joint_transforms)`` pairs) as ``(actor, T, instance_id)``."""
    if actors is None:
        return []
    placed = []
    for k, item in enumerate(actors):
        if isinstance(item, PlacedActor):
            actor, T, iid = item.actor, item.joint_transforms, item.instance_id
        elif isinstance(item, Sequence) and len(item) == 2:
            (actor, T), iid = item, None
        else:
            raise ValueError(f"{where}: actors[{k}]: expected a PlacedActor or an (Actor, joint_transforms) pair, "
                             f"got {type(item).__name__}")
        if not isinstance(actor, Actor):
            raise ValueError(f"{where}: actors[{k}]: expected an Actor, got {type(actor).__name__}")
        T = np.asarray(T, dtype=np.float64)
        J = actor.skeleton.num_joints
        if T.shape != (J, 4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"{where}: actors[{k}].joint_transforms: expected finite ({J}, 4, 4), got {T.shape}")
        iid = k + 1 if iid is None else iid
        if isinstance(iid, bool) or not isinstance(iid, (int, np.integer)) or not 1 <= iid < 2**31:
            raise ValueError(f"{where}: actors[{k}].instance_id: expected an int in [1, 2^31), got {iid!r}")
        placed.append((actor, T, int(iid)))
    ids = [iid for _, _, iid in placed]
    if len(set(ids)) != len(ids):
        raise ValueError(f"{where}: actors: instance ids must be unique, got {ids}")
    return placed


def _near_actor(actor: Actor, T: np.ndarray, origin: np.ndarray, dirs: np.ndarray,
                margin_rad: float | np.ndarray = 0.0) -> np.ndarray:
    """Whether each ray from ``origin (3,)`` along unit ``dirs (N, 3)`` may hit the posed actor: ``(N,)`` bool.

    Conservative: the ray, or any ray within ``margin_rad`` (scalar or ``(N,)``) of it, passes
    through the bounding sphere of one of the actor's parts (``Part.bounding_sphere``).
    """
    spheres = [p.bounding_sphere() for p in actor.parts]
    centres = np.array([T[p.joint, :3, :3] @ c + T[p.joint, :3, 3] for p, (c, _) in zip(actor.parts, spheres, strict=True)])
    radii = np.array([r for _, r in spheres])
    w = centres - origin  # (P, 3)
    w_len = np.linalg.norm(w, axis=1)
    margin = np.asarray(margin_rad, dtype=np.float64)
    near = np.zeros(dirs.shape[0], dtype=bool)
    for k in range(centres.shape[0]):  # per part: (N,) work, no (N, P) temporaries
        proj = dirs @ w[k]
        slack = radii[k] + w_len[k] * margin + 1e-6
        near |= (w_len[k] ** 2 - proj * proj <= slack * slack) & (proj > -slack)
    return near


def _intersect_actor(actor: Actor, T: np.ndarray, origin: np.ndarray, dirs: np.ndarray, candidates: np.ndarray,
                     lighting: Lighting, lamp_xyz_m: np.ndarray) -> ActorHits:
    """``actor.intersect`` of rays from one ``origin (3,)`` along unit ``dirs (N, 3)``, cast only where
    ``candidates (N,)`` (a superset of the rays that can hit, e.g. from ``_near_actor``); the others miss.

    ``Actor.intersect`` is elementwise per ray, so the hits equal those of casting every ray.
    """
    n = dirs.shape[0]
    sel = np.nonzero(candidates)[0]
    t = np.full(n, np.inf)
    hit = np.zeros(n, dtype=bool)
    rgb = np.zeros((n, 3), dtype=np.float32)
    normal = np.zeros((n, 3))
    part = np.full(n, -1, dtype=np.int64)
    if sel.size:
        h = actor.intersect(np.broadcast_to(origin, (sel.size, 3)), dirs[sel], T, lighting, lamp_xyz_m)
        t[sel], hit[sel], rgb[sel], normal[sel], part[sel] = h.t, h.hit, h.rgb, h.normal, h.part_id
    return ActorHits(t=t, hit=hit, rgb=rgb, normal=normal, part_id=part)


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

    def render_gt(self, camera, cam_to_world: np.ndarray, supersample: int = 1,
                  actors: Sequence[PlacedActor | tuple[Actor, np.ndarray]] | None = None) -> GroundTruthView:
        """Render ``camera`` at ``cam_to_world (4, 4)`` (OpenCV axes), with ``actors`` in the room if given.

        Colour is trilinear-filtered by each ray's footprint; with ``supersample = s > 1`` it
        is also averaged over an ``s x s`` grid of sub-pixel rays (stratified centres). Depth,
        ``instance_mask`` and ``part_id`` always come from the pixel-centre ray; ``soft_masks``
        from the colour rays. See ``GroundTruthView``.
        """
        if isinstance(supersample, bool) or not isinstance(supersample, (int, np.integer)) or supersample < 1:
            raise ValueError(f"render_gt: supersample must be an int >= 1, got {supersample!r}")
        pose = _check_pose("render_gt: cam_to_world", cam_to_world)
        placed = _placed_actors(actors, "render_gt")
        R, centre = pose[:3, :3], pose[:3, 3]
        H, W = int(camera.height), int(camera.width)
        K = len(placed)
        jj, ii = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
        uv = np.stack([jj, ii], axis=-1)  # (H, W, 2)
        dirs_cam = np.asarray(camera.unproject(uv), dtype=np.float64)  # (H, W, 3)
        valid = _finite_rows(dirs_cam)
        spread = _pixel_spread_rad(dirs_cam)  # (H, W)

        s = int(supersample)
        sub_dirs = sub_spread = None
        if s > 1:
            offsets = (np.arange(s) + 0.5) / s - 0.5
            oy, ox = np.meshgrid(offsets, offsets, indexing="ij")
            sub_uv = uv[:, :, None, :] + np.stack([ox.ravel(), oy.ravel()], axis=-1)[None, None]  # (H, W, s*s, 2)
            sub_dirs = np.asarray(camera.unproject(sub_uv), dtype=np.float64).reshape(-1, 3)
            sub_spread = np.repeat(spread.reshape(-1) / s, s * s)

        def world(d_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            ok = _finite_rows(d_cam)
            return _rotate(R, np.where(ok[:, None], d_cam, [0.0, 0.0, 1.0])), ok

        def trace(d_world: np.ndarray, ok: np.ndarray, spread_rad: np.ndarray, textured: bool) -> RayHits:
            hits = cast(self.spec, np.broadcast_to(centre, d_world.shape), d_world,
                        self.textures if textured else None, footprint_rad=spread_rad, lighting=self.lighting)
            hits.rgb[~ok] = 0.0
            hits.t[~ok] = np.nan
            return hits

        centre_world, centre_ok = world(dirs_cam.reshape(-1, 3))
        # with supersampling the centre rays only give depth: no texture lookups
        centre_hits = trace(centre_world, centre_ok, spread.reshape(-1), textured=s == 1)
        n_centre = centre_world.shape[0]
        if s > 1:
            sub_world, sub_ok_rays = world(sub_dirs)
            sub_hits = trace(sub_world, sub_ok_rays, sub_spread, textured=True)
        centre_actor = np.full(n_centre, -1, dtype=np.int64)
        centre_part = np.full(n_centre, -1, dtype=np.int64)
        room_colour = centre_hits.rgb if s == 1 else sub_hits.rgb  # the colour rays before actors are merged in
        if placed:
            # one actor query for the centre and the sub-pixel rays together (fewer passes over the parts)
            lamp = self.lighting.lamp_xyz_m(self.spec)
            all_world = centre_world if s == 1 else np.concatenate([centre_world, sub_world])
            margin = 0.0
            if s > 1:  # the largest angle between a pixel's centre ray and its sub-pixel rays
                cos_sub = np.einsum("nkj,nj->nk", sub_world.reshape(n_centre, s * s, 3), centre_world).min(axis=1)
                margin = np.arccos(np.clip(cos_sub, -1.0, 1.0)) + 1e-9
            actor_hits = []
            for actor, T, _ in placed:
                near = _near_actor(actor, T, centre, centre_world, margin)  # per pixel, sub-pixel rays included
                cand = centre_ok & near
                if s > 1:
                    cand = np.concatenate([cand, sub_ok_rays & np.repeat(near, s * s)])
                actor_hits.append(_intersect_actor(actor, T, centre, all_world, cand, self.lighting, lamp))

            def part_of(h: ActorHits, sl: slice) -> ActorHits:
                return ActorHits(t=h.t[sl], hit=h.hit[sl], rgb=h.rgb[sl], normal=h.normal[sl], part_id=h.part_id[sl])

            comp = composite_actors(centre_hits.t, centre_hits.rgb, [part_of(h, slice(0, n_centre)) for h in actor_hits])
            centre_hits = RayHits(t=comp.t, normal=centre_hits.normal, surface_id=centre_hits.surface_id,
                                  face=centre_hits.face, point=centre_hits.point, rgb=comp.rgb)
            centre_actor, centre_part = comp.actor_index, comp.part_id
            if s > 1:
                comp = composite_actors(sub_hits.t, sub_hits.rgb, [part_of(h, slice(n_centre, None)) for h in actor_hits])
                sub_hits = RayHits(t=comp.t, normal=sub_hits.normal, surface_id=sub_hits.surface_id,
                                   face=sub_hits.face, point=sub_hits.point, rgb=comp.rgb)
                sub_actor = comp.actor_index
            else:
                sub_actor = centre_actor
        elif s > 1:
            sub_actor = np.full(sub_world.shape[0], -1, dtype=np.int64)

        depth_range = centre_hits.t.reshape(H, W)
        z = dirs_cam[..., 2]
        depth_z = np.where(valid & (z > 1e-9), depth_range * np.where(valid, z, 0.0), np.nan)
        ids = np.array([0] + [iid for _, _, iid in placed], dtype=np.int32)
        instance_mask = ids[centre_actor + 1].reshape(H, W)
        part_id = centre_part.astype(np.int32).reshape(H, W)
        soft = np.zeros((K, H, W), dtype=np.float32)
        if s == 1:
            rgb = centre_hits.rgb.reshape(H, W, 3)
            room_rgb = room_colour.reshape(H, W, 3) if placed else rgb
            for k in range(K):
                soft[k] = (centre_actor == k).reshape(H, W)
        else:
            sub_ok = _finite_rows(sub_dirs).reshape(H * W, s * s).astype(np.float32)
            count = sub_ok[:, 0].copy()
            for k in range(1, s * s):
                count += sub_ok[:, k]
            count = np.maximum(count, 1.0)

            def pixel_mean(sub_rgb: np.ndarray) -> np.ndarray:
                sub_rgb = sub_rgb.reshape(H * W, s * s, 3)
                total = sub_rgb[:, 0].copy()
                for k in range(1, s * s):  # explicit sums: numpy is slow at reducing short inner axes
                    total += sub_rgb[:, k]
                return (total / count[:, None]).reshape(H, W, 3)

            rgb = pixel_mean(sub_hits.rgb)
            room_rgb = pixel_mean(room_colour) if placed else rgb
            sub_actor = sub_actor.reshape(H * W, s * s)
            for k in range(K):
                seen = (sub_actor == k).astype(np.float32)
                soft[k] = (seen.sum(axis=1) / count).reshape(H, W)
        rgb = np.ascontiguousarray(rgb, dtype=np.float32)
        return GroundTruthView(rgb=rgb, depth_z=depth_z.astype(np.float32), depth_range=depth_range.astype(np.float32),
                               instance_mask=instance_mask, part_id=part_id, soft_masks=soft,
                               room_rgb=np.ascontiguousarray(room_rgb, dtype=np.float32) if placed else rgb)

    def lidar_gt(self, lidar_to_world: np.ndarray, lidar: LidarConfig | LidarSensor,
                 rng: np.random.Generator | None = None,
                 actors: Sequence[PlacedActor | tuple[Actor, np.ndarray]] | None = None) -> LidarScan:
        """Exact scan of a LiDAR at ``lidar_to_world (4, 4)`` (LiDAR frame x fwd, y left, z up).

        lidar: a ``LidarConfig`` (beams evenly over its vertical FoV) or a rig's ``LidarSensor``
        (its own beams, explicit ``vertical_angles_deg`` included, and its config's ranges): the
        beams are ``nsim.sensors.lidar.beams_and_config(lidar)``'s, as ``render_lidar``'s. Rows of
        the scan are its rings (ascending elevation), columns its azimuths.
        With ``range_noise_std_m > 0`` Gaussian noise from ``rng`` (required then) is
        added to every range before the min/max range gate; draws do not depend on the scene.
        ``actors`` (see ``render_gt``) return beams like any surface.
        """
        pose = _check_pose("lidar_gt: lidar_to_world", lidar_to_world)
        placed = _placed_actors(actors, "lidar_gt")
        beams, cfg = beams_and_config(lidar)
        dirs_lidar = beams.directions()  # (C, A, 3)
        dirs_world = _rotate(pose[:3, :3], dirs_lidar.reshape(-1, 3))
        origins = np.broadcast_to(pose[:3, 3], dirs_world.shape)
        hits = cast(self.spec, origins, dirs_world, None, lighting=self.lighting)
        t, surface_id = hits.t, hits.surface_id
        actor_index = np.full(t.shape, -1, dtype=np.int64)
        if placed:
            lamp = self.lighting.lamp_xyz_m(self.spec)
            origin = pose[:3, 3]
            comp = composite_actors(t, hits.rgb, [
                _intersect_actor(actor, T, origin, dirs_world, _near_actor(actor, T, origin, dirs_world),
                                 self.lighting, lamp) for actor, T, _ in placed])
            t, actor_index = comp.t, comp.actor_index
            surface_id = np.where(actor_index >= 0, -1, surface_id)
        ranges = t.reshape(beams.shape)
        if cfg.range_noise_std_m > 0.0:
            if rng is None:
                raise ValueError("lidar_gt: range_noise_std_m > 0 needs a seeded rng (np.random.Generator)")
            ranges = ranges + rng.normal(0.0, cfg.range_noise_std_m, size=ranges.shape)
        returned = np.isfinite(ranges) & (ranges >= cfg.min_range_m) & (ranges <= cfg.max_range_m)
        ranges = np.where(returned, ranges, np.inf)
        points = np.where(returned[..., None], np.where(returned, ranges, 0.0)[..., None] * dirs_lidar, np.nan)
        surface = np.where(returned, surface_id.reshape(ranges.shape), -1)
        ids = np.array([0] + [iid for _, _, iid in placed], dtype=np.int32)
        instance = np.where(returned, ids[actor_index + 1].reshape(ranges.shape), 0).astype(np.int32)
        return LidarScan(ranges_m=ranges.astype(np.float32), points_lidar_m=points.astype(np.float32),
                         surface_id=surface, instance_id=instance)
