"""nsim as users install it: a wheel that carries the presets, where presets are looked up, the
dependency floors that ``make test-floors`` installs."""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

import nsim
import nsim.config as config
from nsim.config import ConfigError, configs_dir, load_config, to_dict

REPO = Path(__file__).resolve().parents[1]
CONFIGS = REPO / "nsim" / "configs"


# ------------------------------------------------------------------------------- preset lookup


@pytest.fixture
def lookup(tmp_path, monkeypatch):
    """nsim.config looking at a package's configs folder under tmp_path (not made yet)."""
    monkeypatch.delenv("NSIM_CONFIGS", raising=False)
    packaged = tmp_path / "site" / "nsim" / "configs"
    monkeypatch.setattr(config, "PACKAGED_CONFIGS", packaged)
    return packaged


def test_lookup_order_env_then_package(lookup, tmp_path, monkeypatch):
    packaged = lookup
    assert configs_dir() == packaged
    monkeypatch.setenv("NSIM_CONFIGS", str(tmp_path / "mine"))
    assert configs_dir() == tmp_path / "mine"


def test_presets_read_from_a_packaged_copy(lookup):
    packaged = lookup
    (packaged / "capture").mkdir(parents=True)
    (packaged / "capture" / "tiny.yaml").write_text("n_frames: 3\n")
    from nsim.stages.capture import Config

    assert load_config(Config, stage="capture", preset="tiny").n_frames == 3


def test_this_checkout_reads_its_configs(monkeypatch):
    if Path(nsim.__file__).resolve().parents[1] != REPO:
        pytest.skip("nsim is not imported from this checkout")
    monkeypatch.delenv("NSIM_CONFIGS", raising=False)
    assert configs_dir() == CONFIGS


def test_missing_presets_folder_is_one_line(lookup, run_cli, tmp_path, monkeypatch):
    repo = lookup
    with pytest.raises(ConfigError, match=r"the presets folder .* is missing \(reinstall nsim, or set \$NSIM_CONFIGS\)"):
        config.preset_path("capture", "tiny")
    code, out, err = run_cli("capture", "synth", "--preset", "tiny")
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and out == "" and len(lines) == 1, err
    assert lines[0] == f"error: --preset: the presets folder {repo} is missing (reinstall nsim, or set $NSIM_CONFIGS)"
    monkeypatch.setenv("NSIM_CONFIGS", str(tmp_path / "nowhere"))
    with pytest.raises(ConfigError, match=r"nowhere is missing \(is \$NSIM_CONFIGS right\?\)"):
        config.preset_path("capture", "tiny")


# ------------------------------------------------------------------------------- dependency floors


@pytest.fixture(scope="module")
def floors():
    spec = importlib.util.spec_from_file_location("nsim_floors_script", REPO / "scripts" / "floors.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_floors_of_this_project(floors, capsys):
    assert floors.main(["--pin", "torch==2.13.0"]) == 0
    lines = capsys.readouterr().out.splitlines()
    for expected in ("pycolmap==4.2.1.*", "OpenEXR==3.4.0.*", "rosbags==0.11.9.*", "numpy==1.24.*", "torch==2.13.0"):
        assert expected in lines
    assert [line for line in lines if line.startswith("ray")] == ["ray==2.49.*"]  # once, without [default]
    assert not any(line.lower().startswith("nsim") for line in lines)
    data = floors.load_pyproject(REPO / "pyproject.toml")
    names = {floors.canonical_name(floors.floor_of(r)[0]) for r in floors.requirements(data)} - {"nsim"}
    assert {floors.canonical_name(line.split("==")[0]) for line in lines} == names


def test_floor_constraints_select_the_floor(floors):
    """What pip makes of the lines: the floor's release series, builds and local labels included."""
    specifiers = pytest.importorskip("packaging.specifiers")
    lines = floors.constraints(
        ["opencv-contrib-python-headless>=4.8", "pycolmap>=4.2.1", "torch>=2.4", "numpy>=1.24,<3"],
        pins=["torch==2.13.0"],
    )
    spec = {line.split("==")[0]: specifiers.SpecifierSet("==" + line.split("==", 1)[1]) for line in lines}
    assert "4.8.0.74" in spec["opencv-contrib-python-headless"] and "4.9.0.80" not in spec["opencv-contrib-python-headless"]
    assert "4.2.1" in spec["pycolmap"] and "4.2.2" not in spec["pycolmap"]
    assert "1.24.0" in spec["numpy"] and "1.25.0" not in spec["numpy"]
    assert "2.13.0+cpu" in spec["torch"] and "2.4.0" not in spec["torch"]


@pytest.mark.parametrize(
    "deps,pins,message",
    [
        (["numpy"], [], "'numpy': no floor (a '>=' version) to test"),
        (["numpy<3"], [], "'numpy<3': no floor"),
        (["numpy>=1.24"], ["numpy==1.20"], "--pin 'numpy==1.20': below the floor numpy>=1.24"),
        (["numpy>=1.24"], ["torch==2.13.0"], "--pin 'torch==2.13.0': torch is not a dependency of demo"),
        (["numpy>=1.24"], ["torch"], "--pin 'torch': expected NAME==VERSION"),
        (["numpy>=>1"], [], "cannot read the specifier"),
    ],
)
def test_floors_refuse_with_one_line(floors, tmp_path, capsys, deps, pins, message):
    pyproject = tmp_path / "pyproject.toml"
    pyproject.write_text(f'[project]\nname = "demo"\ndependencies = {deps!r}\n'.replace("'", '"'))
    argv = ["--pyproject", str(pyproject)] + [a for p in pins for a in ("--pin", p)]
    assert floors.main(argv) == 1
    out, err = capsys.readouterr()
    assert out == "" and len(err.splitlines()) == 1 and message in err, err
    assert err.startswith(f"floors: {pyproject}: ")


# ------------------------------------------------------------------------------- the wheel


def _run(cmd, **kwargs) -> subprocess.CompletedProcess:
    proc = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, **kwargs)
    assert proc.returncode == 0, f"{cmd}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return proc


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """sdist first (it must carry nsim/configs/: package data), then the wheel from the sdist, as ``python -m build`` does."""
    dist = tmp_path_factory.mktemp("dist")
    egg_info = REPO / "nsim.egg-info"  # what setuptools' sdist leaves in the source tree
    had_egg_info = egg_info.exists()
    try:
        sdist = _run([sys.executable, "-c", "import sys; from setuptools import build_meta as b; print(b.build_sdist(sys.argv[1]))",
                      dist], cwd=REPO).stdout.strip().splitlines()[-1]
    finally:
        if not had_egg_info:
            shutil.rmtree(egg_info, ignore_errors=True)
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-q",
          "-w", dist, dist / sdist])
    (whl,) = dist.glob("nsim-*.whl")
    return whl


