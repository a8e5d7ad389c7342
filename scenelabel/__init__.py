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

from ._version import __version__
from .baking import BakedField
from .batch import SceneOutcome, build_many
from .config import BuildConfig, DataConfig, FieldConfig, OutputConfig, SamplingConfig, TrainConfig, preset
from .errors import CheckpointError, ConfigError, InputError, ScenelabelError, TrainingError
from .io import load_scene
from .map_export import write_occupancy_map
from .maps import FREE, UNKNOWN, OccupancyMap
from .pipeline import BuildResult, build
from .scene import Cameras, ClassMap, Scene
from .segmenters import Segmenter, load_segmenter, segment_scene
from .semantic_field import PointQuery, RayQuery, RenderResult, SemanticField
from .sfm import SfmResult, run_sfm
from .synthetic import write_furnished_room, write_toy_scene

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
    "write_furnished_room",
    "ScenelabelError",
    "InputError",
    "ConfigError",
    "TrainingError",
    "CheckpointError",
]
