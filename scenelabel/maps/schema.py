"""The JSON Schema of a map's zarr group attributes (``scenelabel/schemas/occupancy_map.schema.json``)
and the check of attributes against it.
"""

from __future__ import annotations

import functools
import json
from importlib import resources
from pathlib import Path
from typing import Any, Mapping

from scenelabel.errors import InputError
from scenelabel.maps.codes import SCHEMA_FILE

__all__ = ["load_schema", "validate_attributes"]


@functools.lru_cache(maxsize=1)
def _schema_text() -> str:
    return resources.files("scenelabel").joinpath("schemas", SCHEMA_FILE).read_text(encoding="utf-8")


def load_schema() -> dict:
    """The JSON Schema (draft 2020-12) of the map's zarr group attributes (a fresh copy)."""
    return json.loads(_schema_text())


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
    import jsonschema

    attrs = dict(attrs)
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
    ids = [c["id"] for c in attrs["classes"]]
    if len(set(ids)) != len(ids):
        raise InputError(f"class ids must be unique, got {ids}", path=path, field="classes")
