"""`nsim evaluate` at tiny size: a micro scene checkpoint, a short Spot run, a poses-mode render of
the held-out frames; every table, a render equal to its ground truth scoring exactly, the Spot run
rendered with its people for the detection table (people in the render and in the ground truth), and
each bad input ending in one line and exit 2."""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from nsim.cli import main
from nsim.config import configs_dir
from nsim.context import RunContext
from nsim.workspace.store import Store
from tests.stages.micro import CAPTURE
from tests.stages.micro import MICRO_SCENE as MICRO

SPOT = configs_dir() / "robots" / "spot.yaml"
CAMERAS = ("frontleft", "left", "back")
HELDOUT = [0, 8, 16]  # train-scene tiny holds out every 8th of the 24 frames


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """A capture, a micro scene checkpoint, a 2 s Spot run rendered by three cameras (3 frames) and
    the scene's held-out frames rendered at their own cameras."""
    root = tmp_path_factory.mktemp("evaluate")
    ws = str(root / "ws")
    args = ["--workspace", ws, "capture", "synth"]
    for kv in CAPTURE:
        args += ["--set", kv]
    assert main([*args, "--tag", "capture/t"]) == 0
    cfg_file = root / "micro.yaml"
    cfg_file.write_text(yaml.safe_dump(MICRO))
    assert main(["--workspace", ws, "--device", "cpu", "train-scene", "--poses", "capture/t", "--preset", "tiny",
                 "--config", str(cfg_file), "--tag", "scene/t"]) == 0
    assert main(["--workspace", ws, "simulate", "--preset", "tiny", "--set", "max_duration_s=2.0", "--scenario",
                 str(configs_dir() / "scenarios" / "spot_run.json"), "--tag", "trajectory/t"]) == 0
    assert main(["--workspace", ws, "--device", "cpu", "render", "--trajectory", "trajectory/t", "--scene", "scene/t",
                 "--rig", str(SPOT), "--preset", "tiny", "--set", f"sensors=[{','.join(CAMERAS)}]", "--no-people",
                 "--tag", "render/spot"]) == 0
    assert main(["--workspace", ws, "--device", "cpu", "render", "--poses", "capture/t", "--scene", "scene/t",
                 "--preset", "tiny", "--set", "frames=heldout", "--set", "tick_stride=1", "--set", "image_scale=1.0",
                 "--tag", "render/heldout"]) == 0
    return Store(ws)


def evaluate(store: Store, table: str, *renders: str, sets: tuple[str, ...] = ("lpips_net=none",)) -> int:
    args = ["--workspace", str(store.root), "--device", "cpu", "evaluate", "--preset", "tiny", "--table", table]
    for r in renders:
        args += ["--render", r]
    for s in sets:
        args += ["--set", s]
    return main(args)


def latest(store: Store):
    art = store.get(store.resolve("evaluation/latest"))
    meta = json.loads(art.file("evaluation.json").read_text())
    table = json.loads(art.file(f"{meta['table']}.json").read_text())
    records = json.loads(art.file("records.json").read_text())["records"]
    return art, table, records


def cell(value) -> float:
    """A table JSON cell as a float (inf is stored as {"float": "inf"})."""
    return float(value["float"]) if isinstance(value, dict) else float(value)


def variant(store: Store, base_ref: str, name: str, edit) -> str:
    """A copy of a render artifact with ``edit(dir)`` applied, published under the same inputs (a
    stand-in for a render whose files are not what the simulator wrote)."""
    base = store.get(store.resolve(base_ref))
    m = base.manifest
    key = hashlib.sha256(f"test-variant:{base.id}:{name}".encode()).hexdigest()
    with store.publish(kind="render", stage="render", version=m["stage_version"], key=key, config=m["config"],
                       inputs=m["inputs"], seed=m["seed"]) as out:
        for src in base.path.rglob("*"):
            if src.is_file() and src.name != "manifest.json":
                dst = out.dir / src.relative_to(base.path)
                dst.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(src, dst)
                os.chmod(dst, 0o644)
        edit(out.dir)
    return out.ref


