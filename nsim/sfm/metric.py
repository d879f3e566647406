"""Metric, z-up output for a reconstruction: the scale-and-frame step of ``nsim reconstruct``.

One of three sources fixes the scale (at most one may be given):

* a **reference** trajectory (:func:`load_reference`: a nerfstudio ``transforms.json`` with
  metric poses, matched by file stem, falling back to timestamps; or a TUM file, matched by
  timestamp). The reconstruction is mapped onto it with a robust Sim(3) of the camera
  centres, so the output world *is* the reference's world;
* a **known distance** between two points given in the frame of the same reconstruction run
  without any scale source (z-up, floor at 0, arbitrary units: open its sparse PLY and pick
  two points; the run is deterministic, so a second run with the distance sees the same frame);
* the **camera height** above the floor.

Without a reference the world is first gravity-aligned (:func:`nsim.sfm.align.gravity_align`:
floor at z = 0, +z up), unless the input declares itself z-up (an imported nsim capture). An
imported transforms.json may also declare its own units metres (``--metric``, or nsim's keys:
see ``nsim.io.transforms_json``); that is the fourth, weakest source (scale 1). With no source at
all the scale stays arbitrary and the report says so.

:func:`metric_frame` is the core (poses and points in, a :class:`Similarity` out), shared by SfM
runs (:func:`to_metric`) and imports (``nsim.stages.reconstruct``).
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nsim.errors import InputError
from nsim.sfm.align import (
    apply_sim3_to_poses,
    associate_by_name,
    associate_by_time,
    fit_sim3,
    gravity_align,
    require_matches,
    scale_from_camera_height,
    scale_from_known_distance,
    sim3_matrix,
)
from nsim.sfm.colmap import SfmResult, transform_result

log = logging.getLogger(__name__)

#: Default largest |dt| when matching frames to reference poses by timestamp (half a frame at 25 fps).
DEFAULT_MAX_DT_S = 0.02
ARBITRARY_SCALE_MESSAGE = ("scale is arbitrary: no --reference, --known-distance or --camera-height (or, for an "
                           "import, --metric) was given, so distances in the output are in unknown units "
                           "(the floor is z = 0, +z is up)")


@dataclass(frozen=True, eq=False)
class Reference:
    """Metric reference poses.

    source: the file, for messages; cam_to_world: (M, 4, 4) OpenCV axes, metres;
    names: (M,) frame file names or None; timestamps_s: (M,) float64 or None.
    """

    source: str
    cam_to_world: np.ndarray
    names: tuple[str, ...] | None = None
    timestamps_s: np.ndarray | None = None


@dataclass(frozen=True)
class ScaleReport:
    """How the output got its scale and frame (for report.json).

    source: "reference" | "known_distance" | "camera_height" | "metric" (an import declared metric)
    | "arbitrary"; scale: the factor applied to the input's units; matched: reference poses used
    (inliers) of those associated; residual_rms_m / residual_median_m: Sim(3) residuals over the
    inliers (reference only); floor_found: whether gravity alignment found a floor plane (None
    without gravity alignment); frame: "reference" (the reference's world), "gravity" (z up, floor
    at z = 0, found here) or "as_given" (an input declared z-up, kept).
    """

    source: str
    scale: float
    matched: int | None = None
    associated: int | None = None
    associated_by: str | None = None
    residual_rms_m: float | None = None
    residual_median_m: float | None = None
    floor_found: bool | None = None
    floor_inliers: int | None = None
    frame: str = ""
    message: str = ""

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def load_reference(path: str | os.PathLike) -> Reference:
    """Read a reference: ``*.json`` as transforms.json, anything else as a TUM trajectory.

    TUM poses are taken as camera-to-world (the camera is the body). Raises InputError for an
    unreadable or malformed file (from the readers in ``nsim.io``).
    """
    path = Path(path)
    if path.suffix.lower() == ".json":
        from nsim.io.transforms_json import read_transforms

        data = read_transforms(path)
        frames = data.frames
        if not frames:
            raise InputError(f"{path}: no frames")
        times = [f.timestamp_s for f in frames]
        return Reference(
            str(path),
            np.stack([f.cam_to_world for f in frames]),
            tuple(f.file_path for f in frames),
            np.array(times, dtype=np.float64) if all(t is not None for t in times) else None,
        )
    from nsim.io.tum import read_tum

    traj = read_tum(path)
    return Reference(str(path), traj.poses_se3(), None, traj.timestamps_s)


def associate_reference(names: list[str], timestamps_s: dict[str, float] | None, ref: Reference,
                        max_dt_s: float) -> tuple[np.ndarray, np.ndarray, str]:
    """Indices into ``names`` and into the reference's poses that match, and how (``name`` or ``timestamp``):
    by file name when at least three names match, else by time within ``max_dt_s``. InputError when the
    frames cannot be matched (it depends on the inputs only: ``nsim reconstruct`` checks it before SfM)."""
    by_name = (np.zeros(0, np.int64), np.zeros(0, np.int64))
    if ref.names is not None:
        by_name = associate_by_name(names, list(ref.names))
        if len(by_name[0]) >= 3:
            return by_name[0], by_name[1], "name"
    if ref.timestamps_s is not None and timestamps_s:
        timed = [n for n in names if timestamps_s.get(n) is not None]
        ie, ir = associate_by_time(np.array([timestamps_s[n] for n in timed]), ref.timestamps_s, max_dt_s)
        idx = np.array([names.index(timed[i]) for i in ie], dtype=np.int64)
        require_matches(len(idx), len(names), ref.source, f"by timestamp (within {max_dt_s:g} s)")
        return idx, ir, "timestamp"
    if ref.names is not None:
        require_matches(len(by_name[0]), len(names), ref.source, "by file name")
    if ref.timestamps_s is not None:
        raise InputError(f"{ref.source}: the reference has only timestamps, and the input frames have none: name "
                         "the images by their timestamps (1305031102.175304.png, as TUM RGB-D does) or give a "
                         "transforms.json whose file names match the images")
    raise InputError(f"{ref.source}: the reference has neither file names nor timestamps to match frames by")


@dataclass(frozen=True, eq=False)
class Similarity:
    """``x -> s R x + t`` from an input world (SfM's, or an imported file's) to the output world.

    R: (3, 3) rotation; t: (3,). Poses move with ``apply_sim3_to_poses`` (they stay rigid).
    """

    s: float
    R: np.ndarray
    t: np.ndarray

    def matrix(self) -> np.ndarray:
        """(4, 4) ``[[s R, t], [0, 1]]``."""
        return sim3_matrix(self.s, self.R, self.t)


def metric_frame(
    cam_to_world: np.ndarray,
    points_xyz: np.ndarray,
    names: list[str],
    timestamps_s: dict[str, float] | None = None,
    reference: Reference | None = None,
    known_distance: tuple[np.ndarray, np.ndarray, float] | None = None,
    camera_height_m: float | None = None,
    declared_metric: str | None = None,
    declared_z_up: bool = False,
    max_dt_s: float = DEFAULT_MAX_DT_S,
    seed: int = 0,
) -> tuple[Similarity, ScaleReport]:
    """The similarity taking an input world to a metric (or, without a source, z-up arbitrary-scale) one.

    cam_to_world: (N, 4, 4) OpenCV axes in the input world; points_xyz: (P, 3) sparse points there
    (the floor is looked for among them); names: (N,) frame file names, for matching a reference by
    name; timestamps_s: name -> seconds, for matching it by time. known_distance: (point_a (3,),
    point_b (3,), metres) in the output frame of the same input without a scale source.
    declared_metric: why the input's own units are metres (e.g. ``"--metric"``), or None;
    declared_z_up: the input world already has +z up and the floor at z = 0, so it is kept
    (no gravity alignment). The explicit sources (reference, known distance, camera height)
    override a declared metric scale; at most one of them may be given.
    """
    given = [x is not None for x in (reference, known_distance, camera_height_m)]
    if sum(given) > 1:
        raise ValueError("metric_frame: give at most one of reference, known_distance, camera_height_m")
    c2w = np.asarray(cam_to_world, dtype=np.float64)
    pts = np.asarray(points_xyz, dtype=np.float64).reshape(-1, 3)
    if reference is not None:
        ie, ir, how = associate_reference(names, timestamps_s, reference, max_dt_s)
        fit = fit_sim3(c2w[ie, :3, 3], reference.cam_to_world[ir, :3, 3])
        log.info("Sim(3) to %s: scale %.6g, %d of %d pairs, rms %.4f m", reference.source, fit.s,
                 int(fit.inliers.sum()), len(ie), fit.rms_m)
        return Similarity(fit.s, fit.R, fit.t), ScaleReport(
            "reference", fit.s, int(fit.inliers.sum()), len(ie), how, fit.rms_m, fit.median_m, frame="reference",
            message=f"metric scale and frame from {reference.source}")
    if declared_z_up:
        R, t, floor = np.eye(3), np.zeros(3), {"frame": "as_given"}
    else:
        if camera_height_m is not None and len(pts) == 0:
            raise InputError("camera height: there are no sparse points to find the floor among (an import "
                             "without ply_file_path); use --reference or --known-distance instead")
        gravity = gravity_align(pts, c2w, seed=seed)
        if not gravity.floor_found:
            log.warning("no floor plane found among the sparse points: up comes from the cameras only")
        R, t = gravity.R, gravity.t
        floor = {"floor_found": gravity.floor_found, "floor_inliers": gravity.floor_inliers, "frame": "gravity"}
    if known_distance is not None:
        a, b, d = known_distance
        s = scale_from_known_distance(a, b, d)
        source, message = "known_distance", f"metric scale from a known distance of {d:g} m"
    elif camera_height_m is not None:
        s = scale_from_camera_height(apply_sim3_to_poses(1.0, R, t, c2w), camera_height_m)
        source, message = "camera_height", f"metric scale from a camera height of {camera_height_m:g} m"
    elif declared_metric is not None:
        s, source, message = 1.0, "metric", f"metric scale as given ({declared_metric})"
    else:
        log.warning(ARBITRARY_SCALE_MESSAGE)
        s, source, message = 1.0, "arbitrary", ARBITRARY_SCALE_MESSAGE
    return Similarity(s, R, s * t), ScaleReport(source, s, **floor, message=message)


def to_metric(
    result: SfmResult,
    timestamps_s: dict[str, float] | None = None,
    reference: Reference | None = None,
    known_distance: tuple[np.ndarray, np.ndarray, float] | None = None,
    camera_height_m: float | None = None,
    max_dt_s: float = DEFAULT_MAX_DT_S,
    seed: int = 0,
) -> tuple[SfmResult, ScaleReport]:
    """The reconstruction in a metric (or, without a source, z-up arbitrary-scale) world (:func:`metric_frame`).

    timestamps_s: image name -> seconds (video frames), for matching a reference by time.
    known_distance: (point_a (3,), point_b (3,), metres) in the arbitrary-scale output frame.
    Returns the transformed result (the input is not modified) and how its scale was set.
    """
    names = result.registered_names
    sim, report = metric_frame(result.poses_se3(names), result.points_xyz, names, timestamps_s, reference,
                               known_distance, camera_height_m, max_dt_s=max_dt_s, seed=seed)
    return transform_result(result, sim.s, sim.R, sim.t), report
