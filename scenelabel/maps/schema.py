"""The JSON Schema of a map's zarr group attributes (``scenelabel/schemas/occupancy_map.schema.json``)
and the check of attributes against it.

Loading a map checks its attributes, and importing jsonschema alone takes longer than reading a
small map: :func:`quick_check` first decides the keywords this schema uses the way jsonschema
does (Draft 2020-12), and jsonschema runs only when that check finds a problem (to name it) or
meets something it does not decide.
"""

from __future__ import annotations

import functools
import json
import numbers
from importlib import resources
from pathlib import Path
from typing import Any, Callable, Mapping

from scenelabel.errors import InputError
from scenelabel.maps.codes import SCHEMA_FILE

__all__ = ["load_schema", "validate_attributes", "quick_check"]


@functools.lru_cache(maxsize=1)
def _schema_text() -> str:
    return resources.files("scenelabel").joinpath("schemas", SCHEMA_FILE).read_text(encoding="utf-8")


def load_schema() -> dict:
    """The JSON Schema (draft 2020-12) of the map's zarr group attributes (a fresh copy)."""
    return json.loads(_schema_text())


@functools.lru_cache(maxsize=1)
def _schema() -> dict:
    return load_schema()


# ---- the quick check: True / False where jsonschema would say valid / invalid, None where it does not decide

_ANNOTATIONS = frozenset(  # no check of their own ("then" / "else": under "if")
    {"$schema", "$id", "$comment", "$defs", "title", "description", "default", "examples", "then", "else"}
)
_TYPES: dict[str, Callable[[Any], bool]] = {  # jsonschema's Draft 2020-12 type checker
    "integer": lambda x: not isinstance(x, bool) and (isinstance(x, int) or (isinstance(x, float) and x.is_integer())),
    "number": lambda x: not isinstance(x, bool) and isinstance(x, numbers.Number),
    "string": lambda x: isinstance(x, str),
    "array": lambda x: isinstance(x, list),
    "object": lambda x: isinstance(x, dict),
    "boolean": lambda x: isinstance(x, bool),
    "null": lambda x: x is None,
}


def _equal(a: Any, b: Any) -> bool | None:
    """jsonschema's equality of scalars (True is not 1, 1 is 1.0); None for containers."""
    if a is b or isinstance(a, str) or isinstance(b, str):
        return a is b or a == b
    if isinstance(a, (list, tuple, dict)) or isinstance(b, (list, tuple, dict)):
        return None
    if isinstance(a, bool) or isinstance(b, bool):
        return isinstance(a, bool) and isinstance(b, bool) and a == b
    return a == b


def _all(results) -> bool | None:
    """False if any is False, else None if any is None, else True (results: an iterable)."""
    undecided = False
    for result in results:
        if result is False:
            return False
        undecided |= result is None
    return None if undecided else True


def _type(value: Any, x: Any) -> bool | None:
    names = [value] if isinstance(value, str) else value
    return any(_TYPES[name](x) for name in names) if set(names) <= set(_TYPES) else None


def _enum(value: list, x: Any) -> bool | None:
    found = [_equal(x, each) for each in value]
    return True if True in found else (None if None in found else False)


def _ref(value: str, x: Any, root: dict) -> bool | None:
    name = value.removeprefix("#/$defs/")
    if not value.startswith("#/$defs/") or name not in root.get("$defs", {}):
        return None
    return quick_check(x, root["$defs"][name], root)


def _one_of(results: list) -> bool | None:
    return None if None in results else sum(results) == 1


def _if_then_else(condition: bool | None, x: Any, schema: dict, root: dict) -> bool | None:
    if condition is None:
        return None
    branch = schema.get("then" if condition else "else")
    return True if branch is None else quick_check(x, branch, root)


def _number(x: Any) -> bool:
    return _TYPES["number"](x)


