"""Write a field's occupancy map chunk by chunk straight into a zarr store: bounded memory, in
this process or on a Dask cluster.

:func:`write_occupancy_map` writes the store :meth:`OccupancyMap.to_zarr` writes for
``SemanticField.occupancy_map(...)`` (same arrays, attributes, pyramid and NGFF metadata, same
atomic tmp-then-rename), without ever holding the map's arrays whole (but for the ESDF of pass 4,
which needs a level whole: ``esdf=False`` skips it)::

    from scenelabel.query.map_writer import write_occupancy_map
    write_occupancy_map("room/scenelabel", "room.zarr", 0.02)                 # this process
    from distributed import Client
    with Client("tcp://scheduler:8786") as client:                            # a Dask cluster
        write_occupancy_map("/shared/room/scenelabel", "/shared/room.zarr", 0.02, client=client)

Only orchestration lives here; the maths is :func:`scenelabel.query.mapping.evaluate_map_block` (one block
of the lattice), :func:`scenelabel.maps.visibility.camera_surfaces` / :func:`observed_centres` (the
visibility rule) and :func:`scenelabel.maps.pool_block` (the pyramid), the same functions
``occupancy_map`` and ``OccupancyMap.downsample`` use.

Passes, each over zarr chunks (a task writes whole chunks, so concurrent writers never share one):

1. evaluate the field per chunk and write ``label``, ``occupancy``, ``probs``, ``confidence``;
2. read the opacities back from ``occupancy`` as uint8 codes (one byte per voxel, the one global
   array), cast the training cameras' small depth maps through them once to their surfaces
   (transmittance 0.5; plus the field's surfaces outside the map's box when ``bounds`` cut the
   field), then per chunk make the surface voxels occupied and apply the visibility rule;
3. write each pyramid level's chunks from level 0 (a coarse voxel pools its ``2^L``³ level-0
   children, exactly as ``OccupancyMap.downsample(2 ** L)``);
4. per level, in this process: read ``label`` back chunk by chunk into a bool obstacle mask of the
   whole level (1 byte per voxel), run the distance transform (it needs the whole grid) and write
   ``esdf`` chunk by chunk (:func:`scenelabel.maps.zarr_io.write_esdf`, the values
   ``OccupancyMap.esdf()`` gives).

With a ``distributed.Client`` each chunk is a task; tasks get the checkpoint's path and every
worker process loads the field once (cached by path and modification time), so the checkpoint
and the store must be on a filesystem every worker sees.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from scenelabel._cores import update_share
from scenelabel.errors import CheckpointError, InputError
from scenelabel.fields.checkpoint import CHECKPOINT_NAME
from scenelabel.maps import (
    CONFIDENCE_ARRAY,
    DEFAULT_CHUNKS,
    FREE,
    LABEL_ARRAY,
    LEVELS_GROUP,
    OCCUPANCY_ARRAY,
    PROBS_ARRAY,
    PYRAMID_FACTOR,
    QUANTISED_DTYPE,
    UNKNOWN,
    OccupancyMap,
    array_chunks,
    block_centers,
    iter_chunks,
    pool_block,
    uint8_from_unit,
)
from scenelabel.maps.pyramid import check_levels
from scenelabel.maps.visibility import CameraSurfaces, camera_surfaces, observed_centres, surface_mask
from scenelabel.maps.zarr_io import check_target, level_group, root_attributes, staged_group, write_esdf
from scenelabel.query import mapping
from scenelabel.query.field import SemanticField

__all__ = ["write_occupancy_map", "MAX_EXPORT_VOXELS", "EVAL_BLOCK"]

MAX_EXPORT_VOXELS = 1 << 33
"""write_occupancy_map refuses lattices larger than this (8.6e9 voxels: an 8 GiB grid of opacity codes)."""

EVAL_BLOCK = 32
"""The field is evaluated at most this many voxels per axis at a time (as ``occupancy_map``'s
default ``chunk``): bounds the memory of a task whatever the zarr chunks."""

_ARRAYS = (LABEL_ARRAY, OCCUPANCY_ARRAY, PROBS_ARRAY, CONFIDENCE_ARRAY)

Block = tuple[slice, slice, slice]


# --------------------------------------------------------------------------------------------
# The field, once per process
# --------------------------------------------------------------------------------------------

class _Checkpoint(NamedTuple):
    """What a task gets instead of the field: the checkpoint file and its modification time."""

    path: str  # absolute
    mtime_ns: int


_FIELD_LOCK = threading.Lock()
_FIELD_CACHE: dict[_Checkpoint, SemanticField] = {}


def _checkpoint(source: str | Path) -> _Checkpoint:
    """The checkpoint file of a build folder or checkpoint path, as it is now."""
    path = Path(source).expanduser().resolve()
    if path.is_dir():
        path = path / CHECKPOINT_NAME
    if not path.is_file():
        raise CheckpointError(f"{path}: no checkpoint here (expected a build folder or {CHECKPOINT_NAME})")
    return _Checkpoint(str(path), path.stat().st_mtime_ns)


def _cached_field(checkpoint: _Checkpoint) -> SemanticField:
    """The field of a checkpoint, loaded once per process (cached by path and modification
    time; one field at a time is kept). Raises CheckpointError when the file changed since
    ``checkpoint`` was taken (every chunk of a map must come from the same field)."""
    try:
        mtime_ns = Path(checkpoint.path).stat().st_mtime_ns
    except OSError as err:
        raise CheckpointError(f"{checkpoint.path}: cannot read the checkpoint ({err.strerror or err})") from None
    if mtime_ns != checkpoint.mtime_ns:
        raise CheckpointError(f"{checkpoint.path}: the checkpoint changed while the map was being written; export again")
    with _FIELD_LOCK:
        field = _FIELD_CACHE.get(checkpoint)
        if field is None:
            _FIELD_CACHE.clear()
            field = _FIELD_CACHE[checkpoint] = SemanticField.load(checkpoint.path)
        return field


def _field(source: SemanticField | _Checkpoint) -> SemanticField:
    return source if isinstance(source, SemanticField) else _cached_field(source)


# --------------------------------------------------------------------------------------------
# Tasks (module-level: a worker imports them; arguments are small and picklable)
# --------------------------------------------------------------------------------------------


def _open_arrays(store: str, level: int = 0) -> dict[str, Any]:
    """The arrays of pyramid level ``level`` of the map being written at ``store``."""
    import zarr

    group = zarr.open_group(store, mode="r+")
    if level:
        group = group[f"{LEVELS_GROUP}/{level}"]
    return {name: group[name] for name in _ARRAYS}


def _evaluate_chunk(
    source: SemanticField | _Checkpoint, store: str, origin: np.ndarray, voxel_size: float, chunk: Block
) -> None:
    """Pass 1: evaluate the field on one zarr chunk of level 0 and write its four arrays.

    The chunk is evaluated in blocks of at most :data:`EVAL_BLOCK` voxels per axis, on this job's
    share of the cores (:func:`scenelabel._cores.update_share`).
    """
    update_share()
    field = _field(source)
    shape = tuple(s.stop - s.start for s in chunk)
    label = np.empty(shape, np.int16)
    occupancy = np.empty(shape, np.float32)
    probs = np.empty((*shape, field.class_map.num_classes), QUANTISED_DTYPE)
    confidence = np.empty(shape, QUANTISED_DTYPE)
    for local in iter_chunks(shape, EVAL_BLOCK):
        block = tuple(slice(c.start + s.start, c.start + s.stop) for c, s in zip(chunk, local))
        label[local], occupancy[local], probs[local], confidence[local] = mapping.evaluate_map_block(field, origin, voxel_size, block)
    arrays = _open_arrays(store)
    for name, data in zip(_ARRAYS, (label, occupancy, probs, confidence)):
        arrays[name][chunk] = data


def _visibility_inputs(
    source: SemanticField | _Checkpoint, origin: np.ndarray, voxel_size: float, shape: tuple[int, int, int]
):
    """:func:`scenelabel.query.mapping.map_visibility_inputs` (a task: the occluders march the field)."""
    return mapping.map_visibility_inputs(_field(source), origin, voxel_size, shape)


def _apply_visibility_chunk(
    store: str, origin: np.ndarray, voxel_size: float, chunk: Block, surfaces: CameraSurfaces, class_ids: list[int]
) -> int:
    """Pass 2: in one zarr chunk of level 0, make the voxels a camera's surface lies in occupied
    (the class of their most probable ``probs`` channel, occupancy raised to the threshold), then mark the voxels no camera observed
    UNKNOWN (occupancy, probs and confidence 0 there).

    Returns:
        how many voxels became UNKNOWN.
    """
    arrays = _open_arrays(store)
    label = arrays[LABEL_ARRAY][chunk]
    surface = surface_mask(surfaces, chunk) & (label == FREE)
    if surface.any():
        block = (label, arrays[OCCUPANCY_ARRAY][chunk], arrays[PROBS_ARRAY][chunk])
        mapping.mark_surfaces(block, surface, np.asarray(class_ids))
        arrays[OCCUPANCY_ARRAY][chunk] = block[1]
    known = np.flatnonzero(label.reshape(-1) != UNKNOWN)  # outside the bounds: UNKNOWN already
    centres = block_centers(origin, voxel_size, chunk)[known]  # [K, 3]
    seen = observed_centres(centres, label.reshape(-1)[known] >= 0, voxel_size, surfaces)  # [K]
    unseen = np.zeros(label.size, dtype=bool)
    unseen[known[~seen]] = True
    unseen = unseen.reshape(label.shape)
    if unseen.any():
        others = tuple(arrays[name][chunk] for name in (OCCUPANCY_ARRAY, PROBS_ARRAY, CONFIDENCE_ARRAY))
        mapping.clear_unseen((label, *others), unseen)
        for name, data in zip((OCCUPANCY_ARRAY, PROBS_ARRAY, CONFIDENCE_ARRAY), others):
            arrays[name][chunk] = data
    if unseen.any() or surface.any():
        arrays[LABEL_ARRAY][chunk] = label
    return int(unseen.sum())


def _pool_chunk(store: str, level: int, chunk: Block, fine_chunks: tuple[int, int, int], class_ids: list[int]) -> None:
    """Pass 3: one zarr chunk of pyramid level ``level`` >= 1 from its level-0 children.

    The chunk is pooled in blocks whose level-0 region is at most ``max(fine_chunks, 2^L)``
    voxels per axis (:func:`scenelabel.maps.pool_block`, so exactly ``downsample(2 ** L)``).
    """
    factor = PYRAMID_FACTOR**level
    fine = _open_arrays(store)
    fine_shape = fine[LABEL_ARRAY].shape
    shape = tuple(s.stop - s.start for s in chunk)
    out = {
        LABEL_ARRAY: np.empty(shape, np.int16),
        OCCUPANCY_ARRAY: np.empty(shape, np.float32),
        PROBS_ARRAY: np.empty((*shape, len(class_ids)), QUANTISED_DTYPE),
        CONFIDENCE_ARRAY: np.empty(shape, QUANTISED_DTYPE),
    }
    step = tuple(max(1, c // factor) for c in fine_chunks)
    for local in iter_chunks(shape, step):
        region = tuple(
            slice((c.start + s.start) * factor, min((c.start + s.stop) * factor, n))
            for c, s, n in zip(chunk, local, fine_shape)
        )
        pooled = pool_block(
            fine[LABEL_ARRAY][region], fine[OCCUPANCY_ARRAY][region], fine[PROBS_ARRAY][region], factor, class_ids
        )
        for name, data in zip(_ARRAYS, pooled):
            out[name][local] = data
    coarse = _open_arrays(store, level)
    for name, data in out.items():
        coarse[name][chunk] = data


# --------------------------------------------------------------------------------------------
# Running the tasks: a loop here, or futures on a cluster
# --------------------------------------------------------------------------------------------


def _run(client: Any, fn: Callable, calls: Sequence[tuple], desc: str, progress: bool) -> list:
    """``[fn(*args) for args in calls]``, in this process (client None) or as tasks of ``client``.

    On a cluster every task is waited for, even after one failed, before the first error is
    raised: no task is still writing into the store when the caller removes it.
    """
    from tqdm.auto import tqdm

    if client is None:
        return [fn(*args) for args in tqdm(calls, desc=desc, disable=not progress, leave=False)]
    from distributed import as_completed

    futures = [client.submit(fn, *args, pure=False) for args in calls]
    failed = None
    try:
        with tqdm(total=len(futures), desc=desc, disable=not progress, leave=False) as bar:
            for future in as_completed(futures):
                if failed is None and future.status == "error":
                    failed = future
                bar.update()
    except BaseException:
        client.cancel(futures)
        raise
    if failed is not None:
        failed.result()  # raises the task's exception
    return client.gather(futures)


def _header(field: SemanticField, voxel_size: float, origin: np.ndarray, unknown_rule: str) -> OccupancyMap:
    """A one-voxel stand-in carrying the map's metadata: its attributes, its pyramid's voxel
    sizes and origins (``pyramid()``) and its arrays' metadata never depend on the arrays."""
    n_classes = field.class_map.num_classes
    return OccupancyMap(
        label=np.full((1, 1, 1), UNKNOWN, np.int16),
        occupancy=np.zeros((1, 1, 1), np.float32),
        voxel_size=voxel_size,
        origin=origin,
        probs=np.zeros((1, 1, 1, n_classes), QUANTISED_DTYPE),
        confidence=np.zeros((1, 1, 1), QUANTISED_DTYPE),
        **mapping.map_metadata(field, voxel_size, unknown_rule),
    )