# ---------------------------------------------------------------------------------- the tables
def test_scenes_table(world, capsys):
    assert evaluate(world, "scenes", "render/heldout", sets=("lpips_net=alex",)) == 0
    art, table, records = latest(world)
    capsys.readouterr()
    assert evaluate(world, "scenes", "render/heldout", sets=("lpips_net=alex",)) == 0
    assert "cached" in capsys.readouterr().err and world.resolve("evaluation/latest") == art.id
    for name in ("scenes.md", "scenes.tex", "scenes.csv", "scenes.json", "records.json", "evaluation.json",
                 "plots/psnr_db_per_frame.png", "plots/abs_rel_per_frame.png", "plots/bars.png"):
        assert art.file(name).stat().st_size > 0, name
    assert len(list((art.path / "plots" / "depth_error").glob("*.png"))) == 1  # tiny: error_maps 1
    (row,) = table["rows"]
    assert row["Environment"] == "robot-lab" and row["frames"] == len(HELDOUT)
    assert 8.0 < cell(row["PSNR"]) < 60.0 and 0.0 < cell(row["SSIM"]) <= 1.0
    assert 0.0 <= cell(row["AbsRel"]) and 0.0 <= cell(row["δ<1.25"]) <= 1.0
    lp = row["LPIPS"]
    assert (isinstance(lp, dict) and "not_available" in lp) or 0.0 <= lp <= 1.5
    assert len(records) == 2 * len(HELDOUT)  # one image and one depth record per frame
    assert sorted({r["frame"] for r in records}) == HELDOUT
    image = [r for r in records if "psnr_db" in r]
    assert np.isclose(np.mean([r["psnr_db"] for r in image]), cell(row["PSNR"]))
    notes = " ".join(table["notes"])
    assert "its own images and depth EXRs" in notes and "without median scaling" in notes
    assert "| robot-lab |" in art.file("scenes.md").read_text()
    assert r"\toprule" in art.file("scenes.tex").read_text()


def test_scenes_render_equal_to_its_ground_truth_is_exact(world):
    """Frames that are the capture's own images and depth: PSNR inf, SSIM 1, AbsRel 0."""
    cap = world.get(world.resolve("capture/t"))
    frames = json.loads(cap.file("transforms.json").read_text())["frames"]

    def copy_truth(d: Path) -> None:
        for i in HELDOUT:
            shutil.copyfile(cap.path / frames[i]["file_path"], d / "frames" / "rgb" / f"{i:06d}.png")
            shutil.copyfile(cap.path / frames[i]["depth_file_path"], d / "frames" / "depth" / f"{i:06d}.exr")

    ref = variant(world, "render/heldout", "truth", copy_truth)
    assert evaluate(world, "scenes", ref) == 0
    _, table, _ = latest(world)
    (row,) = table["rows"]
    assert math.isinf(cell(row["PSNR"])) and cell(row["SSIM"]) == pytest.approx(1.0)
    assert cell(row["AbsRel"]) == pytest.approx(0.0, abs=1e-7) and cell(row["δ<1.25"]) == 1.0


