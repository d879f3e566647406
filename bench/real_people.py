"""A person from a plain video: the test room's actor capture given as ``video.mp4`` only (ground-truth
poses and masks withheld from the fit, used only to score it).

    PYTHONPATH=. /path/to/people-venv/bin/python bench/real_people.py [--quick] [--steps N] [--threads 1]
        [--fit-only] [--fit FIELD=VALUE] [--set refine.lr=0.0005]

Needs the ``nsim[people]`` extra (MediaPipe) in the interpreter that runs it.

1. ``nsim capture synth --actor`` (the camera is handheld: it follows the person through robot-lab);
2. ``nsim.train.human_data_video.prepare_person_data`` on its ``video.mp4`` (what
   ``train-human --video`` runs: MediaPipe's landmarks and masks, the camera told static or moving
   and placed, the 24-joint fit), with ``--person-height`` set to the actor's height;
3. scores against the withheld truth: mask IoU of the person masks (mean over kept frames), MPJPE of
   the fitted joints after a per-frame Procrustes alignment (``nsim.human.fit.mpjpe_m``, cm);
4. trains the human NeRF (``nsim.stages.train_human``, folder input) twice on the same frames and
   split, once with the fitted poses and cameras and once with the true ones (the capture's own
   folder without its background images, so both composite over the frames), and reports each
   model's held-out (novel-pose) PSNR in the person's box and its render's mask IoU
   (``eval.json``, ``nsim.train.human``: against the folder's masks, MediaPipe's for the fitted one),
   and the same renders' IoU against the capture's true masks (``iou_render_true_masks``). Both trainings
   are scored with the held-out fit (``refine.held_out_steps``, ``nsim.train.human``; the novel-pose protocol
   of Anim-NeRF, InstantAvatar and Vid2Avatar): each held-out frame's pose is fitted to its own image and
   mask with the model frozen, and the keys above are the scores at the fitted poses (the true-mask IoU
   renders them from ``poses_refined.json``); the same keys ending ``_given_poses`` are the scores at the
   poses as given (the true-mask one at the folder's poses). The bench sets ``refine.held_out_steps`` to
   ``HELD_OUT_STEPS`` unless a ``--set refine.held_out_steps=N`` says otherwise (0: no fit, and the two sets
   of keys agree); ``wall_seconds`` has the fits' times (``held_out_fit_fitted``, ``held_out_fit_truth``,
   included in the trainings'), ``held_out_fit`` how far they moved the held-out joints;
5. a second capture whose camera follows behind the walker (``--set actor_view_deg=180``: the person stays in
   the middle of the image while walking on) through the same ``prepare_person_data``: the camera must be told
   moving and its path found (SfM with the person masked out), and the person's walking speed in the world
   (``walking_speed_mps`` in ``person_fit.json``) is scored against the capture's true speed, measured alike
   (``nsim.human.moving_camera.walking_speed_mps``): ``speed_err_following`` is the relative error (goal <= 0.15),
   with ``following`` holding the speeds, the decision, the path's SfM and its time;
6. with pose refinement on (``refine.lr > 0``: the bench sets ``REFINE_LR``, the ``default`` preset's, for both
   presets unless ``--set refine.lr=...`` says otherwise), the refined poses
   (``poses_refined.json``) are scored as in 3: ``mpjpe_cm`` is then the refined skeleton's (the
   pipeline's final fit) and ``mpjpe_cm_landmark_fit`` the landmark fit's before it, with both over
   the trained and the held-out frames and how far refinement moved them under ``pose_refinement``
   (with the held-out fit, the held-out frames' "refined" poses are the fitted ones, also without refinement).

``--quick``: 320x240, 30 frames (3 s), the ``tiny`` preset with 150 steps. Full run: 480x360,
60 frames, the ``default`` preset. ``--fit-only``: steps 1-3 alone (no training; the NeRF keys are
null). ``--mask-threshold`` and ``--min-visibility`` set the person config's mask cut and the fit's
visibility cut (their defaults otherwise); ``--no-mirror`` and ``--one-direction`` how the detector
looks at the frames (``PersonVideoConfig.mirror_landmarks``, ``both_directions``); ``--no-consistent-sides``
fits the limbs' sides as the detector labels them (``consistent_sides``); ``--no-track-outliers`` keeps the
landmarks that jump off their tracks (``track_outlier_torsos``); ``--cross`` also trains with the poses and
masks crossed (the fitted poses with the capture's true masks, the true poses with MediaPipe's masks; key
``crossed``), which splits the fitted model's gap into what its poses and what its masks cost; ``--blend A,B,...``
also trains on the capture's true cameras, images and masks with every kept frame's pose moved a share A of
the way from the true pose to the fitted one (``blended_folder``; key ``pose_blend``: each share's PA-MPJPE,
PSNR in the box, its gap below the true poses' and render IoU), so how far the PSNR falls with pose error alone;
``--device`` runs the trainings on another device (default cpu); ``--fit FIELD=VALUE`` sets a skeleton-fit
weight (``FitConfig``; the earlier weights, before the sides were made consistent: ``--fit smooth_weight_image=0.5 --fit weight_3d=0.05``).
Prints a table; the
last line is a JSON object with keys ``mask_iou, mpjpe_cm, psnr_box, psnr_box_gt_poses, iou_render``,
``psnr_box_given_poses, psnr_box_gt_poses_given_poses, iou_render_given_poses``, ``speed_err_following`` (and more).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nsim.config import load_config  # noqa: E402
from nsim.context import RunContext  # noqa: E402
from nsim.human.data import POSES_REFINED_FILE  # noqa: E402
from nsim.stages import capture, train_human  # noqa: E402
from nsim.workspace.store import Store  # noqa: E402

HELD_OUT_STEPS = 400  # the held-out fit's steps the bench scores with (refine.held_out_steps), unless --set says
REFINE_LR = 0.0005  # pose refinement while training (refine.lr, the default preset's), unless --set says otherwise


def score_fit(person_dir: Path, capture_dir: Path) -> dict:
    """Mask IoU and PA-MPJPE of a person folder written from the capture's video against the capture's truth."""
    from nsim.human.data import HumanData
    from nsim.human.fit import mpjpe_m

    fitted, truth = HumanData.load(person_dir), HumanData.load(capture_dir)
    # frames are named after their index in the video, which is the capture's frame order
    index = [int(Path(p).stem.split("_")[-1]) for p in fitted.image_paths]
    pred_j = fitted.joint_transforms()[..., :3, 3]
    true_j = truth.joint_transforms()[index][..., :3, 3]
    iou = []
    for row, k in enumerate(index):
        p, g = fitted.mask(row), truth.mask(k)
        iou.append(float((p & g).sum() / max((p | g).sum(), 1)))
    return {"frames_scored": len(index), "mask_iou": float(np.mean(iou)),
            "mpjpe_cm": float(100 * mpjpe_m(pred_j, true_j).mean()),
            "mpjpe_cm_no_alignment_root_relative": float(100 * mpjpe_m(pred_j - pred_j[:, :1], true_j - true_j[:, :1],
                                                                      procrustes=False).mean())}


def score_refined(human_dir: Path, person_dir: Path, capture_dir: Path) -> dict:
    """PA-MPJPE (cm) of a human checkpoint's refined poses (``poses_refined.json``) against the capture's truth,
    beside the poses it was given, over the trained and the held-out frames; and how far refinement moved them."""
    from nsim.human.data import HumanData, read_poses
    from nsim.human.fit import mpjpe_m

    given, truth = HumanData.load(person_dir), HumanData.load(capture_dir)
    index = [int(Path(p).stem.split("_")[-1]) for p in given.image_paths]
    true_j = truth.joint_transforms()[index][..., :3, 3]
    errors = {"given": 100 * mpjpe_m(given.joint_transforms()[..., :3, 3], true_j),
              "refined": 100 * mpjpe_m(read_poses(human_dir / POSES_REFINED_FILE).joint_positions_m(), true_j)}
    meta = json.loads((human_dir / "human.json").read_text())
    out = {}
    for part, key in (("trained", "frames_trained"), ("held_out", "frames_held_out")):
        rows = np.asarray(meta[key], dtype=int)
        if rows.size:
            out.update({f"mpjpe_cm_{k}_{part}": float(e[rows].mean()) for k, e in errors.items()})
    out.update({f"mpjpe_cm_{k}": float(e.mean()) for k, e in errors.items()})
    out["moved"] = json.loads((human_dir / "pose_refinement.json").read_text())
    return out


def render_iou_true_masks(human_dir: Path, folder: Path, capture_dir: Path, given_poses: bool = False) -> float:
    """Mean mask IoU of a human checkpoint's held-out renders (opacity > 0.5, at the folder's cameras and
    poses: the refined ones when the checkpoint has them, with the held-out fit the held-out frames' fitted
    ones; ``given_poses``: the folder's own) against the capture's *true* masks, where ``eval.json``'s IoU is
    against the folder's own (for the fitted folder MediaPipe's)."""
    from nsim.human.data import HumanData, read_poses
    from nsim.human.nerf import load_human_model
    from nsim.train.human import mask_iou

    data, truth = HumanData.load(folder), HumanData.load(capture_dir)
    model = load_human_model(human_dir)
    poses = (read_poses(human_dir / POSES_REFINED_FILE).joint_transforms()
             if (human_dir / POSES_REFINED_FILE).is_file() and not given_poses else data.joint_transforms())
    camera, c2w = data.camera(), data.cam_to_world()
    held = json.loads((human_dir / "human.json").read_text())["frames_held_out"]
    ious = []
    for row in held:
        k = int(Path(data.image_paths[row]).stem.split("_")[-1])
        alpha = model.render(camera, c2w[row], poses[row])["alpha"]
        ious.append(mask_iou(alpha > 0.5, truth.mask(k)))
    return float(np.mean(ious))


def following_speed(store: Store, ctx: RunContext, cap_over: list[str], person, tmp: Path) -> dict:
    """Step 5: the capture with a camera that follows behind the walker, fitted from its video alone; the walking
    speed found against the true one (both ``walking_speed_mps`` over the frames the fit kept in one run)."""
    from nsim.human.data import HumanData
    from nsim.human.moving_camera import walking_speed_mps
    from nsim.train.human_data_video import PersonSource, prepare_person_data

    t0 = time.perf_counter()
    cfg = load_config(capture.Config, stage="capture", preset="default", overrides=[*cap_over, "actor_view_deg=180"])
    cap = store.get(capture.run(capture.Inputs(), cfg, ctx).capture)
    cap_s = time.perf_counter() - t0
    truth = HumanData.load(cap.path)
    person = dataclasses.replace(person, body_height_m=truth.poses.height_m)
    t0 = time.perf_counter()
    out = tmp / "person_following"
    report = prepare_person_data(PersonSource(cap.path / "video.mp4", person=person), out)
    fit_s = time.perf_counter() - t0
    fitted = HumanData.load(out)
    index = np.asarray([int(Path(p).stem.split("_")[-1]) for p in fitted.image_paths])
    runs = np.split(index, np.flatnonzero(np.diff(index) != 1) + 1)
    run = max(runs, key=len)  # the fit's walking_speed_mps is over its longest unbroken run
    true_speed = walking_speed_mps(truth.poses.root_to_world[run, :3, 3], report["fps"])
    speed = report["walking_speed_mps"]
    err = abs(speed - true_speed) / true_speed if speed is not None else float("nan")
    return {"speed_err": err, "speed_mps": speed, "true_speed_mps": true_speed, "camera": report["camera"],
            "decision": report["camera_decision"], "camera_path": report["camera_path"],
            "scale_from": report["scale_from"], "cadence_steps_s": report["cadence_steps_s"],
            "frames_kept": report["frames_kept"], "frames_in": report["frames_in"],
            "wall_seconds": {"capture": round(cap_s, 1), "fit": round(fit_s, 1)}}


class _FitTimes(logging.Handler):
    """Collects the held-out fits' wall times from the trainer's log line (its ``held_out_fit_s``)."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.seconds: list[float] = []

    def emit(self, record: logging.LogRecord) -> None:
        if hasattr(record, "held_out_fit_s"):
            self.seconds.append(float(record.held_out_fit_s))


