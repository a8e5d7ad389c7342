"""The map as an OctoMap: a binary occupancy OcTree (``.bt``) or a ColorOcTree with class colours (``.ot``).

Written with pyoctomap (the OctoMap C++ library's Python bindings), imported only when a file is
written or read, so ``import scenelabel.maps.exports`` stays light. The layouts are documented in
docs/formats.md ("Exports", "OctoMap").

**Cells.** OctoMap's grid is fixed: with resolution ``res``, world coordinate ``x`` lies in the
cell of key ``floor(x / res) + 2^15`` (16-bit keys, 65536 cells per axis, centred on the world
origin; cell ``key`` covers ``[(key - 2^15) res, (key - 2^15 + 1) res)``). Voxel ``[i, j, k]`` of
the map (centre ``origin + voxel_size * (i, j, k)``) becomes the leaf of key
``base + (i, j, k)``, ``base = floor(origin / res) + 2^15`` per axis (:func:`octomap_base_key`):
the cell that holds the voxel centre, so one voxel is exactly one leaf. The leaf's centre is the
voxel centre moved by ``(base - 2^15 + 0.5) res - origin`` (:func:`octomap_shift`, each
component in ``(-res/2, res/2]``): 0 when the map's voxels already lie on OctoMap's cells (origin
= an odd multiple of ``res / 2``), ``+res/2`` when the voxel centres lie on cell boundaries
(origin a multiple of ``res``; the voxel goes to the cell above its centre).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from scenelabel._files import atomic_write_bytes
from scenelabel.errors import InputError, ScenelabelError
from scenelabel.maps.codes import FREE
from scenelabel.maps.exports.palette import class_palette, color_lookup
from scenelabel.maps.exports.ply import frame_comments
from scenelabel.maps.occupancy_map import OccupancyMap

__all__ = [
    "FREE_MAX_LOG_ODDS",
    "KEYS_PER_AXIS",
    "KEY_OFFSET",
    "OCTOMAP_SUFFIXES",
    "P_CLAMP_MAX",
    "P_CLAMP_MIN",
    "octomap_base_key",
    "octomap_log_odds",
    "octomap_resolution",
    "octomap_shift",
    "read_octomap",
    "write_octomap",
]

OCTOMAP_SUFFIXES = (".bt", ".ot")
KEY_OFFSET = 1 << 15  # OctoMap's tree_max_val: the cell [0, res) has key 2^15
KEYS_PER_AXIS = 1 << 16  # 16-bit keys: cells 0 .. 65535 per axis
TREE_DEPTH = 16
# OctoMap's default clamping thresholds (OccupancyOcTreeBase: clamping_thres_min / _max), log-odds
# about -2.0 and 3.51: the range OctoMap itself keeps every node in.
P_CLAMP_MIN = 0.1192
P_CLAMP_MAX = 0.971
# FREE voxels are stored at most at this log-odds (occupancy 0.49975), strictly below OctoMap's
# occupancy threshold 0.5 (log-odds 0), so that they read back as free whatever the map's own
# occupancy_threshold.
FREE_MAX_LOG_ODDS = -1e-3
# An origin / res within this of the next integer counts as on it (float noise of a grid-aligned origin).
_ALIGN_TOL = 1e-6
# Keys per updateNodes call (bounds the Python key objects alive at once).
_KEY_BATCH = 1 << 18


def _octomap_path(path: str | Path) -> Path:
    path = Path(path).expanduser()
    if path.suffix.lower() not in OCTOMAP_SUFFIXES:
        raise InputError(
            "an OctoMap file name must end in .bt (binary occupancy OcTree) or .ot (ColorOcTree with class colours)",
            path=path,
        )
    if not path.parent.is_dir():
        raise InputError("the parent folder does not exist", path=path.parent)
    return path


def octomap_resolution(occ_map: OccupancyMap) -> float:
    """The tree's resolution: ``voxel_size`` to 6 significant digits.

    OctoMap writes ``res`` in the file header with C++'s default stream precision (6 significant
    digits); the tree is built at that value so that the file and the keys computed here agree.
    """
    return float(f"{occ_map.voxel_size:.6g}")


def octomap_base_key(occ_map: OccupancyMap, path: str | Path | None = None) -> np.ndarray:
    """The OctoMap key of voxel [0, 0, 0]; voxel [i, j, k] has key ``base + (i, j, k)``.

    ``base = floor(origin / res) + 2^15`` per axis (``origin / res`` within 1e-6 below an integer
    counts as that integer, so a grid-aligned origin does not flip cells on float noise).

    Args:
        occ_map: the map.
        path: the file being written, named in the error (or None).
    Returns:
        [3] int64 key of voxel [0, 0, 0].
    Raises:
        InputError: the map's keys leave OctoMap's range 0 .. 65535 on some axis (the map is wider
            than 65536 voxels, or lies farther than 32768 voxels from the world origin).
    """
    res = octomap_resolution(occ_map)
    base = np.floor(occ_map.origin / res + _ALIGN_TOL) + KEY_OFFSET  # [3] float64
    last = base + np.asarray(occ_map.shape, dtype=np.float64) - 1.0  # [3]
    for axis, name in enumerate("xyz"):
        if base[axis] < 0 or last[axis] > KEYS_PER_AXIS - 1:
            lo, hi = -KEY_OFFSET * res, KEY_OFFSET * res
            raise InputError(
                f"the map does not fit OctoMap's key range: along {name} its {occ_map.shape[axis]} voxels would take "
                f"keys {base[axis]:.0f} to {last[axis]:.0f}, but OctoMap has {KEYS_PER_AXIS} cells per axis (keys 0 to "
                f"{KEYS_PER_AXIS - 1}, world {name} in [{lo:g}, {hi:g}) at voxel size {res:g}); crop the map or "
                "export it at a coarser voxel size",
                path=path,
            )
    return base.astype(np.int64)


def octomap_shift(occ_map: OccupancyMap) -> np.ndarray:
    """[3] float64: the leaf centre of voxel [i, j, k] minus the voxel's centre (each in ``(-res/2, res/2]``)."""
    res = octomap_resolution(occ_map)
    return (octomap_base_key(occ_map) - KEY_OFFSET + 0.5) * res - occ_map.origin


