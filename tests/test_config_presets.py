"""Presets that name another (``inherit:``), every preset file loading, and settings written once
(``param_from``, ``check_params``: SfM's options, mirrored by the reconstruct and evaluate configs)."""

from __future__ import annotations

import dataclasses
import importlib
import typing

import pytest
import yaml

from nsim.config import (
    ConfigError,
    check_params,
    config_digest,
    configs_dir,
    load_config,
    param,
    param_from,
    read_preset,
    read_yaml,
)
from nsim.sfm.options import SfmOptions


@dataclasses.dataclass(frozen=True)
class Optim:
    lr: float = param(1e-2, gt=0)
    steps: int = param(100, ge=1)


@dataclasses.dataclass(frozen=True)
class Demo:
    width: int = param(96, ge=8, le=4096, help="image width")
    name: str = param("lab", choices=("lab", "kitchen"))
    optim: Optim = dataclasses.field(default_factory=Optim)


@pytest.fixture
def presets(tmp_path, monkeypatch):
    root = tmp_path / "configs"
    (root / "demo").mkdir(parents=True)
    monkeypatch.setenv("NSIM_CONFIGS", str(root))

    def write(name: str, text: str) -> None:
        (root / "demo" / f"{name}.yaml").write_text(text)

    return write


def test_inherit_merges_over_the_named_preset(presets):
    presets("base", "width: 16\noptim:\n  lr: 0.5\n  steps: 3\n")
    presets("child", "inherit: base\noptim:\n  steps: 7\n")
    presets("grandchild", "# comments only and a name\ninherit: child\nname: kitchen\n")
    presets("alias", "inherit: base\n")
    assert read_preset("demo", "child") == {"width": 16, "optim": {"lr": 0.5, "steps": 7}}
    cfg = load_config(Demo, stage="demo", preset="grandchild")
    assert cfg == Demo(width=16, name="kitchen", optim=Optim(lr=0.5, steps=7))
    assert load_config(Demo, stage="demo", preset="alias") == load_config(Demo, stage="demo", preset="base")
    # later layers still override an inherited value
    assert load_config(Demo, stage="demo", preset="child", overrides=["width=32"]).width == 32


@pytest.mark.parametrize(
    ("files", "message"),
    [
        ({"a": "inherit: b\n", "b": "inherit: a\n"}, r"a\.yaml: inherit: presets inherit in a cycle \(a -> b -> a\)"),
        ({"a": "inherit: a\n"}, r"inherit in a cycle \(a -> a\)"),
        ({"a": "inherit: nope\n"}, r"a\.yaml: inherit: no preset 'nope' for demo \(available: a\)"),
        ({"a": "inherit: [b]\n", "b": "width: 9\n"}, r"a\.yaml: inherit: expected the name of a demo preset, got \[\"b\"\]"),
        ({"a": "inherit: ../x\n"}, r"a\.yaml: inherit: invalid preset name '\.\./x'"),
        ({"a": "inherit: b\n", "b": "- 1\n"}, r"b\.yaml: expected a mapping at the top level"),
        ({"a": "inherit: b\nwidht: 9\n", "b": "width: 9\n"}, r"a\.yaml: widht: unknown key \(did you mean 'width'\?\)"),
        ({"a": "inherit: b\n", "b": "width: 2\n"}, r"a\.yaml: width: expected int >= 8 and <= 4096, got 2"),
    ],
)
def test_bad_inherit_is_one_line(presets, files, message):
    for name, text in files.items():
        presets(name, text)
    with pytest.raises(ConfigError, match=message):
        load_config(Demo, stage="demo", preset="a")


def test_inherit_is_for_presets_only(tmp_path):
    """A --config file stays strict: it is one layer over a preset, not a preset itself."""
    f = tmp_path / "mine.yaml"
    f.write_text("inherit: base\n")
    with pytest.raises(ConfigError, match="inherit: unknown key"):
        load_config(Demo, config_file=f)


def _stage_configs():
    """(stage folder, its Config class) for every stage whose presets live in nsim/configs/<stage>/."""
    out = []
    for folder in sorted(p.name for p in configs_dir().iterdir() if p.is_dir()):
        if folder == "robot_log":
            out.append((folder, importlib.import_module("nsim.stages.capture").RobotLogConfig))
            continue
        try:
            module = importlib.import_module(f"nsim.stages.{folder}")
        except ModuleNotFoundError as exc:
            if exc.name != f"nsim.stages.{folder}":
                raise
            continue  # robots, scenarios, motions, schemas: not presets
        out.append((folder, module.Config))
    return out


