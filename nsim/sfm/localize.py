"""Localise single images in a scene's sparse model: where in the scene was this camera?

A scene is the ``poses`` artifact of ``nsim reconstruct`` (``images/`` and the COLMAP model in
``sparse/``, metric, z up). :func:`build_scene_index` turns it into a :class:`SceneIndex`; then
:func:`localize` finds the ``cam_to_world`` of any image taken in that scene, with any camera
model COLMAP can estimate a pose for (PINHOLE, OPENCV, FULL_OPENCV, OPENCV_FISHEYE): that is
how a robot's camera frames get poses in the scene's world (``nsim.sfm.register`` then places
the robot's odometry frame from them).

The index. Every registered scene image is re-read and its SIFT features extracted again with
pycolmap's own extractor (``pycolmap.FeatureExtractor``, COLMAP's SIFT with the options
``nsim reconstruct`` uses) rather than OpenCV's: the model's 2D observations are COLMAP SIFT
keypoints, so the same extractor on the same image finds them again exactly (0 px on the test
room), and each keypoint gets the 3D point of the observation nearest to it (within
``max_observation_px``; keypoints without a 3D point are dropped). The database that
reconstruct matched in is not kept in the artifact, hence the re-extraction.

Retrieval. Which scene images does the query see? For each scene image a fixed subsample of its
keypoints (those whose 3D points have the longest tracks: the most often matched ones) is
compared with a subsample of the query's descriptors, and the scene images are ranked by the
number of query descriptors passing Lowe's ratio test against that image alone (a brute-force
product of unit descriptors: exact, deterministic, and cheap at this size). The ``top_k`` best
are matched in full (mutual nearest neighbours with the ratio test, COLMAP's defaults 0.8 and
0.7), their 2D-3D matches pooled (per query keypoint the closest descriptor wins), and
``pycolmap.estimate_and_refine_absolute_pose`` (P3P LO-RANSAC, seeded, then a robust
refinement) gives the pose.

Pixels: nsim's (OpenCV) convention everywhere here; COLMAP's keypoints and cameras are
converted at the calls (``COLMAP_PIXEL_OFFSET``, ``camera_to_colmap``).
"""

from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path

import cv2  # noqa: F401  (must precede pycolmap, see nsim.sfm.colmap)
import numpy as np
import pycolmap
from scipy.spatial import cKDTree

from nsim.errors import InputError
from nsim.geometry.cameras import Camera
from nsim.geometry.conventions import COLMAP_PIXEL_OFFSET
from nsim.geometry.transforms import invert_se3
from nsim.sfm.colmap import camera_to_colmap, colmap_log_level
from nsim.sfm.localize_settings import (
    MAX_DESCRIPTOR_DISTANCE,
    MAX_ERROR_FRACTION,
    MAX_FEATURES,
    MAX_OBSERVATION_PX,
    MIN_INLIERS,
    MIN_MAX_ERROR_PX,
    RATIO,
    RETRIEVAL_PER_IMAGE,
    RETRIEVAL_QUERY_FEATURES,
    TOP_K,
)

log = logging.getLogger(__name__)

#: Query descriptors per block of the brute-force products (bounds their memory: matching makes
#: blocks of _CHUNK x scene keypoints, retrieval _RETRIEVAL_CHUNK x images x RETRIEVAL_PER_IMAGE).
_CHUNK = 1024
_RETRIEVAL_CHUNK = 256


@dataclass(frozen=True, eq=False)
class SceneImage:
    """One scene image's keypoints that see a 3D point of the model.

    xy: (M, 2) float64 pixels (OpenCV convention); descriptors: (M, 128) float32, unit L2 norm;
    xyz_world: (M, 3) float64 the 3D points (scene world, metres); point3d_ids: (M,) int64 their
    ids in the model; track_lengths: (M,) int64 how many images observe each point.
    """

    name: str
    xy: np.ndarray
    descriptors: np.ndarray
    xyz_world: np.ndarray
    point3d_ids: np.ndarray
    track_lengths: np.ndarray


