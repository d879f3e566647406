"""Typed, strict configuration.

Each stage defines a frozen dataclass next to the code that uses it; presets are YAML files
in ``nsim/configs/<stage>/<name>.yaml``. Loading is strict: unknown keys, wrong types and
out-of-range values raise :class:`~nsim.errors.ConfigError` naming the dotted key, e.g.
``train.lr: expected float > 0, got -1``.

A config is resolved in this order, each layer overriding the one before:
dataclass defaults -> preset file -> ``--config FILE`` -> ``--set a.b=value`` (repeatable).

Constraints live in field metadata, written with :func:`param`::

    @dataclass(frozen=True)
    class TrainConfig:
        lr: float = param(1e-2, gt=0)
        steps: int = param(1000, ge=1)
        sampler: str = param("proposal", choices=("proposal", "uniform"))

A field that mirrors another config's (a stage's ``max_features`` is SfM's) takes its
constraints and help from that one definition with :func:`param_from`; a dataclass used directly
from Python checks its own fields with :func:`check_params`.

A preset file may name another preset of the same stage with ``inherit: NAME``: its keys then
override that preset's (``nsim/configs/train_scene/default.yaml`` is ``inherit: cpu``).

Supported field types: ``bool``, ``int``, ``float``, ``str``, ``tuple[T, ...]``,
``tuple[T1, T2]``, ``X | None`` and nested config dataclasses (two levels at most, by
convention). Ints are accepted where a float is expected; YAML strings such as ``1e-3``
(which YAML 1.1 reads as text) are accepted for floats.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import re
import types
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

import yaml

from nsim.errors import ConfigError

T = TypeVar("T")

_FLOAT_RE = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$|^[+-]?(inf|nan)$", re.IGNORECASE)


def param(
    default: Any = dataclasses.MISSING,
    *,
    gt: float | None = None,
    ge: float | None = None,
    lt: float | None = None,
    le: float | None = None,
    choices: Sequence[Any] | None = None,
    help: str = "",
) -> Any:
    """A dataclass field with range/choice constraints checked by the loader."""
    meta = {"gt": gt, "ge": ge, "lt": lt, "le": le, "choices": tuple(choices) if choices else None, "help": help}
    if isinstance(default, (list, dict, set)):
        raise TypeError("mutable defaults are not allowed in frozen configs; use a tuple")
    return dataclasses.field(default=default, metadata=meta)


def param_from(cls: type, name: str, default: Any = dataclasses.MISSING, *, help: str | None = None) -> Any:
    """A field with the constraints (and help) of field ``name`` of config dataclass ``cls``.

    For a setting one config passes on to another (a stage's ``max_features`` to
    ``nsim.sfm.options.SfmOptions``): the bounds and choices are written once, on ``cls``; ``default``
    (else ``cls``'s) and ``help`` (else ``cls``'s) may be the user's own.
    """
    fields = {f.name: f for f in dataclasses.fields(cls)}
    if name not in fields:
        raise TypeError(f"{cls.__name__} has no field {name!r}")
    src = fields[name]
    meta = dict(src.metadata)
    if help is not None:
        meta["help"] = help
    if default is dataclasses.MISSING:
        default = src.default
    if default is dataclasses.MISSING:
        raise TypeError(f"{cls.__name__}.{name} has no default: give one")
    return param(default, gt=meta.get("gt"), ge=meta.get("ge"), lt=meta.get("lt"), le=meta.get("le"),
                 choices=meta.get("choices"), help=meta.get("help", ""))


def check_params(obj: Any) -> None:
    """Check a config dataclass built in Python (not loaded) against its fields' :func:`param` constraints.

    Scalars only (``None`` passes); raises ``ValueError`` with the loader's message, e.g.
    ``max_features: expected int >= 64, got 8``. Call it from ``__post_init__``.
    """
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if value is None or isinstance(value, bool) or not isinstance(value, (int, float, str)):
            continue
        tname = "str" if isinstance(value, str) else ("int" if isinstance(value, int) else "float")
        try:
            _check_range(f.name, value, f.metadata, tname)
        except ConfigError as exc:
            raise ValueError(str(exc)) from None


# --------------------------------------------------------------------------------------
# Loading from plain data
# --------------------------------------------------------------------------------------


def _describe(value: Any) -> str:
    if isinstance(value, str):
        return repr(value)
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, (dict, list, tuple)):
        text = json.dumps(value, default=str)
        return text if len(text) <= 40 else text[:37] + "..."
    return repr(value)


def _type_name(tp: Any) -> str:
    if tp is type(None):
        return "null"
    if isinstance(tp, type):
        return tp.__name__
    return str(tp).replace("typing.", "")


def _check_range(path: str, value: Any, meta: Mapping[str, Any], tname: str) -> None:
    if not meta:
        return
    bounds = []
    ok = True
    for key, sym, cmp in (
        ("gt", ">", lambda v, b: v > b),
        ("ge", ">=", lambda v, b: v >= b),
        ("lt", "<", lambda v, b: v < b),
        ("le", "<=", lambda v, b: v <= b),
    ):
        bound = meta.get(key)
        if bound is not None:
            bounds.append(f"{sym} {bound:g}")
            if not cmp(value, bound):
                ok = False
    if not ok:
        raise ConfigError(f"{path}: expected {tname} {' and '.join(bounds)}, got {_describe(value)}")
    choices = meta.get("choices")
    if choices is not None and value not in choices:
        raise ConfigError(f"{path}: {_describe(value)} is not one of {', '.join(map(str, choices))}")


def _coerce(path: str, value: Any, tp: Any, meta: Mapping[str, Any]) -> Any:
    """Check ``value`` against type ``tp`` and return it in canonical form."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)

    # Optional / unions
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        non_none = [a for a in args if a is not type(None)]
        errors = []
        for a in non_none:
            try:
                return _coerce(path, value, a, meta)
            except ConfigError as exc:
                errors.append(str(exc))
        if len(non_none) == 1:
            raise ConfigError(errors[0])
        raise ConfigError(f"{path}: expected {_type_name(tp)}, got {_describe(value)}")

    if dataclasses.is_dataclass(tp):
        if not isinstance(value, Mapping):
            raise ConfigError(f"{path}: expected a mapping of {tp.__name__} fields, got {_describe(value)}")
        return _from_mapping(tp, value, path)

    if origin is tuple:
        if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
            raise ConfigError(f"{path}: expected a list, got {_describe(value)}")
        if len(args) == 2 and args[1] is Ellipsis:
            item_types = [args[0]] * len(value)
        else:
            item_types = list(args)
            if len(value) != len(item_types):
                raise ConfigError(f"{path}: expected a list of {len(item_types)} items, got {len(value)}")
        return tuple(_coerce(f"{path}[{i}]", v, t, {}) for i, (v, t) in enumerate(zip(value, item_types, strict=True)))

    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{path}: expected bool (true/false), got {_describe(value)}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{path}: expected int, got {_describe(value)}")
        _check_range(path, value, meta, "int")
        return value
    if tp is float:
        if isinstance(value, bool):
            raise ConfigError(f"{path}: expected float, got {_describe(value)}")
        if isinstance(value, str) and _FLOAT_RE.match(value.strip()):
            value = float(value)
        if not isinstance(value, (int, float)):
            raise ConfigError(f"{path}: expected float, got {_describe(value)}")
        value = float(value)
        if math.isnan(value):
            raise ConfigError(f"{path}: expected a number, got nan")
        _check_range(path, value, meta, "float")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{path}: expected str, got {_describe(value)}")
        _check_range(path, value, meta, "str")
        return value
    if tp is Any:
        return value
    raise TypeError(f"unsupported config field type {tp!r} at {path}")