def test_every_preset_loads():
    seen = 0
    for stage, cls in _stage_configs():
        for path in sorted((configs_dir() / stage).glob("*.yaml")):
            load_config(cls, stage=stage, preset=path.stem)
            seen += 1
    assert seen >= 20


def test_train_scene_default_is_cpu():
    from nsim.stages.train_scene import Config

    text = (configs_dir() / "train_scene" / "default.yaml").read_text()
    assert "inherit: cpu" in text and "field:" not in text  # named, not a second copy
    assert read_preset("train_scene", "default") == read_yaml(configs_dir() / "train_scene" / "cpu.yaml")
    default = load_config(Config, stage="train_scene", preset="default")
    assert default == load_config(Config, stage="train_scene", preset="cpu")
    assert config_digest(default) == config_digest(load_config(Config, stage="train_scene", preset="cpu"))


def test_train_scene_photos_is_cpu_with_the_real_capture_changes():
    import dataclasses

    from nsim.stages.train_scene import Config

    cpu = load_config(Config, stage="train_scene", preset="cpu")
    photos = load_config(Config, stage="train_scene", preset="photos")
    assert photos.field.hash_max_resolution == 0 and photos.optim.appearance_mean_share == 0.25
    assert photos == dataclasses.replace(cpu, field=dataclasses.replace(cpu.field, hash_max_resolution=0),
                                         optim=dataclasses.replace(cpu.optim, appearance_mean_share=0.25))


# ------------------------------------------------------------------------------ settings written once


def test_param_from_copies_the_constraints():
    @dataclasses.dataclass(frozen=True)
    class Mirror:
        width: int = param_from(Demo, "width")
        narrow: int = param_from(Demo, "width", 64, help="mine")

    assert Mirror() == Mirror(width=96, narrow=64)
    meta = {f.name: f.metadata for f in dataclasses.fields(Mirror)}
    assert meta["width"]["ge"] == 8 and meta["width"]["le"] == 4096 and meta["width"]["help"] == "image width"
    assert meta["narrow"]["ge"] == 8 and meta["narrow"]["help"] == "mine"
    with pytest.raises(ConfigError, match="narrow: expected int >= 8 and <= 4096, got 5000"):
        load_config(Mirror, overrides=["narrow=5000"])
    with pytest.raises(TypeError, match="no field 'height'"):
        param_from(Demo, "height")


def test_check_params_checks_a_config_built_in_python():
    @dataclasses.dataclass(frozen=True)
    class Checked:
        width: int = param(96, ge=8)
        name: str = param("lab", choices=("lab", "kitchen"))
        fov_deg: float | None = param(None, gt=0, lt=180)

        def __post_init__(self):
            check_params(self)

    Checked(fov_deg=90.0)
    with pytest.raises(ValueError, match="width: expected int >= 8, got 4"):
        Checked(width=4)
    with pytest.raises(ValueError, match="name: 'garage' is not one of lab, kitchen"):
        Checked(name="garage")
    with pytest.raises(ValueError, match="fov_deg: expected float > 0 and < 180, got 180.0"):
        Checked(fov_deg=180.0)


SFM_MIRRORS = {
    "reconstruct": ("camera_model", "shared_intrinsics", "matcher", "overlap", "loop_detection", "max_features",
                    "min_registered_fraction", "refine_principal_point"),
    "slam": ("camera_model", "matcher", "overlap", "max_features", "min_registered_fraction"),
}


def _mirror_classes():
    from nsim.evaluation.evaluate_config import SlamConfig
    from nsim.stages.reconstruct import Config

    return {"reconstruct": Config, "slam": SlamConfig}


