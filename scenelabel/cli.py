"""The command line: ``scenelabel build | demo | toy | export | view | segment | sfm | upgrade-checkpoint``.

Errors a user can cause print one line (``scenelabel: error: ...``) and exit with status 2;
they never show a traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
import warnings
from pathlib import Path

from scenelabel._version import __version__
from scenelabel.config import AUTO_PRESET, BUILD_SECONDS_WITH_DEPTH, PRESETS, TIME_BUDGET, preset
from scenelabel.errors import InputError, ScenelabelError, TrainingInterrupted

__all__ = ["main"]

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130


def _overrides(args: argparse.Namespace) -> dict:
    train: dict = {}
    if args.steps is not None:
        train["steps"] = args.steps
        train["time_budget"] = None  # the steps asked for, not the preset's budget
    if args.time_budget is not None:
        train["time_budget"] = args.time_budget
    if args.seed is not None:
        train["seed"] = args.seed
    if args.holdout is not None:
        train["holdout"] = args.holdout
    overrides: dict = {"train": train}
    data = {key: getattr(args, key) for key in ("downscale", "scale") if getattr(args, key, None) is not None}
    if data:
        overrides["data"] = data
    if args.voxel_size is not None:
        overrides["output"] = {"map_voxel_size": args.voxel_size}
    if args.config:
        try:
            extra = json.loads(Path(args.config).read_text())
        except (OSError, json.JSONDecodeError) as err:
            raise ScenelabelError(f"{args.config}: cannot read the config file ({err})") from None
        for section, values in extra.items():
            if isinstance(values, dict):
                overrides.setdefault(section, {}).update(values)
            else:
                overrides[section] = values
    return overrides


def _add_build_options(p: argparse.ArgumentParser, default_preset: str = AUTO_PRESET) -> None:
    p.add_argument("--out", help="output folder (default: SCENE/scenelabel)")
    p.add_argument(
        "--preset", default=default_preset, choices=sorted(PRESETS), help=f"model/training preset (default: {default_preset}"
        + ("; auto: voxels where the cameras are forward-facing and no room layout is found, else fast)" if default_preset == AUTO_PRESET else ")"),
    )
    p.add_argument("--steps", type=int, help="training steps (alone: no time budget)")
    p.add_argument(
        "--time-budget", type=float, metavar="SECONDS",
        help=f"stop training after this many seconds (auto and fast: {TIME_BUDGET:g} by default; with sensor depth "
        f"what a build of {BUILD_SECONDS_WITH_DEPTH:g} s leaves)",
    )
    p.add_argument("--seed", type=int, help="random seed (a build is deterministic for a seed)")
    p.add_argument("--holdout", type=int, help="hold out every N-th view for evaluation (0: train on all); "
                   "not used when the input has its own splits (transforms_train / _val / _test.json)")
    p.add_argument("--voxel-size", type=float, help="occupancy-map voxel size in world units")
    p.add_argument("--downscale", type=int, metavar="N", help="shrink images N times (uses LLFF-style images_N/ when present)")
    p.add_argument(
        "--scale", type=float, help="multiply the input's world units by this (e.g. metres per COLMAP unit); recorded in exports"
    )
    p.add_argument("--config", help="JSON file of config overrides: {section: {key: value}}")
    p.add_argument("--device", help="cpu or cuda (default: cuda when available)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _print_metrics(metrics: dict, out_dir: Path) -> None:
    if metrics.get("rank", 0):  # a data-parallel rank other than 0: rank 0 reports
        return
    keys = ["psnr", "ssim", "miou", "miou_common", "miou_smoothed", "depth_error"]
    parts = [f"{k}={metrics[k]:.4f}" for k in keys if k in metrics]
    print(f"held-out ({metrics.get('n_test_views', 0)} views): " + ", ".join(parts))
    print(
        f"trained {metrics['steps']} steps in {metrics['train_seconds']:.1f} s "
        f"({metrics['steps_per_second']:.1f} steps/s); wrote {out_dir}"
    )


def _segment(scene: str, spec: str, overwrite: bool, device: str | None, quiet: bool) -> None:
    """Write labels/ and classes.json for ``scene`` with the segmenter ``spec``, and say what was found."""
    from scenelabel.data.segmenters import load_segmenter, segment_scene

    segmenter = load_segmenter(spec, device=device)
    result = segment_scene(scene, segmenter, overwrite=overwrite, progress=not quiet)
    total = max(1, sum(result.counts.values()))
    shown = ", ".join(
        f"{segmenter.classes.get(i, 'unlabelled')} {100 * n / total:.1f}%" for i, n in result.counts.items() if n > 0
    )
    print(f"wrote {len(result.label_paths)} masks to {result.labels_dir} and {result.classes_path}")
    print(f"classes present: {shown}")


def _cmd_segment(args: argparse.Namespace) -> None:
    _segment(args.scene, args.model, args.overwrite, args.device, args.quiet)


def _cmd_sfm(args: argparse.Namespace) -> None:
    from scenelabel.data.sfm import run_sfm

    result = run_sfm(
        args.scene,
        args.matcher,
        args.max_image_size,
        max_num_features=args.max_features,
        min_registered=args.min_registered,
        undistort=args.undistort,
        force=args.force,
    )
    print(result.summary())
    if result.unregistered:
        print("not registered: " + ", ".join(result.unregistered))


EXIT_SCENES_FAILED = 1
"""``build`` of several scenes: the exit status when at least one scene failed."""


def _build_many(args: argparse.Namespace) -> int:
    """``build`` of several scenes (or of one on a Dask cluster): independent jobs and a summary table."""
    from scenelabel.train.batch import SUMMARY_MD, build_many, summary_table

    if args.resume or args.segmenter:
        raise ScenelabelError("--resume and --segmenter take one scene folder; run `scenelabel build SCENE` per scene")
    config = preset(args.preset, _overrides(args))
    with contextlib.ExitStack() as stack:
        client = _dask_client(stack, args.workers, args.scheduler)
        outcomes = build_many(args.scene, args.out, config, client=client, device=args.device, progress=not args.quiet)
    print(summary_table(outcomes))
    failed = [o for o in outcomes if not o.ok]
    where = f"; summary: {Path(args.out) / SUMMARY_MD}" if args.out else ""
    print(f"built {len(outcomes) - len(failed)} of {len(outcomes)} scenes" + (f", {len(failed)} failed" if failed else "") + where)
    return EXIT_SCENES_FAILED if failed else 0


def _scene_folder(scene: str) -> Path:
    """The folder of a ``build`` argument: ``clip/`` beside a video ``clip.mp4``, else the argument."""
    from scenelabel.data.video import is_video, video_scene_dir

    return video_scene_dir(scene) if is_video(scene) else Path(scene)


def _cmd_build(args: argparse.Namespace) -> int | None:
    from scenelabel.train.pipeline import build, resume_config

    if len(args.scene) > 1 or args.workers is not None or args.scheduler:
        return _build_many(args)
    args.scene = args.scene[0]
    folder = _scene_folder(args.scene)
    if args.resume:
        out = Path(args.out) if args.out else folder / "scenelabel"
        config = resume_config(out, args.steps, args.time_budget)
    else:
        config = preset(args.preset, _overrides(args))
    if args.segmenter and not (folder / "labels").is_dir():
        if folder != Path(args.scene):  # a video: its frames first, to segment them
            from scenelabel.data.video import prepare_video_scene

            d = config.data
            prepare_video_scene(args.scene, d.video_frames_per_second, d.video_max_frames, progress=not args.quiet)
        _segment(str(folder), args.segmenter, False, args.device, args.quiet)
    result = build(args.scene, args.out, config, progress=not args.quiet, device=args.device, resume=args.resume)
    _print_metrics(result.metrics, result.out_dir)


def _cmd_toy(args: argparse.Namespace) -> None:
    from scenelabel.data.synthetic import write_furnished_room, write_toy_scene

    writer = write_furnished_room if args.room else write_toy_scene
    path = writer(args.path)
    print(f"wrote {'furnished room' if args.room else 'toy two-box scene'} to {path}")


def _cmd_demo(args: argparse.Namespace) -> None:
    """Generate the toy two-box scene, build it, print held-out metrics, write renders and map."""
    from scenelabel.data.synthetic import write_toy_scene
    from scenelabel.train.pipeline import build

    scene_dir = Path(args.path)
    write_toy_scene(scene_dir)
    print(f"toy two-box scene written to {scene_dir}")
    config = preset(args.preset, _overrides(args))
    out = Path(args.out) if args.out else scene_dir / "scenelabel"
    result = build(scene_dir, out, config, progress=not args.quiet, device=args.device)
    _print_metrics(result.metrics, result.out_dir)
    print(f"renders: {out / 'renders'}   map: {out / 'map.zarr'}")


EXPORT_FORMATS = ("zarr", "ply", "mesh", "glb", "nav2", "octomap", "rrd")
FORMAT_OF_SUFFIX = {".zarr": "zarr", ".ply": "ply", ".glb": "glb", ".bt": "octomap", ".ot": "octomap", ".rrd": "rrd"}
"""The export formats an output's name says by itself (mesh: a folder, nav2: a path stem)."""