@dataclass(frozen=True, eq=False)
class SceneIndex:
    """A scene's images as features with 3D points, plus a retrieval subsample of each.

    retrieval_descriptors: (I, R, 128) float32, up to R keypoints per image (longest tracks
    first), zero rows where an image has fewer; retrieval_valid: (I, R) bool.
    """

    images: tuple[SceneImage, ...]
    retrieval_descriptors: np.ndarray
    retrieval_valid: np.ndarray
    source: str = ""

    @property
    def num_points(self) -> int:
        """Distinct 3D points seen by the indexed keypoints."""
        ids = [im.point3d_ids for im in self.images]
        return int(len(np.unique(np.concatenate(ids)))) if ids else 0


@dataclass(frozen=True, eq=False)
class Localization:
    """An image's pose in the scene.

    cam_to_world: (4, 4) float64, OpenCV camera axes, the scene's world (metres, z up).
    num_matches: 2D-3D matches given to RANSAC; num_inliers: those consistent with the pose.
    median_error_px / rms_error_px: reprojection error of the inliers through the query camera.
    scene_images: the retrieved scene images the matches came from (best first).
    inlier_xy: (n, 2) query pixels (OpenCV convention); inlier_xyz_world: (n, 3) their 3D points.
    """

    cam_to_world: np.ndarray
    num_matches: int
    num_inliers: int
    median_error_px: float
    rms_error_px: float
    scene_images: tuple[str, ...]
    inlier_xy: np.ndarray
    inlier_xyz_world: np.ndarray


# --------------------------------------------------------------------------------------
# Features
# --------------------------------------------------------------------------------------


def _extractor(max_features: int) -> pycolmap.FeatureExtractor:
    options = pycolmap.FeatureExtractionOptions()
    options.num_threads = 1
    options.sift.max_num_features = int(max_features)
    with colmap_log_level():
        return pycolmap.FeatureExtractor.create(options, pycolmap.Device.cpu)


def _sift(extractor: pycolmap.FeatureExtractor, grey: pycolmap.Bitmap) -> tuple[np.ndarray, np.ndarray]:
    """(xy (n, 2) float64 OpenCV pixels, descriptors (n, 128) float32 unit) of a grey bitmap."""
    with colmap_log_level():
        keypoints, descriptors = extractor.extract(grey)
    xy = np.array([(k.x, k.y) for k in keypoints], dtype=np.float64).reshape(-1, 2) - COLMAP_PIXEL_OFFSET
    if not len(xy):
        return xy, np.zeros((0, 128), dtype=np.float32)
    d = np.asarray(descriptors.data, dtype=np.float32).reshape(len(xy), -1)
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    return xy, d


def extract_sift(image: np.ndarray, max_features: int = MAX_FEATURES) -> tuple[np.ndarray, np.ndarray]:
    """COLMAP's SIFT on an image ``(H, W)`` or ``(H, W, 3)`` uint8 (RGB).

    Returns keypoints ``xy (n, 2)`` float64 in OpenCV pixels and ``descriptors (n, 128)``
    float32 with unit norm. Colour is converted to grey by COLMAP (as its feature extraction
    does for image files).
    """
    image = np.asarray(image)
    if image.dtype != np.uint8 or not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)):
        raise ValueError(f"image: expected (H, W) or (H, W, 3) uint8, got {image.dtype} {image.shape}")
    bitmap = pycolmap.Bitmap.from_array(np.ascontiguousarray(image))
    return _sift(_extractor(max_features), bitmap if image.ndim == 2 else bitmap.clone_as_grey())


# --------------------------------------------------------------------------------------
# The index
# --------------------------------------------------------------------------------------