def _field_types(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _from_mapping(cls: type[T], data: Mapping[str, Any], prefix: str = "") -> T:
    hints = _field_types(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for key in data:
        if key not in fields:
            path = f"{prefix}.{key}" if prefix else str(key)
            near = _closest(str(key), fields)
            hint = f" (did you mean '{near}'?)" if near else ""
            raise ConfigError(f"{path}: unknown key{hint}; valid keys: {', '.join(fields)}")
    kwargs = {}
    for name, f in fields.items():
        path = f"{prefix}.{name}" if prefix else name
        if name in data:
            kwargs[name] = _coerce(path, data[name], hints[name], f.metadata)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ConfigError(f"{path}: required key is missing")
    try:
        obj = cls(**kwargs)
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"{prefix or cls.__name__}: {exc}") from None
    return obj


def _closest(key: str, names: Mapping[str, Any]) -> str | None:
    import difflib

    hits = difflib.get_close_matches(key, list(names), n=1, cutoff=0.7)
    return hits[0] if hits else None


def from_dict(cls: type[T], data: Mapping[str, Any] | None) -> T:
    """Build and validate a config dataclass from plain data (strict)."""
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ConfigError(f"{cls.__name__}: expected a mapping, got {_describe(data)}")
    return _from_mapping(cls, data)


def to_dict(cfg: Any) -> dict[str, Any]:
    """Plain, JSON-ready data for a config dataclass (tuples become lists)."""

    def conv(v: Any) -> Any:
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            return {f.name: conv(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, (list, tuple)):
            return [conv(x) for x in v]
        return v

    return conv(cfg)


def canonical_json(data: Any) -> bytes:
    """Canonical JSON bytes: sorted keys, no whitespace, floats by repr."""
    return json.dumps(data, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=True).encode()


def config_digest(cfg: Any) -> str:
    return hashlib.sha256(canonical_json(to_dict(cfg))).hexdigest()


# --------------------------------------------------------------------------------------
# Files, presets and --set overrides
# --------------------------------------------------------------------------------------


#: The presets, rigs, scenarios, motions and schemas: package data (``nsim/configs/``), so a checkout, an editable
#: install and a wheel read the same files from the same place (pyproject.toml's ``package-data``).
PACKAGED_CONFIGS = Path(__file__).resolve().parent / "configs"


def configs_dir() -> Path:
    """Directory holding the preset YAML files (and the rigs, scenarios, motions and schemas beside them):
    ``$NSIM_CONFIGS`` if set, else the package's own ``nsim/configs/``."""
    env = os.environ.get("NSIM_CONFIGS")
    return Path(env) if env else PACKAGED_CONFIGS


def read_text_file(path: str | os.PathLike[str], what: str, error: type[Exception] = ConfigError) -> str:
    """The text of ``path``, or one ``error`` line: ``<path>: <what> file not found`` / ``cannot read <what> file``."""
    path = Path(path)
    try:
        return path.read_text()
    except FileNotFoundError:
        raise error(f"{path}: {what} file not found") from None
    except (IsADirectoryError, PermissionError, UnicodeDecodeError) as exc:
        raise error(f"{path}: cannot read {what} file ({exc.__class__.__name__})") from None


def read_yaml(path: Path, what: str = "config") -> Any:
    return parse_yaml(read_text_file(path, what), path)


def parse_yaml(text: str, path: str | os.PathLike[str], error: type[Exception] = ConfigError) -> Any:
    """``yaml.safe_load`` whose failure is one ``error`` naming the file and line."""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}:" if mark is not None else ""
        problem = getattr(exc, "problem", None) or "invalid YAML"
        raise error(f"{path}:{where} malformed YAML: {problem}") from None


def preset_path(stage: str, preset: str) -> Path:
    if not re.fullmatch(r"[A-Za-z0-9_.-]+", preset) or preset.startswith("."):
        raise ConfigError(f"--preset: invalid preset name {preset!r}")
    root = configs_dir()
    if not root.is_dir():
        hint = "is $NSIM_CONFIGS right?" if os.environ.get("NSIM_CONFIGS") else "reinstall nsim, or set $NSIM_CONFIGS"
        raise ConfigError(f"--preset: the presets folder {root} is missing ({hint})")
    base = root / stage
    path = base / f"{preset}.yaml"
    if not path.is_file():
        names = sorted(p.stem for p in base.glob("*.yaml")) if base.is_dir() else []
        raise ConfigError(f"--preset: no preset '{preset}' for {stage} (available: {', '.join(names) or 'none'})")
    return path


#: The key by which a preset file names the preset of the same stage it builds on.
INHERIT_KEY = "inherit"


def read_preset(stage: str, preset: str) -> dict[str, Any]:
    """The data of preset ``preset`` of ``stage``, with any ``inherit: NAME`` chain resolved.

    A preset ``inherit``-ing another is that one's data with its own keys deep-merged over it
    (its sections merge key by key). Chains are followed; a cycle, a missing parent or a
    non-string name is a one-line :class:`ConfigError` naming the file.
    """
    chain: list[str] = []
    layers: list[dict[str, Any]] = []
    name = preset
    while True:
        if name in chain:
            raise ConfigError(f"{preset_path(stage, chain[0])}: {INHERIT_KEY}: presets inherit in a cycle "
                              f"({' -> '.join([*chain, name])})")
        path = preset_path(stage, name)
        data = read_yaml(path)
        if data is None:
            data = {}
        if not isinstance(data, Mapping):
            raise ConfigError(f"{path}: expected a mapping at the top level, got {_describe(data)}")
        chain.append(name)
        data = dict(data)
        parent = data.pop(INHERIT_KEY, None)
        layers.append(data)
        if parent is None:
            break
        if not isinstance(parent, str):
            raise ConfigError(f"{path}: {INHERIT_KEY}: expected the name of a {stage} preset, got {_describe(parent)}")
        try:
            preset_path(stage, parent)
        except ConfigError as exc:
            raise ConfigError(f"{path}: {INHERIT_KEY}: {str(exc).removeprefix('--preset: ')}") from None
        name = parent
    out: dict[str, Any] = {}
    for layer in reversed(layers):
        out = _deep_merge(out, layer)
    return out


def _deep_merge(base: dict[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in over.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), Mapping):
            out[k] = _deep_merge(dict(out[k]), v)
        else:
            out[k] = v
    return out


def parse_set(expr: str) -> tuple[list[str], Any]:
    """Parse one ``--set a.b=value``; the value is read as YAML (``[1, 2]``, ``true``, ``0.5``)."""
    if "=" not in expr:
        raise ConfigError(f"--set {expr}: expected KEY=VALUE, e.g. --set train.lr=0.01")
    key, raw = expr.split("=", 1)
    key = key.strip()
    if not key or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*", key):
        raise ConfigError(f"--set {expr}: invalid key {key!r}")
    try:
        value = yaml.safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError:
        raise ConfigError(f"--set {key}: cannot parse value {raw!r}") from None
    return key.split("."), value


def _set_path(data: dict[str, Any], keys: list[str], value: Any, cls: type) -> None:
    node = data
    cur_cls: Any = cls
    for i, k in enumerate(keys):
        dotted = ".".join(keys[: i + 1])
        names = {f.name: f for f in dataclasses.fields(cur_cls)} if dataclasses.is_dataclass(cur_cls) else {}
        if k not in names:
            near = _closest(k, names)
            hint = f" (did you mean '{near}'?)" if near else ""
            raise ConfigError(f"{dotted}: unknown key{hint}")
        if i == len(keys) - 1:
            node[k] = value
            return
        cur_cls = _field_types(cur_cls)[k]
        if not dataclasses.is_dataclass(cur_cls):
            raise ConfigError(f"{'.'.join(keys)}: '{dotted}' is a value, not a section")
        child = node.get(k)
        if not isinstance(child, dict):
            child = {}
            node[k] = child
        node = child


def load_config(
    cls: type[T],
    *,
    stage: str | None = None,
    preset: str | None = None,
    config_file: str | Path | None = None,
    overrides: Sequence[str] = (),
) -> T:
    """Resolve a config: defaults -> preset -> file -> ``--set`` overrides, strictly checked."""
    data: dict[str, Any] = {}
    layers: list[tuple[Path, Any]] = []
    if preset is not None:
        if stage is None:
            raise ValueError("a preset needs a stage name")
        layers.append((preset_path(stage, preset), read_preset(stage, preset)))
    if config_file is not None:
        p = Path(config_file)
        layers.append((p, read_yaml(p)))
    for path, layer in layers:
        if layer is None:
            continue
        if not isinstance(layer, Mapping):
            raise ConfigError(f"{path}: expected a mapping at the top level, got {_describe(layer)}")
        try:
            from_dict(cls, _deep_merge(data, layer))
        except ConfigError as exc:
            raise ConfigError(f"{path}: {exc}") from None
        data = _deep_merge(data, layer)
    for expr in overrides:
        keys, value = parse_set(expr)
        try:
            _set_path(data, keys, value, cls)
        except ConfigError as exc:
            raise ConfigError(f"--set {exc}") from None
        try:
            from_dict(cls, data)
        except ConfigError as exc:
            raise ConfigError(f"--set {exc}") from None
    return from_dict(cls, data)