def cross_folders(person_dir: Path, truth_dir: Path, capture_dir: Path, tmp: Path) -> dict[str, Path]:
    """``--cross``: the fitted folder with the capture's true masks, and the true folder (no background images)
    with the fitted folder's masks (MediaPipe's) on the frames it kept (the others keep their true ones)."""
    from nsim.human.data import HumanData

    truth = HumanData.load(capture_dir)
    poses_fitted = tmp / "fitted_poses_true_masks"
    shutil.copytree(person_dir, poses_fitted)
    for mask in (poses_fitted / "masks").glob("*.png"):
        shutil.copyfile(truth.mask_paths[int(mask.stem.split("_")[-1])], mask)
    poses_true = tmp / "true_poses_mediapipe_masks"
    shutil.copytree(truth_dir, poses_true)
    for k, mask in enumerate(HumanData.load(poses_true).mask_paths):
        found = person_dir / "masks" / f"frame_{k:05d}.png"
        if found.is_file():
            shutil.copyfile(found, mask)
    return {"fitted_poses_true_masks": poses_fitted, "true_poses_mediapipe_masks": poses_true}


def blended_folder(person_dir: Path, truth_dir: Path, alpha: float, out: Path) -> float:
    """``--blend``: the true folder (cameras, images, masks, bone lengths) with each kept frame's pose moved a share
    ``alpha`` of the way from the true pose to the fitted one (0: the truth; 1: the fitted pose). The fitted pose
    is first carried into the true world through the frame's cameras (fitted camera -> true camera), so the
    fitted cameras' own errors are left out; local rotations and the root's orientation are interpolated along the
    shortest arc (slerp), the root's position linearly. Writes ``out`` and returns the blended poses' PA-MPJPE
    (cm) against the truth over the kept frames."""
    from nsim.geometry.transforms import matrix_from_quat_wxyz, quat_wxyz_from_matrix
    from nsim.human.data import HumanData, write_poses
    from nsim.human.fit import mpjpe_m
    from nsim.human.skeleton import quat_slerp_wxyz

    truth, fitted = HumanData.load(truth_dir), HumanData.load(person_dir)
    index = [int(Path(p).stem.split("_")[-1]) for p in fitted.image_paths]
    # the fitted roots carried into the true world through each frame's cameras (fitted camera -> true camera)
    fit_root = truth.cam_to_world()[index] @ np.linalg.inv(fitted.cam_to_world()) @ fitted.poses.root_to_world
    root, quats = truth.poses.root_to_world.copy(), truth.poses.local_rotations_wxyz.copy()
    turn = quat_slerp_wxyz(quat_wxyz_from_matrix(root[index, :3, :3]), quat_wxyz_from_matrix(fit_root[:, :3, :3]), alpha)
    root[index, :3, :3] = matrix_from_quat_wxyz(turn)
    root[index, :3, 3] = (1.0 - alpha) * root[index, :3, 3] + alpha * fit_root[:, :3, 3]
    quats[index] = quat_slerp_wxyz(quats[index], fitted.poses.local_rotations_wxyz, alpha)
    shutil.copytree(truth_dir, out)
    write_poses(out / "poses.json", dataclasses.replace(truth.poses, root_to_world=root, local_rotations_wxyz=quats))
    blended = HumanData.load(out).joint_transforms()[index][..., :3, 3]
    return float(100 * mpjpe_m(blended, truth.joint_transforms()[index][..., :3, 3]).mean())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--workspace", type=Path, default=None)
    ap.add_argument("--steps", type=int, default=None)
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default 2, 1 with --quick)")
    ap.add_argument("--fit-only", action="store_true", help="score the masks and the skeleton fit, train nothing")
    ap.add_argument("--mask-threshold", type=float, default=None,
                    help="the person config's mask_threshold (default: TRAINING_MASK_THRESHOLD)")
    ap.add_argument("--min-visibility", type=float, default=None,
                    help="the skeleton fit's min_visibility (default: FitConfig's)")
    ap.add_argument("--no-mirror", action="store_true",
                    help="the person detector looks at each frame once, not also mirrored (mirror_landmarks=False)")
    ap.add_argument("--one-direction", action="store_true",
                    help="the person detector runs over the frames first to last only (both_directions=False)")
    ap.add_argument("--cross", action="store_true",
                    help="also train with the poses and masks crossed (fitted poses with the true masks, true poses "
                         "with MediaPipe's masks): which of the two costs the fitted model more (key crossed)")
    ap.add_argument("--blend", default=None, metavar="A,B,...",
                    help="also train on the true cameras, images and masks with the poses moved each share A of the way "
                         "from the true ones to the fitted ones (how far the PSNR falls with pose error; key pose_blend)")
    ap.add_argument("--device", default="cpu", help="the trainings' device: cpu, cuda, auto (default cpu)")
    ap.add_argument("--no-consistent-sides", action="store_true",
                    help="fit the detector's left and right limbs as it labels them (consistent_sides=False)")
    ap.add_argument("--no-track-outliers", action="store_true",
                    help="keep the landmarks that jump off their tracks in the fit (track_outlier_torsos=None)")
    ap.add_argument("--fit", dest="fit_overrides", action="append", default=[], metavar="FIELD=VALUE",
                    help="a skeleton-fit setting (nsim.human.fit.FitConfig field, a number), e.g. smooth_weight=2")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="a train_human config override for both trainings, e.g. refine.lr=0 (repeatable)")
    args = ap.parse_args()
    from nsim.context import resolve_device
    from nsim.errors import InputError

    try:
        resolve_device(args.device)
    except InputError as err:
        ap.error(str(err))
    blend_shares: list[float] = []
    if args.blend:  # checked before any work
        try:
            blend_shares = sorted({float(a) for a in args.blend.split(",")} - {0.0})
        except ValueError:
            ap.error(f"--blend {args.blend}: expected shares in [0, 1] separated by commas, e.g. 0.25,0.5,1")
        if not all(0.0 < a <= 1.0 for a in blend_shares):
            ap.error(f"--blend {args.blend}: every share must be in [0, 1]")
    from nsim.human.person_video import PersonVideoConfig
    from nsim.train.human_data_video import PersonSource, prepare_person_data

    q = args.quick
    threads = args.threads or (1 if q else 2)
    cap_over = ["actor=true", "video=true"] + (["width=320", "height=240", "n_frames=30"] if q
                                               else ["width=480", "height=360", "n_frames=60"])
    steps = args.steps or (150 if q else None)
    given = {o.split("=")[0].strip() for o in args.overrides}
    held_out = [f"{k}={v}" for k, v in (("refine.held_out_steps", HELD_OUT_STEPS), ("refine.lr", REFINE_LR))
                if k not in given]
    th_over = [f"optim.num_threads={threads}"] + ([f"optim.steps={steps}"] if steps else []) + held_out + args.overrides
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        store = Store(args.workspace or tmp / "ws")
        ctx = RunContext(store=store, device_spec=args.device, seed=0, progress=False)
        t0 = time.perf_counter()
        cap_cfg = load_config(capture.Config, stage="capture", preset="default", overrides=cap_over)
        cap = store.get(capture.run(capture.Inputs(), cap_cfg, ctx).capture)
        cap_s = time.perf_counter() - t0
        height = float(json.loads((cap.path / "poses.json").read_text())["height_m"])
        t0 = time.perf_counter()
        person_dir = tmp / "person"
        person = PersonVideoConfig(body_height_m=height)
        if args.mask_threshold is not None:
            person = dataclasses.replace(person, mask_threshold=args.mask_threshold)
        if args.no_mirror:
            person = dataclasses.replace(person, mirror_landmarks=False)
        if args.one_direction:
            person = dataclasses.replace(person, both_directions=False)
        if args.no_consistent_sides:
            person = dataclasses.replace(person, consistent_sides=False)
        if args.no_track_outliers:
            person = dataclasses.replace(person, track_outlier_torsos=None)
        if args.min_visibility is not None:
            person = dataclasses.replace(person, fit=dataclasses.replace(person.fit, min_visibility=args.min_visibility))
        for item in args.fit_overrides:
            field, _, value = item.partition("=")
            if field not in {f.name for f in dataclasses.fields(person.fit)}:
                ap.error(f"--fit {item}: FitConfig has no field {field!r}")
            kind = type(getattr(person.fit, field))
            person = dataclasses.replace(person, fit=dataclasses.replace(person.fit, **{field: kind(value)}))
        source = PersonSource(cap.path / "video.mp4", person=person)
        report = prepare_person_data(source, person_dir)
        fit_s_person = time.perf_counter() - t0
        scores = score_fit(person_dir, cap.path)
        truth_dir = tmp / "truth"  # the capture's own folder, without background images (as the fitted one)
        shutil.copytree(cap.path, truth_dir, ignore=shutil.ignore_patterns("background", "depth", "video.mp4"))
        transforms = json.loads((truth_dir / "transforms.json").read_text())
        for frame in transforms["frames"]:
            frame.pop("background_path", None)
        (truth_dir / "transforms.json").write_text(json.dumps(transforms))
        print(f"person fit: {json.dumps(scores)}", flush=True)
        following = following_speed(store, ctx, cap_over, person, tmp)
        print(f"following camera: walking speed {following['speed_mps']} m/s against {following['true_speed_mps']:.3f} "
              f"(relative error {following['speed_err']:.3f}; camera {following['camera']}, scale from "
              f"{following['scale_from']}; fit {following['wall_seconds']['fit']} s)", flush=True)
        follow_keys = {"speed_err_following": round(following["speed_err"], 4),
                       "following": {k: (round(v, 4) if isinstance(v, float) else v) for k, v in following.items()}}
        if args.fit_only:
            print(json.dumps({"quick": q, "fit_only": True, "mask_threshold": person.mask_threshold,
                              "min_visibility": person.fit.min_visibility, "fit": dataclasses.asdict(person.fit),
                              "mirror_landmarks": person.mirror_landmarks, "both_directions": person.both_directions,
                              "consistent_sides": person.consistent_sides, "sides_relabelled": report["sides_relabelled"],
                              "track_outlier_torsos": person.track_outlier_torsos,
                              "track_outliers": len(report["track_outliers"]),
                              "camera": report["camera"],
                              "frames_kept": report["frames_kept"], "frames_in": report["frames_in"],
                              "mask_iou": round(scores["mask_iou"], 4), "mpjpe_cm": round(scores["mpjpe_cm"], 3),
                              "psnr_box": None, "psnr_box_gt_poses": None, "iou_render": None, **follow_keys,
                              "wall_seconds": {"capture": round(cap_s, 1), "fit": round(fit_s_person, 1)}}))
            return
        cfg = load_config(train_human.Config, stage="train_human", preset="tiny" if q else "default",
                          overrides=th_over)
        ctx = dataclasses.replace(ctx, force=True)
        evals, walls, refined, fits, fit_s = {}, {}, {}, {}, {}
        fit_log = _FitTimes()
        trainer_log = logging.getLogger("nsim.train.human")
        trainer_log.addHandler(fit_log)
        if not trainer_log.isEnabledFor(logging.INFO):
            trainer_log.setLevel(logging.INFO)
        for name, folder in (("fitted", person_dir), ("truth", truth_dir)):
            t0 = time.perf_counter()
            fit_log.seconds.clear()
            out = train_human.run(train_human.Inputs(folder=folder), cfg, ctx)
            walls[name] = time.perf_counter() - t0
            fit_s[name] = sum(fit_log.seconds)
            art = store.get(out.human)
            evals[name] = json.loads(art.file("eval.json").read_text())["mean"]
            evals[name]["mask_iou_true_masks"] = render_iou_true_masks(art.path, folder, cap.path)
            fitted_held_out = (art.path / "held_out_fit.json").is_file()
            evals[name]["mask_iou_true_masks_given_poses"] = (
                render_iou_true_masks(art.path, folder, cap.path, given_poses=True) if fitted_held_out
                else evals[name]["mask_iou_true_masks"])
            if fitted_held_out:
                fits[name] = json.loads(art.file("held_out_fit.json").read_text())["moved"]
            if (art.path / POSES_REFINED_FILE).is_file():
                refined[name] = score_refined(art.path, person_dir if name == "fitted" else truth_dir, cap.path)
        crossed = {}
        if args.cross:  # which costs more, the fitted poses or MediaPipe's masks: each with the other's truth
            for name, folder in cross_folders(person_dir, truth_dir, cap.path, tmp).items():
                art = store.get(train_human.run(train_human.Inputs(folder=folder), cfg, ctx).human)
                mean = json.loads(art.file("eval.json").read_text())["mean"]
                crossed[name] = {k: round(mean[k], 4) for k in ("psnr_box", "mask_iou", "psnr_box_given_poses",
                                                                "mask_iou_given_poses") if k in mean}
        blend = []
        if args.blend:  # PSNR against pose error alone: the truth with the poses moved towards the fitted ones
            base = evals["truth"]
            blend.append({"alpha": 0.0, "mpjpe_cm": 0.0, "psnr_box": round(base["psnr_box"], 3), "psnr_gap_db": 0.0,
                          "iou_render": round(base["mask_iou"], 4)})
            for alpha in blend_shares:
                folder = tmp / f"blend_{alpha:g}"
                err = blended_folder(person_dir, truth_dir, alpha, folder)
                art = store.get(train_human.run(train_human.Inputs(folder=folder), cfg, ctx).human)
                mean = json.loads(art.file("eval.json").read_text())["mean"]
                blend.append({"alpha": alpha, "mpjpe_cm": round(err, 3), "psnr_box": round(mean["psnr_box"], 3),
                              "psnr_gap_db": round(base["psnr_box"] - mean["psnr_box"], 3),
                              "iou_render": round(mean["mask_iou"], 4)})
                print(f"blend {alpha:g}: PA-MPJPE {err:.2f} cm, PSNR box {mean['psnr_box']:.2f} "
                      f"({base['psnr_box'] - mean['psnr_box']:+.2f} dB below the true poses), "
                      f"render IoU {mean['mask_iou']:.3f}", flush=True)
    print(f"actor capture {cap_over[2:]} in {cap_s:.0f} s (camera {report['camera']}); person fit in {fit_s_person:.0f} s, "
          f"{report['frames_kept']} of {report['frames_in']} frames kept, height {report['height_m']:.2f} m, "
          f"camera height {report['camera_height_m']:.2f} m")
    print(f"mask IoU {scores['mask_iou']:.3f}; MPJPE after Procrustes {scores['mpjpe_cm']:.2f} cm "
          f"(root-relative, no alignment {scores['mpjpe_cm_no_alignment_root_relative']:.2f} cm)")
    for name, r in refined.items():
        print(f"{name} poses refined with the NeRF (held-out frames {'fitted' if name in fits else 'by neighbours'}): "
              f"PA-MPJPE {r['mpjpe_cm_given']:.2f} -> {r['mpjpe_cm_refined']:.2f} cm "
              f"(trained frames {r.get('mpjpe_cm_given_trained', float('nan')):.2f} -> "
              f"{r.get('mpjpe_cm_refined_trained', float('nan')):.2f}, held-out "
              f"{r.get('mpjpe_cm_given_held_out', float('nan')):.2f} -> {r.get('mpjpe_cm_refined_held_out', float('nan')):.2f}); "
              f"moved {json.dumps(r['moved'])}")
    print(f"held-out fit: {cfg.refine.held_out_steps} steps (scores at the fitted poses, then at the given ones)")
    print(f"{'poses':>8} {'PSNR box':>9} {'render IoU':>11} {'IoU true masks':>15} {'given: PSNR':>12} {'IoU':>6} "
          f"{'true':>6} {'fit s':>6} {'wall s':>7}")
    nan = float("nan")
    for name in ("fitted", "truth"):
        m = evals[name]
        print(f"{name:>8} {m.get('psnr_box', nan):9.2f} {m['mask_iou']:11.3f} {m['mask_iou_true_masks']:15.3f} "
              f"{m.get('psnr_box_given_poses', m.get('psnr_box', nan)):12.2f} "
              f"{m.get('mask_iou_given_poses', m['mask_iou']):6.3f} {m['mask_iou_true_masks_given_poses']:6.3f} "
              f"{fit_s[name]:6.1f} {walls[name]:7.0f}")
    for name, m in crossed.items():
        print(f"{name}: PSNR box {m.get('psnr_box', nan):.2f}, render IoU {m['mask_iou']:.3f}")
    given = {name: {"psnr_box": m.get("psnr_box_given_poses", m.get("psnr_box", nan)),
                    "mask_iou": m.get("mask_iou_given_poses", m["mask_iou"])} for name, m in evals.items()}
    print(json.dumps({"quick": q, "steps": cfg.optim.steps, "threads": threads, "camera": report["camera"],
                      "frames_kept": report["frames_kept"], "frames_in": report["frames_in"],
                      "mask_iou": round(scores["mask_iou"], 4),
                      "mpjpe_cm": round(refined["fitted"]["mpjpe_cm_refined"] if "fitted" in refined and cfg.refine.lr > 0
                                        else scores["mpjpe_cm"], 3),
                      "mpjpe_cm_landmark_fit": round(scores["mpjpe_cm"], 3),
                      "pose_refinement": {name: {k: (round(v, 3) if isinstance(v, float) else v)
                                                 for k, v in r.items()} for name, r in refined.items()},
                      "psnr_box": round(evals["fitted"].get("psnr_box", float("nan")), 3),
                      "psnr_box_gt_poses": round(evals["truth"].get("psnr_box", float("nan")), 3),
                      "iou_render": round(evals["fitted"]["mask_iou"], 4),
                      "iou_render_gt_poses": round(evals["truth"]["mask_iou"], 4),
                      "iou_render_true_masks": round(evals["fitted"]["mask_iou_true_masks"], 4),
                      "iou_render_gt_poses_true_masks": round(evals["truth"]["mask_iou_true_masks"], 4),
                      "held_out_steps": cfg.refine.held_out_steps,
                      "psnr_box_given_poses": round(given["fitted"]["psnr_box"], 3),
                      "psnr_box_gt_poses_given_poses": round(given["truth"]["psnr_box"], 3),
                      "iou_render_given_poses": round(given["fitted"]["mask_iou"], 4),
                      "iou_render_gt_poses_given_poses": round(given["truth"]["mask_iou"], 4),
                      "iou_render_true_masks_given_poses": round(evals["fitted"]["mask_iou_true_masks_given_poses"], 4),
                      "iou_render_gt_poses_true_masks_given_poses":
                          round(evals["truth"]["mask_iou_true_masks_given_poses"], 4),
                      "held_out_fit": {name: {k: round(v, 3) for k, v in moved.items()} for name, moved in fits.items()},
                      **follow_keys,
                      **({"crossed": crossed} if crossed else {}),
                      **({"pose_blend": blend} if blend else {}),
                      "wall_seconds": {"capture": round(cap_s, 1), "fit": round(fit_s_person, 1),
                                       **{f"train_{k}": round(v, 1) for k, v in walls.items()},
                                       **{f"held_out_fit_{k}": round(v, 1) for k, v in fit_s.items()}}}))


if __name__ == "__main__":
    main()
