"""The CLI: one-line errors with exit 2 for every malformed flag, config and reference."""

from __future__ import annotations

import pytest

# (arguments, text the one-line message must contain)
BAD_INVOCATIONS = [
    (["capture", "synth", "--preset", "huge"], "--preset: no preset 'huge' for capture"),
    (["capture", "synth", "--preset", "../x"], "--preset: invalid preset name"),
    (["capture", "synth", "--preset", "tiny", "--set", "widht=3"], "--set widht: unknown key (did you mean 'width'?)"),
    (["capture", "synth", "--preset", "tiny", "--set", "width=3"], "--set width: expected int >= 16 and <= 4096, got 3"),
    (["capture", "synth", "--preset", "tiny", "--set", "width=abc"], "--set width: expected int, got 'abc'"),
    (["capture", "synth", "--preset", "tiny", "--set", "n_frames"], "--set n_frames: expected KEY=VALUE"),
    (["capture", "synth", "--preset", "tiny", "--set", "fps=-1"], "--set fps: expected float > 0"),
    (["capture", "synth", "--preset", "tiny", "--set", "video=maybe"], "--set video: expected bool"),
    (["capture", "synth", "--preset", "tiny", "--room", "garage"], "room: 'garage' is not one of robot-lab"),
    (["capture", "synth", "--preset", "tiny", "--camera", "lidar"], "camera: 'lidar' is not one of pinhole, fisheye"),
    (["capture", "synth", "--config", "/nonexistent/cfg.yaml"], "/nonexistent/cfg.yaml: config file not found"),
    (["capture", "synth", "--bogus-flag"], "--bogus-flag"),
    (["--seed", "-1", "ls"], "--seed"),
    (["--seed", "abc", "ls"], "--seed"),
    (["--device", "tpu", "ls"], "--device"),
    (["show", "nothing-here"], "no artifact or ref named 'nothing-here'"),
    (["show", "ab"], "no artifact or ref named 'ab'"),
    (["verify", "deadbeef"], "no artifact or ref named 'deadbeef'"),
    (["tag", "deadbeef", "x"], "no artifact or ref named 'deadbeef'"),
    (["tag", "--delete", "x", "no/such/ref"], "no ref named no/such/ref"),
    (["frobnicate"], "No such command 'frobnicate'"),
]


@pytest.mark.parametrize("args,message", BAD_INVOCATIONS, ids=[" ".join(a) for a, _ in BAD_INVOCATIONS])
def test_bad_invocations_exit_2_with_one_line(run_cli, args, message, tmp_path):
    from nsim.workspace.store import Store

    Store(tmp_path / "ws")  # an empty workspace: the read-only commands refuse a missing one
    code, out, err = run_cli(*args)
    assert code == 2, (out, err)
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("error: ")
    assert message in lines[0], lines[0]
    assert "Traceback" not in err


def test_malformed_config_file(run_cli, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("width: [1,\n")
    code, _, err = run_cli("capture", "synth", "--config", str(bad))
    assert code == 2 and "malformed YAML" in err and str(bad) in err
    typo = tmp_path / "typo.yaml"
    typo.write_text("n_frame: 3\n")
    code, _, err = run_cli("capture", "synth", "--config", str(typo))
    assert code == 2 and "n_frame: unknown key (did you mean 'n_frames'?)" in err


def test_cuda_request_without_cuda(run_cli):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    from nsim.context import resolve_device
    from nsim.errors import InputError

    with pytest.raises(InputError, match="no CUDA device"):
        resolve_device("cuda")
    assert resolve_device("auto") == "cpu"


def test_help_creates_no_workspace(run_cli, tmp_path):
    code, out, _ = run_cli("--help", workspace=tmp_path / "never")
    assert code == 0 and "capture" in out
    assert not (tmp_path / "never").exists()


def test_bad_input_leaves_workspace_untouched(run_cli, tmp_path):
    code, out, _ = run_cli("capture", "synth", "--preset", "tiny", "--set", "n_frames=3", "--set", "video=false")
    assert code == 0
    before = sorted(p.relative_to(tmp_path) for p in (tmp_path / "ws").rglob("*"))
    code, _, _ = run_cli("capture", "synth", "--preset", "tiny", "--set", "width=2")
    assert code == 2
    after = sorted(p.relative_to(tmp_path) for p in (tmp_path / "ws").rglob("*"))
    assert before == after
