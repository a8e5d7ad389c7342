"""Regenerate docs/images/render_panel.png: a held-out view of the toy scene as ``build`` draws it.

    .venv/bin/python tools/pictures.py             # the toy scene and a quick build in a temporary folder (minutes)
    .venv/bin/python tools/pictures.py --build toy_scene/scenelabel --scene toy_scene   # reuse a build

The picture is :func:`scenelabel.viz.pictures.write_panels` of the first held-out view, exactly what
``build`` writes to ``renders/<view>.png`` (scenelabel.train.evaluation.evaluate).
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "images" / "render_panel.png"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200, help="training steps of the quick build (default: 200)")
    parser.add_argument("--build", type=Path, help="an existing build folder of the toy scene (skips training)")
    parser.add_argument("--scene", type=Path, help="its scene folder (default: the build folder's parent)")
    parser.add_argument("--out", type=Path, default=OUT, help=f"the PNG to write (default: {OUT.relative_to(ROOT)})")
    args = parser.parse_args()

    from scenelabel import SemanticField, build, preset, write_toy_scene
    from scenelabel.data.io import load_scene
    from scenelabel.train.evaluation import evaluate
    from scenelabel.train.pipeline import choose_views

    with tempfile.TemporaryDirectory() as tmp:
        if args.build is None:
            scene_dir = write_toy_scene(Path(tmp) / "toy_scene")
            overrides = {"train": {"steps": args.steps}, "output": {"write_map": False, "write_renders": False}}
            config = preset("quick", overrides)
            out_dir = build(scene_dir, Path(tmp) / "build", config, progress=True).out_dir
        else:
            out_dir, scene_dir = args.build, args.scene or args.build.resolve().parent
        field = SemanticField.load(out_dir)
        scene = load_scene(scene_dir, field.config.data.downscale)
        _, test, _ = choose_views(scene, field.config.train.holdout)
        renders = Path(tmp) / "renders"
        renders.mkdir()
        metrics = evaluate(field, scene, test[:1], field.config.output.smooth_sigma, renders)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(renders / f"{scene.names[test[0]]}.png", args.out)
    view = metrics["per_view"][0]
    miou = view.get("miou", float("nan"))
    print(f"wrote {args.out}: view {view['view']}, PSNR {view['psnr']:.2f} dB, mIoU {miou:.3f}")


if __name__ == "__main__":
    main()
