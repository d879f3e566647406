"""JSON Schema validation (the ``jsonschema`` library) with nsim's one-line messages, and the defaults filled in.

``SchemaValidator(schema).validate(data)`` checks plain data (what ``json`` or ``yaml.safe_load``
returns) against a draft 2020-12 schema with ``jsonschema`` and returns a *resolved* copy:
properties the data leaves out that have a ``default`` are added, integers in ``number`` fields
become floats and integral floats in ``integer`` fields become ints (JSON Schema counts ``2.0`` as
an integer), so equal content gives equal canonical JSON. The first error, in document order (the
order ``jsonschema``'s ``iter_errors`` yields them: the schema's keywords in turn, properties in
the schema's order), is raised as a :class:`SchemaViolation` whose ``path`` is the error's
``absolute_path`` and whose message is nsim's::

    humans[2].behaviour: 'angry' is not one of regular, impassive, surprised, ...
    dt_s: expected a number > 0 and <= 0.5, got -0.05
    durations: unknown key (did you mean 'duration_s'?); valid keys: ...

A ``oneOf`` that no branch matches names the one branch whose ``required`` keys the object has (its
first error), else lists the keys that tell the branches apart. The JSON data model has no NaN,
infinity or non-string keys, which a validator would pass over silently: ``validate`` refuses them
first, naming the field.

Defaults are filled by walking the schema alongside the data (``properties``, ``items``,
``prefixItems``, ``oneOf``, local ``$ref``). A schema using an applicator this walk does not follow
(``anyOf``, ``allOf``, ``if``, ``patternProperties``, ...) is refused when the validator is built, so a
default can never be silently skipped.
"""

from __future__ import annotations

import copy
import difflib
import json
import math
from collections.abc import Mapping, Sequence
from typing import Any

TYPE_NAMES = {
    "object": "an object",
    "array": "a list",
    "string": "a string",
    "number": "a number",
    "integer": "an integer",
    "boolean": "true or false",
    "null": "null",
}
_NOT_WALKED = (
    "allOf",
    "anyOf",
    "not",
    "if",
    "then",
    "else",
    "dependentSchemas",
    "patternProperties",
    "propertyNames",
    "contains",
    "unevaluatedItems",
    "unevaluatedProperties",
    "$dynamicRef",
)
"""Applicators the default filler does not follow (refused in a schema)."""


class SchemaViolation(Exception):
    """One schema error: ``path`` (keys and indices) and a message."""

    def __init__(self, path: Sequence[str | int], message: str):
        super().__init__(message)
        self.path = tuple(path)
        self.message = message

    def where(self) -> str:
        return format_path(self.path)


def format_path(path: Sequence[str | int]) -> str:
    """``("humans", 2, "behaviour")`` -> ``humans[2].behaviour``; ``()`` -> ``(top level)``."""
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out or "(top level)"


def describe(value: Any) -> str:
    """A short rendering of a value for messages."""
    if isinstance(value, str):
        return repr(value) if len(value) <= 40 else repr(value[:37] + "...")
    if isinstance(value, bool):
        return str(value).lower()
    if value is None:
        return "null"
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, (dict, list, tuple)):
        text = json.dumps(value, default=str)
        return text if len(text) <= 40 else text[:37] + "..."
    return repr(value)


def _json_data_problem(value: Any, path: tuple) -> SchemaViolation | None:
    """The first value outside the JSON data model (non-finite number, non-string key), in document order."""
    if isinstance(value, float) and not math.isfinite(value):
        return SchemaViolation(path, f"expected a finite number, got {describe(value)}")
    if isinstance(value, dict):
        for key, item in value.items():
            if not isinstance(key, str):
                return SchemaViolation(path, f"keys must be strings, got {describe(key)}")
            if (bad := _json_data_problem(item, (*path, key))) is not None:
                return bad
    elif isinstance(value, list):
        for k, item in enumerate(value):
            if (bad := _json_data_problem(item, (*path, k))) is not None:
                return bad
    return None


def _check_walkable(node: Any, where: str) -> None:
    if not isinstance(node, Mapping):
        return
    for key in _NOT_WALKED:
        if key in node:
            raise ValueError(
                f"schema {where}: keyword {key!r} is not supported by SchemaValidator (its defaults would not be filled)"
            )
    if isinstance(node.get("additionalProperties"), Mapping):
        raise ValueError(f"schema {where}: a schema for additionalProperties is not supported by SchemaValidator")
    ref = node.get("$ref")
    if ref is not None and not str(ref).startswith("#/"):
        raise ValueError(f"schema {where}: only local $ref are supported, got {ref!r}")
    for key in ("properties", "$defs"):
        for name, sub in node.get(key, {}).items():
            _check_walkable(sub, f"{where}/{key}/{name}")
    if "items" in node:
        _check_walkable(node["items"], f"{where}/items")
    for key in ("prefixItems", "oneOf"):
        for k, sub in enumerate(node.get(key, [])):
            _check_walkable(sub, f"{where}/{key}/{k}")