def export_format(requested: str | None, out: Path) -> str:
    """The format of ``export ... OUT``: ``--format`` when given, else the one OUT's suffix says
    (:data:`FORMAT_OF_SUFFIX`); a suffix that names another format than ``--format`` is an error,
    as is an OUT whose name says none when ``--format`` is not given."""
    named = FORMAT_OF_SUFFIX.get(out.suffix.lower())
    if requested is None:
        if named is None:
            raise InputError(
                "cannot tell the format from the name: end OUT in .zarr, .ply, .glb, .bt, .ot or .rrd, or give "
                "--format mesh (a folder) or --format nav2 (a path stem)",
                path=out,
            )
        return named
    if named is not None and named != requested:
        raise InputError(f"--format {requested}, but the name ends in {out.suffix} (a {named} file): rename OUT or drop --format", path=out)
    return requested


def _is_build(source: Path) -> bool:
    """A build folder (with checkpoint.pt) or a checkpoint file."""
    return (source / "checkpoint.pt").is_file() or (source.is_file() and source.suffix == ".pt")


def _reused_map(source: Path, voxel_size: float | None):
    """The map a build folder wrote itself when it fits (:func:`scenelabel.query.build_outputs.own_map`),
    said on stdout; else None."""
    from scenelabel.query.build_outputs import MAP_NAME, own_map

    occ = own_map(source, voxel_size)
    if occ is not None:
        print(f"using the build's own map {source / MAP_NAME} (voxel size {occ.voxel_size:g})")
    return occ


