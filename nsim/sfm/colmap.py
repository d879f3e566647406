"""Structure from motion with pycolmap: SIFT, matching, incremental mapping, global BA.

``run_sfm(image_dir, work_dir, options)`` (:class:`SfmOptions`, defined in ``nsim.sfm.options``)
reconstructs the images of a folder and returns an
:class:`SfmResult`: the pycolmap reconstruction (the largest model when COLMAP makes several),
per-image ``cam_to_world`` (OpenCV axes, the reconstruction's arbitrary world frame and scale)
and intrinsics as :class:`nsim.geometry.cameras.Camera` (OpenCV pixel centres: COLMAP's
``cx, cy`` minus 0.5), the sparse points, and statistics with the wall time of each phase.

Focal length. A video carries no EXIF focal length, and COLMAP's default guess
(``1.2 * max(W, H)``, a 45 deg horizontal field of view) is far from a phone's ~65-75 deg: on
a synthetic 70 deg room at 320x240 the mapper then split 48 frames into five models (the
largest 32 frames), while a 65 deg guess registered all 48. pycolmap marks fisheye pairs
without a focal prior as degenerate, so those cannot be matched at all. So, unless ``known_camera`` is given, the mapper is
run with an initial focal length from a guessed horizontal field of view
(``SfmOptions.hfov_guesses_deg``, per-model defaults in ``DEFAULT_HFOV_GUESSES_DEG``; the
fisheye guess is equidistant), and again with the next guess while fewer than
``retry_below_fraction`` of the images register; the attempt registering the most images
wins. Bundle adjustment refines the focal length (and distortion) from there.

Loop detection (sequential matching) needs a visual vocabulary. COLMAP would download one;
instead a small one is built from the sequence's own descriptors (``VisualIndex.build``),
which needs no network and suits one room.

Far pairs. For ordered frames (``matcher="sequential"``) the pairs further apart in the
sequence than ``overlap`` (loop closures and the quadratic-overlap pairs) are where repeated
textures fool two-view verification: in the kitchen test room the two opposite faces of the
island carry the same texture, frames on opposite sides of the room matched with up to 665
"inliers" each, and the mapper, seeded among those frames, placed 19 of 150 frames rotated by
180 deg (median rotation error 17 deg after the fit). A wrong pair cannot be told from a right
one by its own inliers, only by its disagreement with everything else. So, before mapping, the
near pairs alone (which a video makes reliable) are mapped once, and every far pair whose
images both lie in one of those models is checked against it: a far pair is dropped from the
database when most of its inlier matches do not reproject onto the matched keypoint
(``FAR_PAIR_*``). Drift over a room-sized loop is far below that tolerance, so true loop
closures stay and then correct that drift in the final mapping. The check costs one extra
mapping of the near pairs (phase ``far_pair_check``).

Determinism. Every RANSAC and the mapper get ``options.seed``; with
``options.deterministic`` (the default) matching with its two-view verification, mapping, bundle
adjustment and loop retrieval run on one thread, because their multi-threaded forms are not
bit-for-bit repeatable (Ceres' reductions; matching and verification: on the tiny demo's 100
frames at 160x120 three reruns on two cores gave three different models, up to 4 cm apart in
position and 0.15 px in focal length, and with one matching thread every rerun the same bytes,
no slower on two cores). Feature extraction stays multi-threaded, with one guard: images are
imported before extraction (extraction alone numbers them in the order its threads finish, and
the mapper's choices depend on the ids). Sequential pairs are generated first and matched as an
explicit list (``match_sequential`` with loop detection and several threads now and then drops a
pair). The same images and options then give the same poses bit for bit.

Known poses. With ``known_poses`` (camera-to-world per image name, OpenCV axes, e.g. a motion-capture
trajectory) and a ``known_camera``, nothing is mapped: the images get those poses and the matched
features are only triangulated (``pycolmap.triangulate_points``, down to ``KNOWN_POSES_MIN_ANGLE_DEG``
between rays). That is for captures whose own SfM cannot start: a camera turning about itself (TUM
RGB-D's fr1_rpy: its centre moves 4 cm over 24 s) leaves every pair a homography, which COLMAP never
takes as an initial pair, while the motion capture's few centimetres still triangulate its desk at
0.6-0.9 m to about 2 px.

A known camera is not judged. COLMAP drops cameras whose distortion coefficients exceed
``max_extra_param`` (1.0) as a diverged refinement ("bogus" parameters); a calibrated camera can
legitimately exceed that (the TUM RGB-D fr1 Kinect's k3 is 1.1633, its k2 -0.9531), and with a
known camera that stays fixed the check would only refuse it: it is lifted then (``_mapper_options``).

Import order: ``cv2`` must be imported before ``pycolmap``. With pycolmap 4.2.1 and
opencv-contrib-python-headless 5.0 loaded the other way round, ``cv2.imencode('.png')`` aborts
the whole process (a double free in zlib's ``deflateEnd`` under OpenCV's libpng: the two wheels'
bundled libraries clash). This module imports cv2 first; code that imports pycolmap directly
should do the same (or import ``nsim.sfm.colmap`` instead).
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import os
import re
import shutil
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2  # noqa: F401  (must precede pycolmap, see the module docstring)
import numpy as np
import pycolmap

from nsim.errors import InputError
from nsim.geometry.cameras import Camera
from nsim.geometry.conventions import principal_point_from_colmap, principal_point_to_colmap
from nsim.geometry.transforms import invert_se3
from nsim.sfm.options import FISHEYE_MODELS, SfmOptions

log = logging.getLogger(__name__)

PHASES = ("features", "matching", "far_pair_check", "mapping", "bundle_adjustment")
#: RANSAC trial cap of two-view verification (COLMAP's 10000 made loop-closure candidates, which
#: often have low inlier ratios, take 4x longer to verify than all sequential pairs together).
VERIFY_MAX_RANSAC_TRIALS = 2000
#: Far-pair check (see ``_check_far_pairs``): a match agrees with the near-pairs model when its
#: 3D point reprojects within this fraction of max(width, height) of the matched keypoint (8 px at
#: 320x240; true loop closures of the test room agree to 1-2 px, false ones are off by ~100 px) ...
FAR_PAIR_MAX_ERROR_FRACTION = 0.025
#: ... and a far pair is dropped when fewer than this fraction of its checkable matches agree ...
FAR_PAIR_MIN_AGREEING = 0.5
#: ... unless fewer than this many of its matches have a 3D point in that model (then it is kept).
FAR_PAIR_MIN_CHECKABLE = 10
#: A frame whose pose differs this much from both temporal neighbours (which agree) is rejected.
JUMP_MIN_ROTATION_DEG = 30.0
JUMP_MIN_STEPS = 10.0

#: Principal-point refinement ("auto"): only with one shared camera seen by at least this many
#: registered images (fewer cannot separate it from rotation and focal length), ...
PP_AUTO_MIN_IMAGES = 20
#: ... only when refining lowers the mean reprojection error by at least this fraction (on the
#: instant-ngp fox, 50 phone photos, freeing it gained 0.7 % and moved it 15.5 px, where COLMAP
#: puts it 15.5 px off centre too; on centred synthetic cameras the gain is noise), ...
PP_AUTO_MIN_GAIN = 0.005
#: ... and only when it lands within this fraction of max(width, height) of the image centre.
PP_AUTO_MAX_SHIFT = 0.1

#: (phase, done, total) progress callback.
ProgressFn = Callable[[str, int, int], None]


@dataclass(frozen=True)
class SfmStats:
    """Numbers for report.json. Errors in pixels, times in seconds.

    unregistered: every input image without a pose; rejected: those among them that COLMAP
    registered but whose pose jumped away from their neighbours (see ``_reject_pose_jumps``).
    far_pairs_checked / far_pairs_dropped: far image pairs checked against the near-pairs model
    and those dropped as disagreeing with it (see the module docstring), summed over attempts.
    """

    images_given: int
    images_registered: int
    unregistered: tuple[str, ...]
    rejected: tuple[str, ...]
    mean_reprojection_error_px: float
    mean_track_length: float
    num_points3d: int
    num_models: int
    attempts: tuple[dict[str, Any], ...]
    device: str
    phase_wall_s: dict[str, float]
    far_pairs_checked: int = 0
    far_pairs_dropped: int = 0
    principal_point: dict[str, Any] = dataclasses.field(default_factory=dict)

    @property
    def registered_fraction(self) -> float:
        return self.images_registered / max(self.images_given, 1)

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["unregistered"] = list(self.unregistered)
        d["rejected"] = list(self.rejected)
        d["attempts"] = [dict(a) for a in self.attempts]
        return d


@dataclass(frozen=True, eq=False)
class SfmResult:
    """A reconstruction in its own (arbitrary) world frame and scale.

    cam_to_world: image name -> (4, 4) float64, OpenCV axes, registered images only.
    cameras: image name -> intrinsics (OpenCV pixel convention), registered images only.
    points_xyz: (P, 3) float64; points_rgb: (P, 3) uint8; points_error_px: (P,) float64 mean
    reprojection error; points_track_length: (P,) int64. image_names: every input image, in order.
    """

    reconstruction: pycolmap.Reconstruction
    image_names: tuple[str, ...]
    cam_to_world: dict[str, np.ndarray]
    cameras: dict[str, Camera]
    points_xyz: np.ndarray
    points_rgb: np.ndarray
    points_error_px: np.ndarray
    points_track_length: np.ndarray
    stats: SfmStats

    @property
    def registered_names(self) -> list[str]:
        """Registered image names in input order."""
        return [n for n in self.image_names if n in self.cam_to_world]

    def poses_se3(self, names: list[str] | None = None) -> np.ndarray:
        """(N, 4, 4) cam_to_world of ``names`` (default: every registered image, input order)."""
        names = self.registered_names if names is None else names
        return np.stack([self.cam_to_world[n] for n in names]) if names else np.zeros((0, 4, 4))


# --------------------------------------------------------------------------------------
# Camera conversions (COLMAP <-> nsim)
# --------------------------------------------------------------------------------------


def camera_from_colmap(cam: pycolmap.Camera) -> Camera:
    """A pycolmap camera as an nsim Camera (principal point shifted by -0.5 to OpenCV's convention).

    SIMPLE_RADIAL and RADIAL become OPENCV with the same radial terms (identical projection);
    FULL_OPENCV becomes OPENCV when its rational terms k4..k6 are zero.
    """
    model, p = cam.model_name, [float(v) for v in cam.params]
    if model == "SIMPLE_PINHOLE":
        f, cx, cy = p
        fx, fy, dist, out = f, f, (), "PINHOLE"
    elif model == "PINHOLE":
        fx, fy, cx, cy = p
        dist, out = (), "PINHOLE"
    elif model == "SIMPLE_RADIAL":
        f, cx, cy, k = p
        fx, fy, dist, out = f, f, (k, 0.0, 0.0, 0.0, 0.0), "OPENCV"
    elif model == "RADIAL":
        f, cx, cy, k1, k2 = p
        fx, fy, dist, out = f, f, (k1, k2, 0.0, 0.0, 0.0), "OPENCV"
    elif model == "OPENCV":
        fx, fy, cx, cy, k1, k2, p1, p2 = p
        dist, out = (k1, k2, p1, p2, 0.0), "OPENCV"
    elif model == "FULL_OPENCV":
        fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6 = p
        if any((k4, k5, k6)):
            dist, out = (k1, k2, p1, p2, k3, k4, k5, k6), "FULL_OPENCV"
        else:
            dist, out = (k1, k2, p1, p2, k3), "OPENCV"
    elif model == "OPENCV_FISHEYE":
        fx, fy, cx, cy, k1, k2, k3, k4 = p
        dist, out = (k1, k2, k3, k4), "OPENCV_FISHEYE"
    else:
        raise ValueError(f"COLMAP camera model {model} has no nsim equivalent")
    cx, cy = principal_point_from_colmap(cx, cy)
    return Camera(out, int(cam.width), int(cam.height), fx, fy, cx, cy, dist)


def camera_to_colmap(camera: Camera, camera_id: int = 1) -> pycolmap.Camera:
    """An nsim Camera as a pycolmap camera (principal point + 0.5) with a focal length prior.

    OPENCV with a nonzero k3 becomes FULL_OPENCV (COLMAP's OPENCV has no k3).
    """
    cx, cy = principal_point_to_colmap(camera.cx, camera.cy)
    if camera.model == "PINHOLE":
        model, params = "PINHOLE", [camera.fx, camera.fy, cx, cy]
    elif camera.model == "OPENCV":
        k1, k2, p1, p2, k3 = camera.dist
        if k3 == 0.0:
            model, params = "OPENCV", [camera.fx, camera.fy, cx, cy, k1, k2, p1, p2]
        else:
            model, params = "FULL_OPENCV", [camera.fx, camera.fy, cx, cy, k1, k2, p1, p2, k3, 0.0, 0.0, 0.0]
    elif camera.model == "FULL_OPENCV":
        model, params = "FULL_OPENCV", [camera.fx, camera.fy, cx, cy, *camera.dist]
    elif camera.model == "OPENCV_FISHEYE":
        model, params = "OPENCV_FISHEYE", [camera.fx, camera.fy, cx, cy, *camera.dist]
    else:
        raise ValueError(f"camera model {camera.model} cannot be used for SfM")
    cam = pycolmap.Camera.create_from_model_name(camera_id, model, camera.fx, camera.width, camera.height)
    cam.params = params
    cam.has_prior_focal_length = True
    return cam


def initial_focal_px(model: str, width: int, height: int, hfov_deg: float) -> float:
    """Focal length giving a horizontal field of view ``hfov_deg`` across ``max(width, height)``.

    Pinhole ``f = (W/2) / tan(hfov/2)``; fisheye equidistant ``f = (W/2) / (hfov/2 in rad)``.
    """
    half = math.radians(hfov_deg) / 2.0
    size = max(width, height) / 2.0
    return size / half if model in FISHEYE_MODELS else size / math.tan(half)


def _guess_camera(model: str, width: int, height: int, hfov_deg: float, camera_id: int,
                  prior: bool = False) -> pycolmap.Camera:
    f = initial_focal_px(model, width, height, hfov_deg)
    cam = pycolmap.Camera.create_from_model_name(camera_id, model, f, width, height)
    # Fisheye pairs need a focal prior to be verified at all; perspective ones are verified
    # with a fundamental matrix, and without a prior the mapper re-estimates the focal length
    # (unless the images state it: ``prior``, from EXIF).
    cam.has_prior_focal_length = prior or model in FISHEYE_MODELS
    return cam


# --------------------------------------------------------------------------------------
# The pipeline
# --------------------------------------------------------------------------------------


def _image_sizes(image_dir: Path, names: list[str]) -> dict[str, tuple[int, int]]:
    sizes = {}
    for name in names:
        path = image_dir / name
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise InputError(f"{path}: not a readable image")
        sizes[name] = (int(image.shape[1]), int(image.shape[0]))
    return sizes


def _resolve_device(device: str) -> pycolmap.Device:
    if device == "cuda":
        if pycolmap.has_cuda:
            return pycolmap.Device.cuda
        log.warning("pycolmap was built without CUDA; SIFT runs on the CPU")
    return pycolmap.Device.cpu


def _two_view_options(seed: int) -> pycolmap.TwoViewGeometryOptions:
    opts = pycolmap.TwoViewGeometryOptions()
    opts.ransac.random_seed = seed
    opts.ransac.max_num_trials = VERIFY_MAX_RANSAC_TRIALS
    return opts


def _build_vocabulary(db_path: Path, out_path: Path, seed: int, deterministic: bool) -> Path:
    """A small visual vocabulary from the database's own descriptors (for loop detection)."""
    db = pycolmap.Database.open(db_path)
    try:
        chunks = [db.read_descriptors(im.image_id).to_float().data for im in db.read_all_images()]
    finally:
        db.close()
    descriptors = np.concatenate([c for c in chunks if len(c)]).astype(np.float32)
    rng = np.random.default_rng(seed)
    if len(descriptors) > 200_000:
        descriptors = descriptors[np.sort(rng.choice(len(descriptors), 200_000, replace=False))]
    # ~64 training descriptors per word, a power of two between 64 and 16384 words
    words = int(2 ** np.clip(np.floor(np.log2(max(len(descriptors), 1) / 64)), 6, 14))
    index = pycolmap.VisualIndex.create(descriptors.shape[1], 64)
    build = pycolmap.VisualIndex.BuildOptions()
    build.num_visual_words = words
    build.num_iterations = 20
    build.num_threads = 1 if deterministic else -1
    index.build(build, pycolmap.FeatureDescriptorsFloat(pycolmap.FeatureExtractorType.SIFT, descriptors))
    index.write(out_path)
    return out_path


def _matching_threads(options: SfmOptions) -> int:
    """Threads for matching and two-view verification: one when ``deterministic`` (their threads' order shows in
    the result), else ``num_threads``."""
    return 1 if options.deterministic else options.num_threads


def _match(db_path: Path, work_dir: Path, n_images: int, options: SfmOptions, device: pycolmap.Device) -> None:
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = _matching_threads(options)
    matching.use_gpu = device == pycolmap.Device.cuda
    verification = _two_view_options(options.seed)
    if options.matcher == "exhaustive":
        pycolmap.match_exhaustive(db_path, matching_options=matching, verification_options=verification,
                                  device=device)
        return
    pairing = pycolmap.SequentialPairingOptions()
    pairing.overlap = options.overlap
    pairing.quadratic_overlap = True
    pairing.num_threads = 1 if options.deterministic else options.num_threads
    if options.loop_detection and n_images > 2 * options.overlap + 2:
        pairing.loop_detection = True
        pairing.vocab_tree_path = _build_vocabulary(db_path, work_dir / "vocabulary.bin", options.seed,
                                                    options.deterministic)
        pairing.loop_detection_period = max(1, options.overlap // 2)
        pairing.loop_detection_num_images = options.overlap
        pairing.loop_detection_min_index_distance = options.overlap + 1
    # The pairs are generated first and matched as an explicit list: pycolmap's match_sequential
    # with loop detection and several threads sometimes drops a pair (seen with 4.2.1), so the
    # same input could give different matches.
    db = pycolmap.Database.open(db_path)
    try:
        names = {im.image_id: im.name for im in db.read_all_images()}
        pairs = pycolmap.SequentialPairGenerator(pairing, db).all_pairs()
    finally:
        db.close()
    if any(len(name.split()) != 1 for name in names.values()):  # the pair list is space-separated
        pycolmap.match_sequential(db_path, matching_options=matching, pairing_options=pairing,
                                  verification_options=verification, device=device)
        return
    unique = dict.fromkeys((min(a, b), max(a, b)) for a, b in pairs if a != b)
    pair_file = work_dir / "pairs.txt"
    pair_file.write_text("".join(f"{names[a]} {names[b]}\n" for a, b in unique))
    imported = pycolmap.ImportedPairingOptions()
    imported.match_list_path = pair_file
    pycolmap.match_image_pairs(db_path, matching_options=matching, pairing_options=imported,
                               verification_options=verification, device=device)


def _set_cameras(db_path: Path, make: Callable[[pycolmap.Camera], pycolmap.Camera], reverify: bool,
                 seed: int, num_threads: int) -> None:
    """Replace every camera of the database by ``make(old)``; re-run verification if asked."""
    db = pycolmap.Database.open(db_path)
    try:
        for cam in db.read_all_cameras():
            db.update_camera(make(cam))
        if reverify:
            db.clear_two_view_geometries()
    finally:
        db.close()
    if reverify:
        verifier = pycolmap.GeometricVerifierOptions()
        verifier.num_threads = num_threads
        pycolmap.geometric_verification(db_path, verifier_options=verifier,
                                        two_view_geometry_options=_two_view_options(seed))


#: COLMAP's bound on a camera's distortion coefficients when the camera is known and fixed (no bound).
KNOWN_CAMERA_MAX_EXTRA_PARAM = float(np.finfo(np.float32).max)
#: The smallest angle between two rays a point is triangulated from when the poses are known (COLMAP: 1.5 deg).
KNOWN_POSES_MIN_ANGLE_DEG = 1.0


def _triangulate_known(db_path: Path, image_dir: Path, out_dir: Path, known_poses: Mapping[str, np.ndarray],
                       options: SfmOptions) -> pycolmap.Reconstruction:
    """The database's images at ``known_poses`` (camera-to-world, OpenCV axes, by image name) with their matched
    features triangulated; the cameras are the database's (the known camera) and stay fixed."""
    db = pycolmap.Database.open(db_path)
    try:
        rec = pycolmap.Reconstruction()
        for cam in db.read_all_cameras():
            rec.add_camera_with_trivial_rig(cam)
        for image in db.read_all_images():
            keypoints = db.read_keypoints(image.image_id)[:, :2].astype(np.float64)
            points = pycolmap.Point2DList([pycolmap.Point2D(xy) for xy in keypoints])
            posed = pycolmap.Image(name=image.name, camera_id=image.camera_id, image_id=image.image_id,
                                   points2D=points)
            w2c = invert_se3(np.asarray(known_poses[image.name], dtype=np.float64))
            rec.add_image_with_trivial_frame(posed, pycolmap.Rigid3d(w2c[:3, :]))
    finally:
        db.close()
    opts = _mapper_options(options, refine_intrinsics=False)
    opts.triangulation.min_angle = KNOWN_POSES_MIN_ANGLE_DEG
    if out_dir.exists():
        shutil.rmtree(out_dir)
    out_dir.mkdir(parents=True)
    return pycolmap.triangulate_points(rec, db_path, image_dir, out_dir, options=opts)


def _mapper_options(options: SfmOptions, refine_intrinsics: bool) -> pycolmap.IncrementalPipelineOptions:
    opts = pycolmap.IncrementalPipelineOptions()
    if not refine_intrinsics:
        # a known camera kept fixed: COLMAP's check for diverged distortion (|coefficient| > 1) would only
        # refuse a calibrated camera that exceeds it (module docstring, "A known camera is not judged")
        opts.max_extra_param = KNOWN_CAMERA_MAX_EXTRA_PARAM
        opts.mapper.max_extra_param = KNOWN_CAMERA_MAX_EXTRA_PARAM
        opts.triangulation.max_extra_param = KNOWN_CAMERA_MAX_EXTRA_PARAM
    opts.num_threads = 1 if options.deterministic else options.num_threads
    opts.random_seed = options.seed
    opts.multiple_models = True
    opts.max_num_models = 10
    opts.extract_colors = True
    opts.ba_refine_focal_length = refine_intrinsics
    opts.ba_refine_extra_params = refine_intrinsics
    opts.ba_refine_principal_point = False
    opts.mapper.abs_pose_refine_focal_length = refine_intrinsics
    opts.mapper.abs_pose_refine_extra_params = refine_intrinsics
    opts.mapper.random_seed = options.seed
    opts.mapper.num_threads = opts.num_threads
    opts.triangulation.random_seed = options.seed
    return opts


def _incremental_mapping(db_path: Path, image_dir: Path, out_dir: Path, names: list[str], options: SfmOptions,
                         refine_intrinsics: bool,
                         on_image: Callable[[], None] | None) -> dict[int, pycolmap.Reconstruction]:
    """One incremental mapping run; returns every model COLMAP made."""
    if out_dir.exists():
        shutil.rmtree(out_dir)
    out_dir.mkdir(parents=True)
    opts = _mapper_options(options, refine_intrinsics)
    opts.image_names = names
    return pycolmap.incremental_mapping(db_path, image_dir, out_dir, options=opts, next_image_callback=on_image)


def _map_once(db_path: Path, image_dir: Path, out_dir: Path, names: list[str], options: SfmOptions,
              refine_intrinsics: bool, on_image: Callable[[], None] | None) -> tuple[pycolmap.Reconstruction | None, int]:
    """One incremental mapping run; returns (largest model or None, number of models)."""
    models = _incremental_mapping(db_path, image_dir, out_dir, names, options, refine_intrinsics, on_image)
    if not models:
        return None, 0
    best = max(sorted(models), key=lambda k: (models[k].num_reg_images(), -k))
    return models[best], len(models)


def _check_far_pairs(db_path: Path, image_dir: Path, out_dir: Path, names: list[str], options: SfmOptions,
                     refine_intrinsics: bool) -> tuple[int, int]:
    """Drop far pairs that disagree with a model of the near pairs; returns (checked, dropped).

    Near pairs are at most ``options.overlap`` apart in ``names`` (time) order; every other
    verified pair is far. The near pairs of a copy of the database are mapped, and a far pair
    whose two images lie in one of the models is checked: each inlier match with a 3D point
    (from the first image's keypoint, else the second's) is projected into the other image,
    and the pair's two-view geometry is deleted from ``db_path`` when fewer than
    ``FAR_PAIR_MIN_AGREEING`` of them land within ``FAR_PAIR_MAX_ERROR_FRACTION * max(W, H)``
    of the matched keypoint. Pairs that cannot be checked (an image outside every model, or
    fewer than ``FAR_PAIR_MIN_CHECKABLE`` matches with a 3D point) are kept.
    """
    position = {name: k for k, name in enumerate(names)}
    db = pycolmap.Database.open(db_path)
    try:
        image_name = {im.image_id: im.name for im in db.read_all_images()}
        pair_ids, geometries = db.read_two_view_geometries()
    finally:
        db.close()
    far = []
    for pair_id, geometry in zip(pair_ids, geometries, strict=True):
        a, b = pycolmap.pair_id_to_image_pair(pair_id)
        if abs(position[image_name[a]] - position[image_name[b]]) > options.overlap and len(geometry.inlier_matches):
            far.append((a, b, np.asarray(geometry.inlier_matches)))
    if not far:
        return 0, 0
    near_db = out_dir / "near.db"
    out_dir.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(db_path, near_db)
    db = pycolmap.Database.open(near_db)
    try:
        for a, b, _ in far:
            db.delete_two_view_geometry(a, b)
    finally:
        db.close()
    models = _incremental_mapping(near_db, image_dir, out_dir / "models", names, options, refine_intrinsics, None)
    views = {}  # image id -> (model index, world_to_cam (4, 4), Camera, keypoints (K, 2) OpenCV px, point3D ids (K,))
    points = {}
    for k in sorted(models):
        rec = models[k]
        points[k] = rec.points3D
        for image in rec.images.values():
            if image.has_pose and image.image_id not in views:
                w2c = np.eye(4)
                w2c[:3, :] = image.cam_from_world().matrix()
                p2d = image.points2D
                xy = np.array([p.xy for p in p2d], dtype=np.float64).reshape(-1, 2) - 0.5
                ids = np.array([p.point3D_id if p.has_point3D() else -1 for p in p2d], dtype=np.int64)
                views[image.image_id] = (k, w2c, camera_from_colmap(image.camera), xy, ids)
    checked, drop = 0, []
    for a, b, matches in far:
        if a not in views or b not in views or views[a][0] != views[b][0]:
            continue
        k = views[a][0]
        pid_a, pid_b = views[a][4][matches[:, 0]], views[b][4][matches[:, 1]]
        use_a = pid_a >= 0
        has = use_a | (pid_b >= 0)
        if has.sum() < FAR_PAIR_MIN_CHECKABLE:
            continue
        checked += 1
        agree = 0
        # a's 3D point projected into b where a's keypoint has one, else b's point into a
        for sel, pids, target, column in ((use_a, pid_a, views[b], 1), (has & ~use_a, pid_b, views[a], 0)):
            if not sel.any():
                continue
            _, w2c, cam, xy, _ = target
            xyz = np.array([points[k][int(i)].xyz for i in pids[sel]], dtype=np.float64)
            uv, valid = cam.project(xyz @ w2c[:3, :3].T + w2c[:3, 3])
            tol = FAR_PAIR_MAX_ERROR_FRACTION * max(cam.width, cam.height)
            close = np.linalg.norm(uv - xy[matches[sel, column]], axis=1) < tol
            agree += int(np.sum(np.asarray(valid) & close))
        if agree < FAR_PAIR_MIN_AGREEING * has.sum():
            drop.append((a, b))
    if drop:
        db = pycolmap.Database.open(db_path)
        try:
            for a, b in drop:
                db.delete_two_view_geometry(a, b)
        finally:
            db.close()
    log.info("far-pair check: %d of %d far pairs checked against %d near-pairs model(s); %d disagreed and were dropped",
             checked, len(far), len(models), len(drop))
    return checked, len(drop)


def _reject_pose_jumps(rec: pycolmap.Reconstruction, names: list[str]) -> list[str]:
    """De-register frames whose pose jumps away from both temporal neighbours; returns their names.

    For ordered (video) input. A frame is rejected when its rotation differs from both its
    previous and its next registered frame by more than ``JUMP_MIN_ROTATION_DEG`` while those
    two agree to within half of that difference, or likewise its centre is more than
    ``JUMP_MIN_STEPS`` median frame steps from both. On the full-size fisheye test room one frame of
    150 was registered mirrored (180 deg, 4 m off) with 362 consistent points; nothing else
    in COLMAP's statistics set it apart.
    """
    from nsim.geometry.transforms import rotation_angle_deg

    reg = [rec.find_image_with_name(n) for n in names]
    reg = [im for im in reg if im is not None and im.has_pose]
    if len(reg) < 3:
        return []
    w2c = np.stack([np.vstack([im.cam_from_world().matrix(), [0.0, 0.0, 0.0, 1.0]]) for im in reg])
    c2w = invert_se3(w2c)
    R, c = c2w[:, :3, :3], c2w[:, :3, 3]
    step = float(np.median(np.linalg.norm(np.diff(c, axis=0), axis=1)))
    rejected = []
    for i in range(len(reg)):
        a, b = (i - 1, i + 1) if 0 < i < len(reg) - 1 else ((i + 1, i + 2) if i == 0 else (i - 1, i - 2))
        rot = min(rotation_angle_deg(R[i], R[a]), rotation_angle_deg(R[i], R[b]))
        rot_ab = rotation_angle_deg(R[a], R[b])
        dist = min(np.linalg.norm(c[i] - c[a]), np.linalg.norm(c[i] - c[b]))
        dist_ab = np.linalg.norm(c[a] - c[b])
        if (rot > JUMP_MIN_ROTATION_DEG and rot_ab < 0.5 * rot) or (
                dist > JUMP_MIN_STEPS * step and dist_ab < 0.5 * dist):
            log.warning("%s: pose %.0f deg and %.1f frame steps away from both neighbours; left unregistered",
                        reg[i].name, rot, dist / max(step, 1e-12))
            rejected.append(reg[i])
    for im in rejected:
        rec.deregister_frame(im.frame_id)
    return [im.name for im in rejected]


def _bundle_adjust(rec: pycolmap.Reconstruction, options: SfmOptions, refine_intrinsics: bool,
                   principal_point: bool) -> None:
    ba = pycolmap.BundleAdjustmentOptions()
    ba.refine_focal_length = refine_intrinsics
    ba.refine_extra_params = refine_intrinsics
    ba.refine_principal_point = principal_point
    ba.print_summary = False
    ba.ceres.solver_options.num_threads = 1 if options.deterministic else options.num_threads
    pycolmap.bundle_adjustment(rec, ba)


def _principal_point_shift(rec: pycolmap.Reconstruction) -> float:
    """The largest distance of a camera's principal point from its image centre, as a fraction of max(W, H)."""
    shift = 0.0
    for cam in rec.cameras.values():
        d = math.hypot(cam.principal_point_x - cam.width / 2.0, cam.principal_point_y - cam.height / 2.0)
        shift = max(shift, d / max(cam.width, cam.height))
    return shift


def _global_bundle_adjustment(rec: pycolmap.Reconstruction, options: SfmOptions,
                              refine_intrinsics: bool) -> tuple[pycolmap.Reconstruction, dict[str, Any]]:
    """The final bundle adjustment, then (``refine_principal_point``) the same with the principal point free.

    Returns the reconstruction to keep and what was decided (for report.json). In "auto", the
    refined copy is kept only with one shared camera, at least PP_AUTO_MIN_IMAGES registered images,
    a reprojection error lower by PP_AUTO_MIN_GAIN and a principal point within PP_AUTO_MAX_SHIFT of
    the centre: a phone's lens is rarely centred on its sensor (15.5 px on a 1080x1920 phone
    capture), but on few images or on centred synthetic cameras freeing it only fits noise.
    """
    _bundle_adjust(rec, options, refine_intrinsics, principal_point=False)
    mode = options.refine_principal_point
    info: dict[str, Any] = {"mode": mode, "refined": False}
    if not refine_intrinsics or mode == "off":
        return rec, info
    n_reg, n_cams = rec.num_reg_images(), len(rec.cameras)
    if mode == "auto" and (n_cams != 1 or n_reg < PP_AUTO_MIN_IMAGES):
        info["why"] = f"auto: {n_reg} registered images, {n_cams} camera(s); needs one camera and >= {PP_AUTO_MIN_IMAGES}"
        return rec, info
    trial = pycolmap.Reconstruction(rec)
    _bundle_adjust(trial, options, refine_intrinsics, principal_point=True)
    before, after = rec.compute_mean_reprojection_error(), trial.compute_mean_reprojection_error()
    shift = _principal_point_shift(trial)
    info.update(reprojection_error_px_fixed=round(float(before), 6), reprojection_error_px_refined=round(float(after), 6),
                shift_fraction=round(float(shift), 6))
    gain = (before - after) / max(before, 1e-12)
    if mode == "on" or (gain >= PP_AUTO_MIN_GAIN and shift <= PP_AUTO_MAX_SHIFT):
        info["refined"] = True
        return trial, info
    info["why"] = (f"auto: refining gained {gain:.1%} (needs {PP_AUTO_MIN_GAIN:.1%}) with the principal point "
                   f"{shift:.1%} of the image size off centre (allowed {PP_AUTO_MAX_SHIFT:.0%})")
    return rec, info


@contextlib.contextmanager
def colmap_log_level(level: int | None = None) -> Iterator[None]:
    """Set COLMAP's (glog) minimum log level for a block: 0 info, 1 warning, 2 error, 3 fatal.

    Default: info when this module's logger is at DEBUG (``nsim -vv``), warnings and errors at
    INFO (``-v``), else fatal only: COLMAP's messages are per image and per pair, far too much
    for a terminal, and nsim reports failures itself in one line.
    """
    if level is None:
        level = 0 if log.isEnabledFor(logging.DEBUG) else 1 if log.isEnabledFor(logging.INFO) else 3
    old = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = level
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = old


def run_sfm(
    image_dir: str | os.PathLike,
    work_dir: str | os.PathLike,
    options: SfmOptions = SfmOptions(),  # noqa: B008  (frozen: immutable)
    known_camera: Camera | None = None,
    image_names: list[str] | None = None,
    progress: ProgressFn | None = None,
    mask_dir: str | os.PathLike | None = None,
    known_poses: Mapping[str, np.ndarray] | None = None,
) -> SfmResult:
    """Reconstruct the images ``image_names`` (default: every jpg/jpeg/png) of ``image_dir``.

    known_poses: camera-to-world (4 x 4, OpenCV axes) of every image, by name; with a
    ``known_camera`` the images are not mapped but placed there and their features triangulated
    (module docstring, "Known poses"); the result's world is then the poses'.

    mask_dir: optional feature masks, COLMAP's convention: ``<mask_dir>/<image name>.png``, no
    features where the mask is 0 (e.g. a person walking through the view).

    work_dir receives COLMAP's database, the vocabulary and one model folder per mapping
    attempt (it is emptied first). ``known_camera`` fixes the intrinsics of every image (kept
    fixed unless ``options.refine_known_intrinsics``); its size must match the images.

    Raises InputError for fewer than 3 images, mixed image sizes with shared intrinsics, a
    known camera of the wrong size, or fewer than ``options.min_registered_fraction`` of the
    images registered; the message says what to change.
    """
    with colmap_log_level(), native_stderr_to_log():
        return _run_sfm(Path(image_dir), Path(work_dir), options, known_camera, image_names, progress, mask_dir,
                        known_poses)


_NATIVE_LINE = re.compile(r"^([IWEF]\d{8} |WARNING clustering |Clustering |Sampling )")


@contextlib.contextmanager
def native_stderr_to_log() -> Iterator[None]:
    """Route what C++ code (COLMAP's glog, faiss) prints on file descriptor 2 into this logger.

    Some COLMAP messages (bundle adjustment headings) ignore ``minloglevel``, and faiss warns
    with ``fprintf(stderr)``; neither belongs on a user's terminal. The block's fd-2 output goes
    to a temporary file; afterwards native lines are logged at DEBUG (``nsim -vv`` shows them)
    and any other line (Python's own output in the block) is written back to stderr.
    """
    import sys
    import tempfile

    try:
        fd = sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):  # stderr replaced (pytest capture, notebooks)
        yield
        return
    sys.stderr.flush()
    saved = os.dup(fd)
    with tempfile.TemporaryFile(mode="w+b") as sink:
        os.dup2(sink.fileno(), fd)
        try:
            yield
        finally:
            sys.stderr.flush()
            os.dup2(saved, fd)
            os.close(saved)
            sink.seek(0)
            for line in sink.read().decode(errors="replace").splitlines():
                if _NATIVE_LINE.match(line):
                    log.debug("colmap: %s", line)
                elif line.strip():
                    sys.stderr.write(line + "\n")


def _run_sfm(image_dir: Path, work_dir: Path, options: SfmOptions, known_camera: Camera | None,
             image_names: list[str] | None, progress: ProgressFn | None,
             mask_dir: str | os.PathLike | None = None,
             known_poses: Mapping[str, np.ndarray] | None = None) -> SfmResult:
    from nsim.sfm.frames import MIN_IMAGES, list_image_files

    t_start = time.perf_counter()
    names = list(image_names) if image_names is not None else [p.name for p in list_image_files(image_dir)]
    if len(names) < MIN_IMAGES:
        raise InputError(f"{image_dir}: {len(names)} images to reconstruct; need at least {MIN_IMAGES}")
    if len(set(names)) != len(names):
        raise ValueError("image_names: names must be unique")
    sizes = _image_sizes(image_dir, names)
    if options.shared_intrinsics and len(set(sizes.values())) > 1:
        first = names[0]
        other = next(n for n in names if sizes[n] != sizes[first])
        raise InputError(
            f"{image_dir / other}: image is {sizes[other][0]}x{sizes[other][1]} but {first} is "
            f"{sizes[first][0]}x{sizes[first][1]}; shared intrinsics need one image size "
            "(resize the images or reconstruct with per-image intrinsics)")
    if known_camera is not None:
        bad = [n for n in names if sizes[n] != (known_camera.width, known_camera.height)]
        if bad:
            raise InputError(f"{image_dir / bad[0]}: image is {sizes[bad[0]][0]}x{sizes[bad[0]][1]} but the known "
                             f"camera is {known_camera.width}x{known_camera.height}")
    if known_poses is not None:
        if known_camera is None:
            raise InputError("known poses need a known camera (--intrinsics): only the points are triangulated")
        if missing := [n for n in names if n not in known_poses]:
            raise InputError(f"{image_dir / missing[0]}: no known pose for this image ({len(missing)} of {len(names)} "
                             "without one)")
    if work_dir.exists():
        shutil.rmtree(work_dir)
    work_dir.mkdir(parents=True)
    db_path = work_dir / "database.db"
    device = _resolve_device(options.device)
    pycolmap.set_random_seed(options.seed)
    model = options.camera_model if known_camera is None else camera_to_colmap(known_camera).model_name
    wall: dict[str, float] = {}
    report = progress or (lambda phase, done, total: None)
    n = len(names)

    # Features. The reader makes one camera (shared) or one per image; both are replaced below
    # by the known camera or the first focal-length guess.
    t = time.perf_counter()
    report("features", 0, n)
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = model
    if mask_dir is not None:
        reader.mask_path = str(mask_dir)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = options.num_threads
    extraction.use_gpu = device == pycolmap.Device.cuda
    extraction.sift.max_num_features = options.max_features
    mode = pycolmap.CameraMode.SINGLE if options.shared_intrinsics else pycolmap.CameraMode.PER_IMAGE
    # Import first: image ids then follow the name order. Extraction alone numbers images in the
    # order its threads finish, and the mapper's choices depend on the ids (not deterministic).
    pycolmap.Database.open(db_path).close()
    pycolmap.import_images(db_path, image_dir, camera_mode=mode, image_names=names, options=reader)
    pycolmap.extract_features(db_path, image_dir, image_names=names, camera_mode=mode, reader_options=reader,
                              extraction_options=extraction, device=device)

    def camera_for(guess: float | None) -> Callable[[pycolmap.Camera], pycolmap.Camera]:
        def make(old: pycolmap.Camera) -> pycolmap.Camera:
            if guess is None:
                return camera_to_colmap(known_camera, old.camera_id)
            return _guess_camera(model, old.width, old.height, guess, old.camera_id,
                                 prior=guess == options.focal_prior_hfov_deg)
        return make

    guesses: list[float | None] = [None] if known_camera is not None else list(options.hfov_guesses)
    _set_cameras(db_path, camera_for(guesses[0]), reverify=False, seed=options.seed,
                 num_threads=_matching_threads(options))
    wall["features"] = time.perf_counter() - t
    report("features", n, n)

    t = time.perf_counter()
    report("matching", 0, 1)
    _match(db_path, work_dir, n, options, device)
    wall["matching"] = time.perf_counter() - t
    report("matching", 1, 1)

    if known_poses is not None:
        t = time.perf_counter()
        report("triangulation", 0, 1)
        rec = _triangulate_known(db_path, image_dir, work_dir / "known_poses", known_poses, options)
        wall["triangulation"] = time.perf_counter() - t
        report("triangulation", 1, 1)
        if rec.num_points3D() == 0:
            raise InputError(f"{image_dir}: no point triangulated from the known poses (the cameras barely move, or "
                             "the poses do not belong to these images)")
        wall["total"] = time.perf_counter() - t_start
        model_dir = work_dir / "sparse"
        model_dir.mkdir()
        rec.write(model_dir)
        return _result(rec, names, 1, [{"known_poses": True, "registered": rec.num_reg_images(), "models": 1}],
                       "cuda" if device == pycolmap.Device.cuda else "cpu", wall)

    # Mapping, retried with the next focal-length guess while too few images register.
    t = time.perf_counter()
    refine = known_camera is None or options.refine_known_intrinsics
    best: tuple[pycolmap.Reconstruction | None, int] = (None, 0)
    attempts: list[dict[str, Any]] = []
    registered = [0]

    def on_image() -> None:
        registered[0] += 1
        report("mapping", min(registered[0], n), n)

    far_checked = far_dropped = 0
    check_far = options.matcher == "sequential"
    for k, guess in enumerate(guesses):
        reverified = k == 0
        if k > 0:
            # Perspective pairs were verified without a focal prior: only fisheye needs re-verifying.
            reverified = model in FISHEYE_MODELS
            _set_cameras(db_path, camera_for(guess), reverify=reverified, seed=options.seed,
                         num_threads=_matching_threads(options))
        if check_far and reverified:
            t_check = time.perf_counter()
            report("far_pair_check", 0, 1)
            checked, dropped = _check_far_pairs(db_path, image_dir, work_dir / f"near{k}", names, options, refine)
            report("far_pair_check", 1, 1)
            far_checked, far_dropped = far_checked + checked, far_dropped + dropped
            wall["far_pair_check"] = wall.get("far_pair_check", 0.0) + time.perf_counter() - t_check
        registered[0] = 0
        report("mapping", 0, n)
        rec, n_models = _map_once(db_path, image_dir, work_dir / f"attempt{k}", names, options, refine, on_image)
        n_reg = rec.num_reg_images() if rec is not None else 0
        attempts.append({"hfov_guess_deg": guess, "registered": n_reg, "models": n_models})
        log.info("mapping attempt %d (hfov guess %s deg): %d of %d images registered in %d model(s)",
                 k, guess, n_reg, n, n_models)
        if rec is not None and (best[0] is None or n_reg > best[0].num_reg_images()):
            best = (rec, n_models)
        if n_reg >= options.retry_below_fraction * n:
            break
    rec, n_models = best
    # Sequential matching means ordered frames: a pose that jumps away from both neighbours is wrong.
    rejected = _reject_pose_jumps(rec, names) if rec is not None and options.matcher == "sequential" else []
    wall["mapping"] = time.perf_counter() - t - wall.get("far_pair_check", 0.0)
    n_reg = rec.num_reg_images() if rec is not None else 0
    if n_reg < max(options.min_registered_fraction * n, 2) or rec is None:
        raise InputError(
            f"only {n_reg} of {n} frames registered (need at least {options.min_registered_fraction:.0%}): "
            "capture with more overlap between frames (move the camera more slowly) or select more frames (--frames)")

    t = time.perf_counter()
    report("bundle_adjustment", 0, 1)
    rec, pp_info = _global_bundle_adjustment(rec, options, refine)
    wall["bundle_adjustment"] = time.perf_counter() - t
    report("bundle_adjustment", 1, 1)
    wall["total"] = time.perf_counter() - t_start

    model_dir = work_dir / "sparse"
    model_dir.mkdir()
    rec.write(model_dir)
    return _result(rec, names, n_models, attempts, "cuda" if device == pycolmap.Device.cuda else "cpu", wall,
                   rejected, (far_checked, far_dropped), pp_info)


def _result(rec: pycolmap.Reconstruction, names: list[str], n_models: int, attempts: list[dict[str, Any]],
            device: str, wall: dict[str, float], rejected: list[str] = (),
            far_pairs: tuple[int, int] = (0, 0), principal_point: dict[str, Any] | None = None) -> SfmResult:
    cam_to_world, cameras = {}, {}
    for image in rec.images.values():
        if not image.has_pose:
            continue
        w2c = np.eye(4)
        w2c[:3, :] = image.cam_from_world().matrix()
        cam_to_world[image.name] = invert_se3(w2c)
        cameras[image.name] = camera_from_colmap(image.camera)
    ids = sorted(rec.points3D)
    pts = [rec.points3D[i] for i in ids]
    xyz = np.array([p.xyz for p in pts], dtype=np.float64).reshape(-1, 3)
    rgb = np.array([p.color for p in pts], dtype=np.uint8).reshape(-1, 3)
    track = np.array([p.track.length() for p in pts], dtype=np.int64)
    err, mean_err = _reprojection_errors(rec, ids, xyz, cam_to_world, cameras)
    stats = SfmStats(
        images_given=len(names),
        images_registered=len(cam_to_world),
        unregistered=tuple(n for n in names if n not in cam_to_world),
        rejected=tuple(rejected),
        mean_reprojection_error_px=mean_err,
        mean_track_length=float(rec.compute_mean_track_length()),
        num_points3d=len(ids),
        num_models=n_models,
        attempts=tuple(attempts),
        device=device,
        phase_wall_s={k: round(v, 3) for k, v in wall.items()},
        far_pairs_checked=far_pairs[0],
        far_pairs_dropped=far_pairs[1],
        principal_point=dict(principal_point or {}),
    )
    return SfmResult(rec, tuple(names), cam_to_world, cameras, xyz, rgb, err, track, stats)


def _reprojection_errors(rec: pycolmap.Reconstruction, ids: list[int], xyz: np.ndarray,
                         cam_to_world: dict[str, np.ndarray], cameras: dict[str, Camera]) -> tuple[np.ndarray, float]:
    """Per-point mean reprojection error (px) and their mean, projected with nsim's cameras.

    Same definitions as COLMAP's ``Point3D.error`` and ``compute_mean_reprojection_error``
    (equal to 1e-13 px on perspective models), but COLMAP's own ``Point3D.error`` is astronomically large (1e153) for a fisheye point seen at
    exactly 90 deg off-axis, which made the mean meaningless; nsim's fisheye model handles it.
    """
    row = {pid: k for k, pid in enumerate(ids)}
    err_sum = np.zeros(len(ids))
    count = np.zeros(len(ids))
    for image in rec.images.values():
        if not image.has_pose:
            continue
        obs = image.get_observation_points2D()
        if not obs:
            continue
        uv_obs = np.array([p.xy for p in obs], dtype=np.float64) - 0.5  # COLMAP -> OpenCV pixel centres
        k = np.array([row[p.point3D_id] for p in obs])
        w2c = invert_se3(cam_to_world[image.name])
        uv, _ = cameras[image.name].project(xyz[k] @ w2c[:3, :3].T + w2c[:3, 3])
        np.add.at(err_sum, k, np.linalg.norm(uv - uv_obs, axis=1))
        np.add.at(count, k, 1.0)
    per_point = err_sum / np.maximum(count, 1.0)
    return per_point, float(per_point.mean()) if len(per_point) else 0.0


def transform_result(result: SfmResult, s: float, R: np.ndarray, t: np.ndarray) -> SfmResult:
    """The same reconstruction in a new world frame ``x -> s R x + t``; ``result`` is not modified.

    Poses, points and the pycolmap model (a copy, transformed with ``Reconstruction.transform``)
    move together; intrinsics, errors in pixels and statistics are unchanged.
    """
    from nsim.sfm.align import apply_sim3_to_points, apply_sim3_to_poses

    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64).reshape(3)
    rec = pycolmap.Reconstruction(result.reconstruction)
    rec.transform(pycolmap.Sim3d(float(s), pycolmap.Rotation3d(R), t))
    c2w = {name: apply_sim3_to_poses(s, R, t, pose) for name, pose in result.cam_to_world.items()}
    return dataclasses.replace(result, reconstruction=rec, cam_to_world=c2w,
                               points_xyz=apply_sim3_to_points(s, R, t, result.points_xyz))


def write_model(result: SfmResult, model_dir: str | os.PathLike) -> Path:
    """Write the COLMAP model (binary cameras.bin, images.bin, points3D.bin, rigs.bin, frames.bin)."""
    out = Path(model_dir)
    out.mkdir(parents=True, exist_ok=True)
    result.reconstruction.write(out)
    return out
