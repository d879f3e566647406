"""Comparing a rebuilt artifact with the original: figures against hand-made ground truth, verdicts
against the kind's tolerances, bad files as notes, and ``nsim verify --rebuild`` end to end."""

from __future__ import annotations

import hashlib
import json
import math
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from nsim.io.exr import write_depth_exr
from nsim.io.images import write_image
from nsim.io.ply import write_ply
from nsim.io.tum import Trajectory, write_tum
from nsim.workspace.compare import TOLERANCES, FileDelta, compare_artifacts
from nsim.workspace.store import KINDS


# ------------------------------------------------------------------------------- helpers
def _manifest_files(root: Path) -> dict[str, dict]:
    return {
        p.relative_to(root).as_posix(): {"sha256": hashlib.sha256(p.read_bytes()).hexdigest(), "size": p.stat().st_size}
        for p in sorted(root.rglob("*")) if p.is_file()
    }


def _compare(tmp_path: Path, kind: str):
    old, new = tmp_path / "old", tmp_path / "new"
    return compare_artifacts(old, new, kind, _manifest_files(old), _manifest_files(new))


def _pair(tmp_path: Path, rel: str) -> tuple[Path, Path]:
    a, b = tmp_path / "old" / rel, tmp_path / "new" / rel
    a.parent.mkdir(parents=True, exist_ok=True)
    b.parent.mkdir(parents=True, exist_ok=True)
    return a, b


def _only(comparison) -> FileDelta:
    assert len(comparison.deltas) == 1, comparison.deltas
    return comparison.deltas[0]


def test_every_kind_has_tolerances():
    assert set(TOLERANCES) == set(KINDS)
    with pytest.raises(ValueError, match="no tolerances"):
        compare_artifacts(Path("."), Path("."), "nonsense", {}, {})


# ------------------------------------------------------------------------------- images
@pytest.mark.parametrize("step,kind,within", [(1, "capture", True), (8, "capture", False), (8, "scene-checkpoint", True)])
def test_png_psnr_matches_the_formula(tmp_path, step, kind, within):
    rng = np.random.default_rng(0)
    img = rng.integers(20, 230, size=(24, 32, 3), dtype=np.uint8)
    noise = rng.choice(np.array([-step, step]), size=img.shape)
    a, b = _pair(tmp_path, "images/frame_00000.png")
    write_image(a, img)
    write_image(b, (img.astype(int) + noise).astype(np.uint8))
    d = _only(_compare(tmp_path, kind))
    expected = 10 * math.log10(1.0 / np.mean((noise / 255.0) ** 2))  # = 20 log10(255 / step)
    assert d.measure == "psnr_db" and d.value == pytest.approx(expected, abs=1e-5)  # to_float is float32
    assert d.tolerance == TOLERANCES[kind].min_psnr_db and d.within is within
    assert str(d).startswith(f"images/frame_00000.png: PSNR {expected:.1f} dB (tolerance >= ")
    assert str(d).endswith(" ok" if within else " OUTSIDE")


def test_png_same_pixels_other_bytes_is_inf_db(tmp_path):
    img = np.full((8, 8, 3), 100, np.uint8)
    a, b = _pair(tmp_path, "images/x.png")
    write_image(a, img)
    b.write_bytes(cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 0])[1].tobytes())  # other bytes
    d = _only(_compare(tmp_path, "capture"))
    assert d.value == math.inf and d.within and d.to_dict()["value"] == "inf"


@pytest.mark.parametrize("kind,within", [("capture", False), ("scene-checkpoint", True)])
def test_mask_share_of_changed_pixels(tmp_path, kind, within):
    mask = np.zeros((10, 20), np.uint8)
    mask[2:6, 3:9] = 255
    changed = mask.copy()
    changed[0, 0] = changed[9, 19] = 255
    changed[3, 4] = 0
    a, b = _pair(tmp_path, "masks/frame_00000.png")
    write_image(a, mask)
    write_image(b, changed)
    d = _only(_compare(tmp_path, kind))
    assert d.measure == "changed_share" and d.value == pytest.approx(3 / 200) and d.within is within


def test_instance_mask_png16(tmp_path):
    from nsim.io.coco import write_instance_mask

    ids = np.zeros((10, 10), np.uint16)
    ids[2:5, 2:5] = 1
    other = ids.copy()
    other[2, 2] = 2
    a, b = _pair(tmp_path, "back/mask/000000.png")
    write_instance_mask(a, ids)
    write_instance_mask(b, other)
    d = _only(_compare(tmp_path, "render"))
    assert d.measure == "changed_share" and d.value == pytest.approx(0.01) and d.within  # render: <= 1 %