def _load_map(source: Path, voxel_size: float | None):
    """The occupancy map of a build folder (the field evaluated at ``voxel_size``) or of a map .zarr folder."""
    from scenelabel.maps import OccupancyMap

    is_zarr = source.is_dir() and ((source / "zarr.json").is_file() or (source / ".zgroup").is_file())
    if _is_build(source):
        from scenelabel.query.field import SemanticField

        return SemanticField.load(source).occupancy_map(voxel_size)
    if is_zarr:
        if voxel_size is not None:
            raise InputError("--voxel-size applies to a build folder; a map keeps its own voxel size", path=source)
        return OccupancyMap.from_zarr(source)
    raise InputError("neither a build folder (with checkpoint.pt) nor an occupancy map (.zarr folder)", path=source)


def _dask_client(stack, workers: int | None, scheduler: str | None):
    """A Dask client for ``--workers N`` (a local cluster of N processes, one thread each) or
    ``--scheduler ADDRESS``, closed with ``stack``; None for neither."""
    if workers is None and not scheduler:
        return None
    if workers is not None and workers < 1:
        raise InputError(f"must be at least 1, got {workers}", field="--workers")
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            return stack.enter_context(Client(scheduler))
        except (OSError, TimeoutError, ValueError) as err:
            raise ScenelabelError(f"cannot connect to the Dask scheduler at {scheduler}: {err}") from None
    cluster = stack.enter_context(LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None))
    return stack.enter_context(Client(cluster))


