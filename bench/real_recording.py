"""Sim against a real recording, on real sensor data: a TUM RGB-D sequence split into a capture the scene trains
on and a robot recording it never saw, imported, registered, rendered and scored (the paper's Tables II/III on a
real Kinect instead of the test room's oracle).

    python bench/real_recording.py SEQUENCE [--quick] [--workspace DIR] [--capture-fraction 0.6]
                                   [--capture-frames N] [--recording-frames N] [--steps N] [--camera fr1|fr2|fr3]
                                   [--capture-poses reference|sfm] [--depth-weight 0.1] [--min-extent-m 0.02]
                                   [--max-residual-deg 3]

``--quick``: 40 capture frames, 6 recorded frames, 300 training steps (about 6 min on 2 cores, the training and the
render of the 12 recorded frames at 640x480 most of it); the default (full) size: 120 capture frames, 24 recorded frames, 8000
steps of 512 rays with the capture's sparse points as depth supervision (``--depth-weight``), 46 min on 2
shared cores (training 17 min, the render of 48 frames 15 min, the SLAM table's SfM 8 min).

SEQUENCE is a TUM RGB-D sequence folder as TUM publishes it: ``rgb/``, ``depth/`` (16-bit PNG, 1/5000 m),
``rgb.txt``, ``depth.txt`` and ``groundtruth.txt`` (the motion-capture trajectory of the colour camera's optical
centre, OpenCV axes). Nothing of it is committed; fetch one, e.g. the whole of ``fr1_rpy`` (723 colour and 722
depth frames, 24 s, the sequence's own ``groundtruth.txt``) that the public repository ``jmstark/gpu_odometry``
carries in its ``data/`` folder (commit aec7c853676c7d809d9fd89e728c3f54b725a63e)::

    git clone --depth 1 https://github.com/jmstark/gpu_odometry /tmp/gpu_odometry
    mv /tmp/gpu_odometry/data /tmp/realseq/rgbd_dataset_freiburg1_rpy

or any sequence from https://cvg.cit.tum.de/data/datasets/rgbd-dataset/download (``.tgz``, unpacked). The TUM
RGB-D dataset is licensed CC BY 4.0 (Sturm et al., IROS 2012).

**The split.** In time: the first ``--capture-fraction`` of the colour frames is the capture (``--capture-frames``
of them, evenly spaced, are reconstructed and trained on), the rest is the robot recording (``--recording-frames``
of them, evenly spaced, with the depth frame nearest each); a gap of 0.5 s between the two keeps the recording's
frames from being neighbours of trained ones. The recording's views must lie where the capture looked, or the scene
cannot render them: the JSON reports ``view_overlap`` (per recorded frame, the smallest angle between its optical
axis and a capture frame's, and the smallest distance between the centres: median and max, and the fraction within
15 degrees).

**The chain**, each step the ``nsim`` command in its own process (as a user would run it), in ``--workspace``
(a temporary one by default):

1. ``nsim reconstruct CAPTURE --reference groundtruth.txt --reference-poses --intrinsics kinect.json``: the
   capture's frames, named by their TUM stamps so the reference is matched by time, placed at their motion-capture
   poses and their SIFT features triangulated there (``--capture-poses reference``, the default: fr1_rpy's Kinect
   turns in place, its centre moving some 5 cm, and pycolmap's SfM registered none of the quick capture's 40
   frames, finding no pair to start from among near-homographies); ``--capture-poses sfm`` runs pycolmap's SfM instead, made metric by the Sim(3) fit of its camera
   centres to the motion capture. Either way the scene is metric *and in the motion-capture frame*;
2. ``nsim train-scene`` on those poses;
3. a recording folder (``nsim.io.robot_folder``'s layout: ``cameras/kinect/`` colour, ``depth/kinect/`` depth with
   TUM's ``depth.txt``, both with the calibrated camera_info.yaml, ``rig.yaml`` with the camera as the body, and
   the motion capture over the recording's stretch as ``trajectory.tum``: a drift-free odometry in the
   motion-capture frame), ``nsim import-log``;
4. ``nsim register-log --poses`` the capture's poses, with three settings a handheld Kinect needs and says
   why: ``register.min_extent_m`` 0.02 (``--min-extent-m``; the default 0.1 m asks the robot to move, and this
   camera's centre moves 5 cm while it turns), ``register.max_median_residual_deg`` 3 (``--max-residual-deg``; the
   default 1 deg is below what localising a frame of a camera turning 100 deg/s gives, about 1.5 deg) and
   ``refine_drift=false`` (the odometry is the motion capture: no drift);
5. ``nsim render --recording``; 6. ``nsim evaluate --table spot-rgb / spot-depth`` (and ``slam`` unless
   ``--quick``) of that render.

``register_err_m`` / ``register_err_deg``: the registered odometry frame against the truth. The recording's
odometry frame *is* the motion-capture frame, and so (by step 1) is the scene's world, so the true odom_to_world is
the identity and the true clock offset 0: the error is the translation norm and rotation angle of the registered
odom_to_world, and ``clock_err_s`` the registered clock offset. With ``--capture-poses sfm`` they include the
reconstruct's own Sim(3) fit error (``reconstruct.fit_rms_m``; 0 with the reference's poses).

Depth is scored on the real sensor's valid pixels (the Kinect's non-zero depth), colour raw and after the per-camera
affine colour correction (``PSNR cc``). The last printed line is one JSON object: ``frames_train, frames_heldout,
register_err_m, register_err_deg, clock_err_s, rgb_psnr, rgb_psnr_corrected, rgb_ssim, rgb_ssim_corrected,
rgb_lpips, rgb_lpips_corrected, depth_absrel, depth_rmse_m, depth_delta1, slam_ate_real_m, slam_ate_sim_m,
scene_heldout_psnr`` (the scene's own held-out capture frames, train-scene's eval.json), ``view_overlap,
reconstruct`` (images given / registered, fit rms), ``localised, tried, na`` (why a metric is null), ``sequence,
sizes, wall_s, steps_s, peak_rss_gb`` (the peak resident memory of this process or any one child,
``resource.getrusage``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from bench.real_capture import nsim  # noqa: E402
from bench.robot_log import column  # noqa: E402

#: TUM RGB-D's calibrated colour cameras (https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats):
#: fx fy cx cy, and the plumb_bob distortion d0..d4 (k1 k2 p1 p2 k3) of the raw colour image.
TUM_CAMERAS: dict[str, tuple[tuple[float, float, float, float], tuple[float, ...]]] = {
    "fr1": ((517.3, 516.5, 318.6, 255.3), (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)),
    "fr2": ((520.9, 521.0, 325.1, 249.7), (0.2312, -0.7849, -0.0033, -0.0001, 0.9172)),
    "fr3": ((535.4, 539.2, 320.1, 247.6), (0.0, 0.0, 0.0, 0.0, 0.0)),
}
CAMERA = "kinect"  # the stream's and the sensor's name in the recording
GAP_S = 0.5  # between the capture's last frame and the recording's first

#: Sizes: capture frames, recording frames, train steps and preset, register-log's frames, the evaluate preset, and
#: whether the SLAM table is tried. The render is at the recording's own size (640x480), as render --recording must.
SIZES: dict[str, dict[str, Any]] = {
    "quick": {"capture_frames": 40, "recording_frames": 6, "steps": 300, "train_preset": "tiny", "rays_per_batch": 256,
              "register_frames": 6, "register_preset": "tiny", "evaluate_preset": "tiny",
              "slam": False},
    "full": {"capture_frames": 120, "recording_frames": 24, "steps": 8000, "train_preset": "tiny", "rays_per_batch": 512,
             "register_frames": 20, "register_preset": "tiny", "evaluate_preset": "tiny",
             "slam": True},
}


# ----------------------------------------------------------------------------------- the sequence
def read_list(path: Path) -> list[tuple[str, str]]:
    """A TUM list (rgb.txt, depth.txt): (stamp as written, file path relative to the sequence), in file order."""
    rows = []
    for line in path.read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        if len(parts) < 2:
            raise SystemExit(f"{path}: expected 'timestamp filename', got {line!r}")
        rows.append((parts[0], parts[1]))
    return rows


def read_groundtruth(path: Path) -> np.ndarray:
    """groundtruth.txt as an (N, 8) array: stamp (s), tx ty tz, qx qy qz qw."""
    rows = [[float(v) for v in line.split()] for line in path.read_text().splitlines()
            if line.strip() and not line.lstrip().startswith("#")]
    return np.asarray(rows, dtype=np.float64).reshape(-1, 8)


def camera_of(seq: Path, rgb_txt: Path, given: str | None) -> str:
    """fr1 / fr2 / fr3: given, else from rgb.txt's ``# file: 'rgbd_dataset_freiburgN_...'`` line or the folder name."""
    if given is not None:
        return given
    for text in (rgb_txt.read_text()[:500], seq.name):
        if m := re.search(r"freiburg([123])", text):
            return f"fr{m.group(1)}"
    raise SystemExit(f"{seq}: which Kinect (fr1, fr2, fr3)? Not in rgb.txt's header nor the folder name: "
                     "give --camera")


