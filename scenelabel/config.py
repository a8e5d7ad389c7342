"""Configuration: small flat dataclasses, one per stage, with named presets.

Unknown keys are an error (:func:`config_from_dict`); the resolved config is saved with each
checkpoint (:func:`config_to_dict`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from scenelabel.errors import ConfigError

__all__ = [
    "DataConfig",
    "FieldConfig",
    "SamplingConfig",
    "TrainConfig",
    "OutputConfig",
    "BuildConfig",
    "PRESETS",
    "AUTO_PRESET",
    "preset",
    "with_preset",
    "AUTO",
    "DISTORTION_AUTO_WEIGHT",
    "DISTORTION_THIN_MAX",
    "SENSOR_FREE_MARGIN",
    "LAYOUT_FREE_MARGIN",
    "LAYOUT_OPEN_RAYS",
    "POINTS_PAD",
    "config_from_dict",
    "config_to_dict",
    "render_background",
]


def _check_choice(name: str, value, allowed: tuple[str, ...]) -> None:
    if value not in allowed:
        raise ConfigError(f"unknown {name} {value!r}; choose one of {list(allowed)}")


POINTS_PAD = 0.1
"""Bounds from observed points are padded by this fraction of their longest side on every face
(:func:`scenelabel.geometry.frame.aabb_from_points`): a wall whose observed points fall short of
its plane (a coarse field's depth errs both ways) is still inside the box. ``data.bounds_pad``."""


@dataclass
class DataConfig:
    """How the scene folder is read (saved with the checkpoint, so a resumed build reads it alike)."""

    downscale: int = 1  # shrink images by this integer factor (LLFF-style images_N/ folders are used when present)
    scale: float | None = None  # multiply the input's world units by this (e.g. metres per COLMAP unit); None: 1
    # a video input (scenelabel.data.video): frames kept per second of video (the sharpest of each run of
    # consecutive frames, blurred ones dropped), and at most this many frames in all
    video_frames_per_second: float = 3.0
    video_max_frames: int = 150
    # without sensor depth: the floor, wall and ceiling pixels of the training views get the depth of the room's
    # layout, found where their masks meet (scenelabel.data.layout_depth), and the build trains on it as on sensor
    # depth; with sensor depth, the layout fills the sensor's holes on those pixels (a far wall beyond a phone's
    # range). Only where the classes name a floor and walls. layout_mounted: so do the pixels of classes that hang
    # flat on walls (geometry.layout.WALL_MOUNTED_CLASSES: pictures, posters, mirrors), the wall's depth behind them
    layout_depth: bool = True
    layout_mounted: bool = True
    # where the input has no near/far or aabb, the bounds of the observed points (sensor depth, the
    # room's layout, or a coarse fit) are padded by this fraction of their longest side on every face
    bounds_pad: float = POINTS_PAD

    def __post_init__(self) -> None:
        if isinstance(self.downscale, bool) or not isinstance(self.downscale, int) or self.downscale < 1:
            raise ConfigError(f"data.downscale must be an integer >= 1, got {self.downscale!r}")
        if self.scale is not None and not (isinstance(self.scale, (int, float)) and 0 < self.scale < float("inf")):
            raise ConfigError(f"data.scale must be a positive finite number, got {self.scale!r}")
        fps = self.video_frames_per_second
        if isinstance(fps, bool) or not (isinstance(fps, (int, float)) and 0 < fps < float("inf")):
            raise ConfigError(f"data.video_frames_per_second must be a positive finite number, got {fps!r}")
        n = self.video_max_frames
        if isinstance(n, bool) or not isinstance(n, int) or n < 2:
            raise ConfigError(f"data.video_max_frames must be an integer >= 2, got {n!r}")
        for key in ("layout_depth", "layout_mounted"):
            if not isinstance(getattr(self, key), bool):
                raise ConfigError(f"data.{key} must be true or false, got {getattr(self, key)!r}")
        pad = self.bounds_pad
        if isinstance(pad, bool) or not (isinstance(pad, (int, float)) and 0 <= pad <= 1):
            raise ConfigError(f"data.bounds_pad must be a number in [0, 1], got {pad!r}")


@dataclass
class FieldConfig:
    """The network: encoding + heads (see scenelabel.fields)."""

    encoding: str = "triplane"  # triplane | dense | positional (NeRF's frequency encoding)
    resolutions: tuple[int, ...] = (64, 128)  # tri-plane levels (plane side, cells)
    channels: int = 8  # features per plane / voxel
    plane_cells: str = "square"  # square: r x r planes over the box | cubic: fields.encodings.cubic_plane_vertices
    grid_resolution: int = 96  # dense grid: cells along the cube's longest side (the others in proportion: fields.model.dense_grid_shape)
    pe_frequencies: int = 10  # positional encoding of points: frequencies 2^0..2^(n-1)
    # mlp: networks read the encoding | direct: no network, a dense grid's channels are σ, rgb and
    # class logits themselves (Plenoxels / DVGO style; view-independent colour)
    head: str = "mlp"
    hidden: int = 64  # width of the trunk's and heads' hidden layers
    layers: int = 2  # linear layers of the trunk (NeRF: 8)
    skip_layer: int | None = None  # the encoded point is concatenated again before this trunk layer (NeRF: 5)
    view_dependent: bool = True  # colour depends on view direction
    view_encoding: str = "sh"  # sh: spherical harmonics degree 2 | positional: pe_view_frequencies
    pe_view_frequencies: int = 4
    density_bias: float = -1.0  # σ = exp(raw + density_bias) (trunc_exp): low initial density
    # the colour sigmoid's gradient is at least its slope at this |logit| (fields.model.live_sigmoid; 0: the
    # plain sigmoid's): a channel driven deep while the field is still transparent can learn again.
    # The default preset sets 4 (docs/suite_phone_depth_live.md); the others were not measured with it
    colour_live_logit: float = 0.0
    class_head: str = "linear"  # linear: scalar σ + class head (eq. 6) | density: per-class σ_j (eq. 5)
    density_combine: str = "sum"  # with class_head=density: σ = sum_j σ_j or max_j σ_j (eq. 4)
    semantic_rendering: str = "probs"  # probs: composite softmax per sample (eq. 7) | scores: softmax after (eq. 3)

    def __post_init__(self) -> None:
        _check_choice("field.encoding", self.encoding, ("triplane", "dense", "positional"))
        _check_choice("field.view_encoding", self.view_encoding, ("sh", "positional"))
        _check_choice("field.head", self.head, ("mlp", "direct"))
        _check_choice("field.plane_cells", self.plane_cells, ("square", "cubic"))
        if self.head == "direct" and self.encoding != "dense":
            raise ConfigError(f"field.head 'direct' reads a dense grid's channels: set field.encoding 'dense', not {self.encoding!r}")
        if self.head == "direct" and self.view_dependent:
            raise ConfigError("field.head 'direct' stores one colour per vertex: set field.view_dependent false")
        if not (isinstance(self.grid_resolution, int) and self.grid_resolution >= 2):
            raise ConfigError(f"field.grid_resolution must be an integer >= 2, got {self.grid_resolution!r}")
        if not (isinstance(self.layers, int) and self.layers >= 2):
            raise ConfigError(f"field.layers must be an integer >= 2, got {self.layers!r}")
        if self.skip_layer is not None and not (isinstance(self.skip_layer, int) and 0 < self.skip_layer < self.layers):
            raise ConfigError(f"field.skip_layer must be None or in 1..{self.layers - 1}, got {self.skip_layer!r}")
        live = self.colour_live_logit
        if isinstance(live, bool) or not (isinstance(live, (int, float)) and math.isfinite(live) and live >= 0):
            raise ConfigError(f"field.colour_live_logit must be a finite number >= 0, got {live!r}")
        _check_choice("field.class_head", self.class_head, ("linear", "density"))
        _check_choice("field.density_combine", self.density_combine, ("sum", "max"))
        _check_choice("field.semantic_rendering", self.semantic_rendering, ("probs", "scores"))


@dataclass
class SamplingConfig:
    """Where samples go along rays and how empty space is skipped."""

    n_steps: int = 192  # marching steps across the scene box diagonal (sets the step size); disparity: per ray
    warp: str = "auto"  # box: uniform cells over the scene box | forward: frustum cells, disparity steps (LLFF-style) | auto
    grid_resolution: int = 64  # density grid side
    grid_update_every: int = 16  # training steps between occupancy-grid refreshes
    grid_warmup: int = 16  # steps before the first refresh (all cells occupied until then)
    alpha_threshold: float = 0.005  # a cell is occupied if one step through it is this opaque
    # each refresh keeps max(decay x a cell's remembered density, its density now): a cell the field
    # has emptied stays occupied until its early density has decayed below the threshold. "auto":
    # GRID_DECAY_WITH_DEPTH where the training rays carry sensor depth (and train.depth_weight > 0),
    # else GRID_DECAY; the build saves the number it chose
    grid_decay: float | str = "auto"
    # true: each training step's samples also raise their cells' remembered density to the largest σ
    # seen there, besides the refreshes' one random point per cell. Measured and left off: no better
    # on the suite's rooms, and it did not keep tools/bench.py's lamp pole (docs/suite_grid.md, where
    # it was on and variant no-grid-from-training off; docs/bench_grid.md; docs/models.md)
    grid_from_training: bool = False
    # each training step, this share of its rays, those with the largest colour error, re-open the
    # density-grid cells from their start to their rendered depth (render.sampling.DensityGrid.reopen):
    # a thin object the grid emptied before the field had learnt it is sampled again (0: off);
    # until grid_reopen_until of the run. Measured and left off: lower mIoU on the suite's rooms,
    # builds 1.25x as long, one diverged (docs/suite_reopen.md; docs/models.md)
    grid_reopen: float = 0.0
    grid_reopen_until: float = 0.5
    # which rays re-open: "colour", the largest colour error; "labels", among the rays whose rendered
    # class is wrong, the largest cross-entropy (a thin object's pixels render the wall behind it).
    # "labels" measured and left off too: lower mIoU on two of three rooms, builds 1.26-1.29x, one
    # diverged (docs/suite_reopen_labels.md)
    grid_reopen_by: str = "colour"
    # each training step adds this many rays, drawn class by class from the training labels (a rare
    # class's pixels as often as a common one's), that sample every marching step whatever the grid
    # holds, until grid_open_until of the run: a thin object whose cells the grid emptied before the
    # field had learnt it gets a gradient, and its cells re-open once the field holds density there (0: off).
    # Their colour error counts at their class's share of the pixels (their labels: grid_open_labels).
    # "auto": LAYOUT_OPEN_RAYS where all the training depth comes from the room's layout and the
    # cameras do not all look one way, else 0 (docs/suite_open_64_all.md; docs/models.md)
    grid_open_rays: int | str = "auto"
    grid_open_until: float = 0.5
    # what the open rays' labels train: "balanced", their cross-entropy unweighted (each class's labels
    # as often as another's); "share", weighted like their colour error, at their class's share of the
    # pixels; "geometry", unweighted but moving density only (their samples' class logits detached).
    # "geometry" keeps hires-5x4's lamp shade, which "balanced" thins, and the nine tuning rooms' median
    # mIoU 0.963 against 0.953, but their worst 0.881 against 0.898 (hall-10x6's lamp thinner): one run,
    # docs/suite_open_geometry.md, so "balanced" stays until a second run and the held-out rooms decide
    grid_open_labels: str = "balanced"
    # with sensor depth (and train.depth_weight > 0): grid cells that depth rays cross well in front of
    # their measured surface start empty (space carving, render.sampling.free_cells_from_depth), so
    # the first steps march as few samples as the last; box warp only (docs/depth_carve_suite.md)
    depth_carve: bool = True
    # at this fraction of the run the carved cells beside uncarved ones are handed back to the field's
    # own refreshes: a cell carved wrongly (beside a surface whose depth edge is a hole) comes back if
    # the field holds density there; open space stays carved (1: never)
    depth_carve_until: float = 0.5
    # with depth_carve: a training ray with sensor depth ends this many grid cells past its measured
    # depth (plus CARVE_MARGIN of it), not at the box: behind a surface nothing is seen (0: at the box).
    # The depth term still places a ray's transparent rest at the box's far side
    depth_ray_end: float = 2.0
    # training evaluates a ray's samples in order and stops where its transmittance falls below this
    # (render.marcher.Skipping's min_trans; nerfacc's early_stop_eps): what lies behind an opaque
    # surface gets no gradient worth the work (0: every sample in an occupied cell)
    train_min_trans: float = 1e-4
    # rays per chunk when rendering outside training: a 160x120 view in one chunk (the early-stop marcher
    # evaluates at most chunk_rays x EARLY_STOP_SEGMENT samples at once; per chunk it pays a fixed cost)
    chunk_rays: int = 32768
    # grid: march n_steps, skipping cells the density grid holds empty | hierarchical: NeRF's
    # coarse + fine networks (n_coarse stratified samples, n_fine more drawn from the coarse weights)
    strategy: str = "grid"
    n_coarse: int = 64
    n_fine: int = 128

    def __post_init__(self) -> None:
        _check_choice("sampling.warp", self.warp, ("auto", "box", "forward"))
        _check_choice("sampling.strategy", self.strategy, ("grid", "hierarchical"))
        _check_choice("sampling.grid_reopen_by", self.grid_reopen_by, ("colour", "labels"))
        _check_choice("sampling.grid_open_labels", self.grid_open_labels, ("balanced", "share", "geometry"))
        for name in ("n_coarse", "n_fine"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ConfigError(f"sampling.{name} must be an integer >= 1, got {value!r}")
        until = self.depth_carve_until
        if isinstance(until, bool) or not (isinstance(until, (int, float)) and 0 <= until <= 1):
            raise ConfigError(f"sampling.depth_carve_until must be a fraction in [0, 1], got {until!r}")
        decay = self.grid_decay
        if decay != AUTO and (isinstance(decay, bool) or not (isinstance(decay, (int, float)) and 0 < decay <= 1)):
            raise ConfigError(f"sampling.grid_decay must be \"auto\" or in (0, 1], got {decay!r}")
        n_open = self.grid_open_rays
        if n_open != AUTO and (isinstance(n_open, bool) or not (isinstance(n_open, int) and n_open >= 0)):
            raise ConfigError(f"sampling.grid_open_rays must be an integer >= 0 or \"{AUTO}\", got {n_open!r}")
        for name in ("grid_reopen", "grid_reopen_until", "grid_open_until"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (isinstance(value, (int, float)) and 0 <= value <= 1):
                raise ConfigError(f"sampling.{name} must be a fraction in [0, 1], got {value!r}")
        if not isinstance(self.grid_from_training, bool):
            raise ConfigError(f"sampling.grid_from_training must be true or false, got {self.grid_from_training!r}")
        stop = self.train_min_trans
        if isinstance(stop, bool) or not (isinstance(stop, (int, float)) and 0 <= stop < 1):
            raise ConfigError(f"sampling.train_min_trans must be a number in [0, 1), got {stop!r}")
        end = self.depth_ray_end
        if isinstance(end, bool) or not (isinstance(end, (int, float)) and math.isfinite(end) and end >= 0):
            raise ConfigError(f"sampling.depth_ray_end must be a finite number >= 0, got {end!r}")


AUTO = "auto"
"""``train.distortion_weight``: chosen by the build from how many views see the observed geometry;
``sampling.grid_decay``, ``train.steps`` and ``train.time_budget``: from whether the training rays carry
sensor depth; ``sampling.grid_open_rays``: from the source of the training depth and where the cameras look."""

GRID_DECAY = 0.95
"""``sampling.grid_decay`` "auto" without sensor depth."""

GRID_DECAY_WITH_DEPTH = 0.8
"""``sampling.grid_decay`` "auto" with sensor depth: the depth terms empty free space in the first
refreshes, and a grid that forgets the early fog sooner marches fewer samples per ray; same
geometry and labels on the suite's rooms (docs/depth_grid_decay.md)."""


STEPS = 2000
"""``train.steps`` "auto", with sensor depth or without. Builds with phone-like depth once stopped at
1600 steps (the depth terms make surfaces early: docs/depth_step_count.md); since the marching went
to 288 steps (docs/suite_steps192.md), 2000 steps with depth gave higher held-out mIoU than 1600 on ten of
the twelve suite rooms, with builds of 55-72 s at 160x120, well within BUILD_SECONDS_WITH_DEPTH
(docs/depth_2000.md against docs/suite_steps192.md's phone-depth rows). Up to 3000 steps with depth (the
plan ending them at 2482-2741) gave mIoU within 0.0013 of 2000's on three rooms, in builds of 84-85 s
against 62-67 s (docs/suite_grid_first.md, variant phone-depth-3000)."""

TIME_BUDGET = 150.0
"""``train.time_budget`` "auto" (the fast preset's) without sensor depth: seconds of training."""

BUILD_SECONDS_WITH_DEPTH = 88.0
"""``train.time_budget`` "auto" with sensor depth: the seconds a whole build should take on 2 cores
(setup, training, evaluation; the map apart), so that one stays within 90 s with the noise of the
evaluation's estimate (issue 24's target). Training gets what setup and the expected evaluation
leave (:func:`time_budget_with_depth`), and stops at STEPS steps if that comes first."""

MIN_TIME_BUDGET = 60.0
"""Training seconds a build with depth keeps however long its setup and expected evaluation take
(it then runs over BUILD_SECONDS_WITH_DEPTH). It was 20 s: in docs/suite_3584cf9.md's run, whose builds
with depth made 14.1-18.8 steps/s at 160x120 (29.8-37.4 in docs/suite_steps192.md's), hires-5x4
(26 views at 640x480) spent 27 s setting up and expected 35 s of evaluation, so it trained 25.5 s,
351 steps, and came out fog (PSNR 21.0, surface labels 22 %, mIoU 0.730); given 60 s the same day
it trained 1037 steps (PSNR 38.7, 99.4 %, mIoU 0.982) in a build of 114 s
(docs/depth_min_budget.md). Of the 160x120 rooms there only dense-5x4 (150 views) planned less:
57 s."""


def time_budget_with_depth(setup_seconds: float = 0.0, finish_seconds: float = 0.0) -> float:
    """Training seconds of ``train.time_budget`` "auto" with sensor depth: BUILD_SECONDS_WITH_DEPTH
    less the seconds the build spent before training and the ``finish_seconds`` expected after it
    (:func:`scenelabel.train.evaluation.expected_finish_seconds`), at least MIN_TIME_BUDGET. A
    trainer made outside a build has neither: the whole BUILD_SECONDS_WITH_DEPTH."""
    return max(BUILD_SECONDS_WITH_DEPTH - setup_seconds - finish_seconds, MIN_TIME_BUDGET)


def resolve_by_depth(config: BuildConfig, with_depth: bool) -> BuildConfig:
    """``config`` with its "auto" settings made numbers, following the training rays' sensor depth:
    ``sampling.grid_decay`` and ``train.time_budget`` become GRID_DECAY_WITH_DEPTH and
    :func:`time_budget_with_depth` (the build then plans it from its setup and held-out views) when
    the rays carry depth the build trains on (``with_depth``), else GRID_DECAY and TIME_BUDGET;
    ``train.steps`` becomes STEPS either way. ``sampling.grid_open_rays`` still "auto" (the build chose
    none) becomes 0."""
    sc, tc = config.sampling, config.train
    if sc.grid_open_rays == AUTO:  # chosen by the build (choices.resolve_open_rays); a trainer made without it: off
        sc = dataclasses.replace(sc, grid_open_rays=0)
    if sc.grid_decay == AUTO:
        sc = dataclasses.replace(sc, grid_decay=GRID_DECAY_WITH_DEPTH if with_depth else GRID_DECAY)
    if tc.steps == AUTO:
        tc = dataclasses.replace(tc, steps=STEPS)
    if tc.time_budget == AUTO:
        tc = dataclasses.replace(tc, time_budget=time_budget_with_depth() if with_depth else TIME_BUDGET)
    return dataclasses.replace(config, sampling=sc, train=tc)


def resolve_for_layout(config: BuildConfig) -> BuildConfig:
    """``config`` for a build whose only depth is its room layout's (``data.layout_depth``,
    :mod:`scenelabel.data.layout_depth`): no space carving, since the layout gives furniture no
    depth and so nothing keeps the rays beside a chair leg or a table's edge from carving its cells
    (docs/layout_carve_first.md); and ``train.steps`` / ``train.time_budget`` "auto" as without depth
    (STEPS, TIME_BUDGET): the furniture's shape and labels still come from colour."""
    tc = config.train
    if tc.steps == AUTO:
        tc = dataclasses.replace(tc, steps=STEPS)
    if tc.time_budget == AUTO:
        tc = dataclasses.replace(tc, time_budget=TIME_BUDGET)
    return dataclasses.replace(config, sampling=dataclasses.replace(config.sampling, depth_carve=False), train=tc)


DISTORTION_AUTO_WEIGHT = 0.002
"""The distortion weight ``"auto"`` chooses where the views see the scene well."""

DISTORTION_THIN_MAX = 0.05
"""``"auto"`` turns the distortion term on only where at most this fraction of the observed geometry is
seen by fewer than :data:`scenelabel.geometry.coverage.THIN_VIEWS` training views: with one or two views
to fix a surface's depth, gathering weight into a surface commits it to a wrong depth. Chosen on the
scene suite's tuning rooms, between those the term helped and those it harmed (docs/models.md;
docs/suite.md gives each room's fraction and the weight its build chose)."""

SENSOR_FREE_MARGIN = 0.05
"""``train.free_margin`` "auto" with sensor depth: the free-space term counts weight in front of
``depth * (1 - margin) - one marching step``, so measurements off by a few per cent (a phone's LiDAR
is 1-2 %) and one step of quadrature do not pull a true surface forward."""

LAYOUT_FREE_MARGIN = 0.02
"""``train.free_margin`` "auto" where all the depth comes from the room's layout
(:mod:`scenelabel.data.layout_depth`): its planes put 88-100 % of the floor, wall and ceiling pixels
within 1 % of their depth (docs/layout.md). The free-space term pushes the fog of the first steps
to the edge of the space it empties, and a forward rig's far wall, which parallax barely places,
can stay there: at :data:`SENSOR_FREE_MARGIN` office-5x4-forward's depth error was 2.80 and 1.90 %
in training seeds 0 and 1, at 0.02 0.37 and 2.11 % (docs/suite_margin.md, one run): narrower, the
edge still held seed 1's wall."""

LAYOUT_OPEN_RAYS = 64
"""``sampling.grid_open_rays`` "auto" where all the training depth comes from the room's layout and the
training cameras do not all look one way: the rooms seen from inside that the scene suite measured
it on. 16 kept hall-10x6's lamp and chairs with no build diverging (docs/suite_open_share.md); 64
also keeps library-7x4's lamp shade, which the density grid empties before it forms with 16: over
the nine tuning rooms the worst one's mIoU 0.901 against 0.884 and the median F-score 0.976
against 0.957, for a median mIoU of 0.956 against 0.963 (docs/suite_open_64_all.md, one run;
docs/models.md). It thins hires-5x4's lamp: 0.901 against 0.973 in a second run
(docs/suite_open_64_hires.md), and 32 thins it too while behind 64 on the tuning rooms' median and
worst mIoU (docs/suite_open_32_all.md), so a count keeping both lamps is still open. A sensor's depth
and forward-facing rigs were not measured with it, so there "auto" is 0."""

RANDOM_BACKGROUND = "random"
"""``train.background``: a random colour per training ray and step (renders and queries use white)."""
DEPTH_RANDOM_BACKGROUND = RANDOM_BACKGROUND
"""``train.depth_background``: a random colour behind each training ray that carries depth."""
DEPTH_SCENE_BACKGROUND = "scene"
"""``train.depth_background``: ``train.background`` behind rays with depth too."""


def render_background(background: tuple[float, float, float] | str | None) -> tuple[float, float, float] | None:
    """The colour renders composite on for a ``train.background``: that colour, white for
    RANDOM_BACKGROUND, None (black) for None. Held-out evaluation composites transparent ground
    truth (``Scene.image_alphas``) on the same colour."""
    if background == RANDOM_BACKGROUND:
        return (1.0, 1.0, 1.0)
    return None if background is None else tuple(float(c) for c in background)  # type: ignore[return-value]


@dataclass
class TrainConfig:
    """The optimisation loop."""

    # "auto": STEPS (with sensor depth the time budget "auto" may stop it sooner); the build saves
    # the number it chose
    steps: int | str = "auto"
    batch_rays: int = 1024
    lr_encoding: float = 2e-2
    lr_mlp: float = 5e-3
    lr_final_ratio: float = 0.1  # exponential decay to this fraction of the lr at the run's end (last step or budget)
    semantic_weight: float = 0.04  # weight of the cross-entropy term beside photometric MSE
    # weight of mip-NeRF 360's distortion loss (weights gathered into surfaces, no fog; 0: off).
    # "auto": DISTORTION_AUTO_WEIGHT where the build measured the observed geometry (an input without
    # near/far or aabb) and at most DISTORTION_THIN_MAX of it is seen by fewer than 3 training views
    # (scenelabel.geometry.coverage), else 0; the build saves the number it chose
    distortion_weight: float | str = "auto"
    # the distortion loss is on from this fraction of the run (Trainer.progress): surfaces form
    # first, then their weight gathers (0: from the start)
    distortion_start: float = 0.0
    # weight of the solid-interior term (losses.solid_interior_loss): density pushed up just past
    # where each ray becomes opaque, so that points inside walls and furniture read occupied (0: off)
    solid_weight: float = 0.0
    # the solid-interior term's points lie up to this many marching steps past where each ray becomes
    # opaque: a layer just inside the surface. 2 steps (5-10 cm on a room) thickened thin objects
    # (shelf boards, chair legs, lamps) and cost held-out labels at their edges (docs/depth.md)
    solid_depth_steps: float = 0.5
    # weight of the depth terms when views carry sensor depth (Scene.sensor_depths: RGB-D, phone
    # LiDAR): Huber on the relative error of the expected termination plus the weight in front of
    # the measured surface (losses.depth_loss, losses.free_space_loss); without sensor depth: no effect
    depth_weight: float = 0.1
    # with sensor depth (and depth_weight > 0) the solid-interior term is on at least at this weight:
    # the measured surfaces say where the interior behind them begins (docs/captures.md)
    depth_solid_weight: float = 0.01
    # the free-space term counts weight in front of depth * (1 - free_margin) - one marching step.
    # "auto": LAYOUT_FREE_MARGIN where all the depth comes from the room's layout, SENSOR_FREE_MARGIN
    # otherwise; the build saves the number it chose
    free_margin: float | str = "auto"
    # the colour behind a training ray that carries depth: "random" (a new random colour per ray and
    # step: the ray must be opaque by its measured surface, since a room has no backdrop behind it, and a
    # wall left half transparent in front of the white background no longer matches its pixels;
    # docs/suite_phone_depth_live.md, with field.colour_live_logit) | "scene" (train.background, as every
    # other ray)
    depth_background: str = DEPTH_RANDOM_BACKGROUND
    # weight of the squared total variation of a dense grid (losses.total_variation), on a random
    # slab of TV_SLAB vertex rows each step (0: off; only field.encoding "dense")
    tv_weight: float = 0.0
    class_balance: bool = False  # median-frequency class weights in the cross-entropy (training views only)
    semantic_loss: str = "ce"  # ce: cross-entropy | focal: focal loss (Lin et al. 2017) with focal_gamma
    focal_gamma: float = 2.0  # focusing parameter of the focal loss (0: cross-entropy)
    detach_semantic_weights: bool = False  # the semantic loss does not move geometry (weights detached)
    # seconds; training stops early when spent (None: no budget), and once it is going to, the schedules
    # follow the clock to its end (scenelabel.train.schedule). "auto": TIME_BUDGET, or where the
    # training rays carry sensor depth what a BUILD_SECONDS_WITH_DEPTH build leaves; the build saves the number
    time_budget: float | str | None = None
    seed: int = 0
    # every holdout-th view is held out for evaluation; 0 = train on all. Not used when the input
    # has its own splits (Scene.splits, e.g. transforms_train / _val / _test.json): train on its
    # train split, evaluate on its test split (its val split when the test split is empty)
    holdout: int = 8
    # colour behind the scene (RGB in [0, 1]); None: black; "random": a new random colour per ray and
    # step in training, so that a ray left partly transparent never matches its pixel (renders: white).
    # Images with alpha (RGBA) are composited on it: target = rgb * alpha + background * (1 - alpha)
    background: tuple[float, float, float] | str | None = (1.0, 1.0, 1.0)
    checkpoint_every: int = 500  # steps between checkpoints
    log_every: int = 25  # steps between progress-bar updates

    def __post_init__(self) -> None:
        steps = self.steps
        if steps != AUTO and (isinstance(steps, bool) or not isinstance(steps, int) or steps < 0):
            raise ConfigError(f"train.steps must be \"auto\" or an integer >= 0, got {steps!r}")
        budget = self.time_budget
        if budget not in (None, AUTO) and (
            isinstance(budget, bool) or not (isinstance(budget, (int, float)) and math.isfinite(budget) and budget > 0)
        ):
            raise ConfigError(f"train.time_budget must be a number of seconds > 0, \"auto\" or null, got {budget!r}")
        _check_choice("train.semantic_loss", self.semantic_loss, ("ce", "focal"))
        bg = self.background
        if isinstance(bg, str):
            _check_choice("train.background", bg, (RANDOM_BACKGROUND,))
        elif bg is not None and not (
            len(bg) == 3 and all(isinstance(c, (int, float)) and not isinstance(c, bool) and 0 <= c <= 1 for c in bg)
        ):
            raise ConfigError(f"train.background must be 3 numbers in [0, 1], \"random\" or null, got {bg!r}")
        if not (isinstance(self.focal_gamma, (int, float)) and self.focal_gamma >= 0):
            raise ConfigError(f"train.focal_gamma must be a number >= 0, got {self.focal_gamma!r}")
        start = self.distortion_start
        if isinstance(start, bool) or not (isinstance(start, (int, float)) and 0 <= start <= 1):
            raise ConfigError(f"train.distortion_start must be a fraction in [0, 1], got {start!r}")
        steps = self.solid_depth_steps
        if isinstance(steps, bool) or not (isinstance(steps, (int, float)) and math.isfinite(steps) and steps > 0):
            raise ConfigError(f"train.solid_depth_steps must be a finite number > 0, got {steps!r}")
        depth_backgrounds = (DEPTH_RANDOM_BACKGROUND, DEPTH_SCENE_BACKGROUND)
        _check_choice("train.depth_background", self.depth_background, depth_backgrounds)
        margin = self.free_margin
        if margin != AUTO and (isinstance(margin, bool) or not (isinstance(margin, (int, float)) and 0 <= margin < 1)):
            raise ConfigError(f"train.free_margin must be a fraction in [0, 1) or \"{AUTO}\", got {margin!r}")
        for name in ("distortion_weight", "tv_weight", "solid_weight", "depth_weight", "depth_solid_weight"):
            w = getattr(self, name)
            if name == "distortion_weight" and w == AUTO:
                continue
            if isinstance(w, bool) or not (isinstance(w, (int, float)) and math.isfinite(w) and w >= 0):
                also = f' or "{AUTO}"' if name == "distortion_weight" else ""
                raise ConfigError(f"train.{name} must be a finite number >= 0{also}, got {w!r}")


@dataclass
class OutputConfig:
    """What a build writes beside the checkpoint."""

    smooth_sigma: float = 1.0  # Gaussian smoothing (pixels) for the smoothed-label renders
    map_voxel_size: float | None = None  # None: what the images can resolve
    write_map: bool = True
    write_renders: bool = True


@dataclass
class BuildConfig:
    """Everything one build resolves to; saved with the checkpoint."""

    data: DataConfig = dataclasses.field(default_factory=DataConfig)
    field: FieldConfig = dataclasses.field(default_factory=FieldConfig)
    sampling: SamplingConfig = dataclasses.field(default_factory=SamplingConfig)
    train: TrainConfig = dataclasses.field(default_factory=TrainConfig)
    output: OutputConfig = dataclasses.field(default_factory=OutputConfig)
    preset: str = "fast"


_MLP_FIELD = {"encoding": "positional", "view_encoding": "positional"}
_MLP_TRAIN = {"lr_mlp": 5e-4, "batch_rays": 512}  # NeRF's Adam lr (5e-4, decaying 10x)

AUTO_PRESET = "auto"
"""The default preset: ``fast``, or ``voxels`` where the training cameras are forward-facing and the
masks give no room layout (LLFF captures like fern); the build chooses once it has loaded the scene
(:func:`scenelabel.train.choices.resolve_preset`), carrying over the settings given on top of it
(:func:`with_preset`), and saves the choice."""

AUTO_CARRIES = {"train": {"time_budget": AUTO}}
"""What the preset "auto" hands on to the preset it becomes (:func:`with_preset`): its time plan, a
build time known before it starts; its other settings are the fast preset's."""

# the inward-looking default: tri-plane 64+128 x 8 channels, 1024-ray batches; at most 2000 steps or 150 s of
# training, whichever comes first (with sensor depth: what a build of 88 s leaves after setup and
# evaluation, train.time_budget "auto"), so that a default build's time is known before it starts
# (docs/suite.md: this build on rooms of 3x3 to 10x6 m, with and without phone-like depth).
# 288 marching steps across the box (the suite's rooms: 2-5 cm, living-6x5's 3.6): with 192 (3-8 cm,
# living's 5.4) chair legs and picture frames came out half transparent (docs/suite_steps192.md: variant
# steps-192); docs/models.md says what changes with the step (the samples and the density grid's
# threshold) and what it costs (tools/bench.py's room loses its lamp's pole).
# The colour sigmoid keeps a gradient (field.colour_live_logit 4): without it a random training seed
# could kill colour channels in the first steps and leave half-transparent walls (docs/models.md,
# docs/suite_phone_depth_live.md, docs/suite_colour_live_rooms.md). Tri-planes of 64, 128 and 256 cells: the
# images resolve finer than a 128-cell (docs/models.md); measured in docs/suite_planes.md
_FAST = {"field": {"colour_live_logit": 4.0, "resolutions": (64, 128, 256)}, "sampling": {"n_steps": 288}, "train": {"time_budget": AUTO}}

PRESETS: dict[str, dict] = {
    AUTO_PRESET: _FAST,  # as "fast" until the build resolves it (what it hands on: AUTO_CARRIES)
    "fast": _FAST,
    # captures with sensor depth (RGB-D, phone LiDAR; docs/captures.md) when time matters more than
    # labels: the depth terms make surfaces early, so 800 steps (at most 75 s of training) gave the
    # geometry (depth, surface labels, F-score) of the then default 2000 steps in about 60 % of its
    # time, but held-out labels lagged (docs/depth.md); the default preset gives both
    "rgbd": {"train": {"steps": 800, "time_budget": 75.0}},
    "quick": {  # for tests and smoke runs: a few seconds on a 2-core CPU
        "field": {"resolutions": (32, 64), "channels": 8, "hidden": 32},
        "sampling": {"n_steps": 128, "grid_resolution": 32, "grid_warmup": 16},
        "train": {"steps": 500},
    },
    "dense": {  # a second explicit encoding: one 96^3 x 8 voxel grid instead of tri-planes
        "field": {"encoding": "dense", "grid_resolution": 96, "channels": 8},
    },
    # No network: one dense grid whose channels are σ, colour and class logits (head "direct",
    # Plenoxels / DVGO style), 256 cells along its longest axis; a step costs a few memory reads
    # per sample, so batches are 4x larger and the grid learns at a higher rate. The grid starts
    # at σ = 1 (density_bias 0) so that no cell is skipped before it has learnt; 128 marching
    # steps, about one per grid cell along a ray; a light total-variation prior against floaters.
    # Training marches every occupied sample (train_min_trans 0): the pass that finds where a ray
    # turns opaque reads all of the grid's channels, as the evaluation itself does, and on fern it
    # cost more than it saved (docs/real_fern_train_stop.md: 2149 steps in 480 s, against 2500 in
    # 360 s without it, docs/real_fern_auto_8a3a480.md)
    "voxels": {
        "field": {
            "encoding": "dense", "head": "direct", "view_dependent": False, "grid_resolution": 256, "density_bias": 0.0,
        },
        "sampling": {"n_steps": 128, "train_min_trans": 0.0},
        "train": {"steps": 2500, "batch_rays": 4096, "lr_encoding": 0.1, "tv_weight": 0.001},
    },
    # The seed paper's MLP family (positional encoding 10 / 4 frequencies). `paper` samples as the
    # original NeRF: a coarse and a fine network, 64 + 128 samples per ray. Its smaller variants
    # use the occupancy-grid marcher of the fast presets (192 steps across the box). A 32^3 grid
    # keeps the refreshes affordable for a large MLP (the grid also serves point queries and maps).
    "paper": {  # the original NeRF: 8 x 256 with the input again before layer 5
        "field": {**_MLP_FIELD, "hidden": 256, "layers": 8, "skip_layer": 5},
        # hierarchical rendering evaluates every sample of a chunk at once: 4096 rays x 193 samples x 256
        "sampling": {
            "grid_resolution": 32, "strategy": "hierarchical", "n_coarse": 64, "n_fine": 128, "chunk_rays": 4096,
        },
        "train": {**_MLP_TRAIN, "steps": 20000},
    },
    "multihead": {  # the seed's 6-layer variant; colour and class heads separate from the trunk
        "field": {**_MLP_FIELD, "hidden": 128, "layers": 6},
        "sampling": {"grid_resolution": 32},
        "train": {**_MLP_TRAIN, "steps": 20000},
    },
    "tiny": {  # the seed's 3-layer variant
        "field": {**_MLP_FIELD, "hidden": 64, "layers": 3},
        "sampling": {"grid_resolution": 32},
        "train": {**_MLP_TRAIN, "lr_mlp": 2e-3, "steps": 5000},
    },
}


def preset(name: str = AUTO_PRESET, overrides: dict | None = None) -> BuildConfig:
    """The named preset's config, with ``overrides`` (nested dict by stage) applied on top."""
    if name not in PRESETS:
        raise ConfigError(f"unknown preset {name!r}; choose one of {sorted(PRESETS)}")
    merged: dict = {"preset": name}
    for source in (PRESETS[name], overrides or {}):
        for key, value in source.items():
            if isinstance(value, dict):
                merged.setdefault(key, {}).update(value)
            else:
                merged[key] = value
    return config_from_dict(merged)


def with_preset(config: BuildConfig, name: str) -> BuildConfig:
    """The preset ``name`` with what made ``config`` on top: its own preset's settings (for the preset
    "auto": ``train.time_budget`` "auto", a build time known before it starts) and the settings that
    differ from that preset's (the user's; one given equal to its preset's value is not told apart
    from one left alone)."""
    base, own = config_to_dict(preset(config.preset)), config_to_dict(config)
    carried = AUTO_CARRIES if config.preset == AUTO_PRESET else PRESETS[config.preset]
    overrides = {stage: dict(values) for stage, values in carried.items()}
    for stage, values in own.items():
        if isinstance(values, dict):
            overrides.setdefault(stage, {}).update({k: v for k, v in values.items() if v != base[stage][k]})
    return preset(name, overrides)


def _stage_from_dict(cls, data: dict, where: str):
    if not isinstance(data, dict):
        raise ConfigError(f"{where} must be a mapping, got {type(data).__name__}")
    names = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(names))
    if unknown:
        raise ConfigError(f"unknown {where} config key(s) {unknown}; known: {sorted(names)}")
    values = {}
    for key, value in data.items():
        if isinstance(value, list):
            value = tuple(value)
        values[key] = value
    return cls(**values)


def config_from_dict(data: dict) -> BuildConfig:
    """Build a :class:`BuildConfig` from a nested dict; unknown keys raise :class:`ConfigError`."""
    stages = {"data": DataConfig, "field": FieldConfig, "sampling": SamplingConfig, "train": TrainConfig, "output": OutputConfig}
    unknown = sorted(set(data) - set(stages) - {"preset"})
    if unknown:
        raise ConfigError(f"unknown config section(s) {unknown}; known: {sorted(stages) + ['preset']}")
    kwargs = {name: _stage_from_dict(cls, data.get(name, {}), name) for name, cls in stages.items()}
    return BuildConfig(**kwargs, preset=data.get("preset", "fast"))


def config_to_dict(config: BuildConfig) -> dict:
    """A JSON-ready nested dict of ``config``."""
    return dataclasses.asdict(config)
