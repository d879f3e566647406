"""Sweep files (a grid of seeds x crowd sizes x behaviour sets x robot controllers over one scenario) and their summary table.

``load_sweep`` reads and checks the file; the simulate stage runs one trajectory per grid cell
(``nsim.stages.simulate.run_sweep``); ``nsim.crowd.run_output.sweep_table_markdown`` prints the rows it returns.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from nsim.config import from_dict, param, read_yaml
from nsim.crowd.behaviours import BEHAVIOUR_NAMES
from nsim.errors import ConfigError, InputError


@dataclasses.dataclass(frozen=True)
class SweepSpec:
    """A sweep file (YAML): a grid of seeds x crowd sizes x behaviour sets over one base scenario.

    scenario: the base scenario file, relative to the sweep file. seeds: scenario seeds.
    crowd_sizes: how many extra people to spawn in free space (0 = the scenario as it is).
    behaviours: behaviour sets the extra people's behaviours are drawn from; each a name or a list
    of names. keep_scenario_humans: false drops the scenario's own people. controllers: the
    robot's ``robot.controller`` per cell (``nsim.crowd.controllers``: ``replay``, ``social_force``,
    ``orca`` or ``{python: "file.py:Class", params: {...}}``, a file relative to the sweep file);
    every controller runs on the same seeds and crowds.
    """

    scenario: str = param(help="base scenario file, relative to the sweep file")
    seeds: tuple[int, ...] = param((0,))
    crowd_sizes: tuple[int, ...] = param((0,))
    behaviours: tuple[str | tuple[str, ...], ...] = param(("regular",))
    keep_scenario_humans: bool = True
    controllers: tuple[Any, ...] = param(("replay",), help="robot.controller entries compared on the same cells")


def load_sweep(path: str | Path) -> tuple[SweepSpec, Path]:
    """The sweep file, strictly checked (errors name the file and the key), and its scenario's path."""
    path = Path(path)
    data = read_yaml(path, what="sweep")
    try:
        spec = from_dict(SweepSpec, data)
    except ConfigError as exc:
        raise InputError(f"{path}: {exc}") from None
    for name, values in (("seeds", spec.seeds), ("crowd_sizes", spec.crowd_sizes)):
        if not values:
            raise InputError(f"{path}: {name}: expected at least one value")
        for k, v in enumerate(values):
            if v < 0:
                raise InputError(f"{path}: {name}[{k}]: expected int >= 0, got {v}")
    if not spec.behaviours:
        raise InputError(f"{path}: behaviours: expected at least one behaviour set")
    for k, b in enumerate(spec.behaviours):
        names = (b,) if isinstance(b, str) else b
        for name in names or ("[]",):
            if name not in BEHAVIOUR_NAMES:
                raise InputError(f"{path}: behaviours[{k}]: {name!r} is not one of {', '.join(BEHAVIOUR_NAMES)}")
    if not spec.controllers:
        raise InputError(f"{path}: controllers: expected at least one controller")
    resolved = []
    for k, c in enumerate(spec.controllers):
        if isinstance(c, dict) and isinstance(c.get("python"), str):
            module, _, cls = c["python"].rpartition(":")
            if module.endswith(".py") and not Path(module).is_absolute():
                c = {**c, "python": f"{(path.parent / module).resolve()}:{cls}"}
        elif not isinstance(c, str):
            raise InputError(f"{path}: controllers[{k}]: expected a name or {{python: 'module:Class'}}, got {c!r}")
        resolved.append(c)
    spec = dataclasses.replace(spec, controllers=tuple(resolved))
    return spec, (path.parent / spec.scenario)