def write_occupancy_map(
    source: SemanticField | str | Path,
    path: str | Path,
    voxel_size: float | None = None,
    *,
    bounds=None,
    zarr_format: int = 3,
    chunks: tuple[int, int, int] = DEFAULT_CHUNKS,
    levels: int | None = None,
    visibility: bool = True,
    overwrite: bool = True,
    client: Any = None,
    progress: bool = False,
    esdf: bool = True,
) -> Path:
    """Evaluate a field's occupancy map chunk by chunk straight into a zarr store.

    The store equals ``field.occupancy_map(voxel_size, bounds, visibility=visibility)
    .to_zarr(path, zarr_format, chunks, levels=levels, esdf=esdf)``: the same arrays, attributes, pyramid
    levels and OME-NGFF metadata (docs/formats.md), written the same way (into a hidden sibling
    ``.NAME.tmp-PID``, root group attributes last, renamed into place; on any error, a task's
    included, the target is left as it was).

    Memory: the map's arrays are never held whole (the ESDF's pass aside, below). A task holds one
    zarr chunk of each array (pass 1 evaluates it :data:`EVAL_BLOCK`³ voxels at a time; a pyramid
    chunk reads its level-0 children in blocks of at most ``max(chunks, 2^L)`` per axis). The one
    global array of passes 1 to 3 is the grid of opacity codes, ``[nx, ny, nz]`` uint8 (1 byte
    per voxel), read back from ``occupancy`` chunk by chunk in this process to cast the training
    cameras' depth maps through it (at most 80 pixels wide, two float64 maps per camera, and the
    voxels their surfaces lie in), which every visibility task then gets. The ``esdf`` arrays
    (pass 4) cost more, in this
    process: the Euclidean distance transform needs a level whole, so ``label`` is read back into
    a bool obstacle mask (1 byte per voxel) and scipy's feature transform (int32, 12 bytes per
    voxel) plus the float32 result make about 19 bytes per voxel of level 0 at the peak (19 GB
    for 10^9 voxels); ``esdf=False`` leaves them out.

    Args:
        source: a build folder or its checkpoint.pt (tasks load the field from it, once per
            process), or a loaded :class:`SemanticField` (this process only).
        path: the target directory (``*.zarr``); with a client, on a filesystem every worker
            sees, as must the checkpoint be.
        voxel_size: voxel edge, world units (default: the field's ``default_voxel_size``).
        bounds: (2, 3) world box to cover (default: the modelled bounds, cut to the observed
            geometry: :func:`scenelabel.query.mapping.map_lattice`).
        zarr_format: 3 (default) or 2.
        chunks: spatial chunk shape of every array (clipped to each level's shape): the unit of
            work and of memory.
        levels: pyramid levels, level 0 included; None: :func:`scenelabel.maps.default_levels`.
        visibility: mark voxels no training camera observed as UNKNOWN (as ``occupancy_map``).
        overwrite: replace an existing zarr group at ``path``; otherwise raise.
        client: a ``distributed.Client``: each chunk becomes a task on its cluster; None: a loop
            in this process.
        progress: tqdm progress bars, one per pass.
        esdf: write the ``esdf`` arrays (as ``to_zarr(esdf=True)``, the default) and attributes.
    Returns:
        the absolute path written.
    Raises:
        InputError: bad arguments (as ``occupancy_map`` and ``to_zarr``), a lattice of more
            than :data:`MAX_EXPORT_VOXELS` voxels, a loaded field together with a client.
        CheckpointError: no readable checkpoint at ``source``.
    """
    import zarr

    zarr_format, chunks, path = check_target(path, zarr_format, chunks, overwrite)
    if isinstance(source, SemanticField):
        if client is not None:
            raise InputError(
                "with a client, pass the build folder or checkpoint path: workers load the field from it", field="source"
            )
        field = task_source = source
    else:
        task_source = _checkpoint(source)
        field = _cached_field(task_source)
    voxel_size, origin, shape = mapping.map_lattice(field, voxel_size, bounds, max_voxels=MAX_EXPORT_VOXELS)
    n_levels = check_levels(levels, shape)
    vis_future = None
    if visibility and client is not None:  # the occluders march the field: a task, beside pass 1
        vis_future = client.submit(_visibility_inputs, task_source, origin, voxel_size, shape, pure=False)

    with staged_group(path) as tmp:
        store = str(tmp)
        root = zarr.open_group(store, mode="w", zarr_format=zarr_format)
        draft = _header(field, voxel_size, origin, "bounds")  # metadata of the arrays
        level_shapes = [tuple(-(-n // PYRAMID_FACTOR**level) for n in shape) for level in range(n_levels)]
        groups = [root] + [level_group(root, level) for level in range(1, n_levels)]
        for group, level_shape in zip(groups, level_shapes):
            draft.create_arrays(group, zarr_format, chunks, level_shape, esdf=esdf)
        level0 = list(iter_chunks(shape, array_chunks(chunks, shape)))

        # pass 1: the field, chunk by chunk
        _run(client, _evaluate_chunk, [(task_source, store, origin, voxel_size, c) for c in level0], "map: evaluate", progress)

        # pass 2: the visibility rule
        if not visibility:
            inputs = None
        elif vis_future is not None:
            inputs = vis_future.result()
        else:
            inputs = _visibility_inputs(field, origin, voxel_size, shape)
        if inputs is not None:
            cameras, occluders = inputs
            occupancy = root[OCCUPANCY_ARRAY]
            codes = np.zeros(shape, dtype=QUANTISED_DTYPE)  # the one global array: 1 byte per voxel
            for c in level0:
                codes[c] = uint8_from_unit(occupancy[c])
            surfaces = camera_surfaces(codes, origin, voxel_size, cameras, occluders)
            del codes
            shared = surfaces if client is None else client.scatter(surfaces, broadcast=True)
            class_ids = field.class_ids.tolist()
            calls = [(store, origin, voxel_size, c, shared, class_ids) for c in level0]
            _run(client, _apply_visibility_chunk, calls, "map: visibility", progress)

        # pass 3: the pyramid, every level from level 0
        pyramid = _header(field, voxel_size, origin, "visibility" if inputs is not None else "bounds").pyramid(n_levels)
        class_ids = field.class_ids.tolist()
        fine_chunks = array_chunks(chunks, shape)
        calls = [
            (store, level, c, fine_chunks, class_ids)
            for level in range(1, n_levels)
            for c in iter_chunks(level_shapes[level], array_chunks(chunks, level_shapes[level]))
        ]
        _run(client, _pool_chunk, calls, "map: pyramid", progress)

        # pass 4: each level's ESDF from its labels, here (the distance transform needs the whole level)
        if esdf:
            for group, level_map in zip(groups, pyramid):
                write_esdf(group, level_map.voxel_size)
        for level in range(1, n_levels):
            groups[level].attrs.update(pyramid[level].group_attributes(level, n_levels, esdf=esdf))
        root.attrs.update(root_attributes(pyramid, zarr_format, esdf=esdf))  # last: marks the map complete
    return path
