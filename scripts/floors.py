#!/usr/bin/env python
"""Pip constraints that hold every dependency of nsim at the floor pyproject.toml states.

    python scripts/floors.py [--pyproject PATH] [--pin NAME==VERSION ...] > floors.txt
    pip install -c floors.txt -e . pytest

Reads ``[project].dependencies`` and every optional extra (a constraint only acts on what gets
installed, so listing the extras costs nothing) and prints one constraint a line: ``name>=X`` becomes
``name==X.*``, the floor's release series (a floor of ``4.8`` must match ``4.8.0.74``, which ``==4.8``
does not; a three-part floor such as ``4.2.1`` selects that release). ``--pin`` replaces a floor
(``make test-floors`` pins torch to the CPU wheel ``make setup`` installs). Extras of a requirement
(``ray[default]``) are dropped, since pip refuses them in constraints; a package named twice keeps its
highest floor; nsim's references to itself are skipped.

Exit status 0, or 1 with one line naming the requirement when one has no floor (``>=`` or ``==``) or
cannot be read. Runs on the standard library alone (``tomllib``, or ``tomli`` on Python 3.10).
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path

PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"

# name [extras] specifiers [; marker] (PEP 508 without URLs, which nsim does not use)
_REQ = re.compile(
    r"^\s*(?P<name>[A-Za-z0-9][A-Za-z0-9._-]*)\s*(?:\[(?P<extras>[^\]]*)\])?\s*"
    r"(?P<specs>[^;]*?)\s*(?:;\s*(?P<marker>.+?))?\s*$"
)
_SPEC = re.compile(r"^\s*(?P<op>~=|===|==|!=|<=|>=|<|>)\s*(?P<version>[A-Za-z0-9][A-Za-z0-9.*+!_-]*)\s*$")


class FloorsError(Exception):
    """A requirement without a usable floor: one line, naming it."""


def canonical_name(name: str) -> str:
    """PEP 503 normalised name (``OpenEXR`` -> ``openexr``, ``PyYAML`` -> ``pyyaml``)."""
    return re.sub(r"[-_.]+", "-", name).lower()


def _release(version: str) -> tuple[int, ...]:
    """The numeric release of a version (``2.13.0+cpu`` -> ``(2, 13, 0)``), for comparing floors."""
    m = re.match(r"^\s*v?(\d+(?:\.\d+)*)", version)
    if m is None:
        raise FloorsError(f"cannot read version {version!r}")
    parts = [int(p) for p in m.group(1).split(".")]
    while len(parts) > 1 and parts[-1] == 0:
        parts.pop()
    return tuple(parts)


def floor_of(requirement: str) -> tuple[str, str, str | None]:
    """``(name, floor version, marker)`` of one requirement string, e.g. ``"numpy>=1.24"``."""
    m = _REQ.match(requirement)
    if m is None:
        raise FloorsError(f"{requirement!r}: cannot read this requirement")
    floors = []
    for spec in filter(None, (s.strip() for s in m.group("specs").split(","))):
        s = _SPEC.match(spec)
        if s is None:
            raise FloorsError(f"{requirement!r}: cannot read the specifier {spec!r}")
        if s.group("op") in (">=", "==", "==="):
            floors.append(s.group("version"))
    if not floors:
        raise FloorsError(f"{requirement!r}: no floor (a '>=' version) to test")
    return m.group("name"), max(floors, key=_release), m.group("marker")


def requirements(pyproject: dict) -> list[str]:
    """``[project].dependencies`` then every extra's, in file order."""
    project = pyproject.get("project", {})
    out = list(project.get("dependencies", []))
    for reqs in project.get("optional-dependencies", {}).values():
        out.extend(reqs)
    return out


def constraints(reqs: Iterable[str], pins: Sequence[str] = (), project: str = "nsim") -> list[str]:
    """One pip constraint a line for ``reqs`` (see the module docstring); ``pins`` override floors."""
    chosen: dict[str, tuple[str, str, str | None]] = {}  # canonical name -> (name, floor, marker)
    for req in reqs:
        name, floor, marker = floor_of(req)
        key = canonical_name(name)
        if key == canonical_name(project):
            continue
        if key not in chosen or _release(floor) > _release(chosen[key][1]):
            chosen[key] = (name, floor, marker)
    pinned: dict[str, str] = {}
    for pin in pins:
        m = re.fullmatch(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*)\s*==\s*(\S+)\s*", pin)
        if m is None:
            raise FloorsError(f"--pin {pin!r}: expected NAME==VERSION")
        key = canonical_name(m.group(1))
        if key not in chosen:
            raise FloorsError(f"--pin {pin!r}: {m.group(1)} is not a dependency of {project}")
        if _release(m.group(2)) < _release(chosen[key][1]):
            raise FloorsError(f"--pin {pin!r}: below the floor {chosen[key][0]}>={chosen[key][1]}")
        pinned[key] = f"{chosen[key][0]}=={m.group(2)}"
    lines = []
    for key, (name, floor, marker) in chosen.items():
        series = f"{floor}.*" if re.fullmatch(r"\d+(\.\d+)*", floor) else floor  # 1.0rc1 has no series
        line = pinned.get(key, f"{name}=={series}")
        lines.append(f"{line} ; {marker}" if marker else line)
    return lines


def load_pyproject(path: Path) -> dict:
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        try:
            import tomli as tomllib  # type: ignore[no-redef]
        except ModuleNotFoundError:
            raise FloorsError("reading it needs Python >= 3.11 (tomllib) or the tomli package") from None
    try:
        return tomllib.loads(Path(path).read_text())
    except FileNotFoundError:
        raise FloorsError("not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise FloorsError(f"malformed TOML ({exc})") from None


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pyproject", type=Path, default=PYPROJECT, help="pyproject.toml to read (default: the repo's)")
    parser.add_argument("--pin", action="append", default=[], metavar="NAME==VERSION",
                        help="use this version instead of the floor (repeatable)")
    args = parser.parse_args(argv)
    try:
        data = load_pyproject(args.pyproject)
        lines = constraints(requirements(data), args.pin, data.get("project", {}).get("name", "nsim"))
    except FloorsError as exc:
        print(f"floors: {args.pyproject}: {exc}", file=sys.stderr)
        return 1
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
