"""`nsim render` checks its destinations (the --rosbag directory, the Ray cluster) before any work:
one line on stderr, exit 2, no traceback and nothing published. The artifacts named here do not
exist, so a check that ran after resolving the inputs would fail on them instead."""

from __future__ import annotations

import socket
import time

import pytest

from nsim.config import configs_dir
from nsim.workspace.store import Store

SPOT = str(configs_dir() / "robots" / "spot.yaml")


@pytest.fixture(autouse=True)
def workspace(tmp_path) -> Store:
    """An empty workspace, so that only the checks under test can fail before the inputs are resolved."""
    return Store(tmp_path / "ws")


def _one_line_error(code: int, err: str, *fragments: str) -> str:
    assert code == 2, err
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    for f in fragments:
        assert f in lines[0], lines[0]
    assert "nothere" not in lines[0]  # the (absent) input artifacts were never looked up
    return lines[0]


def _nothing_published(tmp_path) -> None:
    assert Store(tmp_path / "ws").all_ids() == []


def test_inputs_are_resolved_after_the_checks(run_cli):
    code, _, err = run_cli("render", "--trajectory", "trajectory/nothere", "--rig", SPOT)
    assert code == 2 and "trajectory/nothere" in err  # without a bad destination, the bad input is what fails


@pytest.mark.parametrize("existing", ["empty_dir", "bag_dir", "file"])
def test_rosbag_destination_exists(run_cli, tmp_path, existing):
    dest = tmp_path / existing
    if existing == "file":
        dest.write_text("x")
    else:
        dest.mkdir()
        if existing == "bag_dir":
            (dest / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    before = sorted(p.name for p in tmp_path.iterdir() if p.name != "ws")
    code, _, err = run_cli("render", "--trajectory", "trajectory/nothere", "--rig", SPOT, "--rosbag", str(dest))
    expected = f"--rosbag {dest}: exists already" if existing != "file" else f"'--rosbag': Directory '{dest}' is a file"
    assert _one_line_error(code, err, expected).startswith("error: ")  # a file: click's own check says so
    _nothing_published(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != "ws") == before  # left as it was, no temp dir


def test_rosbag_parent_missing(run_cli, tmp_path):
    dest = tmp_path / "no" / "such" / "bag"
    code, _, err = run_cli("render", "--trajectory", "trajectory/nothere", "--rig", SPOT, "--rosbag", str(dest))
    _one_line_error(code, err, f"--rosbag {dest}: the parent directory {dest.parent} does not exist")
    _nothing_published(tmp_path)
    assert not (tmp_path / "no").exists()


def test_rosbag_of_a_poses_render_is_refused_up_front(run_cli, tmp_path):
    dest = tmp_path / "bag"
    code, _, err = run_cli("render", "--poses", "poses/nothere", "--scene", "scene/nothere", "--rosbag", str(dest))
    _one_line_error(code, err, f"--rosbag {dest}: only a --trajectory render", "not a --poses render")
    _nothing_published(tmp_path)
    assert not dest.exists()


@pytest.fixture
def closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("via", ["env", "option"])
def test_unreachable_ray_cluster_fails_in_seconds(run_cli, tmp_path, monkeypatch, closed_port, via):
    ray = pytest.importorskip("ray")
    if ray.is_initialized():
        pytest.skip("this process already runs Ray (render would reuse it)")

    def no_init(*args, **kwargs):  # the probe must refuse before Ray's own connection retries start
        raise AssertionError("ray.init was reached")

    monkeypatch.setattr(ray, "init", no_init)
    address = f"127.0.0.1:{closed_port}"
    args = ["render", "--trajectory", "trajectory/nothere", "--rig", SPOT, "--engine", "ray"]
    if via == "env":
        monkeypatch.setenv("RAY_ADDRESS", address)
    else:
        monkeypatch.delenv("RAY_ADDRESS", raising=False)
        args += ["--address", address]
    t0 = time.monotonic()
    code, _, err = run_cli(*args)
    assert time.monotonic() - t0 < 90  # Ray itself would retry for minutes; generous for a busy machine
    where = "$RAY_ADDRESS" if via == "env" else "--address"
    _one_line_error(code, err, f"{where} {address}: cannot connect to a Ray cluster there")
    _nothing_published(tmp_path)
    assert not ray.is_initialized()