class SchemaValidator:
    """Validate plain data against a JSON Schema with ``jsonschema`` and fill in its defaults (see the module docstring)."""

    def __init__(self, schema: Mapping[str, Any]):
        from jsonschema import Draft202012Validator, SchemaError
        from jsonschema.validators import validator_for

        _check_walkable(schema, "#")
        cls = validator_for(schema, default=Draft202012Validator)
        try:
            cls.check_schema(schema)
        except SchemaError as exc:
            raise ValueError(f"schema: not a valid JSON Schema: {exc.message}") from None
        self.schema = schema
        self._validator = cls(schema)

    def validate(self, data: Any) -> Any:
        """A resolved copy of ``data`` (defaults in, numbers normalised); :class:`SchemaViolation` on the first error."""
        if (bad := _json_data_problem(data, ())) is not None:
            raise bad
        error = next(iter(self._validator.iter_errors(data)), None)
        if error is not None:
            raise self._violation(error)
        return self._fill(self.schema, data)

    # -------------------------------------------------------------------------------- messages

    def _resolve(self, node: Any) -> Any:
        while isinstance(node, Mapping) and "$ref" in node:
            target: Any = self.schema
            for part in node["$ref"][2:].split("/"):
                target = target[part]
            node = target
        return node

    def _violation(self, error) -> SchemaViolation:
        """nsim's message for one ``jsonschema.ValidationError``."""
        path = tuple(error.absolute_path)
        kw, want, node, value = error.validator, error.validator_value, error.schema, error.instance
        if kw == "oneOf":
            return self._one_of(error, path)
        if kw == "type":
            allowed = want if isinstance(want, list) else [want]
            return SchemaViolation(path, f"expected {' or '.join(TYPE_NAMES[t] for t in allowed)}, got {describe(value)}")
        if kw == "const":
            return SchemaViolation(path, f"expected {describe(want)}, got {describe(value)}")
        if kw == "enum":
            return SchemaViolation(path, f"{describe(value)} is not one of {', '.join(map(str, want))}")
        if kw in ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum"):
            return SchemaViolation(path, _bounds_message(node, value))
        if kw == "minLength":
            return SchemaViolation(path, f"expected a string of at least {want} characters, got {describe(value)}")
        if kw == "pattern":
            return SchemaViolation(path, f"{describe(value)} does not match {want}")
        if kw in ("minItems", "maxItems") or (kw == "items" and want is False):
            n = len(node.get("prefixItems", [])) if kw == "items" else want
            side = "at least" if kw == "minItems" else "at most"
            return SchemaViolation(path, f"expected {side} {n} item{'s' * (n != 1)}, got {len(value)}")
        if kw == "additionalProperties":
            props = list(node.get("properties", {}))
            key = next(k for k in value if k not in props)
            near = difflib.get_close_matches(key, props, n=1, cutoff=0.7)
            hint = f" (did you mean '{near[0]}'?)" if near else ""
            return SchemaViolation((*path, key), f"unknown key{hint}; valid keys: {', '.join(props)}")
        if kw == "required":
            key = next(k for k in want if k not in value)
            return SchemaViolation((*path, key), "required key is missing")
        if kw is None:  # the schema `false`
            return SchemaViolation(path, "no value is allowed here")
        return SchemaViolation(path, error.message)

    def _one_of(self, error, path: tuple) -> SchemaViolation:
        keys = [self._resolve(b).get("required", []) if isinstance(b, Mapping) else [] for b in error.validator_value]
        options = ", ".join("/".join(k) for k in keys)
        if not error.context:  # no error inside: more than one branch matched
            return SchemaViolation(path, f"matches more than one of the forms with {options}")
        value = error.instance
        if isinstance(value, dict):
            candidates = [k for k, req in enumerate(keys) if req and all(r in value for r in req)]
            if len(candidates) == 1:
                first = next(e for e in error.context if e.relative_schema_path[0] == candidates[0])
                return self._violation(first)
        return SchemaViolation(path, f"expected an object with exactly one of the keys {options}, got {describe(value)}")

    # -------------------------------------------------------------------------------- defaults

    def _fill(self, node: Any, value: Any) -> Any:
        """``value`` (valid against ``node``) with defaults in and numbers normalised: a new object."""
        node = self._resolve(node)
        if not isinstance(node, Mapping):  # `true` (anything), or `false` (never reached: the data is valid)
            return copy.deepcopy(value)
        if "oneOf" in node:
            branch = next(b for b in node["oneOf"] if self._validator.evolve(schema=b).is_valid(value))
            value = self._fill(branch, value)
        types = node.get("type", [])
        types = types if isinstance(types, list) else [types]
        if isinstance(value, bool):
            pass
        elif isinstance(value, int) and "number" in types and "integer" not in types:
            value = float(value)  # canonical: a number field holds floats
        elif isinstance(value, float) and "integer" in types and value.is_integer():
            value = int(value)  # JSON Schema: 2.0 is an integer
        if isinstance(value, list):
            prefix, rest = node.get("prefixItems", []), node.get("items", True)
            return [self._fill(prefix[k] if k < len(prefix) else rest, item) for k, item in enumerate(value)]
        if isinstance(value, dict):
            props = node.get("properties", {})
            out = {}
            for key, sub in props.items():
                if key in value:
                    out[key] = self._fill(sub, value[key])
                elif isinstance(resolved := self._resolve(sub), Mapping) and "default" in resolved:
                    out[key] = copy.deepcopy(resolved["default"])
            for key in value:
                if key not in props:
                    out[key] = copy.deepcopy(value[key])
            return out
        return value


def _bounds_message(node: Mapping[str, Any], value: float) -> str:
    """``expected a number > 0 and <= 0.5, got -0.05``: every bound of ``node``, as the old messages."""
    bounds = [
        f"{sym} {node[key]:g}"
        for key, sym in (("exclusiveMinimum", ">"), ("minimum", ">="), ("exclusiveMaximum", "<"), ("maximum", "<="))
        if key in node
    ]
    types = node.get("type", [])
    tname = "an integer" if "integer" in (types if isinstance(types, list) else [types]) else "a number"
    return f"expected {tname} {' and '.join(bounds)}, got {describe(value)}"