# ------------------------------------------------------------------------------- depth
def _depth() -> np.ndarray:
    depth = np.linspace(0.5, 5.0, 100, dtype=np.float32).reshape(10, 10)
    depth[0, 0] = np.inf  # no hit
    depth[0, 1] = np.nan  # no measurement
    return depth


def test_exr_depth_offset_is_the_max_abs_in_metres(tmp_path):
    depth = _depth()
    shifted = depth + np.float32(0.02)
    shifted[9, 9] = np.nan  # valid in the original only: 1 pixel in 100
    a, b = _pair(tmp_path, "depth/frame_00000.exr")
    write_depth_exr(a, depth)
    write_depth_exr(b, shifted)
    both = np.isfinite(depth) & np.isfinite(shifted)
    truth = np.abs(shifted[both].astype(np.float64) - depth[both].astype(np.float64))
    d = _only(_compare(tmp_path, "capture"))  # max 1 cm, median 1 mm, 0.1 % invalid
    assert d.measure == "max_abs_m" and d.value == pytest.approx(truth.max(), abs=0) and d.value == pytest.approx(0.02)
    assert not d.within and "median |diff| 0.02 m" in d.note and "valid in one only 1%" in d.note
    d = _only(_compare(tmp_path, "render"))  # any max; median 1 cm
    assert d.measure == "median_abs_m" and d.value == pytest.approx(np.median(truth)) and not d.within


def test_exr_depth_within_a_retrained_scene(tmp_path):
    depth = _depth()
    a, b = _pair(tmp_path, "frames/depth/000000.exr")
    write_depth_exr(a, depth)
    write_depth_exr(b, depth + np.float32(0.005))
    d = _only(_compare(tmp_path, "render"))
    assert d.within and d.value == pytest.approx(0.005, abs=1e-6)


# ------------------------------------------------------------------------------- documents
def _doc(abs_rel: float, name: str = "lab") -> dict:
    rows = [{"name": name, "abs_rel": 0.1}, {"name": "b", "abs_rel": 0.2}, {"name": "c", "abs_rel": abs_rel}]
    return {"tables": {"rows": rows}, "frames": 3, "psnr": 25.0}


@pytest.mark.parametrize("kind,within", [("evaluation", False), ("scene-checkpoint", True)])
def test_json_names_the_worst_key_path(tmp_path, kind, within):
    a, b = _pair(tmp_path, "evaluation.json")
    a.write_text(json.dumps(_doc(0.25)))
    b.write_text(json.dumps(_doc(0.253), indent=2))
    d = _only(_compare(tmp_path, kind))
    tol = TOLERANCES[kind]
    assert d.measure == "max_abs" and d.value == pytest.approx(0.003)
    assert d.tolerance == pytest.approx(tol.max_metric_abs + tol.max_metric_rel * 0.253)
    assert "at tables.rows[2].abs_rel: 0.25 -> 0.253" in d.note and d.within is within


def test_json_strings_and_structure_must_match(tmp_path):
    a, b = _pair(tmp_path, "evaluation.json")
    a.write_text(json.dumps(_doc(0.25)))
    b.write_text(json.dumps({**_doc(0.25, name="kitchen"), "extra": 1}))
    d = _only(_compare(tmp_path, "scene-checkpoint"))
    assert d.measure == "structure" and not d.within and d.value is None
    assert "keys differ; new ['extra']" in d.note and 'tables.rows[0].name: "lab" -> "kitchen"' in d.note


def test_json_same_numbers_other_text_is_within(tmp_path):
    a, b = _pair(tmp_path, "report.json")
    a.write_text('{"x": 0.0, "y": [1, 2]}')
    b.write_text('{"y": [1.0, 2.0], "x": -0.0}')
    d = _only(_compare(tmp_path, "capture"))
    assert d.within and d.value == 0.0