def test_spot_rgb_and_depth_tables(world):
    n_frames = len(json.loads(world.get(world.resolve("render/spot")).file("render.json").read_text())["frames"])
    assert evaluate(world, "spot-rgb", "render/spot") == 0
    art, table, records = latest(world)
    assert [r["Camera"] for r in table["rows"]] == list(CAMERAS)
    assert len(records) == n_frames * len(CAMERAS)
    for row in table["rows"]:
        assert 5.0 < cell(row["PSNR"]) < 60.0 and row["frames"] == n_frames
        assert row["LPIPS"] == {"not_available": "LPIPS not computed"}
    assert art.file("plots/ssim_per_frame.png").is_file()
    assert evaluate(world, "spot-depth", "render/spot") == 0
    art, table, records = latest(world)
    assert len(records) == n_frames * len(CAMERAS)
    for row in table["rows"]:
        assert math.isfinite(cell(row["AbsRel"])) and cell(row["AbsRel"]) >= 0.0
        deltas = [cell(row[k]) for k in ("δ<1.05", "δ<1.10", "δ<1.25", "δ<1.25²", "δ<1.25³")]
        assert all(0.0 <= d <= 1.0 for d in deltas) and deltas == sorted(deltas)
    assert len(list((art.path / "plots" / "depth_error").glob("*.png"))) == len(CAMERAS)


def test_spot_render_equal_to_the_oracle_is_exact(world):
    """Camera images and depth made by the oracle at the frames' camera poses score exactly: checks
    that evaluation finds the same cameras, poses, exposure and depth kind as the renderer."""
    from nsim.evaluation.oracle_truth import sensor_depth_gt
    from nsim.evaluation.renders import uint8_rgb
    from nsim.io.exr import write_depth_exr
    from nsim.io.images import write_image
    from nsim.io.transforms_json import read_transforms
    from nsim.sensors.rig import Rig
    from nsim.synth.oracle import RoomOracle
    from nsim.synth.room import RoomSpec

    cap = world.get(world.resolve("capture/t"))
    oracle = RoomOracle(RoomSpec.from_dict(json.loads(cap.file("room.json").read_text())["spec"]))

    def oracle_frames(d: Path) -> None:
        rig = Rig.from_resolved(json.loads((d / "rig.json").read_text()))
        for s in rig.cameras:
            for f in read_transforms(d / "cameras" / f"{s.name}.json").frames:
                view = oracle.render_gt(f.camera, f.cam_to_world, 1)
                write_image(d / f.file_path, uint8_rgb(s.expose(view.rgb)))
                write_depth_exr(d / f.file_path.replace("/rgb/", "/depth/").replace(".png", ".exr"),
                                sensor_depth_gt(s, view.depth_range).astype(np.float32))

    ref = variant(world, "render/spot", "oracle", oracle_frames)
    assert evaluate(world, "spot-rgb", ref) == 0
    for row in latest(world)[1]["rows"]:
        assert math.isinf(cell(row["PSNR"])) and cell(row["SSIM"]) == pytest.approx(1.0)
    assert evaluate(world, "spot-depth", ref) == 0
    for row in latest(world)[1]["rows"]:
        assert cell(row["AbsRel"]) < 1e-6 and cell(row["δ<1.05"]) == 1.0