def build_scene_index(poses_dir: str | os.PathLike, *, max_features: int = MAX_FEATURES,
                      max_observation_px: float = MAX_OBSERVATION_PX,
                      retrieval_per_image: int = RETRIEVAL_PER_IMAGE) -> SceneIndex:
    """Index a poses artifact's folder (``images/`` and ``sparse/``) for :func:`localize`.

    Raises InputError when the folder has no sparse model (an imported poses artifact has none)
    or an image the model names is missing.
    """
    root = Path(poses_dir)
    sparse = root / "sparse"
    if not (sparse / "images.bin").is_file() and not (sparse / "images.txt").is_file():
        raise InputError(f"{root}: no COLMAP model in sparse/ (localising needs a poses artifact from nsim "
                         "reconstruct's SfM, not an import)")
    with colmap_log_level():
        rec = pycolmap.Reconstruction(sparse)
    return index_reconstruction(rec, root / "images", max_features=max_features,
                                max_observation_px=max_observation_px, retrieval_per_image=retrieval_per_image,
                                source=str(root))


def index_reconstruction(rec: pycolmap.Reconstruction, image_dir: str | os.PathLike, *,
                         max_features: int = MAX_FEATURES, max_observation_px: float = MAX_OBSERVATION_PX,
                         retrieval_per_image: int = RETRIEVAL_PER_IMAGE, source: str = "") -> SceneIndex:
    """Index the registered images of ``rec`` (files in ``image_dir``, by the model's names), in name order."""
    if retrieval_per_image < 2:
        raise ValueError(f"retrieval_per_image: expected >= 2 (a ratio test needs two neighbours), got "
                         f"{retrieval_per_image}")
    image_dir = Path(image_dir)
    extractor = _extractor(max_features)
    images = []
    for image in sorted((im for im in rec.images.values() if im.has_pose), key=lambda im: im.name):
        path = image_dir / image.name
        if not path.is_file():
            raise InputError(f"{path}: the scene's model names this image but the file is missing")
        grey = pycolmap.Bitmap.read(path, False)
        if grey is None:
            raise InputError(f"{path}: not a readable image")
        xy, desc = _sift(extractor, grey)
        obs = image.get_observation_points2D()
        if not obs or not len(xy):
            continue
        obs_xy = np.array([p.xy for p in obs], dtype=np.float64) - COLMAP_PIXEL_OFFSET
        obs_ids = np.array([p.point3D_id for p in obs], dtype=np.int64)
        dist, nearest = cKDTree(obs_xy).query(xy, distance_upper_bound=max_observation_px)
        keep = np.isfinite(dist)
        if not keep.any():
            continue
        ids = obs_ids[nearest[keep]]
        points = [rec.points3D[int(i)] for i in ids]
        images.append(SceneImage(
            name=image.name, xy=xy[keep], descriptors=desc[keep],
            xyz_world=np.array([p.xyz for p in points], dtype=np.float64).reshape(-1, 3), point3d_ids=ids,
            track_lengths=np.array([p.track.length() for p in points], dtype=np.int64)))
    R = int(retrieval_per_image)
    retrieval = np.zeros((len(images), R, 128), dtype=np.float32)
    valid = np.zeros((len(images), R), dtype=bool)
    for i, im in enumerate(images):
        order = np.argsort(-im.track_lengths, kind="stable")[:R]
        retrieval[i, :len(order)] = im.descriptors[order]
        valid[i, :len(order)] = True
    log.info("scene index %s: %d images, %d indexed keypoints", source, len(images),
             sum(len(im.xy) for im in images))
    return SceneIndex(tuple(images), retrieval, valid, source)


# --------------------------------------------------------------------------------------
# Matching
# --------------------------------------------------------------------------------------