def test_transforms_json_poses_in_metres_and_degrees(tmp_path):
    def pose(t, angle_deg=0.0):
        m = np.eye(4)
        m[:3, :3] = Rotation.from_euler("z", angle_deg, degrees=True).as_matrix()
        m[:3, 3] = t
        return m.tolist()

    old = {"fl_x": 100.0, "frames": [{"file_path": f"images/{i}.png", "transform_matrix": pose([i, 0, 1])} for i in range(3)]}
    new = json.loads(json.dumps(old))
    new["frames"][1]["transform_matrix"] = pose([1.0, 0.0004, 1.0], angle_deg=0.03)
    new["frames"][2]["transform_matrix"] = pose([2.0, 0.0, 1.0], angle_deg=-0.2)
    a, b = _pair(tmp_path, "transforms.json")
    a.write_text(json.dumps(old))
    b.write_text(json.dumps(new))
    d = _only(_compare(tmp_path, "poses"))  # SfM: 5 mm, 0.1 deg
    assert d.measure == "rotation_deg" and d.value == pytest.approx(0.2) and not d.within
    assert "max position diff 0.0004 m" in d.note and "rotation worst at frames[2].transform_matrix" in d.note


def test_csv_and_yaml_compare_as_numbers(tmp_path):
    a, b = _pair(tmp_path, "scenes.csv")
    a.write_text("scene,PSNR,AbsRel\nlab,25.0,0.1\n")
    b.write_text("scene,PSNR,AbsRel\nlab,25.5,0.1\n")
    a, b = _pair(tmp_path, "map.yaml")
    a.write_text("image: map.pgm\nresolution: 0.1\n")
    b.write_text("image: map.pgm\nresolution: 0.10000001\n")
    deltas = {d.file: d for d in _compare(tmp_path, "scene-checkpoint").deltas}
    assert deltas["scenes.csv"].value == pytest.approx(0.5) and "rows[0].PSNR" in deltas["scenes.csv"].note
    assert deltas["scenes.csv"].within  # 1e-3 + 5 % of 25.5
    assert deltas["map.yaml"].within and "not judged: resolution" in deltas["map.yaml"].note  # not a score
    deltas = {d.file: d for d in _compare(tmp_path, "capture").deltas}  # every number judged
    assert deltas["map.yaml"].within and deltas["map.yaml"].value == pytest.approx(1e-8)


def test_a_retrained_model_is_judged_by_what_it_scores(tmp_path):
    """scene-checkpoint: eval.json's scores decide (within 5 %); its fitting diagnostics and the loss curve are
    reported, not judged; the map's polygons (traced from obstacle_cells.npy) are not compared."""
    a, b = _pair(tmp_path, "eval.json")
    a.write_text(json.dumps({"views": [{"psnr": 30.0, "appearance_fit_shift": 3.6}]}))
    b.write_text(json.dumps({"views": [{"psnr": 29.5, "appearance_fit_shift": 2.7}]}))
    a, b = _pair(tmp_path, "obstacles.json")
    a.write_text(json.dumps({"polygons": [[[0, 0], [1, 0], [1, 1]]]}))
    b.write_text(json.dumps({"polygons": [[[0, 0], [1, 0], [1, 1], [0, 1]]]}))
    deltas = {d.file: d for d in _compare(tmp_path, "scene-checkpoint").deltas}
    d = deltas["eval.json"]
    assert d.within and d.value == pytest.approx(0.5) and "views[0].psnr" in d.note
    assert "not judged: views[0].appearance_fit_shift: 3.6 -> 2.7" in d.note
    assert deltas["obstacles.json"].within and deltas["obstacles.json"].note == "derived file, not compared"
    (tmp_path / "new" / "eval.json").write_text(json.dumps({"views": [{"psnr": 25.0, "appearance_fit_shift": 3.6}]}))
    d = {d.file: d for d in _compare(tmp_path, "scene-checkpoint").deltas}["eval.json"]
    assert not d.within and d.value == pytest.approx(5.0)
    # the same file in a kind without scores to pick: every number decides
    d = {d.file: d for d in _compare(tmp_path, "evaluation").deltas}["eval.json"]
    assert not d.within


# ------------------------------------------------------------------------------- poses, points, arrays
def _trajectory(shift_m: float = 0.0, angle_deg: float = 0.0) -> Trajectory:
    t = np.arange(5) * 0.1
    pos = np.column_stack([t, 2 * t, np.ones(5)])
    pos[3, 0] += shift_m
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (5, 1))
    quat[1] = Rotation.from_euler("x", angle_deg, degrees=True).as_quat(scalar_first=True)
    return Trajectory(t, pos, quat)