def test_a_hole_in_the_scene_is_named_per_camera(world):
    """Issue 42's `left` camera: a scene model with a hole (no return, +inf, where the truth has a surface) in one
    camera's view raises that camera's AbsRel alone; the table's notes and records name the camera and the pixels."""
    from nsim.evaluation.oracle_truth import sensor_depth_gt
    from nsim.io.exr import write_depth_exr
    from nsim.io.transforms_json import read_transforms
    from nsim.sensors.rig import Rig
    from nsim.synth.oracle import RoomOracle
    from nsim.synth.room import RoomSpec

    cap = world.get(world.resolve("capture/t"))
    oracle = RoomOracle(RoomSpec.from_dict(json.loads(cap.file("room.json").read_text())["spec"]))
    holed = "left"

    def holed_frames(d: Path) -> None:
        rig = Rig.from_resolved(json.loads((d / "rig.json").read_text()))
        for s in rig.cameras:
            for f in read_transforms(d / "cameras" / f"{s.name}.json").frames:
                depth = sensor_depth_gt(s, oracle.render_gt(f.camera, f.cam_to_world, 1).depth_range).astype(np.float32)
                if s.name == holed:
                    h, w = depth.shape
                    depth[h // 2 - 2: h // 2 + 2, w // 2 - 2: w // 2 + 2] = np.inf
                write_depth_exr(d / f.file_path.replace("/rgb/", "/depth/").replace(".png", ".exr"), depth)

    ref = variant(world, "render/spot", "holed", holed_frames)
    assert evaluate(world, "spot-depth", ref) == 0
    art, table, _ = latest(world)
    rows = {r["Camera"]: cell(r["AbsRel"]) for r in table["rows"] if r.get("Camera") in CAMERAS}
    assert rows[holed] > 1e-3 and all(v < 1e-6 for k, v in rows.items() if k != holed), rows
    frames = json.loads(art.file("records.json").read_text())["frames"]  # per-frame extras
    n = sum(1 for r in frames if r.get("no_return_px"))
    assert n > 0 and all(r["no_return_px"] == 16 for r in frames if r.get("no_return_px")), frames[:3]
    assert any(f"({holed} {16 * n} px at a median" in note for note in table["notes"]), table["notes"]


def test_lidar_against_the_oracle(world):
    """The LiDAR table against the oracle: a render's sweeps score finite; the oracle's own exact sweeps written as
    the render's score 0 m with every beam agreeing; the same sweeps 10 cm long score a 10 cm median and bias."""
    from nsim.io.lidar_exr import read_lidar_exr, write_lidar_exr
    from nsim.io.tum import read_tum
    from nsim.sensors.rig import Rig
    from nsim.synth.oracle import RoomOracle
    from nsim.synth.room import RoomSpec

    ws = str(world.root)
    assert main(["--workspace", ws, "--device", "cpu", "render", "--trajectory", "trajectory/t", "--scene", "scene/t",
                 "--rig", str(SPOT), "--preset", "tiny", "--set", "sensors=[lidar]", "--set", "max_frames=2",
                 "--no-people", "--tag", "render/lidar"]) == 0
    assert evaluate(world, "lidar", "render/lidar") == 0
    _, table, records = latest(world)
    (row,) = table["rows"]
    assert row["LiDAR"] == "lidar" and row["frames"] == 2 and len(records) == 2
    # a 30-step scene: finite, no bound (its haze stops beams early)
    assert math.isfinite(cell(row["range err median [m]"])) and 0.0 < cell(row["hit agreement"]) <= 1.0

    cap = world.get(world.resolve("capture/t"))
    oracle = RoomOracle(RoomSpec.from_dict(json.loads(cap.file("room.json").read_text())["spec"]))

    def oracle_sweeps(offset_m: float):
        def edit(d: Path) -> None:
            rig = Rig.from_resolved(json.loads((d / "rig.json").read_text()))
            body = read_tum(d / "robot.tum").poses_se3()
            meta = json.loads((d / "render.json").read_text())
            for f, T in zip(meta["frames"], body, strict=True):
                s = rig["lidar"]
                path = d / "lidar" / "scan" / f"{f['index']:06d}.exr"
                exact = oracle.lidar_gt(s.world_pose(T), s).ranges_m
                assert read_lidar_exr(path).range_m.shape == exact.shape
                write_lidar_exr(path, s.scan(exact + np.float32(offset_m)), sensor=s.name,
                                elevations_deg=s.elevations_deg)
        return edit

    assert evaluate(world, "lidar", variant(world, "render/lidar", "oracle-lidar", oracle_sweeps(0.0))) == 0
    (row,) = latest(world)[1]["rows"]
    assert cell(row["range err median [m]"]) < 1e-5 and cell(row["Chamfer [m]"]) < 1e-5
    assert cell(row["hit agreement"]) == 1.0
    assert evaluate(world, "lidar", variant(world, "render/lidar", "oracle-lidar+10cm", oracle_sweeps(0.1))) == 0
    (row,) = latest(world)[1]["rows"]
    assert cell(row["range err median [m]"]) == pytest.approx(0.1, abs=1e-4)
    assert cell(row["range bias [m]"]) == pytest.approx(0.1, abs=1e-4)


def test_slam_failure_is_not_available(world):
    """Three 64x48 frames are too few for SfM: the row is n/a with the reason, not a crash."""
    assert evaluate(world, "slam", "render/spot") == 0
    art, table, _ = latest(world)
    (row,) = table["rows"]
    assert row["Sequence"] == "left"
    assert "not_available" in row["ATE real [m]"] and "not_available" in row["ATE sim [m]"]
    assert "SfM" in row["ATE sim [m]"]["not_available"]
    assert art.file("slam/left/ground_truth.tum").is_file()


def test_detection_without_people_is_not_available(world):
    assert evaluate(world, "detection", "render/spot") == 0
    _, table, _ = latest(world)
    assert [r["Scene"] for r in table["rows"]] == list(CAMERAS)
    assert all("no people" in r["IoU"]["not_available"] for r in table["rows"])


# ---------------------------------------------------------------------------------- people
@pytest.fixture(scope="module")
def people(world):
    """The Spot run of ``world`` rendered with its five people, drawn by a human checkpoint trained
    briefly on an actor capture of the same room (appearance seed 0: the run's seed)."""
    ws = str(world.root)
    assert main(["--workspace", ws, "capture", "synth", "--preset", "tiny", "--actor", "--set", "n_frames=12",
                 "--set", "supersample=1", "--set", "video=false", "--tag", "capture/actor"]) == 0
    assert main(["--workspace", ws, "--device", "cpu", "train-human", "--capture", "capture/actor", "--preset", "tiny",
                 "--steps", "60", "--tag", "human/t"]) == 0
    assert main(["--workspace", ws, "--device", "cpu", "render", "--trajectory", "trajectory/t", "--scene", "scene/t",
                 "--rig", str(SPOT), "--humans", "human/t", "--preset", "tiny",
                 "--set", f"sensors=[{','.join(CAMERAS)}]", "--tag", "render/people"]) == 0
    return world


def test_a_scenario_names_the_checkpoint_that_draws_a_person(people, tmp_path, capsys):
    """``humans[k].appearance`` in the scenario picks person k's human checkpoint among ``--humans`` (the others,
    and names this workspace does not have: k mod M); the render says which drew whom; a checkpoint that is not
    among them is one line (exit 2) before any work, and nothing is published."""
    ws = str(people.root)
    assert main(["--workspace", ws, "--device", "cpu", "train-human", "--capture", "capture/actor", "--preset", "tiny",
                 "--steps", "61", "--tag", "human/t2"]) == 0
    spec = json.loads((configs_dir() / "scenarios" / "spot_run.json").read_text())

    def scenario(name: str, appearance: str) -> str:
        doc = json.loads(json.dumps(spec))
        doc["humans"][0]["appearance"] = appearance
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(doc))
        assert main(["--workspace", ws, "simulate", "--preset", "tiny", "--set", "max_duration_s=2.0", "--scenario",
                     str(path), "--tag", f"trajectory/{name}"]) == 0
        return f"trajectory/{name}"

    def render(traj: str, *humans: str) -> int:
        args = ["--workspace", ws, "--device", "cpu", "render", "--trajectory", traj, "--scene", "scene/t",
                "--rig", str(SPOT), "--preset", "tiny", "--set", "sensors=[left]", "--set", "max_frames=1"]
        for h in humans:
            args += ["--humans", h]
        return main([*args, "--tag", "render/named"])

    t, t2 = people.resolve("human/t"), people.resolve("human/t2")
    n = len(spec["humans"])
    assert render(scenario("named", "human/t2"), "human/t", "human/t2") == 0
    summary = people.get(people.resolve("render/named")).manifest["summary"]
    assert summary["people_checkpoints"] == [t2] + [(t, t2)[k % 2] for k in range(1, n)]
    # spot_run itself names human/ana, human/ben ...: not in this workspace, so a warning and k mod M
    assert render("trajectory/t", "human/t", "human/t2") == 0
    assert people.get(people.resolve("render/named")).manifest["summary"]["people_checkpoints"] == \
        [(t, t2)[k % 2] for k in range(n)]
    before = people.all_ids()
    capsys.readouterr()
    assert render("trajectory/named", "human/t") == 2
    err = capsys.readouterr().err.strip()
    assert "humans[0].appearance 'human/t2' is human checkpoint" in err and "add it" in err and "\n" not in err
    assert set(people.all_ids()) == set(before)