def octomap_log_odds(occupancy: np.ndarray, label: np.ndarray) -> np.ndarray:
    """The log-odds stored for voxels in a ``.ot`` file.

    ``L = log(p / (1 - p))`` with ``p`` the occupancy clipped to ``[P_CLAMP_MIN, P_CLAMP_MAX]`` =
    [0.1192, 0.971], OctoMap's default clamping thresholds (log-odds about [-2.0, 3.51]): finite
    at occupancy 0 and 1, the range OctoMap keeps its own nodes in (so that later sensor updates in
    OctoMap / MoveIt can still change a node within a few hits or misses), and it makes the
    confidently empty voxels identical, so large free regions prune into few leaves. Then the
    label decides the side of OctoMap's occupancy threshold (0.5, log-odds 0; a node is occupied
    when ``L >= 0``): class voxels get at least 0, FREE voxels at most ``FREE_MAX_LOG_ODDS``
    (-0.001). For scenelabel's maps (occupancy_threshold 0.5) only the first clip changes values.

    Args:
        occupancy: [N] float in [0, 1].
        label: [N] int, class id >= 0 or FREE (-1) (UNKNOWN voxels are not stored).
    Returns:
        [N] float32 log-odds.
    """
    p = np.clip(np.asarray(occupancy, dtype=np.float64), P_CLAMP_MIN, P_CLAMP_MAX)  # [N]
    log_odds = np.log(p / (1.0 - p))
    occupied = np.asarray(label) >= 0
    log_odds = np.where(occupied, np.maximum(log_odds, 0.0), np.minimum(log_odds, FREE_MAX_LOG_ODDS))
    return log_odds.astype(np.float32)


def _header_comments(occ_map: OccupancyMap, color: bool) -> bytes:
    """Comment lines for the file header (OctoMap's readers skip lines starting with ``#``)."""
    base = octomap_base_key(occ_map)
    shift = octomap_shift(occ_map)
    lines = [f"scenelabel map; {frame_comments(occ_map)[0]}"]
    lines.append(
        f"voxel [i j k] -> key ({base[0]} {base[1]} {base[2]}) + (i j k); leaf centre = voxel centre + "
        f"({shift[0]:.9g} {shift[1]:.9g} {shift[2]:.9g})"
    )
    if color:
        for cid, rgb in class_palette(occ_map.classes, occ_map.class_colors).items():
            lines.append(f"class {cid} {occ_map.classes[cid]}: rgb {rgb[0]} {rgb[1]} {rgb[2]}")
    text = "".join(f"# {' '.join(line.split())}\n" for line in lines)
    return text.encode("ascii", "backslashreplace")


def _with_comments(data: bytes, comments: bytes) -> bytes:
    """``data`` (an OctoMap file) with ``comments`` inserted after its first line (which readers check)."""
    first, rest = data.split(b"\n", 1)
    return first + b"\n" + comments + rest