@pytest.mark.parametrize("shift_m,angle_deg,measure,within", [
    (0.002, 0.0, "position_m", False), (0.0, 0.2, "rotation_deg", False), (0.0005, 0.02, "position_m", True),
])
def test_tum_position_and_rotation(tmp_path, shift_m, angle_deg, measure, within):
    a, b = _pair(tmp_path, "gt_trajectory.tum")
    write_tum(a, _trajectory())
    write_tum(b, _trajectory(shift_m, angle_deg))
    d = _only(_compare(tmp_path, "capture"))
    expected = {"position_m": shift_m, "rotation_deg": angle_deg}[measure]
    assert d.measure == measure and d.value == pytest.approx(expected, rel=1e-6) and d.within is within


def test_tum_pose_count_differs(tmp_path):
    a, b = _pair(tmp_path, "robot.tum")
    write_tum(a, _trajectory())
    traj = _trajectory()
    write_tum(b, Trajectory(traj.timestamps_s[:4], traj.positions_xyz[:4], traj.orientations_quat_wxyz[:4]))
    d = _only(_compare(tmp_path, "trajectory"))
    assert not d.within and d.note == "5 poses -> 4"


def test_ply_positions_and_counts(tmp_path):
    rng = np.random.default_rng(1)
    xyz = rng.uniform(-1, 1, (50, 3)).astype(np.float32)
    moved = xyz.copy()
    moved[7, 2] += np.float32(0.003)
    a, b = _pair(tmp_path, "lidar/scan/000000.ply")
    write_ply(a, xyz)
    write_ply(b, moved)
    a2, b2 = _pair(tmp_path, "sparse_points.ply")
    write_ply(a2, xyz)
    write_ply(b2, xyz[:49])
    deltas = {d.file: d for d in _compare(tmp_path, "capture").deltas}
    d = deltas["lidar/scan/000000.ply"]
    assert d.measure == "max_abs_m" and d.value == pytest.approx(0.003, rel=1e-4) and d.within  # capture: 1 cm
    d = deltas["sparse_points.ply"]
    assert d.measure == "count_rel" and d.value == pytest.approx(1 / 50) and not d.within and "50 -> 49" in d.note


def test_npy_and_npz_arrays(tmp_path):
    values = np.linspace(-4.0, 4.0, 40)
    a, b = _pair(tmp_path, "weights.npy")
    np.save(a, values)
    np.save(b, values + np.where(np.arange(40) == 5, 0.02, 0.0))
    a, b = _pair(tmp_path, "cells.npz")
    cells = np.zeros((10, 10), np.int8)
    np.savez(a, cells=cells, stamps_ns=np.arange(3))
    np.savez(b, cells=np.where(np.eye(10, dtype=bool), 100, 0).astype(np.int8), stamps_ns=np.arange(3))
    deltas = {d.file: d for d in _compare(tmp_path, "export").deltas}
    d = deltas["weights.npy"]
    assert d.measure == "max_rel" and d.value == pytest.approx(0.02 / 4.0) and d.within  # <= 1 %
    d = deltas["cells.npz"]
    assert d.measure == "changed_share" and d.value == pytest.approx(0.1) and not d.within and "cells" in d.note


class _RunsCode:
    """Pickles to a call of ``_record`` (what a malicious checkpoint would do)."""

    def __reduce__(self):
        return (_record, ("unpickled",))


CALLS: list[str] = []


def _record(what: str) -> str:
    CALLS.append(what)
    return what


def test_torch_checkpoint_relative_l2_per_entry(tmp_path):
    w = torch.randn(64, generator=torch.Generator().manual_seed(0))
    a, b = _pair(tmp_path, "model.pt")
    torch.save({"field.w": w, "field.b": torch.ones(3), "mask": torch.tensor([True, False]), "step": 5}, a)
    torch.save({"field.w": 1.2 * w, "field.b": torch.ones(3), "mask": torch.tensor([True, False]), "step": 5}, b)
    d = _only(_compare(tmp_path, "scene-checkpoint"))
    assert d.measure == "rel_l2" and d.value == pytest.approx(0.2, rel=1e-6) and d.within
    assert "worst entry field.w" in d.note
    d = _only(_compare(tmp_path, "capture"))
    assert not d.within


def test_torch_checkpoint_that_is_not_weights_is_never_unpickled(tmp_path):
    a, b = _pair(tmp_path, "model.pt")
    torch.save({"w": torch.ones(2)}, a)
    torch.save({"w": torch.ones(2), "hook": _RunsCode()}, b)
    d = _only(_compare(tmp_path, "scene-checkpoint"))
    assert CALLS == [] and not d.within and d.value is None and "not a weights-only checkpoint" in d.note