def test_spot_render_with_people_shows_them(people):
    """The run's people are in view of the Spot cameras: the render's person masks and COCO boxes."""
    art = people.get(people.resolve("render/people"))
    meta = json.loads(art.file("render.json").read_text())
    px = {cam: [row[cam]["people_px"] for row in meta["per_frame"]] for cam in CAMERAS}
    assert sum(p > 0 for ps in px.values() for p in ps) >= 3, px
    boxes = [json.loads(art.file(f"{cam}/boxes.json").read_text())["annotations"] for cam in CAMERAS]
    assert sum(len(b) for b in boxes) >= 3


def test_detection_with_people(people):
    """Detection on a render with people: numbers, not n/a; the ground truth (oracle actors) shows the
    people where the render shows them (person masks overlap), dressed like the checkpoint's actor."""
    n_frames = len(json.loads(people.get(people.resolve("render/people")).file("render.json").read_text())["frames"])
    assert evaluate(people, "detection", "render/people") == 0
    art, table, _ = latest(people)
    assert [r["Scene"] for r in table["rows"]] == [*CAMERAS, "all"]
    for row in table["rows"]:
        assert isinstance(row["boxes sim"], int) and isinstance(row["boxes real"], int), row
        assert row["frames"] == (n_frames * len(CAMERAS) if row["Scene"] == "all" else n_frames)
    frames = json.loads(art.file("records.json").read_text())["frames"]
    assert len(frames) == n_frames * len(CAMERAS)
    sim = [f["people_px_sim"] for f in frames]
    real = [f["people_px_real"] for f in frames]
    assert sum(p > 0 for p in sim) >= 3 and sum(p > 0 for p in real) >= 3, (sim, real)
    ious = [f["mask_iou"] for f in frames if f["mask_iou"] is not None]
    assert np.mean(ious) > 0.3, ious  # the same people in the same places on both sides
    assert {f["upright_turns"] for f in frames if f["group"] == "frontleft"} == {3}
    notes = " ".join(table["notes"])
    assert "people in view" in notes and "actor seed 0" in notes and "frontleft 270 deg" in notes
    meta = json.loads(art.file("evaluation.json").read_text())
    assert "oracle" in meta["ground_truth"][people.resolve("render/people")]