def _export_chunked(args: argparse.Namespace, source: Path, out: Path) -> None:
    """``export BUILD OUT.zarr``: the map evaluated chunk by chunk into the store (bounded memory),
    in this process or on a Dask cluster (:func:`scenelabel.query.map_writer.write_occupancy_map`)."""
    import zarr

    from scenelabel.query.map_writer import write_occupancy_map

    with contextlib.ExitStack() as stack:
        client = _dask_client(stack, args.workers, args.scheduler)
        path = write_occupancy_map(
            source, out, args.voxel_size, zarr_format=args.zarr_format, client=client, progress=not args.quiet
        )
    group = zarr.open_group(str(path), mode="r")
    print(f"wrote {path}: {tuple(group['label'].shape)} voxels of {group.attrs['voxel_size']:g}")


def _export_rrd(args: argparse.Namespace, source: Path, out: Path, build: bool) -> None:
    """``export BUILD_OR_MAP OUT.rrd``: a rerun recording (:func:`scenelabel.viz.rerun_log.log_rerun`) of the
    map (a build's own when it fits, as for the other formats), its class meshes, the views (photos and masks
    from ``--scene``), the held-out renders and the training curves."""
    from scenelabel.viz.rerun_log import log_rerun

    occ = _reused_map(source, args.voxel_size) if build else None
    if occ is None:
        occ = _load_map(source, args.voxel_size)
    s = log_rerun(source, out, scene=args.scene, occ_map=occ)
    print(f"wrote {s.path}: {s.n_points} map points, {s.n_meshes} class meshes, {s.n_views} views ({s.n_renders} "
          f"rendered), {s.n_steps} training steps; open it with: rerun {s.path}")


def _cmd_export(args: argparse.Namespace) -> None:
    from scenelabel._cores import sharing_cores

    source, out = Path(args.source), Path(args.out)
    args.format = export_format(args.format, out)
    build, cluster = _is_build(source), args.workers is not None or bool(args.scheduler)
    if cluster and not (args.format == "zarr" and build):
        raise InputError(
            "--workers and --scheduler apply to --format zarr from a build folder (the chunked export)", path=source
        )
    # in this process, the export is a job sharing the cores (scenelabel._cores); a cluster's workers
    # have one thread each
    with contextlib.nullcontext() if cluster else sharing_cores():
        _export(args, source, out, build, cluster)


def _export(args: argparse.Namespace, source: Path, out: Path, build: bool, cluster: bool) -> None:
    from scenelabel.maps import exports

    if args.format == "rrd":
        _export_rrd(args, source, out, build)
        return
    occ = None if cluster or not build else _reused_map(source, args.voxel_size)
    if occ is None and args.format == "zarr" and build:
        _export_chunked(args, source, out)
        return
    if occ is None:
        occ = _load_map(source, args.voxel_size)
    if args.format == "zarr":
        path = occ.to_zarr(out, zarr_format=args.zarr_format)
        print(f"wrote {path}: {occ.shape} voxels of {occ.voxel_size:g}")
    elif args.format == "ply":
        path = exports.write_point_cloud(occ, out)
        print(f"wrote {path}: {int((occ.label >= 0).sum())} occupied voxel centres")
    elif args.format == "mesh":
        paths = exports.write_class_meshes(occ, out)
        names = ", ".join(occ.classes[cid] for cid in paths) or "none (no occupied voxel)"
        print(f"wrote {len(paths)} class meshes to {out}: {names}")
    elif args.format == "glb":
        meshes = exports.class_meshes(occ)
        path = exports.write_glb(occ, out, meshes=meshes)
        counts = ", ".join(f"{occ.classes[cid]} {len(mesh.faces)}" for cid, mesh in meshes.items())
        print(f"wrote {path}: triangles per class: {counts}")
    elif args.format == "octomap":
        path = exports.write_octomap(occ, out)
        n_occupied, n_free = int((occ.label >= 0).sum()), int((occ.label == -1).sum())  # a class, FREE
        leaves = exports.read_octomap(path).getNumLeafNodes()
        print(f"wrote {path}: {n_occupied} occupied and {n_free} free voxels ({occ.label.size - n_occupied - n_free} "
              f"UNKNOWN left out) as {leaves} octree leaves after pruning")
    else:
        paths = exports.write_nav2(occ, out, args.z_min, args.z_max, args.robot_height)
        if args.legend:  # a picture beside the map files; OUT_labels.png stays one pixel per cell
            from scenelabel.viz.pictures import write_floor_plan_picture

            stem = paths["labels"].with_name(paths["labels"].name.replace("_labels.png", "_legend.png"))
            paths["legend"] = write_floor_plan_picture(occ, stem, args.z_min, args.z_max, args.robot_height).path
        print("wrote " + ", ".join(str(p) for p in paths.values()))