# ------------------------------------------------------------------------------- files that cannot be compared
def test_missing_malformed_derived_and_opaque_files(tmp_path):
    for rel, old, new in [
        ("gone.json", "{}", None),
        ("extra.json", None, "{}"),
        ("eval.json", '{"psnr": 25.0}', '{"psnr": 25.0'),
        ("preview.png", "a", "bb"),
        ("video.mp4", "a", "b"),
        ("plots/bars.png", "a", "b"),
        ("sparse/points3D.bin", "a", "b"),
        ("blob.bin", "a", "bcd"),
        ("same.txt", "x", "x"),
        ("depth/frame_00000.exr", "not an exr", "neither"),
    ]:
        a, b = _pair(tmp_path, rel)
        if old is not None:
            a.write_text(old)
        if new is not None:
            b.write_text(new)
    c = _compare(tmp_path, "capture")
    deltas = {d.file: d for d in c.deltas}
    assert c.identical == 1 and "same.txt" not in deltas
    assert deltas["gone.json"].note == "missing from the rebuild" and not deltas["gone.json"].within
    assert deltas["extra.json"].note == "only in the rebuild" and not deltas["extra.json"].within
    bad = deltas["eval.json"]
    assert bad.measure == "unreadable" and not bad.within and "malformed JSON" in bad.note
    for rel in ("preview.png", "video.mp4", "plots/bars.png", "sparse/points3D.bin"):
        assert deltas[rel].within and deltas[rel].measure == "bytes" and "not compared" in deltas[rel].note
    assert not deltas["blob.bin"].within and deltas["blob.bin"].value == 2.0 and "opaque .bin" in deltas["blob.bin"].note
    assert not deltas["depth/frame_00000.exr"].within and "not a readable OpenEXR" in deltas["depth/frame_00000.exr"].note
    assert not c.within and c.summary().startswith("9 files differ, 5 outside tolerance: ")
    json.dumps([d.to_dict() for d in c.deltas], allow_nan=False)


def test_paths_outside_the_artifact_and_links_are_refused(tmp_path):
    a, b = _pair(tmp_path, "x.json")
    a.write_text("1")
    (tmp_path / "secret.json").write_text("2")
    b.symlink_to(tmp_path / "secret.json")
    files = {"x.json": {"sha256": "a", "size": 1}, "../secret.json": {"sha256": "b", "size": 1}}
    c = compare_artifacts(tmp_path / "old", tmp_path / "new", "capture", files,
                          {k: {**v, "sha256": "c"} for k, v in files.items()})
    deltas = {d.file: d for d in c.deltas}
    assert "symbolic link" in deltas["x.json"].note and "not a path inside" in deltas["../secret.json"].note
    assert not c.within


def test_summary_names_the_worst_within(tmp_path):
    rng = np.random.default_rng(2)
    img = rng.integers(20, 230, size=(16, 16, 3), dtype=np.uint8)
    for i, step in enumerate((1, 2)):
        a, b = _pair(tmp_path, f"images/{i}.png")
        write_image(a, img)
        write_image(b, img + np.uint8(step))
    c = _compare(tmp_path, "capture")
    assert c.within and c.summary().startswith("2 files differ, all within tolerance (worst: images/1.png: PSNR 42.1 dB")


# ------------------------------------------------------------------------------- the CLI
CAPTURE = ("capture", "synth", "--preset", "tiny", "--set", "n_frames=3", "--set", "video=false")


def test_verify_rebuild_identical_json(run_cli):
    code, out, err = run_cli(*CAPTURE)
    assert code == 0, err
    art_id = out.strip()
    code, out, err = run_cli("verify", "--rebuild", "--json", "-", art_id[:10])
    assert code == 0, err
    report = json.loads(out)
    assert report["ok"] is True
    (entry,) = report["artifacts"]
    assert entry["id"] == art_id and entry["rebuilt"] == art_id and entry["identical"] is True
    assert entry["within_tolerance"] is True and entry["kind"] == "capture" and entry["stage"] == "capture"