def evenly(idx: np.ndarray, n: int) -> np.ndarray:
    """``n`` indices evenly spaced over ``idx`` (all of them when it has at most ``n``)."""
    if len(idx) <= n:
        return idx
    return idx[np.round(np.linspace(0, len(idx) - 1, n)).astype(int)]


def split(stamps: np.ndarray, capture_fraction: float, n_capture: int, n_recording: int,
          gap_s: float = GAP_S) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the capture's frames (the first ``capture_fraction`` of the frames, ``n_capture`` of them evenly
    spaced) and of the recording's (after a gap of ``gap_s`` seconds, ``n_recording`` evenly spaced): disjoint in
    time, the capture first."""
    if not 0.0 < capture_fraction < 1.0:
        raise SystemExit(f"--capture-fraction: expected a number between 0 and 1, got {capture_fraction}")
    stamps = np.asarray(stamps, dtype=np.float64)
    cut = int(round(len(stamps) * capture_fraction))
    capture = evenly(np.arange(cut), n_capture)
    later = np.flatnonzero(stamps >= stamps[cut - 1] + gap_s)
    if len(capture) < 3 or len(later) < 1:
        raise SystemExit(f"the sequence's {len(stamps)} frames leave {len(capture)} for the capture and "
                         f"{len(later)} for the recording: too few")
    return capture, evenly(later, n_recording)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(N, 4) quaternions x y z w (normalised here) -> (N, 3, 3) rotations."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], -2)


def nearest_rows(gt: np.ndarray, stamps: np.ndarray, max_dt_s: float = 0.02) -> np.ndarray:
    """For each stamp, the index of the ground-truth row nearest in time (-1 when none within ``max_dt_s``)."""
    t = gt[:, 0]
    j = np.clip(np.searchsorted(t, stamps), 1, len(t) - 1)
    j = np.where(np.abs(t[j - 1] - stamps) <= np.abs(t[j] - stamps), j - 1, j)
    return np.where(np.abs(t[j] - stamps) <= max_dt_s, j, -1)


def view_overlap(gt: np.ndarray, capture_s: np.ndarray, recording_s: np.ndarray) -> dict[str, Any]:
    """How far each recorded view is from the capture's: the smallest angle between optical axes (deg) and the
    smallest distance between centres (m), their median and max over the recorded frames, and the fraction of
    recorded frames within 15 degrees of a capture frame's axis."""
    ic, ir = nearest_rows(gt, capture_s), nearest_rows(gt, recording_s)
    ic, ir = ic[ic >= 0], ir[ir >= 0]
    if len(ic) == 0 or len(ir) == 0:
        return {"matched": 0}
    zc = quat_to_matrix(gt[ic, 4:8])[:, :, 2]
    zr = quat_to_matrix(gt[ir, 4:8])[:, :, 2]
    angle = np.degrees(np.arccos(np.clip(zr @ zc.T, -1.0, 1.0))).min(axis=1)
    dist = np.linalg.norm(gt[ir, None, 1:4] - gt[None, ic, 1:4], axis=-1).min(axis=1)
    return {"matched": int(len(ir)), "axis_deg_median": round(float(np.median(angle)), 2),
            "axis_deg_max": round(float(angle.max()), 2), "within_15deg": round(float(np.mean(angle <= 15.0)), 3),
            "centre_m_median": round(float(np.median(dist)), 4), "centre_m_max": round(float(dist.max()), 4)}


