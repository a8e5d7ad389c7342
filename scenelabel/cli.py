"""The command line: ``scenelabel build | demo | toy | export``.

Errors a user can cause print one line (``scenelabel: error: ...``) and exit with status 2;
they never show a traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

from ._version import __version__
from .config import PRESETS, preset
from .errors import ScenelabelError, TrainingInterrupted

__all__ = ["main"]

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130


def _overrides(args: argparse.Namespace) -> dict:
    train: dict = {}
    if args.steps is not None:
        train["steps"] = args.steps
    if args.time_budget is not None:
        train["time_budget"] = args.time_budget
    if args.seed is not None:
        train["seed"] = args.seed
    if args.holdout is not None:
        train["holdout"] = args.holdout
    overrides: dict = {"train": train}
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


def _add_build_options(p: argparse.ArgumentParser, default_preset: str = "fast") -> None:
    p.add_argument("--out", help="output folder (default: SCENE/scenelabel)")
    p.add_argument(
        "--preset", default=default_preset, choices=sorted(PRESETS), help=f"model/training preset (default: {default_preset})"
    )
    p.add_argument("--steps", type=int, help="training steps")
    p.add_argument("--time-budget", type=float, metavar="SECONDS", help="stop training after this many seconds")
    p.add_argument("--seed", type=int, help="random seed (a build is deterministic for a seed)")
    p.add_argument("--holdout", type=int, help="hold out every N-th view for evaluation (0: train on all)")
    p.add_argument("--voxel-size", type=float, help="occupancy-map voxel size in world units")
    p.add_argument("--config", help="JSON file of config overrides: {section: {key: value}}")
    p.add_argument("--device", help="cpu or cuda (default: cuda when available)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _print_metrics(metrics: dict, out_dir: Path) -> None:
    keys = ["psnr", "ssim", "miou", "miou_smoothed", "depth_error"]
    parts = [f"{k}={metrics[k]:.4f}" for k in keys if k in metrics]
    print(f"held-out ({metrics.get('n_test_views', 0)} views): " + ", ".join(parts))
    print(
        f"trained {metrics['steps']} steps in {metrics['train_seconds']:.1f} s "
        f"({metrics['steps_per_second']:.1f} steps/s); wrote {out_dir}"
    )


def _cmd_build(args: argparse.Namespace) -> None:
    from .pipeline import build, resume_config

    if args.resume:
        out = Path(args.out) if args.out else Path(args.scene) / "scenelabel"
        config = resume_config(out, args.steps, args.time_budget)
    else:
        config = preset(args.preset, _overrides(args))
    result = build(args.scene, args.out, config, progress=not args.quiet, device=args.device, resume=args.resume)
    _print_metrics(result.metrics, result.out_dir)


def _cmd_toy(args: argparse.Namespace) -> None:
    from .synthetic import write_furnished_room, write_toy_scene

    writer = write_furnished_room if args.room else write_toy_scene
    path = writer(args.path)
    print(f"wrote {'furnished room' if args.room else 'toy two-box scene'} to {path}")


def _cmd_demo(args: argparse.Namespace) -> None:
    """Generate the toy two-box scene, build it, print held-out metrics, write renders and map."""
    from .pipeline import build
    from .synthetic import write_toy_scene

    scene_dir = Path(args.path)
    write_toy_scene(scene_dir)
    print(f"toy two-box scene written to {scene_dir}")
    config = preset(args.preset, _overrides(args))
    out = Path(args.out) if args.out else scene_dir / "scenelabel"
    result = build(scene_dir, out, config, progress=not args.quiet, device=args.device)
    _print_metrics(result.metrics, result.out_dir)
    print(f"renders: {out / 'renders'}   map: {out / 'map.zarr'}")


def _cmd_export(args: argparse.Namespace) -> None:
    from .semantic_field import SemanticField

    field = SemanticField.load(args.build)
    occ = field.occupancy_map(args.voxel_size)
    path = occ.to_zarr(args.out, zarr_format=args.zarr_format)
    print(f"wrote {path}: {occ.shape} voxels of {occ.voxel_size:g}")


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="scenelabel", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"scenelabel {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("build", help="train a semantic field on a scene folder")
    p.add_argument("scene", help="scene folder (images/, labels/, classes.json, transforms.json or poses_bounds.npy)")
    _add_build_options(p)
    p.add_argument(
        "--resume",
        action="store_true",
        help="continue from the checkpoint in the output folder, with its saved config (--steps/--time-budget may extend it)",
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

    p = sub.add_parser("export", help="export the occupancy map of a build")
    p.add_argument("build", help="build folder (with checkpoint.pt)")
    p.add_argument("out", help="output .zarr path")
    p.add_argument("--voxel-size", type=float, help="voxel size in world units (default: from the images)")
    p.add_argument("--zarr-format", type=int, choices=(2, 3), default=3)
    p.set_defaults(func=_cmd_export)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = make_parser()
    args = parser.parse_args(argv)
    warnings.formatwarning = lambda msg, cat, *a, **k: f"scenelabel: warning: {msg}\n"
    try:
        args.func(args)
    except TrainingInterrupted as err:
        print(f"scenelabel: {err}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except ScenelabelError as err:
        print(f"scenelabel: error: {err}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("scenelabel: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    return 0


if __name__ == "__main__":
    sys.exit(main())