def _cmd_upgrade_checkpoint(args: argparse.Namespace) -> None:
    from scenelabel.fields.checkpoint import FORMAT_VERSION, upgrade_checkpoint

    path, converted = upgrade_checkpoint(args.path)
    if converted:
        print(f"converted {path} to checkpoint format {FORMAT_VERSION}")
    else:
        print(f"{path} is in checkpoint format {FORMAT_VERSION} already; nothing to do")


VIEW_FIELD_WAIT = 10.0
"""``scenelabel view BUILD``: seconds the field waits for a browser to connect before it loads anyway."""

VIEW_FIELD_SETTLE = 2.5
"""``scenelabel view BUILD``: seconds between a browser's connecting and the field's loading, for the
browser to draw the map first (loading torch and the checkpoint takes the same cores): headless
Chromium on 2 cores, WebGL in software, takes well over a second from the URL to the toy's map drawn
(docs/viewer_timings.md), so a shorter wait had the field's loading overlap the page's first frames."""


def _cmd_view(args: argparse.Namespace) -> None:
    """Serve the web viewer of a build or a map until Ctrl-C (or --timeout)."""
    from scenelabel.viz.viewer import ViewerApp

    # a build's own map is served first; its field (torch, the checkpoint) is loaded once a browser has
    # the page (or after VIEW_FIELD_WAIT seconds), so that the two do not start on the same cores at once
    app = ViewerApp.open(args.source, voxel_size=args.voxel_size, images=args.images, device=args.device, field_later=True)
    url = app.start(args.port, args.host)
    print(f"scenelabel: viewer of {args.source} at {url} (Ctrl-C to stop)", flush=True)
    try:
        if app.field_pending:
            with contextlib.suppress(TimeoutError):  # no browser yet: load it anyway
                app.wait_for_client(VIEW_FIELD_WAIT if args.timeout is None else min(VIEW_FIELD_WAIT, args.timeout))
                time.sleep(VIEW_FIELD_SETTLE)
        if app.load_field():
            print("scenelabel: field loaded (training cameras, queries and renders by the field)", flush=True)
        app.serve_forever(args.timeout)
    except KeyboardInterrupt:
        print("scenelabel: viewer stopped", flush=True)


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="scenelabel", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"scenelabel {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser(
        "build",
        help="train a semantic field on a scene folder (or on several, one field each)",
        description="Several scenes are independent jobs, one field each: --out is then the root of their "
        "output folders (OUT/<scene folder name>; default: each SCENE/scenelabel), each with its build.log; "
        "a failed scene does not stop the others. A table of every scene is printed (and written to "
        "OUT/summary.md and OUT/summary.json); the exit status is 1 when a scene failed.",
    )
    p.add_argument(
        "scene",
        nargs="+",
        help="scene folder(s) (images/, labels/, classes.json, transforms.json or poses_bounds.npy), or video "
        "file(s) (.mp4 .mov .avi .mkv .m4v: sharp frames into clip/images/ beside clip.mp4, poses by structure from "
        "motion; config data.video_frames_per_second, data.video_max_frames)",
    )
    _add_build_options(p)
    cluster = p.add_mutually_exclusive_group()
    cluster.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help="run the scenes on a local Dask cluster of N worker processes, one thread each (default: one after another)",
    )
    cluster.add_argument(
        "--scheduler", metavar="ADDRESS", help="run the scenes on the Dask cluster at this scheduler (tcp://HOST:8786)"
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="continue from the checkpoint in the output folder, with its saved config (--steps/--time-budget may extend it)",
    )
    p.add_argument(
        "--segmenter",
        metavar="SPEC",
        help="when the scene has no labels/: write them first with this 2D segmentation model (see `segment`)",
    )
    p.set_defaults(func=_cmd_build)

    p = sub.add_parser("demo", help="generate the toy two-box scene and build it end to end")
    p.add_argument("path", nargs="?", default="toy_scene", help="where to write the toy scene (default: ./toy_scene)")
    _add_build_options(p, default_preset="quick")  # the toy scene is small: a ~30 s build
    p.set_defaults(func=_cmd_demo)

    p = sub.add_parser("toy", help="write a synthetic scene folder (exact labels and depth)")
    p.add_argument("path")
    p.add_argument("--room", action="store_true", help="the furnished room instead of the two-box toy scene")
    p.set_defaults(func=_cmd_toy)

    p = sub.add_parser(
        "export",
        help="export the occupancy map of a build (or of a map .zarr) as zarr, a point cloud, meshes, a Nav2 map "
        "or an OctoMap",
        description="Formats (docs/formats.md, 'Exports'): zarr: OUT is a .zarr folder; ply: OUT is a .ply point "
        "cloud of occupied voxel centres; mesh: OUT is a folder of per-class .ply meshes; glb: OUT is a .glb file of "
        "the same meshes (a node and a material per class, Y-up); nav2: OUT is a path stem "
        "for OUT.pgm, OUT.yaml and OUT_labels.png (a 2D floor plan of a height band); octomap: OUT is a .bt (binary "
        "occupancy OcTree) or .ot (ColorOcTree: log-odds and class colours) file, UNKNOWN voxels left out; rrd: OUT is "
        "a .rrd rerun recording (map points, meshes, views, renders, training curves; open it with `rerun OUT`).",
    )
    p.add_argument("source", metavar="BUILD_OR_MAP", help="build folder (with checkpoint.pt) or occupancy map (.zarr folder)")
    p.add_argument("out", metavar="OUT", help="output path (see the formats)")
    p.add_argument(
        "--format",
        choices=EXPORT_FORMATS,
        help="output format (default: from OUT's name: .zarr -> zarr, .ply -> ply, .glb -> glb, .bt/.ot -> octomap, "
        ".rrd -> rrd)",
    )
    p.add_argument("--voxel-size", type=float, help="voxel size in world units, for a build folder (default: from the images)")
    p.add_argument("--zarr-format", type=int, choices=(2, 3), default=3, help="zarr format version (--format zarr)")
    p.add_argument("--z-min", type=float, help="nav2: bottom of the height band, world z (default: one voxel above the floor)")
    p.add_argument("--z-max", type=float, help="nav2: top of the height band, world z (default: below the ceiling, or the map's top)")
    p.add_argument("--robot-height", type=float, help="nav2: band top = floor top + this (world units)")
    p.add_argument(
        "--legend", action="store_true", help="nav2: also OUT_legend.png, the floor plan with a legend and a scale bar"
    )
    p.add_argument(
        "--scene",
        help="rrd: the scene folder of the views' photos and masks (default: BUILD/.. for a build in SCENE/scenelabel)",
    )
    cluster = p.add_mutually_exclusive_group()
    cluster.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help="zarr from a build folder: evaluate the map's chunks on a local Dask cluster of N worker processes "
        "(default: chunk by chunk in this process)",
    )
    cluster.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="zarr from a build folder: evaluate the map's chunks on the Dask cluster at this scheduler "
        "(tcp://HOST:8786; the build folder and OUT on a filesystem every worker sees)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_cmd_export)

    p = sub.add_parser(
        "segment",
        help="write labels/ and classes.json for a scene without masks, with a 2D segmentation model",
        description="SPEC (docs/formats.md, 'Segmenters'): torchvision:ARCH[:WEIGHTS.pth] (weights from the local "
        "torch hub cache when WEIGHTS is left out), onnx:MODEL.onnx:CLASSES.json (run by OpenCV dnn), or "
        "python:MODULE:ATTR for your own model (MODULE a module name or a .py file). Nothing is downloaded.",
    )
    p.add_argument("scene", help="scene folder (the photos of images/ are labelled)")
    p.add_argument("--model", required=True, metavar="SPEC", help="the segmentation model (see above)")
    p.add_argument("--overwrite", action="store_true", help="replace existing masks in labels/ and classes.json")
    p.add_argument("--device", help="cpu or cuda, for torch models (default: cuda when available)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_segment)

    p = sub.add_parser(
        "sfm",
        help="recover camera poses of an images-only scene with structure from motion (pycolmap), cached in sparse/0/",
        description="SIFT features, exhaustive or sequential matching, incremental mapping; writes sparse/0/, "
        "sfm/database.db, sfm/report.json and sfm/transforms.json (to inspect). `build` runs this by itself for a "
        "folder with images/ only; run it by hand to choose the matcher.",
    )
    p.add_argument("scene", help="scene folder with images/")
    p.add_argument("--matcher", choices=("auto", "exhaustive", "sequential"), default="auto", help="(default: auto)")
    p.add_argument("--max-image-size", type=int, default=1600, help="longer side for feature detection (default: 1600)")
    p.add_argument("--max-features", type=int, default=8192, help="SIFT features per image (default: 8192)")
    p.add_argument("--min-registered", type=int, help="fewest registered images accepted (default: max(3, half))")
    p.add_argument("--undistort", action="store_true", help="also write pinhole-undistorted images to sfm/undistorted/")
    p.add_argument("--force", action="store_true", help="recompute even when sparse/0/ exists")
    p.set_defaults(func=_cmd_sfm)

    p = sub.add_parser(
        "upgrade-checkpoint",
        help="convert a checkpoint of an older scenelabel (format 1, pickled) to the current format, in place; "
        "run it only on checkpoints you trust",
        description="Format-1 checkpoints are pickles, which can run any code when read, so scenelabel no longer "
        "reads them. This command reads one the old way (torch.load with weights_only=False) because you ask it "
        "to: run it only on checkpoints you made or trust. The file is rewritten in the current format (tensors "
        "and JSON, read without pickle) atomically; a current checkpoint is left as it is.",
    )
    p.add_argument("path", metavar="PATH", help="build folder (with checkpoint.pt) or checkpoint file")
    p.set_defaults(func=_cmd_upgrade_checkpoint)

    p = sub.add_parser(
        "view",
        help="look at a build (map, cameras, point queries, renders) or a map .zarr in the browser (docs/look.md)",
        description="Serves a local web viewer (viser) and prints its URL; runs until Ctrl-C.",
    )
    p.add_argument("source", metavar="BUILD_OR_MAP", help="build folder (with checkpoint.pt) or map (.zarr folder)")
    p.add_argument("--port", type=int, default=8080, help="TCP port (default: 8080; 0: any free port)")
    p.add_argument("--host", default="127.0.0.1", help="interface to listen on (default: 127.0.0.1: this machine)")
    p.add_argument("--voxel-size", type=float, help="a build's map at this voxel size (default: the build's own map)")
    p.add_argument("--images", metavar="DIR", help="the scene's photos, for the frusta (default: the build's scene)")
    p.add_argument("--device", help="cpu or cuda for the field (default: cuda when available)")
    p.add_argument("--timeout", type=float, metavar="SECONDS", help="stop after SECONDS (default: at Ctrl-C)")
    p.set_defaults(func=_cmd_view)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = make_parser()
    args = parser.parse_args(argv)
    warnings.formatwarning = lambda msg, cat, *a, **k: f"scenelabel: warning: {msg}\n"
    try:
        status = args.func(args)  # None: success; an int: the exit status
    except TrainingInterrupted as err:
        print(f"scenelabel: {err}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except ScenelabelError as err:
        print(f"scenelabel: error: {err}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("scenelabel: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    return status or 0


if __name__ == "__main__":
    sys.exit(main())
