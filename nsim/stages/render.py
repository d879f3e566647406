"""``nsim render``: the robot's sensors in the trained world, frame by frame, as a ``render`` artifact.

Three modes:

``trajectory``
    For each selected tick of a ``trajectory`` artifact (``nsim simulate``), for each sensor of a
    rig (``nsim/configs/robots/*.yaml``): world pose = robot pose x mount; rays from the camera model
    or the LiDAR pattern; the scene NeRF rendered along them (marching with the baked occupancy
    grid, early ray termination) and, with human checkpoints, every visible person's samples
    merged with the scene's in depth order (one volume rendering over both).
``poses``
    Every frame (or the held-out frames) of a ``poses`` / ``capture`` artifact with the frame's own
    camera: what ``nsim evaluate`` compares with the captured images.
``recording``
    Exactly the recorded sensors of a ``registration`` (``nsim register-log``) of a ``recording``
    (``nsim import-log``), so that sim and real frames pair one to one (the stream's own camera model, no
    sensor noise; :mod:`nsim.rendering.recording`). With ``--trajectory`` the run's people are drawn too.

A run's people are drawn by ``--humans``, else by the human checkpoints their scenario's appearances name,
else with the default look (``nsim.rendering.default_look``, one warning line); ``--no-people``: nobody.

The scene is rendered by the NeRF (``method: proposal``, the default, or ``march``) or from the scene baked
into a sparse voxel grid (``method: baked``, ``nsim.rendering.baked``; the ``--baked`` artifact of ``nsim
bake``, or one baked here with ``BakeConfig``'s defaults). People composite over either in depth order.

The artifact's layout (every mode) is in :mod:`nsim.rendering.render_output`'s docstring, beside the
code that writes it.

Sharding: frames are cut into shards of ``shard_frames``, each rendered into its own directory under
``<workspace>/tmp/render.<key>.shards/`` (published by atomic rename: a rerun renders only the missing
ones); the artifact is published last. Sensor noise is seeded by (seed, frame, sensor), so the result
does not depend on the shard size, the engine or the number of workers.

This module resolves the inputs (into ``nsim.rendering.render_job.RenderSources``: the artifacts'
folders), keys the run and publishes; the work is the core's:
``nsim.rendering.render_plan`` (the adapted rig, the frames of each mode, the shards),
``nsim.rendering.shard`` (rendering and measuring one shard), ``nsim.rendering.people`` (the run's
people: posing, culling, compositing) and ``nsim.rendering.render_output`` (render.json, previews,
the ROS 2 bag export).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import shutil
from pathlib import Path
from typing import Any

from nsim.context import RunContext
from nsim.errors import InputError
from nsim.rendering import render_plan
from nsim.rendering.render_job import ArtifactDir, RenderSources
from nsim.rendering.render_plan import RenderConfig
from nsim.stages.runner import cached, device_kind, rerun

STAGE = "render"
VERSION = 7  # 2: people culled by the sensor range; no person on invalid (outside the fisheye circle) rays
# 3: ``fill`` (no-return pixels over the training images' mean colour) and ``background``
# 4: preview/preview.mp4 in H.264 (was MPEG-4 Part 2); contact sheet tiles labelled (nsim.io.labels)
# 5: the culling tests a pixel by its centre in the bound's own coordinates (whole numbers; it took u + 0.5,
#    so a person could lose the column or row at the bound's right or bottom edge)
# 6: poses, trajectories and metrics written rounded (nsim.io.canonical: the same bytes on any CPU)
# 7: preview.mp4 the same bytes on any CPU (nsim.io.video.SWS_FLAGS); people drawn by default (default look)

log = logging.getLogger(__name__)


Config = RenderConfig  # defined in the core (nsim.rendering.render_plan), where the shards and sensors read it


@dataclasses.dataclass(frozen=True)
class Inputs:
    """trajectory, poses or registration (exactly one; registration: ``--recording``, a registered
    recording, with which a trajectory only supplies the people); scene: a scene-checkpoint (default:
    the one the trajectory names); rig: a rig file (trajectory mode); humans: human-checkpoint ids;
    baked: a baked-scene of the scene (``nsim bake``; ``method: baked`` only, which bakes one without it)."""

    trajectory: str | None = None
    poses: str | None = None
    scene: str | None = None
    rig: Path | None = None
    humans: tuple[str, ...] = ()
    registration: str | None = None
    baked: str | None = None
    people: bool = True  # False (--no-people): none of the trajectory's people is drawn

    def ids(self) -> dict[str, str]:
        named = {"baked": self.baked, "trajectory": self.trajectory, "poses": self.poses,
                 "registration": self.registration, "scene": self.scene}
        return {k: v for k, v in named.items() if v} | {f"human{k}": h for k, h in enumerate(self.humans)}


@dataclasses.dataclass(frozen=True)
class Outputs:
    render: str
    cache_hit: bool = False
    shards_rendered: int = 0
    shards_reused: int = 0


# ---------------------------------------------------------------------------------- resolving inputs
def resolve_inputs(inputs: Inputs, ctx: RunContext) -> Inputs:
    """Artifact ids resolved and checked (kinds, the scene checkpoint's presence, a baked scene of that scene)."""
    if inputs.humans and not inputs.people:
        raise InputError(f"render: --no-people draws nobody; --humans {' '.join(inputs.humans)} draws them: give one")
    out = resolve_mode_inputs(inputs, ctx)
    if inputs.baked is None:
        return out
    return dataclasses.replace(out, baked=resolve_baked(ctx, inputs.baked, out.scene))


def resolve_baked(ctx: RunContext, spec: str, scene: str) -> str:
    """The ``baked-scene`` artifact ``spec`` (``--baked``), checked: baked from the render's scene checkpoint."""
    store = ctx.store
    baked = store.resolve(spec)
    art = store.get(baked)
    if art.kind != "baked-scene":
        raise InputError(f"--baked {spec}: a {art.kind} artifact; render needs a baked-scene artifact (nsim bake)")
    made_from = art.manifest.get("inputs", {}).get("scene")
    if made_from != scene:
        raise InputError(f"--baked {spec}: baked from scene {str(made_from)[:12]}, the render's scene is {scene[:12]} "
                         f"(nsim bake {scene[:12]})")
    return baked


def sources_of(inputs: Inputs, ctx: RunContext) -> RenderSources:
    """The resolved inputs' folders (held by the store while the run lasts), for the core."""
    store = ctx.store

    def located(art_id: str | None) -> ArtifactDir | None:
        return None if art_id is None else ArtifactDir(art_id, store.get(art_id).path)

    recording = store.get(inputs.registration).manifest["inputs"]["recording"] if inputs.registration else None
    return RenderSources(scene=located(inputs.scene), trajectory=located(inputs.trajectory), poses=located(inputs.poses),
                         registration=located(inputs.registration), recording=located(recording),
                         humans=tuple(located(h) for h in inputs.humans), baked=located(inputs.baked),
                         rig_file=inputs.rig)


def resolve_mode_inputs(inputs: Inputs, ctx: RunContext) -> Inputs:
    """The mode's artifacts (trajectory, poses or registration), the scene and the people, resolved and checked."""
    store = ctx.store
    modes = (inputs.poses, inputs.registration, inputs.trajectory if inputs.registration is None else None)
    if sum(x is not None for x in modes) != 1:
        raise InputError("render: give exactly one of --trajectory, --poses or --recording (with --recording, "
                         "--trajectory only supplies the people)")
    if inputs.registration is not None:
        return resolve_recording_inputs(inputs, ctx)
    traj = poses = None
    if inputs.trajectory is not None:
        traj = store.resolve(inputs.trajectory, kind="trajectory")
        if inputs.rig is None:
            raise InputError("render --trajectory: a rig file is needed (--rig nsim/configs/robots/spot.yaml)")
    else:
        poses = store.resolve(inputs.poses)
        kind = store.get(poses).kind
        if kind not in ("poses", "capture"):
            raise InputError(f"--poses {inputs.poses}: a {kind} artifact; render needs a poses or capture artifact")
        if inputs.humans:  # (the shard renderer would refuse them only after loading the scene)
            raise InputError(f"render --poses: --humans {' '.join(inputs.humans)}: people come from a trajectory "
                             "(nsim simulate); render them with --trajectory")
    scene = inputs.scene
    if scene is None and traj is not None:
        named = store.get(traj).manifest.get("inputs", {}).get("scene")
        if named is None:
            raise InputError(f"trajectory {traj[:12]} names no scene checkpoint: pass --scene")
        if not (store.root / "objects" / named[:2] / named).is_dir():
            raise InputError(f"trajectory {traj[:12]}: its scene checkpoint {named[:12]} is missing from the "
                             f"workspace {store.root} (train it with nsim train-scene, or pass --scene)")
        scene = named
    elif scene is None:
        raise InputError("render --poses: pass --scene (a scene-checkpoint artifact)")
    else:
        scene = store.resolve(scene, kind="scene-checkpoint")
    humans = tuple(store.resolve(h, kind="human-checkpoint") for h in inputs.humans)
    return Inputs(trajectory=traj, poses=poses, scene=scene, rig=inputs.rig, humans=humans, people=inputs.people)


def resolve_recording_inputs(inputs: Inputs, ctx: RunContext) -> Inputs:
    """Recording mode: a registration (its recording present), a metric scene checkpoint, and people (human
    checkpoints and the trajectory whose people they draw) both or neither."""
    store = ctx.store
    reg = store.resolve(inputs.registration)
    kind = store.get(reg).kind
    if kind != "registration":
        raise InputError(f"--recording {inputs.registration}: a {kind} artifact; render --recording needs a "
                         "registration artifact (nsim register-log)")
    rec = store.get(reg).manifest.get("inputs", {}).get("recording")
    if rec is None or not (store.root / "objects" / rec[:2] / rec).is_dir():
        raise InputError(f"--recording {inputs.registration}: its recording {str(rec)[:12]} is missing from the "
                         f"workspace {store.root} (import it again with nsim import-log)")
    if inputs.humans and inputs.trajectory is None:
        raise InputError("render --recording: --humans needs --trajectory, the nsim simulate run whose people they "
                         "draw (a recording has no people of its own)")
    traj = store.resolve(inputs.trajectory, kind="trajectory") if inputs.trajectory is not None else None
    if inputs.rig is not None:
        raise InputError(f"render --recording: --rig {inputs.rig}: a recording renders its own recorded sensors")
    if inputs.scene is None:
        raise InputError("render --recording: pass --scene (a scene-checkpoint artifact of the registration's world)")
    scene = store.resolve(inputs.scene, kind="scene-checkpoint")
    if not render_plan.scene_is_metric(store.get(scene).file("scene.json")):
        raise InputError(f"--scene {inputs.scene}: the scene's scale is arbitrary (trained on poses without a metric "
                         "scale); a registered recording lives in a metric world")
    trained_on = store.get(scene).manifest.get("inputs", {}).get("poses")
    registered_to = store.get(reg).manifest.get("inputs", {}).get("poses")
    if trained_on and registered_to and trained_on != registered_to:
        log.warning("render --recording: scene %s was trained on poses %s, the recording registered to poses %s: "
                    "their worlds must agree", scene[:12], trained_on[:12], registered_to[:12])
    humans = tuple(store.resolve(h, kind="human-checkpoint") for h in inputs.humans)
    return Inputs(scene=scene, registration=reg, trajectory=traj, humans=humans, people=inputs.people)


def action_key(inputs: Inputs, cfg: Config, ctx: RunContext, rig, person_model=None) -> str:
    extra = {"device": device_kind(ctx.device)}
    if render_plan.people_differ_from_default(person_model, len(inputs.humans)):
        extra["people"] = person_model  # the scenario names checkpoints (refs can move: the resolved choice)
    if cfg.method == "baked" and inputs.baked is None:  # baked here: with BakeConfig()'s settings
        from nsim.config import to_dict
        from nsim.rendering.bake_config import BakeConfig

        extra["bake"] = to_dict(BakeConfig())
    if rig is not None:
        extra["rig"] = hashlib.sha256(json.dumps(rig.to_dict(), sort_keys=True, default=str).encode()).hexdigest()
    return ctx.store.action_key(STAGE, VERSION, cfg, inputs.ids(), seed=ctx.seed, extra=extra)


# ---------------------------------------------------------------------------------- the stage
def run(inputs: Inputs, cfg: Config, ctx: RunContext, engine=None) -> Outputs:
    """Render (or find in the run cache). ``engine``: an ``nsim.rendering.engine.EngineConfig``
    (default: local, in-process); it never changes the result."""
    from functools import partial

    from nsim.rendering.engine import EngineConfig, run_shards
    from nsim.rendering.render_output import assemble
    from nsim.rendering.shard import ShardRenderer

    store = ctx.store
    inputs = resolve_inputs(inputs, ctx)
    if inputs.baked is not None and cfg.method != "baked":
        raise InputError(f"--baked {inputs.baked[:12]}: renders from a baked scene need --set method=baked "
                         f"(method is {cfg.method})")
    rig = None
    if inputs.trajectory is not None and inputs.rig is not None:  # trajectory mode (else the people's run)
        from nsim.sensors.rig import Rig

        rig = render_plan.adapt_rig(Rig.load(inputs.rig), cfg)
    sources = sources_of(inputs, ctx)
    people, defaulted = None, []  # which human checkpoint (or the default look) draws each person of the run
    people_from = ("humans" if inputs.humans else "scenario") if inputs.people else "none"
    if inputs.trajectory is not None and inputs.people:
        humans, people, defaulted = render_plan.run_people(sources.trajectory, inputs.humans,
                                                           lambda name: store.find(name, kind="human-checkpoint"))
        if humans != inputs.humans:
            inputs = dataclasses.replace(inputs, humans=humans)
        sources = dataclasses.replace(sources_of(inputs, ctx), people=bool(people))
    key = action_key(inputs, cfg, ctx, rig, people)
    if (hit := cached(ctx, key)) is not None:
        return Outputs(render=hit, cache_hit=True)

    recording = render_plan.plan_recording(sources, cfg) if sources.recording is not None else None
    frames = recording.frames if recording is not None else render_plan.plan_frames(sources, cfg)
    shards = render_plan.shards_of(frames, cfg)
    shard_root = store.root / "tmp" / f"{STAGE}.{key[:24]}.shards"
    shard_root.mkdir(parents=True, exist_ok=True)
    keys = [render_plan.shard_key(key, s) for s in shards]
    present = sum((shard_root / k).is_dir() for k in keys)
    baked_dir = None
    if cfg.method == "baked":  # the --baked artifact, else baked here
        baked_dir = sources.baked.path if sources.baked else render_plan.bake_here(sources.scene, str(ctx.device), shard_root)
    job = render_plan.shard_job(sources, rig, recording, shards, ctx.seed, str(ctx.device), baked_dir, people)
    factory = partial(ShardRenderer, job, cfg)
    done = run_shards(factory, list(range(len(shards))), shard_root, lambda i: keys[i], engine or EngineConfig(),
                      progress=ctx.show_progress)
    with store.publish(kind="render", stage=STAGE, version=VERSION, key=key, config=cfg, inputs=inputs.ids(),
                       seed=ctx.seed) as out:
        summary = assemble(out.dir, sources, cfg, rig, frames, [done[i] for i in range(len(shards))], recording)
        out.summary.update(summary)
        if inputs.trajectory is not None:  # which human checkpoint (or the default look) drew each person
            out.summary.update(render_plan.people_summary(inputs.humans, people, defaulted, people_from))
        if cfg.method == "baked":
            out.summary["baked_scene"] = inputs.baked or "baked by the render (BakeConfig defaults)"
    shutil.rmtree(shard_root, ignore_errors=True)
    return Outputs(render=out.ref, shards_rendered=len(shards) - present, shards_reused=present)


def rebuild(manifest: dict[str, Any], ctx: RunContext) -> str:
    summary = manifest.get("summary", {})
    rig_file = summary.get("rig_file")
    ids = manifest["inputs"]
    people_from = summary.get("people_from")  # scenario: no --humans, drawn again alike; none: --no-people
    humans = tuple(ids[f"human{i}"] for i in range(sum(k.startswith("human") for k in ids)))
    inputs = Inputs(trajectory=ids.get("trajectory"), poses=ids.get("poses"), scene=ids.get("scene"),
                    rig=Path(rig_file) if rig_file else None, humans=() if people_from == "scenario" else humans,
                    registration=ids.get("registration"), baked=ids.get("baked"),
                    people=people_from not in (None, "none") or bool(humans))
    return rerun(run, inputs, Config, manifest, ctx).render
