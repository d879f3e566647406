"""nsim.crowd.schema: jsonschema's errors as nsim's one-line messages, and the schema's defaults filled in."""

from __future__ import annotations

import pytest

from nsim.crowd.schema import SchemaValidator, SchemaViolation

SCHEMA = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "type": "object",
    "additionalProperties": False,
    "required": ["shape"],
    "properties": {
        "shape": {
            "oneOf": [
                {
                    "type": "object",
                    "required": ["r"],
                    "properties": {"r": {"type": "number", "exclusiveMinimum": 0}, "n": {"type": "integer", "default": 8}},
                },
                {"type": "object", "required": ["w"], "properties": {"w": {"$ref": "#/$defs/width"}}},
            ]
        },
        "tags": {"type": "array", "prefixItems": [{"type": "string"}], "items": False},
        "count": {"type": "integer", "minimum": 1, "maximum": 9, "default": 3},
    },
    "$defs": {"width": {"type": "number", "minimum": 0.5}},
}


def _error(data) -> SchemaViolation:
    with pytest.raises(SchemaViolation) as err:
        SchemaValidator(SCHEMA).validate(data)
    return err.value


@pytest.mark.parametrize(
    "data, where, message",
    [
        ({"shape": {"r": 1, "w": 1}}, "shape", "matches more than one of the forms with r, w"),
        ({"shape": {"w": 0.1}}, "shape.w", "expected a number >= 0.5, got 0.1"),
        ({"shape": {"r": -1}}, "shape.r", "expected a number > 0, got -1"),
        ({"shape": 3}, "shape", "expected an object with exactly one of the keys r, w, got 3"),
        ({"shape": {"r": 1}, "tags": ["a", "b"]}, "tags", "expected at most 1 item, got 2"),
        ({"shape": {"r": 1}, 3: 1}, "(top level)", "keys must be strings, got 3"),
        ({"shape": {"r": float("nan")}}, "shape.r", "expected a finite number, got nan"),
        ({"shape": {"r": 1}, "count": 2.5}, "count", "expected an integer, got 2.5"),
        ({"shape": {"r": 1}, "count": 10}, "count", "expected an integer >= 1 and <= 9, got 10"),
        ({"shape": {"r": 1}, "cuont": 2}, "cuont", "unknown key (did you mean 'count'?); valid keys: shape, tags, count"),
        ({}, "shape", "required key is missing"),
    ],
)
def test_errors_name_the_field(data, where, message):
    err = _error(data)
    assert (err.where(), err.message) == (where, message)


def test_first_error_in_document_order():
    # unknown keys, then missing ones, then each property in the schema's order
    assert _error({"tags": [1], "count": 0, "x": 1}).where() == "x"
    assert _error({"tags": [1], "count": 0}).where() == "shape"
    assert _error({"shape": {"r": 1}, "tags": [1], "count": 0}).where() == "tags[0]"


def test_defaults_are_filled_and_numbers_normalised():
    data = {"shape": {"r": 2}}
    out = SchemaValidator(SCHEMA).validate(data)
    assert out == {"shape": {"r": 2.0, "n": 8}, "count": 3}
    assert isinstance(out["shape"]["r"], float) and isinstance(out["count"], int)
    assert data == {"shape": {"r": 2}}  # the input is untouched
    out = SchemaValidator(SCHEMA).validate({"shape": {"w": 1}, "count": 4.0})
    assert out == {"shape": {"w": 1.0}, "count": 4} and isinstance(out["count"], int)


@pytest.mark.parametrize(
    "schema, message",
    [
        ({"type": "object", "anyOf": [{"type": "object"}]}, "'anyOf' is not supported"),
        ({"properties": {"a": {"if": {}, "then": {}}}}, "'if' is not supported"),
        ({"additionalProperties": {"default": 1}}, "a schema for additionalProperties is not supported"),
        ({"properties": {"a": {"$ref": "other.json#/x"}}}, "only local \\$ref"),
        ({"type": 3}, "not a valid JSON Schema"),
    ],
)
def test_schemas_whose_defaults_it_cannot_fill_are_refused(schema, message):
    with pytest.raises(ValueError, match=message):
        SchemaValidator(schema)