def test_the_default_look_is_the_oracles_actor(people):
    """Without --humans the run's people, whose looks (human/ana ...) this workspace lacks, are drawn with the
    default look, the test room's actor (seed 0): the oracle's ground truth shows the same bodies where the render
    does (person masks agree far better than a trained checkpoint's), and detection scores them."""
    ws = str(people.root)
    assert main(["--workspace", ws, "--device", "cpu", "render", "--trajectory", "trajectory/t", "--scene", "scene/t",
                 "--rig", str(SPOT), "--preset", "tiny", "--set", f"sensors=[{','.join(CAMERAS)}]",
                 "--tag", "render/default-look"]) == 0
    summary = people.get(people.resolve("render/default-look")).manifest["summary"]
    assert set(summary["people_checkpoints"]) == {"default look"}
    assert evaluate(people, "detection", "render/default-look") == 0
    art, table, _ = latest(people)
    frames = json.loads(art.file("records.json").read_text())["frames"]
    ious = [f["mask_iou"] for f in frames if f["mask_iou"] is not None]
    assert len(ious) >= 3 and np.mean(ious) > 0.8, ious
    assert "actor seed 0" in " ".join(table["notes"])


def test_detection_ground_truth_is_the_oracle_with_the_people(people):
    """A render whose frames are the oracle's with the actors detects exactly what the ground truth does,
    and its person masks are the oracle's: the evaluation poses and dresses the people as the render does."""
    from nsim.config import load_config
    from nsim.evaluation.evaluate_tables import Evaluation
    from nsim.evaluation.renders import uint8_rgb
    from nsim.io.coco import write_instance_mask
    from nsim.io.images import write_image
    from nsim.io.transforms_json import read_transforms
    from nsim.sensors.rig import Rig
    from nsim.stages import evaluate as ev_stage
    from nsim.stages.evaluate import Inputs

    ctx = RunContext(store=people, device_spec="cpu")
    cfg = load_config(ev_stage.Config, stage="evaluate", preset="tiny", overrides=["table=detection"])
    inputs = ev_stage.evaluation_inputs(Inputs(renders=(people.resolve("render/people"),)), cfg, ctx)
    evaluation = Evaluation(inputs, cfg)
    actors = evaluation.truth.actors(evaluation.renders[0])
    oracle = evaluation.truth.oracle(evaluation.renders[0].lineage.capture)

    def oracle_frames(d: Path) -> None:
        rig = Rig.from_resolved(json.loads((d / "rig.json").read_text()))
        for s in rig.cameras:
            for f in read_transforms(d / "cameras" / f"{s.name}.json").frames:
                tick = int(Path(f.file_path).stem)
                view = oracle.render_gt(f.camera, f.cam_to_world, 1, actors=actors(tick))
                write_image(d / f.file_path, uint8_rgb(s.expose(view.rgb)))
                write_instance_mask(d / s.name / "mask" / f"{tick:06d}.png", view.instance_mask.astype(np.uint16))

    ref = variant(people, "render/people", "oracle-people", oracle_frames)
    # a generous HOG (8x upscale, margin -1) so that the 64x48 frames give boxes at all
    sets = ("lpips_net=none", "detection.hog_upscale=8.0", "detection.hog_hit_threshold=-1.0")
    assert evaluate(people, "detection", ref, sets=sets) == 0
    art, table, records = latest(people)
    frames = json.loads(art.file("records.json").read_text())["frames"]
    assert all(f["mask_iou"] in (None, 1.0) for f in frames) and any(f["mask_iou"] == 1.0 for f in frames)
    assert sum(r["n_sim"] for r in records) > 0
    assert all(r["n_sim"] == r["n_real"] and len(r["ious"]) == r["n_sim"] for r in records)
    assert all(v == pytest.approx(1.0) for r in records for v in r["ious"])
    total = table["rows"][-1]
    assert total["Scene"] == "all" and cell(total["precision"]) == 1.0 and cell(total["recall"]) == 1.0