@pytest.mark.parametrize("which", sorted(SFM_MIRRORS))
def test_sfm_settings_are_sfm_options_fields(which):
    cls = _mirror_classes()[which]
    sfm = {f.name: f for f in dataclasses.fields(SfmOptions)}
    mine = {f.name: f for f in dataclasses.fields(cls)}

    assert set(mine) & set(sfm) == set(SFM_MIRRORS[which])
    for name in SFM_MIRRORS[which]:
        ours, theirs = dict(mine[name].metadata), dict(sfm[name].metadata)
        ours.pop("help"), theirs.pop("help")
        assert ours == theirs, name
        assert typing.get_type_hints(cls)[name] == typing.get_type_hints(SfmOptions)[name], name


def test_reconstruct_passes_every_sfm_setting_on():
    from nsim.stages.reconstruct import SFM_SETTINGS

    assert SFM_SETTINGS == SFM_MIRRORS["reconstruct"]


@pytest.mark.parametrize(
    ("expr", "message"),
    [
        ("max_features=32", "max_features: expected int >= 64, got 32"),
        ("min_registered_fraction=1.5", "min_registered_fraction: expected float >= 0 and <= 1, got 1.5"),
        ("overlap=0", "overlap: expected int >= 1, got 0"),
        ("matcher=fancy", "matcher: 'fancy' is not one of sequential, exhaustive"),
        ("camera_model=FANCY", "camera_model: 'FANCY' is not one of SIMPLE_RADIAL, OPENCV, OPENCV_FISHEYE, PINHOLE"),
    ],
)
def test_one_bound_everywhere(expr, message):
    """The same bad value fails alike in reconstruct's config, evaluate's slam section and SfmOptions."""
    from nsim.stages.evaluate import Config as EvaluateConfig
    from nsim.stages.reconstruct import Config as ReconstructConfig

    with pytest.raises(ConfigError, match=f"--set {message}"):
        load_config(ReconstructConfig, stage="reconstruct", preset="default", overrides=[expr])
    with pytest.raises(ConfigError, match=f"--set slam.{message}"):
        load_config(EvaluateConfig, stage="evaluate", preset="default", overrides=[f"slam.{expr}"])
    key, value = expr.split("=")

    with pytest.raises(ValueError, match=message):
        SfmOptions(**{key: yaml.safe_load(value)})


def test_bounds_that_once_disagreed():
    """max_features >= 64 (the stage configs' bound; SfmOptions took 16) and min_registered_fraction in
    [0, 1] (SfmOptions' range; the stage configs refused 0, which means "any two images")."""
    from nsim.stages.evaluate import Config as EvaluateConfig
    from nsim.stages.reconstruct import Config as ReconstructConfig

    with pytest.raises(ValueError, match="max_features: expected int >= 64, got 16"):
        SfmOptions(max_features=16)
    assert SfmOptions(max_features=64).max_features == 64
    cfg = load_config(ReconstructConfig, stage="reconstruct", preset="default", overrides=["min_registered_fraction=0"])
    assert cfg.min_registered_fraction == 0.0
    ev = load_config(EvaluateConfig, stage="evaluate", preset="default", overrides=["slam.min_registered_fraction=0"])
    assert ev.slam.min_registered_fraction == 0.0
    with pytest.raises(ValueError, match="hfov_guesses_deg: expected values in \\(0, 180\\)"):
        SfmOptions(hfov_guesses_deg=(200.0,))
    assert SfmOptions(camera_model="OPENCV_FISHEYE", hfov_guesses_deg=(200.0,)).hfov_guesses == (200.0,)


def test_stage_defaults_are_unchanged():
    """Single-sourcing moved no default: the configs (and so the artifact ids) are what they were."""
    from nsim.evaluation.evaluate_config import SlamConfig
    from nsim.stages.reconstruct import Config

    assert dataclasses.asdict(Config()) == {
        "frames": 150, "blur_ratio": 0.4, "dedup_threshold": 0.01, "camera_model": "SIMPLE_RADIAL",
        "shared_intrinsics": True, "matcher": "sequential", "overlap": 10, "loop_detection": True,
        "max_features": 8192, "min_registered_fraction": 0.5, "refine_principal_point": "auto",
        "exif_focal_prior": True, "max_dt_s": 0.02}
    assert dataclasses.asdict(SlamConfig()) == {
        "camera": "left", "stride": 1, "max_frames": None, "camera_model": "OPENCV_FISHEYE", "matcher": "sequential",
        "overlap": 10, "max_features": 4096, "min_registered_fraction": 0.5, "alignment": "sim3", "max_dt_s": 0.01}