def place(src: Path, dst: Path) -> None:
    """``src`` at ``dst``: a hard link when the file system allows it (the frames are not copied), else a copy."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


# ----------------------------------------------------------------------------------- the folders
def kinect_camera(kind: str):
    from nsim.geometry.cameras import Camera

    (fx, fy, cx, cy), dist = TUM_CAMERAS[kind]
    if not any(dist):
        return Camera("PINHOLE", 640, 480, fx, fy, cx, cy)
    return Camera("OPENCV", 640, 480, fx, fy, cx, cy, dist=dist)


def write_capture(seq: Path, rgb: list[tuple[str, str]], idx: np.ndarray, out: Path, camera) -> Path:
    """The capture's frames as an image folder named by their TUM stamps, and the camera as an intrinsics file."""
    images = out / "images"
    for i in idx:
        stamp, rel = rgb[i]
        place(seq / rel, images / f"{stamp}{Path(rel).suffix}")
    (out / "kinect.json").write_text(json.dumps(camera.to_dict()))
    return images


def write_recording(seq: Path, rgb: list[tuple[str, str]], depth: list[tuple[str, str]], gt: np.ndarray,
                    idx: np.ndarray, out: Path, camera) -> int:
    """The recording folder (``nsim.io.robot_folder``): the colour frames ``idx``, the depth frame nearest each
    (within 20 ms), the camera as the body, the motion capture over the stretch as the odometry. Returns the number
    of depth frames."""
    import yaml

    from nsim.io.robot_folder import camera_info_yaml

    cams, dep = out / "cameras" / CAMERA, out / "depth" / CAMERA
    for i in idx:
        stamp, rel = rgb[i]
        place(seq / rel, cams / f"{stamp}{Path(rel).suffix}")
    depth_s = np.array([float(s) for s, _ in depth])
    rows = []
    for i in idx:
        j = int(np.argmin(np.abs(depth_s - float(rgb[i][0]))))
        if abs(depth_s[j] - float(rgb[i][0])) <= 0.02 and (not rows or rows[-1][0] != depth[j][0]):
            rows.append(depth[j])
    for stamp, rel in rows:
        place(seq / rel, dep / f"{stamp}{Path(rel).suffix}")
    info = yaml.safe_dump(camera_info_yaml(camera, CAMERA), sort_keys=False)
    for d in (cams, dep):
        d.mkdir(parents=True, exist_ok=True)
        (d / "camera_info.yaml").write_text(info)
    # TUM's own depth list beside the frames: it states their unit (1/5000 m)
    (dep / "depth.txt").write_text("# depth maps\n# timestamp filename\n"
                                   + "".join(f"{s} {Path(r).name}\n" for s, r in rows))
    (out / "rig.yaml").write_text(yaml.safe_dump({"body_frame": "body", "odom_frame": "odom", "sensors": {
        CAMERA: {"translation_m": [0.0, 0.0, 0.0], "quaternion_wxyz": [1.0, 0.0, 0.0, 0.0]}}}))
    t0, t1 = float(rgb[idx[0]][0]) - 1.0, float(rgb[idx[-1]][0]) + 1.0
    keep = gt[(gt[:, 0] >= t0) & (gt[:, 0] <= t1)]
    keep = keep[np.concatenate([[True], np.diff(keep[:, 0]) > 0])]
    (out / "trajectory.tum").write_text("".join(
        f"{r[0]:.4f} " + " ".join(f"{v:.6f}" for v in r[1:]) + "\n" for r in keep))
    return len(rows)


