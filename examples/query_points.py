"""What is at these world points? Class, occupancy and the three likeliest classes (public API only).

Run on the toy scene::

    scenelabel toy toy_scene && scenelabel build toy_scene --preset quick
    python examples/query_points.py toy_scene/scenelabel -0.45,-0.25,0.59 0.4,0.25,0.39 0,0,5
    python examples/query_points.py toy_scene/scenelabel 0.4,0.25,0.39 --json     # for programs
    python examples/query_points.py toy_scene/scenelabel 0.4,0.25,0.39 --baked    # from a baked lattice

Points are ``x,y,z`` in the build's world frame and units (a leading minus sign is fine). Per point:
the label (class name where occupied, FREE where modelled and empty, UNKNOWN outside the modelled
bounds), the occupancy ``1 - exp(-density * occupancy_delta)`` in [0, 1] (occupied at >= 0.5) and
the three likeliest classes with their probabilities. The field's density lives on surfaces (the
inside of a solid box was never seen and may read FREE): the points above lie just below the boxes'
top faces. A planner would call
``SemanticField.query_points`` the same way, with all its points in one [N, 3] array; one that
asks millions of points bakes the field once (``BakedField.from_field``, ``--baked`` here) and asks
the baked field, which answers the same questions without the network.
"""

from __future__ import annotations

import argparse
import json
import re
import sys

import numpy as np

from scenelabel import FREE, UNKNOWN, BakedField, ScenelabelError, SemanticField

NUMBER = r"\s*[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?\s*"
POINT = re.compile(rf"^{NUMBER},{NUMBER},{NUMBER}$")


def parse_point(text):
    if not POINT.match(text):
        raise argparse.ArgumentTypeError(f"expected x,y,z (three numbers), got {text!r}")
    return [float(v) for v in text.split(",")]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("build", help="build folder (scenelabel build's output)")
    parser.add_argument("points", nargs="+", type=parse_point, metavar="x,y,z", help="world points")
    parser.add_argument("--json", action="store_true", help="print one JSON list instead of text")
    parser.add_argument("--baked", action="store_true", help="answer from the field baked on a lattice")
    argv = sys.argv[1:] if argv is None else list(argv)
    # "-0.5,0,1" looks like an option to argparse: move the points behind "--".
    options = [a for a in argv if not POINT.match(a) and a != "--"]
    args = parser.parse_args(options + ["--"] + [a for a in argv if POINT.match(a)])

    try:
        field = SemanticField.load(args.build)
        xyz = np.array(args.points)  # [N, 3]
        q = (BakedField.from_field(field) if args.baked else field).query_points(xyz)
    except ScenelabelError as err:
        print(f"query_points: error: {err}", file=sys.stderr)
        return 2
    names = {**field.classes, FREE: "FREE", UNKNOWN: "UNKNOWN"}
    rows = []
    for n, point in enumerate(xyz):
        # outside the modelled bounds the field has no class probabilities (all 0): no top 3
        top = [] if q.label[n] == UNKNOWN else np.argsort(q.probs[n])[::-1][:3]
        top3 = [{"id": int(q.class_ids[c]), "name": names[int(q.class_ids[c])], "prob": float(q.probs[n, c])} for c in top]
        label = int(q.label[n])
        rows.append({"point": point.tolist(), "label": label, "name": names[label], "occupancy": float(q.occupancy[n]), "top3": top3})
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    for row in rows:
        classes = ", ".join(f"{t['name']} {t['prob']:.2f}" for t in row["top3"]) or "-"
        x, y, z = row["point"]
        print(f"({x:g}, {y:g}, {z:g}): {row['name']}, occupancy {row['occupancy']:.3f}; classes: {classes}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