def _present_voxels(occ_map: OccupancyMap, base: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The voxels that become leaves (label FREE or a class; UNKNOWN is left out), in C order.

    Args:
        base: [3] int64 key of voxel [0, 0, 0] (:func:`octomap_base_key`).
    Returns:
        keys: [N, 3] int64 OctoMap keys.
        label: [N] int16 class id or FREE.
        occupancy: [N] float32.
    """
    present = occ_map.label >= FREE  # [nx, ny, nz]
    keys = base + np.argwhere(present)  # [N, 3]
    return keys, occ_map.label[present], occ_map.occupancy[present]


def _columns(array: np.ndarray) -> list[list[int]]:
    """[N, C] integers -> C lists of N Python ints (flat lists: much faster to build than N rows)."""
    return [array[:, col].tolist() for col in range(array.shape[1])]


def _binary_tree(po: Any, res: float, keys: np.ndarray, occupied: np.ndarray) -> Any:
    """An OcTree with occupied / free leaves at ``keys`` (maximum-likelihood values, as in a .bt)."""
    tree = po.OcTree(res)
    key_type = po.OcTreeKey
    for mask, log_odds in ((occupied, tree.getClampingThresMaxLog()), (~occupied, tree.getClampingThresMinLog())):
        chosen = keys[mask]
        for start in range(0, len(chosen), _KEY_BATCH):
            batch = [key_type(a, b, c) for a, b, c in zip(*_columns(chosen[start : start + _KEY_BATCH]))]
            tree.updateNodes(batch, float(log_odds), True)
    if len(keys):
        tree.updateInnerOccupancy()
    return tree


def _color_tree(po: Any, res: float, keys: np.ndarray, log_odds: np.ndarray, rgb: np.ndarray) -> Any:
    """A ColorOcTree with a leaf of value ``log_odds`` and colour ``rgb`` at each key.

    Args:
        keys: [N, 3] int64; log_odds: [N] float32; rgb: [N, 3] uint8 (rows of white 255, 255,
            255 are left unset: OctoMap's "no colour").
    """
    tree = po.ColorOcTree(res)
    key_type = po.OcTreeKey
    for a, b, c, value in zip(*_columns(keys), log_odds.tolist()):
        tree.updateNode(key_type(a, b, c), value, True)
    colored = np.flatnonzero(np.any(rgb != 255, axis=1))
    for a, b, c, r, g, bl in zip(*_columns(keys[colored]), *_columns(rgb[colored])):
        tree.setNodeColor(key_type(a, b, c), r, g, bl)
    if len(keys):  # OctoMap's ColorOcTree::updateInnerOccupancy dereferences the root: crashes on an empty tree
        tree.updateInnerOccupancy()
    return tree


def _uniform_blocks(keys: np.ndarray, codes: np.ndarray):
    """The inner nodes whose 8 children are leaves with one code, finest first (what may be pruned).

    Args:
        keys: [N, 3] int64 distinct leaf keys (depth 16).
        codes: [N] int64 what a leaf holds (two leaves with one code are interchangeable).
    Yields:
        (level, [M, 3] int64 keys): nodes of edge ``2^level`` cells (depth ``16 - level``), each
        named by the key of its min corner, to collapse after the levels before.
    """
    for level in range(1, TREE_DEPTH):  # depth 16 - level >= 1: the root is never collapsed
        if not len(keys):
            return
        parent = keys >> 1  # [N, 3]
        packed = (parent[:, 0] << 32) | (parent[:, 1] << 16) | parent[:, 2]  # [N]
        order = np.argsort(packed, kind="stable")
        packed, codes = packed[order], codes[order]
        starts = np.flatnonzero(np.r_[True, packed[1:] != packed[:-1]])  # first child of each parent
        counts = np.diff(np.r_[starts, len(packed)])
        lo, hi = np.minimum.reduceat(codes, starts), np.maximum.reduceat(codes, starts)
        keep = (counts == 8) & (lo == hi)
        if not keep.any():
            return
        keys, codes = parent[order[starts[keep]]], lo[keep]
        yield level, keys << level


def _prune_color_tree(po: Any, tree: Any, keys: np.ndarray, codes: np.ndarray) -> None:
    """Collapse exactly the blocks of :func:`_uniform_blocks` (same value **and** colour).

    ColorOcTree's own ``prune`` compares values only and averages the children's colours, which
    would blend the colours of two classes at equal log-odds; this prunes node by node instead.
    """
    key_type = po.OcTreeKey
    for level, block_keys in _uniform_blocks(keys, codes):
        for a, b, c in zip(*_columns(block_keys)):
            node = tree.search(key_type(a, b, c), TREE_DEPTH - level)
            tree.pruneNode(node)


def write_octomap(occ_map: OccupancyMap, path: str | Path) -> Path:
    """Write the map as an OctoMap file: ``.bt`` (binary OcTree) or ``.ot`` (ColorOcTree).

    One leaf per voxel with a class (occupied) or FREE (free); UNKNOWN voxels get no node
    (OctoMap's "unknown" is a missing node). Voxel [i, j, k] is the cell of key
    ``octomap_base_key(occ_map) + (i, j, k)``, the cell holding its centre; the leaf centre is the
    voxel centre + :func:`octomap_shift` (0 when the map's origin is an odd multiple of
    ``res / 2``, +res/2 when it is a multiple of ``res``; see the module docstring). The
    resolution is ``voxel_size`` (to 6 significant digits, what OctoMap's header holds).

    - ``.bt``: occupancy only, as OctoMap's binary format stores it: occupied leaves at the
      clamping maximum (0.971), free ones at the minimum (0.1192) after reading.
    - ``.ot``: a ColorOcTree (OctoMap's full format): each leaf's log-odds from the voxel's
      occupancy (:func:`octomap_log_odds`: clipped to OctoMap's clamping range [0.1192, 0.971] so
      that 0 and 1 stay finite, class voxels >= 0 and FREE < 0) and each occupied leaf the colour
      of its class (:func:`~scenelabel.maps.exports.class_palette`); free leaves carry no colour.

    The tree is pruned: 8 sibling leaves that are the same (occupied or free in a ``.bt``; the
    same log-odds and colour in a ``.ot``) become one node, so large free regions compress.
    Comment lines after the header's first line give the frame, the key of voxel [0, 0, 0], the
    shift and (``.ot``) the class colours; OctoMap's readers skip them.

    Args:
        occ_map: the map.
        path: the ``.bt`` or ``.ot`` file to write (replaced if present).
    Returns:
        the path written.
    Raises:
        InputError: ``path`` does not end in .bt or .ot, its folder does not exist, or the map
            does not fit OctoMap's 65536 cells per axis (:func:`octomap_base_key`).
    """
    path = _octomap_path(path)
    keys, label, occupancy = _present_voxels(occ_map, octomap_base_key(occ_map, path))  # [N, 3], [N], [N]
    res = octomap_resolution(occ_map)
    import pyoctomap as po

    if path.suffix.lower() == ".bt":
        tree = _binary_tree(po, res, keys, label >= 0)
        data = tree.writeBinary()  # OctoMap converts to maximum likelihood and prunes, then serialises
    else:
        log_odds = octomap_log_odds(occupancy, label)  # [N] float32
        rgb = np.full((len(label), 3), 255, np.uint8)  # [N, 3]
        occupied = label >= 0
        rgb[occupied] = color_lookup(class_palette(occ_map.classes, occ_map.class_colors), label[occupied])
        tree = _color_tree(po, res, keys, log_odds, rgb)
        # one int64 per leaf: the log-odds' bits and the colour (equal codes = interchangeable leaves)
        packed_rgb = rgb.astype(np.int64) @ np.array([1 << 16, 1 << 8, 1])  # [N]
        codes = (log_odds.view(np.uint32).astype(np.int64) << 24) | packed_rgb
        _prune_color_tree(po, tree, keys, codes)
        data = tree.write()
    if not isinstance(data, bytes):
        raise ScenelabelError(f"{path}: pyoctomap could not serialise the tree")
    return atomic_write_bytes(path, _with_comments(data, _header_comments(occ_map, color=path.suffix.lower() == ".ot")))


def read_octomap(path: str | Path) -> Any:
    """Read an OctoMap file with pyoctomap: a ``.bt`` as ``pyoctomap.OcTree``, a ``.ot`` as ``pyoctomap.ColorOcTree``.

    Args:
        path: a ``.bt`` or ``.ot`` file.
    Returns:
        the tree (``tree.search(np.array([x, y, z]))`` gives a node or None, ``tree.isNodeOccupied(node)``,
        ``node.getLogOdds()``, ``node.getColor()`` for a ColorOcTree).
    Raises:
        InputError: the name does not end in .bt or .ot, or the file is missing or not an OctoMap
            (a ``.ot`` must hold a ColorOcTree).
    """
    path = Path(path).expanduser()
    if path.suffix.lower() not in OCTOMAP_SUFFIXES:
        raise InputError("an OctoMap file name must end in .bt or .ot", path=path)
    if not path.is_file():
        raise InputError("file not found", path=path)
    if path.suffix.lower() == ".ot":  # pyoctomap takes any tree type for a ColorOcTree: check the header first
        with path.open("rb") as f:
            head = f.read(1 << 16).split(b"\ndata\n", 1)[0].splitlines()
        ids = [line.split()[1] for line in head if line.startswith(b"id ") and len(line.split()) > 1]
        if ids[:1] != [b"ColorOcTree"]:
            found = ids[0].decode(errors="replace") if ids else "none"
            raise InputError(f"not a ColorOcTree file (its header says id {found})", path=path)
    import pyoctomap as po

    if path.suffix.lower() == ".bt":
        tree = po.OcTree(0.1)
        ok = tree.readBinary(str(path))
    else:
        try:
            tree = po.ColorOcTree(str(path))
            ok = True
        except OSError:
            ok = False
    if not ok:
        raise InputError("not a readable OctoMap file", path=path)
    return tree
