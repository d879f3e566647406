from __future__ import annotations

import dataclasses

import pytest

from nsim.config import ConfigError, config_digest, from_dict, load_config, param, to_dict


@dataclasses.dataclass(frozen=True)
class Optim:
    lr: float = param(1e-2, gt=0)
    steps: int = param(100, ge=1)
    betas: tuple[float, float] = (0.9, 0.99)


@dataclasses.dataclass(frozen=True)
class Demo:
    name: str = param("robot-lab", choices=("robot-lab", "kitchen"))
    width: int = param(96, ge=8, le=4096)
    fov_deg: float = param(60.0, gt=0, lt=180)
    flip: bool = False
    levels: tuple[int, ...] = (16, 32)
    note: str | None = None
    optim: Optim = dataclasses.field(default_factory=Optim)


def test_defaults_and_round_trip():
    cfg = from_dict(Demo, {})
    assert cfg == Demo()
    assert from_dict(Demo, to_dict(cfg)) == cfg
    assert config_digest(cfg) == config_digest(Demo())
    assert config_digest(cfg) != config_digest(Demo(width=97))


def test_layers_override_in_order(tmp_path):
    base = tmp_path / "base.yaml"
    base.write_text("width: 128\noptim:\n  lr: 1e-3\n  steps: 5\n")
    cfg = load_config(Demo, config_file=base, overrides=["optim.steps=7", "levels=[1, 2, 3]", "note=hi"])
    assert cfg.width == 128 and cfg.optim.lr == 1e-3 and cfg.optim.steps == 7
    assert cfg.levels == (1, 2, 3) and cfg.note == "hi"
    assert cfg.optim.betas == (0.9, 0.99)


def test_presets_from_directory(tmp_path, monkeypatch):
    (tmp_path / "demo").mkdir()
    (tmp_path / "demo" / "tiny.yaml").write_text("width: 16\n")
    monkeypatch.setenv("NSIM_CONFIGS", str(tmp_path))
    assert load_config(Demo, stage="demo", preset="tiny").width == 16
    with pytest.raises(ConfigError, match="no preset 'huge' for demo \\(available: tiny\\)"):
        load_config(Demo, stage="demo", preset="huge")
    with pytest.raises(ConfigError, match="invalid preset name"):
        load_config(Demo, stage="demo", preset="../etc/passwd")


# Every malformed input we could think of, with the key its message must name.
BAD_DATA = [
    ({"widht": 3}, "widht: unknown key (did you mean 'width'?)"),
    ({"optim": {"lr": -1}}, "optim.lr: expected float > 0, got -1"),
    ({"optim": {"lr": 0}}, "optim.lr: expected float > 0, got 0"),
    ({"optim": {"lr": "fast"}}, "optim.lr: expected float, got 'fast'"),
    ({"optim": {"lr": float("nan")}}, "optim.lr: expected a number, got nan"),
    ({"optim": {"stepz": 1}}, "optim.stepz: unknown key (did you mean 'steps'?)"),
    ({"optim": {"steps": 2.5}}, "optim.steps: expected int, got 2.5"),
    ({"optim": {"steps": True}}, "optim.steps: expected int, got true"),
    ({"optim": {"steps": 0}}, "optim.steps: expected int >= 1, got 0"),
    ({"optim": {"betas": [0.9]}}, "optim.betas: expected a list of 2 items, got 1"),
    ({"optim": {"betas": "0.9"}}, "optim.betas: expected a list, got '0.9'"),
    ({"optim": 3}, "optim: expected a mapping of Optim fields, got 3"),
    ({"width": 5000}, "width: expected int >= 8 and <= 4096, got 5000"),
    ({"fov_deg": 180}, "fov_deg: expected float > 0 and < 180, got 180"),
    ({"flip": "yes"}, "flip: expected bool (true/false), got 'yes'"),
    ({"flip": 1}, "flip: expected bool (true/false), got 1"),
    ({"name": "garage"}, "name: 'garage' is not one of robot-lab, kitchen"),
    ({"name": 7}, "name: expected str, got 7"),
    ({"levels": [1, "x"]}, "levels[1]: expected int, got 'x'"),
    ({"note": 5}, "note: expected str, got 5"),
]


@pytest.mark.parametrize("data,message", BAD_DATA)
def test_malformed_values_name_the_key(data, message):
    with pytest.raises(ConfigError) as info:
        from_dict(Demo, data)
    assert str(info.value).startswith(message), str(info.value)
    assert "\n" not in str(info.value)


BAD_SETS = [
    ("width", "--set width: expected KEY=VALUE"),
    ("=3", "--set =3: invalid key ''"),
    ("wdth=3", "--set wdth: unknown key (did you mean 'width'?)"),
    ("optim.lr=-2", "--set optim.lr: expected float > 0, got -2"),
    ("optim.lr.x=1", "--set optim.lr.x: 'optim.lr' is a value, not a section"),
    ("width.x=1", "--set width.x: 'width' is a value, not a section"),
    ("optim=[1]", "--set optim: expected a mapping of Optim fields"),
    ("levels=[1, ", "--set levels: cannot parse value"),
    ("optim.nope=1", "--set optim.nope: unknown key"),
    ("flip=maybe", "--set flip: expected bool (true/false), got 'maybe'"),
]


@pytest.mark.parametrize("expr,message", BAD_SETS)
def test_malformed_set_names_the_key(expr, message):
    with pytest.raises(ConfigError) as info:
        load_config(Demo, overrides=[expr])
    assert str(info.value).startswith(message), str(info.value)


def test_malformed_files(tmp_path):
    missing = tmp_path / "missing.yaml"
    with pytest.raises(ConfigError, match="missing.yaml: config file not found"):
        load_config(Demo, config_file=missing)
    broken = tmp_path / "broken.yaml"
    broken.write_text("width: [1, 2\n")
    with pytest.raises(ConfigError, match=r"broken.yaml: line \d+: malformed YAML"):
        load_config(Demo, config_file=broken)
    listy = tmp_path / "list.yaml"
    listy.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="list.yaml: expected a mapping at the top level"):
        load_config(Demo, config_file=listy)
    typo = tmp_path / "typo.yaml"
    typo.write_text("optim:\n  lr: -3\n")
    with pytest.raises(ConfigError, match="typo.yaml: optim.lr: expected float > 0, got -3"):
        load_config(Demo, config_file=typo)
    with pytest.raises(ConfigError, match="cannot read config file"):
        load_config(Demo, config_file=tmp_path)


def test_scientific_notation_and_ints_are_floats():
    assert load_config(Demo, overrides=["optim.lr=1e-3"]).optim.lr == 1e-3
    assert load_config(Demo, overrides=["fov_deg=90"]).fov_deg == 90.0
    assert isinstance(load_config(Demo, overrides=["fov_deg=90"]).fov_deg, float)


def test_mutable_defaults_are_refused():
    with pytest.raises(TypeError, match="mutable defaults"):
        param([1, 2])