def test_upright_turns_of_spot_cameras():
    """Spot's front cameras are rolled ~90 deg, its right camera is upside down: turned so up is up."""
    from nsim.evaluation.evaluate_tables import upright_turns
    from nsim.sensors.rig import Rig

    rig = Rig.load(SPOT)
    turns = {s.name: upright_turns(s) for s in rig.cameras}
    assert turns == {"frontleft": 3, "frontright": 3, "left": 0, "right": 2, "back": 0}
    for s in rig.cameras:  # the body's up, projected into the turned image, points up (-y)
        up = s.sensor_to_body[:3, :3].T @ np.array([0.0, 0.0, 1.0])
        dx, dy = up[0], up[1]
        for _ in range(turns[s.name]):
            dx, dy = dy, -dx
        assert -dy > abs(dx), s.name


# ---------------------------------------------------------------------------------- bad input
def _resize_first_rgb(d: Path) -> None:
    from nsim.io.images import read_image, write_image

    p = d / "frames" / "rgb" / f"{HELDOUT[1]:06d}.png"
    write_image(p, read_image(p)[:24, :32])


def _nan_depth(d: Path) -> None:
    from nsim.io.exr import read_depth_exr, write_depth_exr

    p = d / "frames" / "depth" / f"{HELDOUT[0]:06d}.exr"
    depth = read_depth_exr(p)
    depth[20:28, 28:36] = np.nan
    write_depth_exr(p, depth)


