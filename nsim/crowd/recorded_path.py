"""A robot path that names an artifact -- ``robot.trajectory: {recording: REF}`` or ``{registration: REF}`` in a
scenario, or ``nsim simulate --robot-trajectory`` (a recording, a registration or a TUM file) -- read from the
workspace and inlined as timed poses (:func:`nsim.crowd.scenario.with_recorded_trajectory`). ``store`` is the
workspace (its ``resolve`` and ``get``); nothing here writes to it.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from nsim.crowd.scenario import ScenarioSpec, with_recorded_trajectory
from nsim.errors import NsimError

log = logging.getLogger("nsim.stages.simulate")


#: Where a trajectory entry's artifact keeps the body's path: kind -> (TUM file, its stamps in ns, the frame it is in).
RECORDED_PATHS = {
    "recording": ("trajectory.tum", "trajectory_ns.npy", "the recording's odometry frame, taken as the scene's world"),
    "registration": ("trajectory_world.tum", "trajectory_world_ns.npy", "the scene's world (registered)"),
}


def resolve_trajectory(spec: ScenarioSpec, store=None, robot_trajectory: str | None = None) -> ScenarioSpec:
    """``spec`` with a ``robot.trajectory`` that names an artifact (``{recording: REF}``, ``{registration: REF}``)
    replaced by its poses (``nsim.crowd.scenario.with_recorded_trajectory``); ``robot_trajectory`` (the command
    line's ``--robot-trajectory``): a TUM file, or a recording or registration artifact, replacing the file's."""
    from nsim.io.robot_folder import read_tum_ns
    from nsim.io.tum import read_tum

    entry = dict(spec.data["robot"]["trajectory"])
    where = ("robot", "trajectory")
    if robot_trajectory is not None:
        if Path(robot_trajectory).is_file():
            stamps, _ = read_tum_ns(Path(robot_trajectory))
            tum = read_tum(Path(robot_trajectory))
            log.info("simulate: the robot drives along %s (%d poses; --robot-trajectory replaces the scenario's)",
                     robot_trajectory, len(stamps))
            return with_recorded_trajectory(spec, stamps, tum.positions_xyz, tum.orientations_quat_wxyz,
                                            f"file {Path(robot_trajectory).name}")
        entry = {"artifact": robot_trajectory}
        where = "--robot-trajectory"
    kinds = [k for k in RECORDED_PATHS if k in entry] or (["artifact"] if "artifact" in entry else [])
    if not kinds:
        return spec
    ref = entry[kinds[0]]
    if store is None:
        raise spec.error(where, "a recording or registration needs a workspace to resolve it")
    try:
        art_id = store.resolve(ref, kind=None if kinds[0] == "artifact" else kinds[0])
    except NsimError as exc:
        raise spec.error(where, str(exc)) from None
    art = store.get(art_id)
    kind = art.kind
    if kind not in RECORDED_PATHS:
        raise spec.error(where, f"{ref!r} is a {kind} artifact; the robot drives along a recording (nsim import-log) "
                         "or a registration (nsim register-log)")
    tum_name, ns_name, frame = RECORDED_PATHS[kind]
    stamps = np.load(art.file(ns_name), allow_pickle=False)
    tum = read_tum(art.file(tum_name))
    if len(stamps) != len(tum):
        raise spec.error(where, f"{kind} {art_id[:12]}: {ns_name} and {tum_name} disagree")
    if kind == "recording":
        log.warning("simulate: the robot drives along recording %s (%d poses); its odometry frame is taken as the "
                 "scene's world (register-log places a recording with cameras: {registration: REF})", art_id[:12],
                 len(stamps))
    return with_recorded_trajectory(spec, stamps, tum.positions_xyz, tum.orientations_quat_wxyz,
                                    f"{kind} {art_id} ({tum_name}, in {frame})")