def _fake_rebuild(step: int):
    """A rebuild that republishes the artifact with noise of +-step levels on images/frame_00001.png."""

    def rebuild(manifest, ctx):
        store = ctx.store
        src = store.get(manifest["id"]).path
        key = hashlib.sha256(f"fake rebuild {step}".encode()).hexdigest()
        with store.publish(kind="capture", stage="capture", version=manifest["stage_version"], key=key,
                           config=manifest["config"], seed=manifest["seed"]) as out:
            for rel in manifest["files"]:
                (out.dir / rel).parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(src / rel, out.dir / rel)
            from nsim.io.images import read_image

            img = read_image(src / "images/frame_00001.png").astype(int)
            noise = np.random.default_rng(0).choice(np.array([-step, step]), size=img.shape)
            (out.dir / "images/frame_00001.png").unlink()
            write_image(out.dir / "images/frame_00001.png", np.clip(img + noise, 0, 255).astype(np.uint8))
        return out.artifact.id

    return rebuild


@pytest.mark.parametrize("step,code_expected,verdict", [(10, 1, "DIFFERS"), (1, 0, "WITHIN ")])
def test_verify_rebuild_that_differs(run_cli, monkeypatch, tmp_path, step, code_expected, verdict):
    import nsim.stages.capture

    code, out, err = run_cli(*CAPTURE)
    assert code == 0, err
    art_id = out.strip()
    monkeypatch.setattr(nsim.stages.capture, "rebuild", _fake_rebuild(step))
    report_path = tmp_path / "report.json"
    code, out, err = run_cli("verify", "--rebuild", "--json", str(report_path), art_id[:10])
    assert code == code_expected, (out, err)
    lines = out.splitlines()
    assert lines[0].startswith("  images/frame_00001.png: PSNR ") and len(lines) == 2
    assert lines[1].startswith(f"{verdict} {art_id[:12]} rebuilt as ")
    assert "1 file differs" in lines[1] and "images/frame_00001.png: PSNR" in lines[1]
    report = json.loads(report_path.read_text())
    (entry,) = report["artifacts"]
    assert report["ok"] is (code_expected == 0) and entry["identical"] is False
    assert entry["within_tolerance"] is (code_expected == 0)
    (f,) = entry["files"]
    assert f["file"] == "images/frame_00001.png" and f["measure"] == "psnr_db" and f["tolerance"] == 40.0


def test_verify_rebuild_of_what_cannot_be_rebuilt_is_skipped_with_the_reason(run_cli, monkeypatch):
    """An artifact made from files the workspace does not hold is SKIPPED with the reason; the others still run."""
    import nsim.stages.capture
    from nsim.errors import InputError

    code, out, err = run_cli(*CAPTURE)
    assert code == 0, err
    art_id = out.strip()

    def cannot(manifest, ctx):
        raise InputError("made from a video the workspace does not hold")

    monkeypatch.setattr(nsim.stages.capture, "rebuild", cannot)
    code, out, err = run_cli("verify", "--rebuild", art_id[:10])
    assert code == 0 and out.strip() == f"SKIPPED {art_id[:12]} cannot rebuild: made from a video the workspace does not hold"
    code, out, err = run_cli("verify", "--rebuild", "--json", "-", art_id[:10])
    (entry,) = json.loads(out)["artifacts"]
    assert code == 0 and entry["rebuilt"] is None and entry["error"].startswith("cannot rebuild: made from a video")


def test_yaml_alias_bomb_and_deep_json_are_notes(tmp_path, monkeypatch):
    import nsim.workspace.compare as compare

    monkeypatch.setattr(compare, "MAX_NODES", 10_000)
    bomb = "a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]\n" + "".join(
        f"{chr(98 + i)}: &{chr(98 + i)} [*{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}, "
        f"*{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}]\n"
        for i in range(6)
    )
    a, b = _pair(tmp_path, "map.yaml")
    a.write_text(bomb)
    b.write_text(bomb + "z: 1\n")
    a, b = _pair(tmp_path, "deep.json")
    a.write_text("[" * 300 + "]" * 300)
    b.write_text("[" * 300 + "1" + "]" * 300)
    deltas = {d.file: d for d in _compare(tmp_path, "capture").deltas}
    assert not deltas["map.yaml"].within and "more than 10000 values" in deltas["map.yaml"].note
    assert not deltas["deep.json"].within and "nested deeper than" in deltas["deep.json"].note


def test_verify_json_to_a_missing_folder_is_refused_before_any_work(run_cli, tmp_path):
    code, out, err = run_cli("verify", "--json", str(tmp_path / "no" / "such" / "report.json"))
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1
    assert "is not a folder this user can write to" in err