def _frame_out_of_range(d: Path) -> None:
    meta = json.loads((d / "render.json").read_text())
    meta["frames"].append({"index": 999, "name": "frame_00999.png", "time_s": 99.9})
    (d / "render.json").write_text(json.dumps(meta))


def _extra_trajectory_frame(d: Path) -> None:
    meta = json.loads((d / "render.json").read_text())
    meta["frames"].append({"index": 999, "time_s": 49.95})
    (d / "render.json").write_text(json.dumps(meta))


def _empty_masks(d: Path) -> None:
    from nsim.io.coco import write_instance_mask

    for cam in CAMERAS:
        (d / cam / "mask").mkdir(exist_ok=True)
        for f in json.loads((d / "render.json").read_text())["frames"]:
            write_instance_mask(d / cam / "mask" / f"{f['index']:06d}.png", np.zeros(_shape(d, cam), np.uint16))


def _shape(d: Path, cam: str) -> tuple[int, int]:
    data = json.loads((d / "cameras" / f"{cam}.json").read_text())
    return int(data["h"]), int(data["w"])


def _shifted_timestamps(d: Path) -> None:
    data = json.loads((d / "cameras" / "left.json").read_text())
    for f in data["frames"]:
        f["timestamp"] += 1000.0
    (d / "cameras" / "left.json").write_text(json.dumps(data))


BAD = {
    "wrong mode (scenes, trajectory render)": ("scenes", "render/spot", None, (), "trajectory-mode render"),
    "wrong mode (spot-rgb, poses render)": ("spot-rgb", "render/heldout", None, (), "poses-mode render"),
    "sizes differ": ("scenes", "render/heldout", _resize_first_rgb, (), "32x24"),
    "NaN depth at valid pixels": ("scenes", "render/heldout", _nan_depth, (), "NaN"),
    "frame not in the capture": ("scenes", "render/heldout", _frame_out_of_range, (), "frame 999"),
    "frame counts differ (cameras)": ("spot-depth", "render/spot", _extra_trajectory_frame, (), "frame 999"),
    "empty person masks": ("spot-rgb", "render/spot", _empty_masks, ("region=people",), "empty"),
    "no common timestamps": ("slam", "render/spot", _shifted_timestamps, (), "share no timestamp"),
    "unknown table": ("tables", "render/spot", None, (), "table"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_is_one_line_and_exit_2(world, case, capsys):
    table, base, edit, sets, words = BAD[case]
    ref = variant(world, base, case, edit) if edit is not None else base
    capsys.readouterr()
    assert evaluate(world, table, ref, sets=("lpips_net=none", *sets)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and words in err[0], err


def test_stage_run_and_rebuild(world):
    """The stage without the CLI: same artifact as the CLI's, and ``rebuild`` reproduces it."""
    from nsim.config import load_config
    from nsim.stages import evaluate as ev

    ctx = RunContext(store=world, device_spec="cpu")
    cfg = load_config(ev.Config, stage="evaluate", preset="tiny", overrides=["table=spot-depth", "lpips_net=none"])
    out = ev.run(ev.Inputs(renders=("render/spot",)), cfg, ctx)
    manifest = world.get(out.evaluation).manifest
    assert ev.rebuild(manifest, RunContext(store=world, device_spec="cpu")) == out.evaluation
    assert ev.load_table(ctx, out.evaluation).rows[0]["Camera"] == CAMERAS[0]