def test_wheel_carries_the_repository_configs(wheel):
    with zipfile.ZipFile(wheel) as zf:
        packaged = {n.removeprefix("nsim/configs/"): zf.read(n) for n in zf.namelist() if n.startswith("nsim/configs/")}
        assert "nsim/cli.py" in zf.namelist() and "nsim/config.py" in zf.namelist()
    repo = {p.relative_to(CONFIGS).as_posix(): p.read_bytes() for p in CONFIGS.rglob("*") if p.is_file()}
    assert "capture/tiny.yaml" in repo and "schemas/scenario.schema.json" in repo
    assert packaged == repo  # every file, byte for byte, and nothing else


@pytest.mark.skipif(os.name != "posix", reason="venv layout of POSIX systems")
def test_installed_wheel_runs_outside_the_repository(wheel, tmp_path, run_cli):
    """A fresh venv holding only the wheel (the dependencies come from this environment's site-packages as a
    plain path entry, so its editable nsim is never seen), ``nsim capture synth --preset tiny`` run from a
    folder outside the repository, and the same artifact as this checkout makes."""
    venv = tmp_path / "venv"
    _run([getattr(sys, "_base_executable", sys.executable), "-m", "venv", "--without-pip", venv])
    py = venv / "bin" / "python"
    _run([sys.executable, "-m", "pip", "--python", py, "install", "--no-deps", "--no-index", "--no-compile", "-q", wheel])
    site = Path(_run([py, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"]).stdout.strip())
    import sysconfig

    deps = dict.fromkeys([sysconfig.get_path("purelib"), sysconfig.get_path("platlib")])
    (site / "dev_dependencies.pth").write_text("".join(f"{d}\n" for d in deps))  # paths, not site dirs: no .pth run

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "NSIM_CONFIGS")}
    where = _run([py, "-c", "import nsim, nsim.config as c; print(nsim.__file__); print(c.configs_dir())"],
                 cwd=elsewhere, env=env).stdout.splitlines()
    assert Path(where[0]).is_relative_to(site / "nsim"), where
    assert Path(where[1]) == site / "nsim" / "configs", where

    ws = tmp_path / "ws"
    proc = _run([venv / "bin" / "nsim", "--workspace", ws, "capture", "synth", "--preset", "tiny"], cwd=elsewhere, env=env)
    art_id = proc.stdout.strip().splitlines()[-1]
    assert "published" in proc.stderr

    from nsim.stages.capture import Config
    from nsim.workspace.store import Store

    tiny = load_config(Config, stage="capture", preset="tiny")  # this checkout's nsim/configs/capture/tiny.yaml
    manifest = Store(ws).get(art_id).manifest
    assert manifest["kind"] == "capture"
    expected = to_dict(tiny)  # the manifest leaves out the phone model while it is all defaults, and actor_view_deg
    assert manifest["config"] == {k: v for k, v in expected.items() if k in manifest["config"]}
    assert set(expected) - set(manifest["config"]) <= {"phone", "actor_view_deg"}
    assert manifest["summary"]["frames"] == tiny.n_frames
    # this checkout computes the same action key from its own preset: a cache hit on the installed run's artifact
    code, out, err = run_cli("capture", "synth", "--preset", "tiny", workspace=ws)
    assert code == 0 and out.strip() == art_id and "cached" in err, err
