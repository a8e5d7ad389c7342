"""What a build folder holds, for the readers that need no field (the CLI's export, the viewer,
rerun recordings): the map's name and the rule for reusing the map a build wrote itself.
No torch: a build's own map is read with numpy and zarr."""

from __future__ import annotations

import math
from pathlib import Path

from scenelabel.errors import InputError
from scenelabel.maps import OccupancyMap

__all__ = ["MAP_NAME", "CHECKPOINT_FILE", "own_map"]

MAP_NAME = "map.zarr"
"""The occupancy map a build writes into its folder (``scenelabel.train.pipeline``)."""

CHECKPOINT_FILE = "checkpoint.pt"
"""The checkpoint's name in a build folder (``scenelabel.fields.checkpoint.CHECKPOINT_NAME``; named
here too so that reading a build's map does not import torch)."""


def own_map(build_dir: str | Path, voxel_size: float | None = None) -> OccupancyMap | None:
    """The map a build wrote itself (``BUILD/map.zarr``), when it is at least as new as the
    checkpoint and has ``voxel_size`` (any, when None): evaluating the field again would give the
    same map, minutes later on a large room. None when there is no such map (none written, training
    resumed after it was written, another voxel size asked, or a store that does not read).
    """
    build_dir = Path(build_dir)
    path, checkpoint = build_dir / MAP_NAME, build_dir / CHECKPOINT_FILE
    if not (path.is_dir() and checkpoint.is_file()):
        return None
    if path.stat().st_mtime < checkpoint.stat().st_mtime:  # trained on (resumed) after the map was written
        return None
    try:
        occ = OccupancyMap.from_zarr(path)
    except InputError:
        return None
    if voxel_size is not None and not math.isclose(occ.voxel_size, voxel_size, rel_tol=1e-9):
        return None
    return occ
