"""`nsim simulate` with a robot controller in the loop: artifacts, bad specs, a controllers sweep."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from nsim.config import configs_dir
from nsim.crowd.sweep import load_sweep
from nsim.workspace.store import Store

SCENARIOS = configs_dir() / "scenarios"
FAST = ("--preset", "tiny", "--set", "video=false", "--set", "max_duration_s=1")
USER = "tests.crowd.user_controllers"


def _scenario(tmp_path, controller, name="s.json"):
    data = json.loads((SCENARIOS / "spot_run_goals.json").read_text())
    data.pop("$schema")
    if controller is not None:
        data["robot"]["controller"] = controller
    path = tmp_path / name
    path.write_text(json.dumps(data))
    return path


def _objects(tmp_path):
    root = tmp_path / "ws" / "objects"
    return sorted(p.name for p in root.glob("*/*")) if root.is_dir() else []


def test_controller_run_records_commands_and_is_deterministic(run_cli, tmp_path):
    store = Store(tmp_path / "ws")
    path = _scenario(tmp_path, "orca")
    code, out, err = run_cli("simulate", "--scenario", str(path), *FAST)
    assert code == 0, err
    art = store.get(out.strip())
    npz = np.load(art.file("trajectory.npz"))
    ticks = len(npz["time_s"])
    assert npz["robot_command_body"].shape == npz["robot_executed_body"].shape == (ticks - 1, 3)
    assert np.all(np.linalg.norm(npz["robot_executed_body"][:, :2], axis=1) <= 1.6 + 1e-9)
    metrics = json.loads(art.file("metrics.json").read_text())
    assert metrics["run"]["controller"] == "orca"
    # same scenario and seed: the same artifact, even recomputed
    code, again, err = run_cli("simulate", "--scenario", str(path), *FAST, "--force")
    assert code == 0 and again.strip() == art.id, err
    # replay keeps today's artifact: no command arrays, no controller in the metrics
    code, out, err = run_cli("simulate", "--scenario", str(_scenario(tmp_path, None, "r.json")), *FAST)
    rep = store.get(out.strip())
    assert "robot_command_body" not in np.load(rep.file("trajectory.npz"))
    assert "controller" not in json.loads(rep.file("metrics.json").read_text())["run"]


@pytest.mark.parametrize(
    "controller, field, message",
    [
        ({"python": "nsim_no_such_module:X"}, "robot.controller.python", "cannot import module"),
        ({"python": f"{USER}:NoCommand"}, "robot.controller.python", "has no method command"),
        ({"python": f"{USER}:WrongShape"}, "robot.controller (WrongShape) at t = 0 s", "expected (3,)"),
        ({"python": f"{USER}:NotFinite"}, "robot.controller (NotFinite) at t = 0.25 s", "non-finite"),
    ],
)
def test_bad_controllers_exit_2_naming_file_and_field_and_publish_nothing(run_cli, tmp_path, controller, field, message):
    path = _scenario(tmp_path, controller)
    code, out, err = run_cli("simulate", "--scenario", str(path), *FAST)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and out == "" and len(lines) == 1, err
    assert lines[0].startswith(f"error: {path}: {field}") and message in lines[0], lines[0]
    assert _objects(tmp_path) == []


def test_controllers_sweep_compares_on_the_same_cells(run_cli, tmp_path):
    (tmp_path / "goals.json").write_text(_scenario(tmp_path, None).read_text())
    (tmp_path / "user.py").write_text((Path(__file__).resolve().parents[1] / "crowd" / "user_controllers.py").read_text())
    sweep = tmp_path / "sweep.yaml"
    sweep.write_text(
        "scenario: goals.json\nseeds: [0]\ncrowd_sizes: [0]\n"
        "controllers: [replay, orca, {python: 'user.py:GoalSeeker', params: {speed_mps: 0.8}}]\n"
    )
    code, out, err = run_cli("simulate", "--sweep", str(sweep), *FAST, "--summary", str(tmp_path / "s.json"))
    assert code == 0, err
    rows = json.loads((tmp_path / "s.json").read_text())["rows"]
    assert [r["grid"]["controller"] for r in rows] == ["replay", "orca", "GoalSeeker"]
    assert len({r["trajectory"] for r in rows}) == 3
    assert "| metric | replay | orca | GoalSeeker |" in out and "| minimum_distance_to_people_m |" in out
    # the repository's sweep file reads, its user class resolved next to the tests
    spec, scenario = load_sweep(SCENARIOS / "sweeps" / "spot_run_controllers.yaml")
    assert scenario.is_file() and len(spec.controllers) == 4
    assert spec.controllers[3]["python"].endswith("tests/crowd/user_controllers.py:GoalSeeker")
    bad = tmp_path / "bad.yaml"
    bad.write_text("scenario: goals.json\ncontrollers: [3]\n")
    code, out, err = run_cli("simulate", "--sweep", str(bad), *FAST)
    assert code == 2 and f"{bad}: controllers[0]: expected a name" in err
