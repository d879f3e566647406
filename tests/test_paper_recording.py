"""The paper pipeline's ``--recording`` path (``make paper PAPER_ARGS="--size tiny --recording"``), end to end.

``pipelines/paper.py --size tiny --recording`` adds several minutes to the tiny run, over what a test may take,
so this runs the same chain (``spot_run`` then ``run_recording``) on a micro scene of robot-lab: the tiny
4 s Spot run and its realistic robot log at the tiny size (Spot's five cameras at 320x240, 20 ticks 0.2 s
apart: the pixels and the span registration needs), imported, registered in the tiny 100-frame 200x150 map, then
rendered and scored on the left camera, its depth and the LiDAR at two frames (the twin: the left camera at
the same two ticks, against the oracle). Checks the registration against the log's truth with the bounds of
tests/stages/test_register_log.py, the five tables, the colour correction, the agreement rows and the refs.
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path
from types import SimpleNamespace

import pytest

from nsim.context import RunContext
from nsim.workspace.store import Store
from tests.stages.test_register_log import MAX_CLOCK_ERROR_S, MAX_ODOM_FRAME_DEG, MAX_ODOM_FRAME_M
from tests.test_paper import MICRO_TRAIN

REPO = Path(__file__).resolve().parents[1]

def load_paper():
    spec = importlib.util.spec_from_file_location("paper_pipeline", REPO / "pipelines" / "paper.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(float(v))


@pytest.mark.slow
def test_recording_path_registers_renders_and_scores_the_log(tmp_path, monkeypatch):
    paper = load_paper()
    micro = {
        **paper.SIZES["tiny"],
        "capture": ("tiny", ["width=64", "height=48", "n_frames=24", "supersample=1", "video=false"]),
        "train_scene": ("tiny", MICRO_TRAIN),
        "heldout": ("tiny", ["frames=heldout", "tick_stride=1", "image_scale=1.0", "max_frames=1"]),
    }
    recording = {
        **paper.RECORDING["tiny"],
        # from frame 1: frame 0 is the log's first tick, where a clock offset estimated a fraction of a millisecond
        # high puts the camera frame before the first odometry stamp (outside the trajectory: skipped, never
        # extrapolated), as happened under a loaded test run
        "render": ("tiny", ["image_scale=1.0", "lidar_azimuth_scale=1.0", "sensors=[left,lidar]", "tick_stride=10",
                            "max_frames=2", "start=1"]),
        "evaluate": ("tiny", ["lpips_net=none"]),
        "evaluate_detection": ("tiny", ["lpips_net=none"]),
    }
    monkeypatch.setitem(paper.SIZES, "micro", micro)
    monkeypatch.setitem(paper.RECORDING, "micro", recording)
    ws = tmp_path / "ws"
    store = Store(ws)
    ctx = RunContext(store=store, device_spec="cpu", seed=0)
    spot = paper.spot_run(ctx, "micro")
    run = paper.run_recording(ctx, "micro", paper.RecordingRequest(), spot, out_dir=tmp_path / "tables")

    # the log written from the Spot run, with its truth; the registration recovers its odometry frame and clock
    assert run.log.parent == ws / "robot_logs" and run.truth is not None
    assert run.error["position_m"] < MAX_ODOM_FRAME_M, run.error
    assert run.error["rotation_deg"] < MAX_ODOM_FRAME_DEG, run.error
    assert run.error["clock_s"] < MAX_CLOCK_ERROR_S, run.error
    assert run.registration_doc["localised"]["localised"] >= 20
    assert "against the log's truth" in paper.registration_text(run)

    # the five tables against the recording, the four the oracle has against the twin
    assert list(run.tables) == ["spot-rgb", "spot-depth", "lidar", "slam", "detection"]
    assert list(run.oracle) == ["spot-rgb", "spot-depth", "lidar", "slam", "detection"]
    rgb = run.tables["spot-rgb"].rows
    assert [r["Camera"] for r in rgb] == ["left"] and rgb[0]["frames"] == 2
    assert finite(rgb[0]["PSNR"]) and finite(rgb[0]["PSNR cc"]) and rgb[0]["PSNR cc"] >= rgb[0]["PSNR"]
    depth = run.tables["spot-depth"].rows
    assert [r["Camera"] for r in depth] == ["left"] and finite(depth[0]["AbsRel"])  # a 30-step scene: no bound
    lidar = run.tables["lidar"].rows
    assert [r["LiDAR"] for r in lidar] == ["lidar"] and finite(lidar[0]["range err median [m]"])
    assert 0.0 < lidar[0]["hit agreement"] <= 1.0
    assert run.tables["slam"].rows[0]["Sequence"] == "left"  # two frames: SfM's numbers may be n/a, the row is there
    assert all(isinstance(r["boxes real"], int) for r in run.tables["detection"].rows)
    twin = run.oracle["spot-rgb"].rows
    assert [r["Camera"] for r in twin] == ["left"] and twin[0]["frames"] == 2 and finite(twin[0]["PSNR"])

    rows = paper.agreement(run.oracle, run.tables)
    psnr = next(r for r in rows if r["table"] == "spot-rgb" and r["metric"] == "PSNR [dB]")
    assert psnr["diff"] == pytest.approx(psnr["recording"] - psnr["oracle"])
    # The stated tolerances (paper.AGREEMENT_TOLERANCE): the recording's render scored against the recording, and
    # the twin (the same sensors at the same ticks from the true trajectory) against the oracle, agree (the log's
    # faults and the registration are all that differ). Raw PSNR and the LiDAR's numbers are checked here; depth
    # AbsRel of a 30-step scene (6-9) says nothing, bench/robot_log.py measures it on a trained one.
    assert psnr["tolerance"] == ("abs", 1.0) and psnr["within"], psnr
    for metric in ("range err median [m]", "hit agreement"):
        lidar_row = next(r for r in rows if r["table"] == "lidar" and r["metric"] == metric)
        assert lidar_row["oracle"] is not None and lidar_row["within"], lidar_row
    depth = next(r for r in rows if r["table"] == "spot-depth" and r["metric"] == "AbsRel")
    # relative plus the recording's noise floor: judged, not bounded
    assert depth["within"] == (abs(depth["diff"]) <= 0.25 * abs(depth["oracle"]) + paper.DEPTH_NOISE_ABSREL_FLOOR)
    assert "±0.05 within" in paper.agreement_text(rows)
    assert "sim vs recording" in paper.agreement_text(rows)

    for ref in ("recording/paper-robot-log", "registration/paper-robot-log", "render/paper-recording",
                "render/paper-recording-twin", "poses/paper-map-robot-lab", "evaluation/paper-recording-lidar",
                "evaluation/paper-twin-spot-rgb"):
        assert store.resolve(ref)
    assert (tmp_path / "tables" / "recording-spot-rgb.md").read_text().startswith("### ")
    # a rerun writes no log and publishes nothing
    before = store.all_ids()
    again = paper.run_recording(ctx, "micro", paper.RecordingRequest(), spot)
    assert again.render == run.render and store.all_ids() == before


def test_tolerance_bounds_and_their_text():
    paper = load_paper()
    assert paper.tolerance_bound(("abs", 0.05), -3.0) == 0.05
    assert paper.tolerance_bound(("rel", 0.25), -0.2) == pytest.approx(0.05)
    assert paper.tolerance_bound(("rel+abs", 0.25, 0.015), 0.0219) == pytest.approx(0.25 * 0.0219 + 0.015)
    with pytest.raises(ValueError, match="unknown tolerance kind 'ratio'"):
        paper.tolerance_bound(("ratio", 2.0), 1.0)
    # the default-size run's depth row (bench/robot_log.py --size default): +26 %, inside the noise floor
    def depth_table(absrel):
        return {"spot-depth": SimpleNamespace(rows=[{"AbsRel": absrel}], footer_rows=0)}

    rows = paper.agreement(depth_table(0.0219), depth_table(0.0276))
    depth = next(r for r in rows if r["metric"] == "AbsRel")
    assert depth["within"] is True and depth["diff"] == pytest.approx(0.0057)
    assert "±0.25 x+0.02 within" in paper.agreement_text(rows)
    far = paper.agreement(depth_table(0.0219), depth_table(0.06))
    assert next(r for r in far if r["metric"] == "AbsRel")["within"] is False


def test_bad_arguments_fail_before_the_first_stage(tmp_path, monkeypatch):
    """A LOG that is not there, a --poses of another kind, an --out that is a file: one line before any stage."""
    paper = load_paper()
    monkeypatch.setattr(paper, "paper_tables", lambda *a, **k: pytest.fail("the pipeline ran before the check"))
    monkeypatch.setattr(paper, "run_recording", lambda *a, **k: pytest.fail("the pipeline ran before the check"))
    ws = tmp_path / "ws"
    cases = [
        (paper.RecordingRequest(log=tmp_path / "nosuch.bag"), None, "nosuch.bag: no such file or directory"),
        (paper.RecordingRequest(log=tmp_path, poses="nothing", scene="nothing"), None, "no artifact or ref named"),
    ]
    (tmp_path / "out.md").write_text("")
    cases.append((paper.RecordingRequest(), tmp_path / "out.md", "exists and is not a folder"))
    for request, out, words in cases:
        with pytest.raises(paper.NsimError, match=words):
            paper.run_paper_recording(ws, "tiny", 0, "cpu", out, request)
    with pytest.raises(paper.NsimError, match="exists and is not a folder"):
        paper.run_paper(ws, "tiny", 0, "cpu", tmp_path / "out.md")