# keyword -> (its value, the instance, the schema holding it, the root schema) -> bool | None; each
# keyword as jsonschema applies it (numeric, length and item keywords ignore other types)
_KEYWORDS: dict[str, Callable[[Any, Any, dict, dict], bool | None]] = {
    "type": lambda v, x, s, r: _type(v, x),
    "const": lambda v, x, s, r: _equal(x, v),
    "enum": lambda v, x, s, r: _enum(v, x),
    "required": lambda v, x, s, r: not isinstance(x, dict) or all(k in x for k in v),
    "properties": lambda v, x, s, r: not isinstance(x, dict) or _all(quick_check(x[k], v[k], r) for k in v if k in x),
    "additionalProperties": lambda v, x, s, r: True if v is True else None,
    "items": lambda v, x, s, r: not isinstance(x, list) or _all(quick_check(item, v, r) for item in x),
    "minItems": lambda v, x, s, r: not isinstance(x, list) or not len(x) < v,
    "maxItems": lambda v, x, s, r: not isinstance(x, list) or not len(x) > v,
    "minLength": lambda v, x, s, r: not isinstance(x, str) or not len(x) < v,
    "minimum": lambda v, x, s, r: not _number(x) or not x < v,
    "maximum": lambda v, x, s, r: not _number(x) or not x > v,
    "exclusiveMinimum": lambda v, x, s, r: not _number(x) or not x <= v,
    "allOf": lambda v, x, s, r: _all(quick_check(x, sub, r) for sub in v),
    "oneOf": lambda v, x, s, r: _one_of([quick_check(x, sub, r) for sub in v]),
    "if": lambda v, x, s, r: _if_then_else(quick_check(x, v, r), x, s, r),
    "$ref": lambda v, x, s, r: _ref(v, x, r),
}


def quick_check(instance: Any, schema: Any = None, root: Any = None) -> bool | None:
    """Whether ``instance`` is valid under ``schema`` (default: the map attributes' schema), as
    jsonschema (Draft 2020-12) decides it, for the keywords that schema uses: True or False; None
    for a keyword or a value this check does not decide (jsonschema must then be asked)."""
    if schema is None:
        schema = root = _schema()
    if isinstance(schema, bool):
        return schema
    if not isinstance(schema, dict):
        return None
    checks = []
    for key, value in schema.items():
        if key in _ANNOTATIONS:
            continue
        if key not in _KEYWORDS:
            return None
        checks.append((_KEYWORDS[key], value))
    return _all(check(value, instance, schema, root if root is not None else schema) for check, value in checks)


@functools.lru_cache(maxsize=1)
def _validator():
    import jsonschema

    schema = load_schema()
    jsonschema.Draft202012Validator.check_schema(schema)
    return jsonschema.Draft202012Validator(schema)


def validate_attributes(attrs: Mapping[str, Any], path: str | Path | None = None) -> None:
    """Check a map's group attributes against ``schemas/occupancy_map.schema.json``.

    Beyond the schema, class ids must be unique. Unknown extra attributes are allowed.

    Args:
        attrs: the zarr group attributes (a JSON-like dict).
        path: the map's path, used in the error message.
    Raises:
        InputError naming the path and the first offending attribute.
    """
    attrs = dict(attrs)
    if quick_check(attrs) is not True:  # jsonschema names the problem (or decides what the quick check does not)
        _raise_first_error(attrs, path)
    ids = [c["id"] for c in attrs["classes"]]
    if len(set(ids)) != len(ids):
        raise InputError(f"class ids must be unique, got {ids}", path=path, field="classes")


def _raise_first_error(attrs: dict, path: str | Path | None) -> None:
    """InputError naming jsonschema's best match among the attributes' errors (none: return)."""
    import jsonschema

    error = jsonschema.exceptions.best_match(_validator().iter_errors(attrs))
    if error is not None:
        where = "/".join(str(p) for p in error.absolute_path)
        if error.validator == "required":
            # error.message is "'voxel_size' is a required property"; name the attribute itself.
            missing = [k for k in error.validator_value if k not in error.instance]
            where = "/".join([where, missing[0]]) if where and missing else (missing[0] if missing else where)
            problem = f"missing required attribute {missing[0]!r}" if missing else error.message
        else:
            problem = f"invalid attribute: {error.message}"
        raise InputError(problem, path=path, field=where or None)