# ----------------------------------------------------------------------------------- results
def rotation_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def peak_rss_gb() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return max(own, children) / 2**20  # KiB on Linux


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sequence", type=Path, help="a TUM RGB-D sequence folder (rgb/, depth/, rgb.txt, depth.txt, "
                                                "groundtruth.txt)")
    ap.add_argument("--quick", action="store_true", help="tiny sizes: a few minutes on 2 cores")
    ap.add_argument("--workspace", type=Path, default=None, help="default: a temporary workspace")
    ap.add_argument("--capture-fraction", type=float, default=0.6)
    ap.add_argument("--capture-frames", type=int, default=None)
    ap.add_argument("--recording-frames", type=int, default=None)
    ap.add_argument("--steps", type=int, default=None, help="train-scene steps")
    ap.add_argument("--camera", choices=sorted(TUM_CAMERAS), default=None, help="default: from rgb.txt's header")
    ap.add_argument("--capture-poses", choices=("reference", "sfm"), default="reference",
                    help="the capture's camera poses: the motion capture's, features only triangulated "
                         "(reconstruct --reference-poses), or pycolmap's SfM made metric by it")
    ap.add_argument("--depth-weight", type=float, default=0.1,
                    help="train-scene's loss.depth_weight: the capture's triangulated sparse points as depth "
                         "supervision (0: none). A camera turning in place gives the colour loss no parallax to "
                         "learn depth from")
    ap.add_argument("--min-extent-m", type=float, default=0.02,
                    help="register-log's register.min_extent_m (default there 0.1 m: the registered frames must "
                         "spread that far; a handheld Kinect turning in place moves its centre some 5 cm, and its "
                         "rotations fix the odometry frame's orientation)")
    ap.add_argument("--max-residual-deg", type=float, default=3.0,
                    help="register-log's register.max_median_residual_deg (default there 1 deg)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    sizes = dict(SIZES["quick" if args.quick else "full"])
    for key in ("capture_frames", "recording_frames", "steps"):
        if getattr(args, key) is not None:
            sizes[key] = getattr(args, key)

    seq = args.sequence.resolve()
    for name in ("rgb.txt", "depth.txt", "groundtruth.txt"):
        if not (seq / name).is_file():
            raise SystemExit(f"{seq}: no {name}; expected a TUM RGB-D sequence folder (see --help for where to "
                             "fetch one)")
    rgb, depth = read_list(seq / "rgb.txt"), read_list(seq / "depth.txt")
    gt = read_groundtruth(seq / "groundtruth.txt")
    kind = camera_of(seq, seq / "rgb.txt", args.camera)
    camera = kinect_camera(kind)
    rgb_s = np.array([float(s) for s, _ in rgb])
    cap_idx, rec_idx = split(rgb_s, args.capture_fraction, sizes["capture_frames"], sizes["recording_frames"])
    overlap = view_overlap(gt, rgb_s[cap_idx], rgb_s[rec_idx])

    tmp = None
    if args.workspace is None:
        tmp = tempfile.TemporaryDirectory(prefix="nsim-bench-real-recording-")
        args.workspace = Path(tmp.name)
    ws = args.workspace.resolve()
    # the capture and recording folders beside the workspace (an nsim workspace holds only its own files)
    files = ws.parent / f"{ws.name}.real-recording-input"
    if files.exists():
        shutil.rmtree(files)
    images = write_capture(seq, rgb, cap_idx, files / "capture", camera)
    n_depth = write_recording(seq, rgb, depth, gt, rec_idx, files / "recording", camera)
    log = files / "nsim.log"
    print(f"{seq.name} ({kind}): {len(rgb)} colour frames; capture {len(cap_idx)} frames "
          f"{rgb[cap_idx[0]][0]}..{rgb[cap_idx[-1]][0]}, recording {len(rec_idx)} colour + {n_depth} depth frames "
          f"{rgb[rec_idx[0]][0]}..{rgb[rec_idx[-1]][0]}; view overlap {overlap}; log {log}", flush=True)

    steps: dict[str, float] = {}
    t_start = time.perf_counter()

    def step(name: str, *a: str) -> str:
        out, wall, rss = nsim(ws, "--seed", str(args.seed), *a, log=log)
        steps[name] = round(wall, 1)
        print(f"  {name}: {wall:.0f} s, peak RSS {rss:.2f} GB", flush=True)
        return out

    how = ["--reference-poses"] if args.capture_poses == "reference" else []
    step("reconstruct", "reconstruct", str(images), "--reference", str(seq / "groundtruth.txt"), *how,
         "--intrinsics", str(files / "capture" / "kinect.json"), "--tag", "poses/real-capture")
    depth = ["--set", f"loss.depth_weight={args.depth_weight}"] if args.depth_weight > 0 else []
    step("train_scene", "train-scene", "--poses", "poses/real-capture", "--preset", sizes["train_preset"],
         "--steps", str(sizes["steps"]), "--set", f"optim.rays_per_batch={sizes['rays_per_batch']}", *depth,
         "--tag", "scene/real-capture")
    step("import_log", "import-log", str(files / "recording"), "--tag", "recording/real")
    step("register_log", "register-log", "recording/real", "--poses", "poses/real-capture",
         "--preset", sizes["register_preset"], "--set", f"frames_per_camera={sizes['register_frames']}",
         "--set", f"register.min_extent_m={args.min_extent_m}",
         # the odometry is the motion capture: no drift to take up (and the drift graph of a Kinect turning
         # 100 deg/s has a node every few degrees: scipy's finite differences took over 5 min for 6 frames)
         "--set", "refine_drift=false",
         # default 1 deg: the Kinect's frames are localised to ~1.5 deg at 100 deg/s (a 15 ms stamp or
         # rolling-shutter error is 1.5 deg there)
         "--set", f"register.max_median_residual_deg={args.max_residual_deg}", "--tag", "registration/real")
    step("render", "render", "--recording", "registration/real", "--scene", "scene/real-capture",
         "--preset", "tiny", "--set", "image_scale=1.0", "--set", "lidar_azimuth_scale=1.0", "--set", "tick_stride=1",
         "--set", "max_frames=null", "--set", "video=false", "--tag", "render/real-recording")
    tables = ["spot-rgb", "spot-depth"] + (["slam"] if sizes["slam"] else [])
    failed: dict[str, str] = {}
    for table in tables:
        extra = ["--set", f"slam.camera={CAMERA}"] if table == "slam" else []
        try:
            step(f"evaluate_{table}", "evaluate", "--table", table, "--render", "render/real-recording",
                 "--preset", sizes["evaluate_preset"], *extra, "--tag", f"evaluation/real-{table}")
        except SystemExit as exc:  # a table that cannot be computed on these frames (SfM of the SLAM row)
            failed[table] = str(exc).splitlines()[-1] if str(exc).strip() else "failed"
    wall = time.perf_counter() - t_start

    from nsim.context import RunContext
    from nsim.stages import evaluate
    from nsim.workspace.store import Store

    ctx = RunContext(store=Store(ws), device_spec="cpu", seed=args.seed)
    store = ctx.store
    loaded = {}
    for table in tables:
        if table in failed:
            continue
        loaded[table] = evaluate.load_table(ctx, f"evaluation/real-{table}")
        print()
        print(f"== {table}: simulated vs the real recording")
        print(loaded[table].to_text(), end="")

    out: dict[str, Any] = {}
    na: dict[str, str] = {}
    doc = json.loads(store.get(store.resolve("registration/real")).file("registration.json").read_text())
    odom_to_world = np.asarray(doc["odom_to_world"], dtype=np.float64)
    poses = store.get(store.resolve("poses/real-capture"))
    report = json.loads(poses.file("report.json").read_text()) if (poses.path / "report.json").is_file() else {}
    scene = store.get(store.resolve("scene/real-capture"))
    scene_eval = json.loads(scene.file("eval.json").read_text()) if (scene.path / "eval.json").is_file() else {}

    out["frames_train"] = int(len(cap_idx))
    out["frames_heldout"] = int(len(rec_idx))
    out["register_err_m"] = round(float(np.linalg.norm(odom_to_world[:3, 3])), 4)
    out["register_err_deg"] = round(rotation_deg(odom_to_world[:3, :3]), 3)
    out["clock_err_s"] = round(abs(float(doc.get("clock_offset_s", 0.0))), 4)

    def put(key: str, table: str, col: str) -> None:
        if table not in loaded:
            out[key], na[key] = None, failed.get(table, f"no {table} table at this size")
            return
        value, why = column(loaded[table], col)
        out[key] = None if value is None else round(value, 4)
        if why is not None:
            na[key] = why

    for key, table, col in (("rgb_psnr", "spot-rgb", "PSNR"), ("rgb_psnr_corrected", "spot-rgb", "PSNR cc"),
                            ("rgb_ssim", "spot-rgb", "SSIM"), ("rgb_ssim_corrected", "spot-rgb", "SSIM cc"),
                            ("rgb_lpips", "spot-rgb", "LPIPS"), ("rgb_lpips_corrected", "spot-rgb", "LPIPS cc"),
                            ("depth_absrel", "spot-depth", "AbsRel"), ("depth_rmse_m", "spot-depth", "RMSE [m]"),
                            ("depth_delta1", "spot-depth", "δ<1.25"), ("slam_ate_real_m", "slam", "ATE real [m]"),
                            ("slam_ate_sim_m", "slam", "ATE sim [m]")):
        put(key, table, col)
    mean = scene_eval.get("mean", {})
    out["scene_heldout_psnr"] = mean.get("psnr", mean.get("PSNR"))
    out["view_overlap"] = overlap
    scale = report.get("scale", {}) if isinstance(report.get("scale"), dict) else {}
    out["reconstruct"] = {"images_given": report.get("images_given"),
                          "images_registered": report.get("images_registered"),
                          "points3d": report.get("num_points3d"),
                          "reprojection_px": report.get("mean_reprojection_error_px"),
                          "fit_rms_m": scale.get("residual_rms_m"), "fit_median_m": scale.get("residual_median_m")}
    out["localised"] = doc.get("localised", {}).get("localised")
    out["tried"] = doc.get("localised", {}).get("tried")
    out["residual_median_m"] = doc.get("residual", {}).get("median_m")
    out["na"] = na
    out["sequence"] = {"name": seq.name, "camera": kind, "frames": len(rgb), "depth_frames_scored": n_depth}
    out["capture_poses"] = args.capture_poses
    out["depth_weight"] = args.depth_weight
    out["sizes"] = sizes
    out["wall_s"] = round(wall, 1)
    out["steps_s"] = steps
    out["peak_rss_gb"] = round(peak_rss_gb(), 3)
    for key, why in na.items():
        print(f"n/a {key}: {why}")
    if tmp is not None:
        tmp.cleanup()
        shutil.rmtree(files, ignore_errors=True)
    print(json.dumps(out, ensure_ascii=False, default=lambda v: None if isinstance(v, float) and math.isnan(v) else v))


if __name__ == "__main__":
    main()
