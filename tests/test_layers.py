"""The package's shape, checked from its source (ast): stages import only stages below them, no
module imports another's private names or reaches into another's private attributes, and no
modules import each other in a cycle. The layer table is the data flow of README's "Layout"."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

import scenelabel

PACKAGE = Path(scenelabel.__file__).resolve().parent

# Lowest first. A module may import modules of its own layer or of a lower one, never a higher one.
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("core", ("scenelabel.errors", "scenelabel._version", "scenelabel._files", "scenelabel._cores", "scenelabel.config",
              "scenelabel.metrics", "scenelabel.codes")),
    ("geometry", ("scenelabel.geometry",)),
    ("data", ("scenelabel.data",)),
    ("maps", ("scenelabel.maps",)),
    ("render", ("scenelabel.render",)),
    ("fields", ("scenelabel.fields",)),
    ("query", ("scenelabel.query",)),
    ("viz", ("scenelabel.viz",)),  # pictures, rerun recordings, the web viewer: below train, whose renders use it
    ("train", ("scenelabel.train",)),
    ("interface", ("scenelabel.cli", "scenelabel.__main__", "scenelabel")),
)

# Names that look private but are Python's or a library's own protocol, not another module's.
ALLOWED_PRIVATE_ATTRIBUTES = {"_replace", "_asdict", "_fields"}  # namedtuple API


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def layer_of(module: str) -> int:
    best, best_len = None, -1
    for index, (_, prefixes) in enumerate(LAYERS):
        for prefix in prefixes:
            if (module == prefix or module.startswith(prefix + ".")) and len(prefix) > best_len:
                best, best_len = index, len(prefix)
    if best is None:
        raise AssertionError(f"{module} is in no layer of LAYERS: add it to the table")
    return best


def _resolve(node: ast.ImportFrom, module: str, is_package: bool) -> str:
    if node.level == 0:
        return node.module or ""
    base = module.split(".") if is_package else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def imports_of(module: str) -> list[tuple[str, str | None, int]]:
    """(imported scenelabel module, imported name or None, line) for every import in ``module``
    outside ``if TYPE_CHECKING:`` blocks; ``from pkg import submodule`` counts as importing the
    submodule."""
    path = MODULES[module]
    tree = ast.parse(path.read_text(), str(path))
    type_only = {
        id(n)
        for block in ast.walk(tree)
        if isinstance(block, ast.If) and isinstance(block.test, ast.Name) and block.test.id == "TYPE_CHECKING"
        for n in ast.walk(block)
    }
    found = []
    for node in ast.walk(tree):
        if id(node) in type_only:  # annotations only: not imported at run time
            continue
        if isinstance(node, ast.Import):
            found += [(a.name, None, node.lineno) for a in node.names if a.name.split(".")[0] == "scenelabel"]
        elif isinstance(node, ast.ImportFrom):
            target = _resolve(node, module, path.name == "__init__.py")
            if target.split(".")[0] != "scenelabel":
                continue
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                found.append((sub, None, node.lineno) if sub in MODULES else (target, alias.name, node.lineno))
    return found


def test_every_module_has_a_layer():
    for module in MODULES:
        layer_of(module)


def test_no_stage_imports_a_higher_one():
    bad = []
    for module in MODULES:
        for target, _, line in imports_of(module):
            if target in MODULES and layer_of(target) > layer_of(module):
                bad.append(f"{module}:{line} imports {target} ({LAYERS[layer_of(target)][0]} is above {LAYERS[layer_of(module)][0]})")
    assert not bad, "\n".join(bad)


def test_no_private_name_crosses_modules():
    bad = []
    for module in MODULES:
        for target, name, line in imports_of(module):
            if name is not None and name.startswith("_") and not name.startswith("__") and target != module:
                bad.append(f"{module}:{line} imports {target}.{name}")
    assert not bad, "\n".join(bad)


def _own_private_names(tree: ast.Module) -> set[str]:
    """Private names a module defines itself: functions, classes, methods and attributes it assigns."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
            names.add(node.attr)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            names.add(node.id)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
    return {n for n in names if n.startswith("_")}


def test_no_private_attribute_of_another_module_is_read():
    """``x._name`` only for a ``_name`` the module defines itself (its classes' internals, on
    ``self`` or on another instance of the same class), never another module's: what a module
    needs from another is public."""
    bad = []
    for module, path in MODULES.items():
        tree = ast.parse(path.read_text(), str(path))
        own = _own_private_names(tree)
        for node in ast.walk(tree):
            if not isinstance(node, ast.Attribute):
                continue
            attr = node.attr
            if not attr.startswith("_") or attr.startswith("__") or attr in ALLOWED_PRIVATE_ATTRIBUTES | own:
                continue
            bad.append(f"{module}:{node.lineno} reads .{attr}")
    assert not bad, "\n".join(bad)


def test_no_import_cycle():
    graph = {m: sorted({t for t, _, _ in imports_of(m) if t in MODULES and t != m}) for m in MODULES}
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for n in graph[m]:
            if state.get(n) == 1:
                return stack[stack.index(n):] + [n]
            if n not in state and (cycle := visit(n)):
                return cycle
        stack.pop()
        state[m] = 2
        return None

    for m in graph:
        if m not in state and (cycle := visit(m)):
            pytest.fail("import cycle: " + " -> ".join(cycle))


@pytest.mark.parametrize("module", ["scenelabel", "scenelabel.maps", "scenelabel.maps.exports"])
def test_reading_maps_needs_no_torch(module):
    """A planner process reads maps, casts rays and exports without torch (or OpenCV, numba)."""
    code = f"import sys, {module}; heavy = [m for m in ('torch', 'cv2', 'numba') if m in sys.modules]; assert not heavy, heavy"
    subprocess.run([sys.executable, "-c", code], check=True)


MAX_MODULE_LINES = 650
MAX_PARAMETERS = 10
# Public entry points whose keyword arguments are the published API (README, docs): kept as they
# are rather than broken for the rule. Everything else obeys it.
PUBLIC_API_EXCEPTIONS = {
    "scenelabel.query.field:render",  # c2w, size, intrinsics, smoothing, axes, distortion, near, far
    "scenelabel.query.map_writer:write_occupancy_map",  # occupancy_map's and to_zarr's options, a client
    "scenelabel.geometry.cameras:create",  # one argument per field of the Cameras dataclass it builds
}


def test_modules_stay_short():
    """One concept per module: none much over ~600 lines."""
    long = {m: n for m, p in MODULES.items() if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES}
    assert not long, long


def test_functions_take_at_most_ten_parameters():
    """More than ten parameters means a config dataclass or a smaller function is missing."""
    bad = []
    for module, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                a = node.args
                params = [x.arg for x in a.posonlyargs + a.args + a.kwonlyargs if x.arg not in ("self", "cls")]
                if len(params) > MAX_PARAMETERS and f"{module}:{node.name}" not in PUBLIC_API_EXCEPTIONS:
                    bad.append(f"{module}:{node.lineno} {node.name} takes {len(params)}")
    assert not bad, "\n".join(bad)
