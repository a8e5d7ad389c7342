"""scenelabel: photos + 2D masks -> a queryable 3D semantic radiance field and occupancy map.

Public API (numpy in, numpy out)::

    from scenelabel import SemanticField
    field = SemanticField.load("room/scenelabel")
    q = field.query_points(xyz)                 # density, occupancy, probs, label
    r = field.query_rays(origins, directions)   # rgb, depth, opacity, probs, label
    baked = BakedField.from_field(field)     # the same questions from a lattice, without the network
    m = field.occupancy_map(voxel_size=0.05)
    m.to_zarr("room.zarr")
    write_occupancy_map("room/scenelabel", "room.zarr", 0.02)   # chunk by chunk (client=: a Dask cluster)
"""

from importlib import import_module

from scenelabel._version import __version__
from scenelabel.errors import CheckpointError, ConfigError, InputError, ScenelabelError, TrainingError

# Public name -> the module that defines it. Imported on first use (PEP 562), so that reading a
# map (scenelabel.maps) never imports torch, OpenCV or numba.
_HOMES = {
    "BakedField": "scenelabel.query.baked",
    "SceneOutcome": "scenelabel.train.batch",
    "build_many": "scenelabel.train.batch",
    "BuildConfig": "scenelabel.config",
    "DataConfig": "scenelabel.config",
    "FieldConfig": "scenelabel.config",
    "OutputConfig": "scenelabel.config",
    "SamplingConfig": "scenelabel.config",
    "TrainConfig": "scenelabel.config",
    "preset": "scenelabel.config",
    "load_scene": "scenelabel.data.io",
    "write_occupancy_map": "scenelabel.query.map_writer",
    "FREE": "scenelabel.maps",
    "UNKNOWN": "scenelabel.maps",
    "OccupancyMap": "scenelabel.maps",
    "BuildResult": "scenelabel.train.pipeline",
    "build": "scenelabel.train.pipeline",
    "Cameras": "scenelabel.geometry.cameras",
    "ClassMap": "scenelabel.data.scene",
    "Scene": "scenelabel.data.scene",
    "Segmenter": "scenelabel.data.segmenters",
    "load_segmenter": "scenelabel.data.segmenters",
    "segment_scene": "scenelabel.data.segmenters",
    "PointQuery": "scenelabel.query.field",
    "RayQuery": "scenelabel.query.field",
    "RenderResult": "scenelabel.query.field",
    "SemanticField": "scenelabel.query.field",
    "SfmResult": "scenelabel.data.sfm",
    "run_sfm": "scenelabel.data.sfm",
    "write_furnished_room": "scenelabel.data.synthetic",
    "write_toy_scene": "scenelabel.data.synthetic",
    "log_rerun": "scenelabel.viz.rerun_log",
}


def __getattr__(name: str):
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module 'scenelabel' has no attribute {name!r}")
    value = getattr(import_module(home), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


__all__ = [
    "__version__",
    "SemanticField",
    "BakedField",
    "PointQuery",
    "RayQuery",
    "RenderResult",
    "OccupancyMap",
    "write_occupancy_map",
    "FREE",
    "UNKNOWN",
    "build",
    "BuildResult",
    "build_many",
    "SceneOutcome",
    "load_scene",
    "run_sfm",
    "SfmResult",
    "Segmenter",
    "load_segmenter",
    "segment_scene",
    "Scene",
    "Cameras",
    "ClassMap",
    "BuildConfig",
    "DataConfig",
    "FieldConfig",
    "SamplingConfig",
    "TrainConfig",
    "OutputConfig",
    "preset",
    "write_toy_scene",
    "log_rerun",
    "write_furnished_room",
    "ScenelabelError",
    "InputError",
    "ConfigError",
    "TrainingError",
    "CheckpointError",
]