def _top2_distances(query: np.ndarray, scene: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per query row: nearest scene index, nearest and second-nearest distances (unit descriptors).

    query: (n, D); scene: (m, D). Returns (n,) int64, (n,), (n,) float64 (inf when m < 2).
    """
    n, m = len(query), len(scene)
    best = np.zeros(n, dtype=np.int64)
    d1 = np.full(n, np.inf)
    d2 = np.full(n, np.inf)
    if m == 0:
        return best, d1, d2
    for a in range(0, n, _CHUNK):
        sim = query[a:a + _CHUNK] @ scene.T
        if m >= 2:
            top = np.argpartition(-sim, 1, axis=1)[:, :2]
            s = np.take_along_axis(sim, top, axis=1)
            swap = s[:, 1] > s[:, 0]
            top[swap] = top[swap][:, ::-1]
            s[swap] = s[swap][:, ::-1]
            best[a:a + _CHUNK] = top[:, 0]
            d1[a:a + _CHUNK] = np.sqrt(np.maximum(2.0 - 2.0 * s[:, 0], 0.0))
            d2[a:a + _CHUNK] = np.sqrt(np.maximum(2.0 - 2.0 * s[:, 1], 0.0))
        else:
            best[a:a + _CHUNK] = 0
            d1[a:a + _CHUNK] = np.sqrt(np.maximum(2.0 - 2.0 * sim[:, 0], 0.0))
    return best, d1, d2


def match_descriptors(query: np.ndarray, scene: np.ndarray, ratio: float = RATIO,
                      max_distance: float = MAX_DESCRIPTOR_DISTANCE) -> tuple[np.ndarray, np.ndarray]:
    """Mutual nearest neighbours passing the ratio test, between unit descriptors ``(n, D)``, ``(m, D)``.

    Returns ``pairs (k, 2)`` int64 (query row, scene row) and their descriptor distances ``(k,)``.
    """
    best, d1, d2 = _top2_distances(query, scene)
    back, _, _ = _top2_distances(scene, query)
    q = np.arange(len(query))
    ok = (d1 <= max_distance) & (d1 < ratio * d2) & (back[best] == q) if len(scene) else np.zeros(len(query), bool)
    return np.stack([q[ok], best[ok]], axis=1).reshape(-1, 2), d1[ok]


def retrieve(index: SceneIndex, descriptors: np.ndarray, top_k: int = TOP_K, ratio: float = RATIO,
             max_distance: float = MAX_DESCRIPTOR_DISTANCE,
             query_features: int = RETRIEVAL_QUERY_FEATURES) -> tuple[np.ndarray, np.ndarray]:
    """The ``top_k`` scene images sharing the most ratio-test matches with the query.

    descriptors: (n, 128) unit query descriptors (an even subsample of ``query_features`` is
    used). Returns (image indices (k,) best first, their match counts (k,)); images without a
    single match are left out.
    """
    n_img, R, D = index.retrieval_descriptors.shape
    if n_img == 0 or len(descriptors) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    step = max(1, math.ceil(len(descriptors) / query_features))
    q = descriptors[::step]
    flat = index.retrieval_descriptors.reshape(-1, D)
    counts = np.zeros(n_img, dtype=np.int64)
    for a in range(0, len(q), _RETRIEVAL_CHUNK):
        sim = (q[a:a + _RETRIEVAL_CHUNK] @ flat.T).reshape(-1, n_img, R)
        sim = np.where(index.retrieval_valid[None], sim, -2.0)  # padding: distance 2, never a match
        top2 = -np.partition(-sim, 1, axis=2)[:, :, :2]
        d1 = np.sqrt(np.maximum(2.0 - 2.0 * top2[..., 0], 0.0))
        d2 = np.sqrt(np.maximum(2.0 - 2.0 * top2[..., 1], 0.0))
        counts += np.count_nonzero((d1 <= max_distance) & (d1 < ratio * d2), axis=0)
    order = np.argsort(-counts, kind="stable")[:top_k]
    order = order[counts[order] > 0]
    return order, counts[order]


# --------------------------------------------------------------------------------------
# Localisation
# --------------------------------------------------------------------------------------


def localize(image: np.ndarray, camera: Camera, index: SceneIndex, *, top_k: int = TOP_K, ratio: float = RATIO,
             min_inliers: int = MIN_INLIERS, max_error_px: float | None = None, max_features: int = MAX_FEATURES,
             seed: int = 0) -> Localization | None:
    """The pose of ``image`` (``(H, W)`` or ``(H, W, 3)`` uint8, RGB) taken with ``camera`` in ``index``'s scene.

    camera: the image's intrinsics (PINHOLE, OPENCV, FULL_OPENCV or OPENCV_FISHEYE; its size
    must be the image's). top_k: scene images matched in full after retrieval; ratio: Lowe's
    ratio test; min_inliers: fewer RANSAC inliers is a failure; max_error_px: RANSAC's
    reprojection threshold (None: ``MAX_ERROR_FRACTION`` of max(W, H), at least
    ``MIN_MAX_ERROR_PX``); seed: RANSAC's random seed (same inputs, same pose).

    Returns None when the image cannot be localised (too few features, matches or inliers:
    a blank wall, another room), never raising for that; the reason is logged at DEBUG.
    """
    image = np.asarray(image)
    if image.shape[:2] != (camera.height, camera.width):
        raise ValueError(f"image: {image.shape[1]}x{image.shape[0]} but the camera is {camera.width}x{camera.height}")
    colmap_camera = camera_to_colmap(camera)
    xy, desc = extract_sift(image, max_features)
    if len(xy) < 4:
        log.debug("localize: %d SIFT features", len(xy))
        return None
    chosen, _ = retrieve(index, desc, top_k=top_k, ratio=ratio)
    q_idx, xyz, dist = [], [], []
    for i in chosen:
        scene = index.images[int(i)]
        pairs, d = match_descriptors(desc, scene.descriptors, ratio=ratio)
        q_idx.append(pairs[:, 0])
        xyz.append(scene.xyz_world[pairs[:, 1]])
        dist.append(d)
    if not q_idx or sum(len(q) for q in q_idx) < max(4, min_inliers):
        log.debug("localize: %d 2D-3D matches from %d scene images", sum(len(q) for q in q_idx), len(chosen))
        return None
    q_idx, xyz, dist = (np.concatenate(a) for a in (q_idx, xyz, dist))
    # one 3D point per query keypoint: the closest descriptor (ties: the better-ranked image)
    order = np.lexsort((dist, q_idx))
    first = np.r_[True, np.diff(q_idx[order]) != 0]
    keep = order[first]
    q_idx, xyz = q_idx[keep], xyz[keep]
    if len(q_idx) < max(4, min_inliers):
        log.debug("localize: %d distinct 2D-3D matches", len(q_idx))
        return None

    threshold = max_error_px if max_error_px is not None else max(
        MAX_ERROR_FRACTION * max(camera.width, camera.height), MIN_MAX_ERROR_PX)
    estimation = pycolmap.AbsolutePoseEstimationOptions()
    estimation.ransac.max_error = float(threshold)
    estimation.ransac.random_seed = int(seed)
    refinement = pycolmap.AbsolutePoseRefinementOptions()
    with colmap_log_level():
        answer = pycolmap.estimate_and_refine_absolute_pose(
            xy[q_idx] + COLMAP_PIXEL_OFFSET, xyz, colmap_camera, estimation, refinement)
    if answer is None:
        log.debug("localize: RANSAC found no pose among %d matches", len(q_idx))
        return None
    inliers = np.asarray(answer["inlier_mask"], dtype=bool)
    if int(inliers.sum()) < min_inliers:
        log.debug("localize: %d inliers of %d matches (need %d)", int(inliers.sum()), len(q_idx), min_inliers)
        return None
    world_to_cam = np.eye(4)
    world_to_cam[:3, :] = answer["cam_from_world"].matrix()
    cam_to_world = invert_se3(world_to_cam)
    in_xy, in_xyz = xy[q_idx[inliers]], xyz[inliers]
    uv, _ = camera.project(in_xyz @ world_to_cam[:3, :3].T + world_to_cam[:3, 3])
    err = np.linalg.norm(uv - in_xy, axis=1)
    names = tuple(index.images[int(i)].name for i in chosen)
    return Localization(cam_to_world=cam_to_world, num_matches=int(len(q_idx)), num_inliers=int(inliers.sum()),
                        median_error_px=float(np.median(err)), rms_error_px=float(np.sqrt(np.mean(err ** 2))),
                        scene_images=names, inlier_xy=in_xy, inlier_xyz_world=in_xyz)
