"""A procedurally varied suite of furnished rooms: the scenes the project's defaults are chosen on.

Each :class:`SuiteSpec` in :data:`SUITE` fully determines one room (deterministic for its seed):
geometry (:func:`suite_geometry`: floor, ceiling and walls as 10 cm slabs plus furniture built
from templates, placed by a seeded generator), textures (plain: nearly uniform, very low
contrast; mixed: like the furnished room; busy: soft checkers / stripes of 5-10 cm period) and a
camera path (:func:`suite_cameras`: "walk" along the walls, "orbit" round the room centre looking
outward and across, "handheld" a wobbling loop, "forward" an LLFF-like rig: photos taken from a
small patch near one wall, all looking across the room). :func:`write_suite_scene` renders with the exact
ray caster of :mod:`scenelabel.data.synthetic` and writes no near/far and no aabb, like users' files.

Frame: world z up, metres; the interior is ``[0, sx] x [0, sy] x [0, h]`` for ``size = (sx, sy,
h)``. One class vocabulary (:data:`SUITE_CLASSES`, non-contiguous ids; background / ignore 255);
only classes a room has boxes for appear in its labels. Furniture parts are named
``"<kind>#<piece>/<part>"`` (``"table#0/leg"``); the slabs are :data:`STRUCTURAL_PARTS`.

Rooms with ``tuning=False`` are held out: they stay out of every tuning decision and are
reported apart. Views form one closed interleaved loop (view i sits between views i - 1 and
i + 1), so the project's hold-out (index % 8 == 0) falls between training views; views tilt up
and down from one view to the next so that floor and ceiling are seen by training views.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scenelabel.data.synthetic import Box, ClassInfo, SyntheticScene, cast_rays, look_at, write_scene
from scenelabel.data.synthetic.geometry import Texture
from scenelabel.data.synthetic.textures import patterned_texture
from scenelabel.errors import InputError

__all__ = [
    "CAMERA_CLEARANCE",
    "FOV_X_DEG",
    "FORWARD_SUITE",
    "LAYOUT_POOL",
    "RIG_HALF_WIDTH",
    "RIG_HEIGHTS",
    "SUITE",
    "SUITE_CLASSES",
    "STRUCTURAL_PARTS",
    "SuiteSpec",
    "check_cameras",
    "forward_cameras",
    "loop_positions",
    "suite_cameras",
    "suite_geometry",
    "suite_spec",
    "write_suite_scene",
]

FOV_X_DEG = 60.0  # horizontal field of view of every suite camera
CAMERA_CLEARANCE = 0.25  # every camera is at least this far (m) from every box
WALK_CLEAR, LOOP_CLEAR = 0.6, 0.5  # target clearance of walk cameras / of orbit and handheld cameras
OPENING = 0.15  # radius (m) of the morphological opening that rounds camera loops
SLAB = 0.1  # thickness of walls, floor and ceiling
STRUCTURAL_PARTS = ("floor", "ceiling", "wall_x-", "wall_x+", "wall_y-", "wall_y+")

FLOOR, WALL, CEILING, TABLE, CHAIR, SOFA = 1, 2, 4, 6, 7, 9
CABINET, SHELF, BED, LAMP, PICTURE, DOOR = 12, 14, 16, 20, 23, 25
SUITE_CLASSES: tuple[ClassInfo, ...] = (
    ClassInfo(FLOOR, "floor", (160, 110, 60)),
    ClassInfo(WALL, "wall", (200, 200, 170)),
    ClassInfo(CEILING, "ceiling", (235, 235, 255)),
    ClassInfo(TABLE, "table", (120, 60, 20)),
    ClassInfo(CHAIR, "chair", (220, 60, 50)),
    ClassInfo(SOFA, "sofa", (40, 170, 80)),
    ClassInfo(CABINET, "cabinet", (50, 100, 220)),
    ClassInfo(SHELF, "shelf", (150, 90, 200)),
    ClassInfo(BED, "bed", (240, 150, 180)),
    ClassInfo(LAMP, "lamp", (240, 200, 20)),
    ClassInfo(PICTURE, "picture", (20, 200, 200)),
    ClassInfo(DOOR, "door", (130, 90, 50)),
)


@dataclass(frozen=True)
class SuiteSpec:
    """One suite room.

    name: unique name ("<theme>-<sx>x<sy>"); seed: geometry / texture / camera seed;
    size: (sx, sy, h) interior extent in metres (interior ``[0, sx] x [0, sy] x [0, h]``);
    furniture: number of furniture pieces (pictures and doors count as pieces);
    texture: "plain" | "mixed" | "busy"; path: "walk" | "orbit" | "handheld" | "forward";
    n_views, width, height: view count and image size; tuning: False = held out.
    """

    name: str
    seed: int
    size: tuple[float, float, float]
    furniture: int
    texture: str
    path: str
    n_views: int
    width: int
    height: int
    tuning: bool = True


SUITE: tuple[SuiteSpec, ...] = (
    SuiteSpec("studio-3x3", 11, (3.0, 3.0, 2.4), 4, "mixed", "handheld", 40, 160, 120, True),
    SuiteSpec("bedroom-4x4", 12, (4.0, 4.0, 2.5), 5, "plain", "walk", 40, 160, 120, True),
    SuiteSpec("kitchen-4x3", 13, (4.0, 3.2, 2.6), 5, "busy", "handheld", 40, 160, 120, False),
    SuiteSpec("office-5x4", 14, (5.0, 4.0, 2.7), 7, "busy", "walk", 48, 160, 120, True),
    SuiteSpec("living-6x5", 15, (6.0, 5.0, 2.7), 8, "mixed", "orbit", 48, 160, 120, True),
    SuiteSpec("den-5x5", 16, (5.0, 5.0, 2.6), 6, "plain", "orbit", 40, 160, 120, False),
    SuiteSpec("library-7x4", 17, (7.0, 4.0, 3.0), 9, "busy", "walk", 56, 160, 120, True),
    SuiteSpec("gallery-8x5", 18, (8.0, 5.0, 3.2), 8, "mixed", "walk", 56, 160, 120, False),
    SuiteSpec("hall-10x6", 19, (10.0, 6.0, 3.2), 10, "plain", "walk", 60, 160, 120, True),
    # one room at three view densities / resolutions (same seed, same geometry)
    SuiteSpec("sparse-5x4", 20, (5.0, 4.0, 2.6), 4, "mixed", "handheld", 20, 160, 120, True),
    SuiteSpec("dense-5x4", 20, (5.0, 4.0, 2.6), 4, "mixed", "handheld", 150, 160, 120, True),
    SuiteSpec("hires-5x4", 20, (5.0, 4.0, 2.6), 4, "mixed", "handheld", 26, 640, 480, True),
)

# Forward-facing captures (LLFF's layout, like fern): every photo from a patch about 0.6 x 0.4 m near
# one wall, looking across the room. New seeds and layouts: none of these rooms is a SUITE room.
FORWARD_SUITE: tuple[SuiteSpec, ...] = (
    SuiteSpec("living-6x5-forward", 31, (6.0, 5.0, 2.7), 8, "mixed", "forward", 30, 160, 120, True),
    SuiteSpec("office-5x4-forward", 32, (5.0, 4.0, 2.7), 7, "busy", "forward", 30, 160, 120, True),
    SuiteSpec("bedroom-4x4-forward", 33, (4.0, 4.0, 2.5), 5, "plain", "forward", 24, 160, 120, False),
    SuiteSpec("gallery-8x5-forward", 34, (8.0, 5.0, 3.2), 8, "mixed", "forward", 30, 160, 120, False),
)

# Forward-facing rooms that only the room layout's probe writes (tools/probe_layout.py, docs/layout.md):
# no build, no suite run. The suite's held-out forward rooms stay out of the layout's decisions; these
# are what those decisions are checked on.
LAYOUT_POOL: tuple[SuiteSpec, ...] = tuple(
    SuiteSpec(f"{theme}-{size[0]:g}x{size[1]:g}-forward-{seed}", seed, size, furniture, texture, "forward", 24 + 2 * (seed % 4), 160, 120)
    for seed, (theme, size, furniture, texture) in enumerate(
        (("studio", (3.0, 3.0, 2.4), 4, "mixed"), ("kitchen", (4.0, 3.2, 2.6), 5, "busy"),
         ("den", (5.0, 5.0, 2.6), 6, "plain"), ("library", (7.0, 4.0, 3.0), 9, "busy"),
         ("hall", (10.0, 6.0, 3.2), 10, "plain"), ("office", (5.0, 4.0, 2.7), 7, "mixed"),
         ("living", (6.0, 5.0, 2.7), 8, "plain"), ("bedroom", (4.0, 4.0, 2.5), 5, "busy"),
         ("gallery", (8.0, 5.0, 3.2), 8, "busy"), ("studio", (3.5, 3.0, 2.5), 4, "plain")),
        start=51,
    )
)

#: furniture kinds a room of a theme (name before "-") gets first; the rest are drawn at random
THEMES: dict[str, tuple[str, ...]] = {
    "studio": ("table", "chair", "lamp", "picture", "cabinet", "shelf"),
    "bedroom": ("bed", "cabinet", "lamp", "picture", "shelf", "chair"),
    "kitchen": ("cabinet", "table", "chair", "cabinet", "shelf", "picture"),
    "office": ("table", "chair", "shelf", "cabinet", "door", "picture", "lamp", "shelf"),
    "living": ("sofa", "table", "lamp", "shelf", "picture", "picture", "cabinet", "chair"),
    "den": ("sofa", "shelf", "lamp", "table", "picture", "door"),
    "library": ("shelf", "shelf", "shelf", "table", "chair", "lamp", "picture", "door", "chair"),
    "gallery": ("picture", "picture", "picture", "picture", "sofa", "lamp", "door", "picture"),
    "hall": ("door", "sofa", "table", "chair", "chair", "cabinet", "picture", "picture", "lamp", "shelf"),
    **dict.fromkeys(("sparse", "dense", "hires"), ("table", "lamp", "cabinet", "picture")),
}
RANDOM_KINDS = ("table", "chair", "cabinet", "shelf", "lamp", "picture")


def suite_spec(name: str) -> SuiteSpec:
    """The :data:`SUITE`, :data:`FORWARD_SUITE` or :data:`LAYOUT_POOL` entry called ``name``
    (InputError naming the known names otherwise)."""
    rooms = SUITE + FORWARD_SUITE + LAYOUT_POOL
    for spec in rooms:
        if spec.name == name:
            return spec
    raise InputError(f"unknown suite room {name!r}; known: {', '.join(s.name for s in rooms)}", field="name")


def _check_spec(spec: SuiteSpec) -> None:
    for field, allowed in (("texture", ("plain", "mixed", "busy")), ("path", ("walk", "orbit", "handheld", "forward"))):
        if getattr(spec, field) not in allowed:
            raise InputError(f"{field} must be one of {allowed}, got {getattr(spec, field)!r}", field=field)
    if spec.n_views < 2 or spec.width < 1 or spec.height < 1 or spec.furniture < 0:
        raise InputError(f"bad view count / size / furniture in {spec}", field="n_views")


# --------------------------------------------------------------------------------------------
# Textures: t(points, normals) in [0, 1] blended between two colours with a contrast per level


# class -> (pattern, colour 0, colour 1, period for "mixed", period for "busy")
LOOKS: dict[int, tuple[str, tuple, tuple, float, float]] = {
    FLOOR: ("wood", (0.80, 0.63, 0.42), (0.60, 0.45, 0.30), 0.45, 0.08),
    WALL: ("stripes", (0.88, 0.85, 0.78), (0.70, 0.74, 0.70), 0.8, 0.06),
    CEILING: ("checker", (0.97, 0.97, 0.97), (0.82, 0.82, 0.88), 1.0, 0.10),
    TABLE: ("wood", (0.45, 0.28, 0.16), (0.30, 0.18, 0.10), 0.2, 0.05),
    CHAIR: ("diagonal", (0.75, 0.28, 0.22), (0.55, 0.18, 0.15), 0.25, 0.06),
    SOFA: ("checker", (0.25, 0.58, 0.36), (0.15, 0.40, 0.25), 0.4, 0.07),
    CABINET: ("stripes", (0.30, 0.46, 0.74), (0.20, 0.33, 0.58), 0.3, 0.05),
    SHELF: ("wood", (0.58, 0.42, 0.28), (0.42, 0.30, 0.20), 0.15, 0.05),
    BED: ("stripes", (0.88, 0.82, 0.90), (0.70, 0.60, 0.78), 0.3, 0.07),
    LAMP: ("diagonal", (0.95, 0.82, 0.32), (0.80, 0.66, 0.20), 0.2, 0.05),
    PICTURE: ("painting", (0.15, 0.55, 0.70), (0.90, 0.45, 0.20), 0.25, 0.08),
    DOOR: ("wood", (0.62, 0.46, 0.30), (0.48, 0.34, 0.22), 0.3, 0.06),
}
CONTRAST = {"plain": 0.06, "mixed": 1.0, "busy": 1.0}


def _textures(spec: SuiteSpec) -> dict[int, Texture]:
    """One texture per vocabulary class for the spec's texture level; colours jittered by seed."""
    rng = np.random.default_rng([spec.seed, 2])
    out = {}
    for info in SUITE_CLASSES:
        pattern, c0, c1, period_mixed, period_busy = LOOKS[info.id]
        jitter = 1.0 + rng.uniform(-0.08, 0.08, 3)
        c0, c1 = np.clip(np.asarray(c0) * jitter, 0, 1), np.clip(np.asarray(c1) * jitter, 0, 1)
        pattern = "tiles" if spec.texture == "busy" and info.id == FLOOR else pattern
        period = period_busy if spec.texture == "busy" else period_mixed
        contrast = CONTRAST[spec.texture] if info.id != PICTURE else max(0.3, CONTRAST[spec.texture])
        out[info.id] = patterned_texture(pattern, c0, c1, period, contrast, spec.size[2] if info.id == WALL else None)
    return out


# --------------------------------------------------------------------------------------------
# Furniture templates: local frame x along the wall [0, w], y away from the wall [0, d], z up


@dataclass
class _Template:
    kind: str
    class_id: int
    parts: list  # (lo, hi, part) in the local frame
    wall_prob: float  # probability of standing against a wall (else free-standing)
    wall_gap: float = 0.0  # distance from the wall when against one
    keepout_depth: float = 0.0  # extra clear depth in front (doors)


def _template(kind: str, rng: np.random.Generator) -> _Template:
    u = rng.uniform
    if kind == "table":
        w, d, top, th, leg = u(0.9, 1.5), u(0.6, 0.85), u(0.72, 0.76), u(0.03, 0.04), u(0.04, 0.05)
        parts = [((0, 0, top - th), (w, d, top), "top")]
        for x0 in (0.03, w - 0.03 - leg):
            for y0 in (0.03, d - 0.03 - leg):
                parts.append(((x0, y0, 0), (x0 + leg, y0 + leg, top - th), "leg"))
        return _Template(kind, TABLE, parts, 0.35)
    if kind == "chair":
        s, seat, leg = u(0.42, 0.48), u(0.44, 0.47), u(0.04, 0.045)
        parts = [((0, 0, seat - 0.04), (s, s, seat), "seat"), ((0, 0, seat), (s, 0.04, seat + u(0.4, 0.5)), "back")]
        for x0 in (0.0, s - leg):
            for y0 in (0.0, s - leg):
                parts.append(((x0, y0, 0), (x0 + leg, y0 + leg, seat - 0.04), "leg"))
        return _Template(kind, CHAIR, parts, 0.3, wall_gap=0.05)
    if kind == "sofa":
        w, d, arm = u(1.6, 2.2), u(0.85, 0.95), u(0.16, 0.2)
        parts = [((arm, 0.22, 0), (w - arm, d, 0.42), "seat"), ((0, 0, 0), (w, 0.22, u(0.8, 0.9)), "back"),
                 ((0, 0.22, 0), (arm, d, 0.62), "arm"), ((w - arm, 0.22, 0), (w, d, 0.62), "arm")]
        return _Template(kind, SOFA, parts, 0.8)
    if kind == "cabinet":
        w, d, h = u(0.6, 1.2), u(0.4, 0.55), u(0.8, 2.0)
        parts = [((0, 0, 0), (w, d, h), "body"), ((0.02, d, 0.08), (w - 0.02, d + 0.02, h - 0.04), "front")]
        return _Template(kind, CABINET, parts, 1.0)
    if kind == "shelf":
        w, d, h, board = u(0.7, 1.2), u(0.28, 0.36), u(1.5, 2.0), u(0.02, 0.03)
        side, back = 0.02, 0.015
        parts = [((0, 0, 0), (side, d, h), "side"), ((w - side, 0, 0), (w, d, h), "side"),
                 ((side, 0, 0), (w - side, back, h), "back")]
        n_boards = int(rng.integers(4, 6))
        for k in range(n_boards):
            z = k * (h - board) / (n_boards - 1)
            parts.append(((side, back, z), (w - side, d, z + board), "board"))
        return _Template(kind, SHELF, parts, 1.0)
    if kind == "bed":
        w, d = u(1.4, 1.6), u(1.95, 2.05)
        parts = [((0, 0, 0), (w, 0.05, u(0.95, 1.1)), "headboard"), ((0, 0.05, 0), (w, d, 0.3), "frame"),
                 ((0.03, 0.05, 0.3), (w - 0.03, d - 0.03, 0.5), "mattress")]
        return _Template(kind, BED, parts, 1.0)
    if kind == "lamp":
        base, pole, h, shade = u(0.25, 0.32), u(0.03, 0.04), u(1.45, 1.65), u(0.35, 0.45)
        c = shade / 2
        parts = [
            ((c - base / 2, c - base / 2, 0), (c + base / 2, c + base / 2, 0.03), "base"),
            ((c - pole / 2, c - pole / 2, 0.03), (c + pole / 2, c + pole / 2, h), "pole"),
            ((0, 0, h), (shade, shade, h + u(0.25, 0.32)), "shade"),
        ]
        return _Template(kind, LAMP, parts, 0.5, wall_gap=0.08)
    if kind == "picture":
        w, h, z0 = u(0.4, 1.0), u(0.3, 0.7), u(1.15, 1.45)
        return _Template(kind, PICTURE, [((0, 0, z0), (w, 0.02, z0 + h), "frame")], 1.0)
    if kind == "door":
        w, h = u(0.8, 0.9), u(2.0, 2.1)
        parts = [((0, 0, 0), (w, 0.04, h), "panel"), ((w - 0.16, 0.04, 0.98), (w - 0.04, 0.07, 1.02), "handle")]
        return _Template(kind, DOOR, parts, 1.0, keepout_depth=0.9)
    raise InputError(f"unknown furniture kind {kind!r}", field="kind")


def _rotate(lo, hi, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Box corners rotated by k x 90 degrees about the z axis."""
    c = np.array([[lo[0], lo[1]], [hi[0], hi[1]]], np.float64)
    for _ in range(k % 4):
        c = np.stack([-c[:, 1], c[:, 0]], axis=1)
    return np.array([*c.min(axis=0), lo[2]]), np.array([*c.max(axis=0), hi[2]])


def _place(tpl: _Template, spec: SuiteSpec, rng: np.random.Generator):
    """Random placement of a template: (boxes [(lo, hi, part)], keep-out (lo, hi)) in world."""
    sx, sy, _ = spec.size
    parts = list(tpl.parts)
    if tpl.keepout_depth:
        parts.append(((0, 0, 0), (max(p[1][0] for p in parts), tpl.keepout_depth, 2.0), "keepout"))
    against_wall = rng.uniform() < tpl.wall_prob
    k = int(rng.integers(4))  # wall y-, x+, y+, x- (local +y points into the room) or free rotation
    rotated = [(*_rotate(lo, hi, k), name) for lo, hi, name in parts]
    lo_all = np.min([r[0] for r in rotated], axis=0)
    hi_all = np.max([r[1] for r in rotated], axis=0)
    fx, fy = hi_all[0] - lo_all[0], hi_all[1] - lo_all[1]
    gap = tpl.wall_gap
    if against_wall:
        along = (sx - fx) if k % 2 == 0 else (sy - fy)
        if along < 0.1:
            return None
        t = rng.uniform(0.05, along - 0.05)
        corner = {0: (t, gap), 1: (sx - gap - fx, t), 2: (t, sy - gap - fy), 3: (gap, t)}[k]
    else:
        margin = 0.4
        if sx - fx < 2 * margin or sy - fy < 2 * margin:
            return None
        corner = (rng.uniform(margin, sx - fx - margin), rng.uniform(margin, sy - fy - margin))
    shift = np.array([corner[0] - lo_all[0], corner[1] - lo_all[1], 0.0])
    boxes = [(lo + shift, hi + shift, name) for lo, hi, name in rotated if name != "keepout"]
    return boxes, (lo_all + shift, hi_all + shift)


def _choose_kinds(spec: SuiteSpec, rng: np.random.Generator) -> list[str]:
    theme = THEMES.get(spec.name.split("-")[0], ())
    kinds = list(theme[: spec.furniture])
    while len(kinds) < spec.furniture:
        kinds.append(str(rng.choice(RANDOM_KINDS)))
    return kinds


def _structure(spec: SuiteSpec) -> list[Box]:
    (sx, sy, h), s = spec.size, SLAB
    return [
        Box((-s, -s, -s), (sx + s, sy + s, 0.0), FLOOR, "floor"),
        Box((-s, -s, h), (sx + s, sy + s, h + s), CEILING, "ceiling"),
        Box((-s, -s, 0.0), (0.0, sy + s, h), WALL, "wall_x-"),
        Box((sx, -s, 0.0), (sx + s, sy + s, h), WALL, "wall_x+"),
        Box((0.0, -s, 0.0), (sx, 0.0, h), WALL, "wall_y-"),
        Box((0.0, sy, 0.0), (sx, sy + s, h), WALL, "wall_y+"),
    ]


def suite_geometry(spec: SuiteSpec) -> SyntheticScene:
    """The room of ``spec`` as a :class:`~scenelabel.data.synthetic.SyntheticScene` (deterministic).

    Floor, ceiling and walls are 10 cm slabs outside the interior. ``spec.furniture`` pieces
    (kinds from the room's theme, then random) are placed one by one by a seeded generator,
    each retried until it stays inside the room, 5 cm clear of every other piece (and of the
    space in front of a door) and leaves the free floor space one region a camera can go round
    (:func:`_free_space_ok`). Most kinds stand against a wall (local +y into the room), some free.
    ``classes`` lists the whole suite vocabulary.
    """
    _check_spec(spec)
    rng = np.random.default_rng([spec.seed, 1])
    sx, sy, h = spec.size
    boxes = _structure(spec)
    keepouts, footprints = [], []  # per piece (lo, hi) 3D keep-out boxes; 2D footprints of all boxes
    for index, kind in enumerate(_choose_kinds(spec, rng)):
        for _attempt in range(300):
            tpl = _template(kind, rng)
            placed = _place(tpl, spec, rng)
            if placed is None:
                continue
            pboxes, (klo, khi) = placed
            if np.any(klo < -1e-9) or np.any(khi > np.array([sx, sy, h - 0.05]) + 1e-9):
                continue
            if any(np.all(klo < ohi + 0.05) and np.all(khi > olo - 0.05) for olo, ohi in keepouts):
                continue
            trial = footprints + [(lo[:2], hi[:2]) for lo, hi, _ in pboxes]
            if not _free_space_ok(spec, trial):
                continue
            break
        else:
            raise AssertionError(f"{spec.name}: could not place {kind} #{index}")
        keepouts.append((klo, khi))
        footprints = trial
        for lo, hi, part in pboxes:
            boxes.append(Box(tuple(map(float, lo)), tuple(map(float, hi)), tpl.class_id, f"{kind}#{index}/{part}"))
    return SyntheticScene(spec.name, tuple(boxes), SUITE_CLASSES, _textures(spec), frame_id=f"suite_{spec.name}")


# --------------------------------------------------------------------------------------------
# Camera loops: boundaries of the floor space with enough 2D clearance to walls and furniture


def _clearance(points: np.ndarray, size, rects) -> np.ndarray:
    """[...] 2D distance of points [..., 2] to the walls and to every footprint rectangle."""
    x, y = points[..., 0], points[..., 1]
    d = np.minimum(np.minimum(x, size[0] - x), np.minimum(y, size[1] - y))
    for lo, hi in rects:
        dx = np.maximum(np.maximum(lo[0] - x, x - hi[0]), 0.0)
        dy = np.maximum(np.maximum(lo[1] - y, y - hi[1]), 0.0)
        d = np.minimum(d, np.hypot(dx, dy))
    return d


def _field(spec: SuiteSpec, rects, step: float):
    """Grid (xs [nx], ys [ny]) over the interior and the 2D clearance field [ny, nx] on it."""
    sx, sy, _ = spec.size
    xs, ys = np.arange(0.0, sx + step / 2, step), np.arange(0.0, sy + step / 2, step)
    gx, gy = np.meshgrid(xs, ys)
    return xs, ys, _clearance(np.stack([gx, gy], -1), spec.size, rects)


def _region(spec: SuiteSpec, xs, ys, d, target: float, pole=None, opening: float = OPENING) -> np.ndarray:
    """Field [ny, nx], >= 0 where clearance >= target (and, given a pole, inside the orbit's circle /
    handheld's wobbly star round it), morphologically opened with radius ``opening``."""
    from scipy import ndimage  # scipy is a dependency

    field = d - target
    if pole is not None:
        gx, gy = np.meshgrid(xs, ys)
        r = np.hypot(gx - pole[0], gy - pole[1])
        if spec.path == "orbit":
            r_nom = np.clip(0.28 * min(spec.size[:2]), 0.5, 1.4)
        else:
            ang = np.arctan2(gy - pole[1], gx - pole[0])
            r_nom = 0.3 * min(spec.size[:2]) * (1.0 + 0.35 * np.sin(3 * ang + spec.seed))
        field = np.minimum(field, r_nom - r)
    step = xs[1] - xs[0]
    core = ndimage.distance_transform_edt(field >= 0) * step > opening
    if core.any():  # morphological opening: no narrow spikes or necks in the loop
        field = opening - ndimage.distance_transform_edt(~core) * step
    return field


def _largest_area(field: np.ndarray, step: float) -> float:
    """Largest connected area (m^2) of field >= 0."""
    from scipy import ndimage

    labels, n = ndimage.label(field >= 0)
    return float(np.bincount(labels.ravel())[1:].max()) * step * step if n else 0.0


def _free_space_ok(spec: SuiteSpec, rects) -> bool:
    """One region a person can walk round (WALK_CLEAR from walls / furniture, opened) of >= 1 m^2
    holds >= 90% of the room's free space at that clearance."""
    step = 0.05
    xs, ys, d = _field(spec, rects, step)
    target = min(WALK_CLEAR, 0.8 * d.max())  # checked on a coarse grid with a wider opening: conservative
    largest = _largest_area(_region(spec, xs, ys, d, target, opening=OPENING + 0.1), step)
    return largest >= 1.0 and largest >= 0.9 * float((d >= target).sum()) * step * step


def _best_pole(spec: SuiteSpec, rects) -> np.ndarray:
    """Pole of an orbit / handheld loop: the point whose loop region is largest, near the centre.

    Orbit poles may sit on furniture (the loop then circles it); handheld poles are free.
    """
    step = 0.05
    xs, ys, d = _field(spec, rects, step)
    target = min(LOOP_CLEAR, 0.8 * d.max())
    centre = np.array(spec.size[:2]) / 2
    centre_weight = 0.8 if spec.path == "orbit" else 0.3
    best, best_score = None, -np.inf
    for px in np.arange(0.25, spec.size[0], 0.25):
        for py in np.arange(0.25, spec.size[1], 0.25):
            pole = np.array([px, py])
            if spec.path == "handheld" and _clearance(pole, spec.size, rects) < target + 0.1:
                continue  # an orbit may circle furniture; a handheld loop goes round free space
            area = _largest_area(_region(spec, xs, ys, d, target, pole), step)
            score = area * (1.0 - centre_weight * np.linalg.norm(pole - centre) / min(spec.size[:2]))
            if score > best_score:
                best, best_score = pole, score
    if best is None:
        raise AssertionError(f"{spec.name}: no free point for the camera loop")
    return best


def loop_positions(spec: SuiteSpec, scene: SyntheticScene):
    """Dense closed loop [m, 2] of camera positions and the point it goes round.

    The loop is the outer boundary (marching squares) of the largest component of the camera
    region (:func:`_region`); "walk" goes round the room's centre of free space.
    """
    from skimage.measure import find_contours  # scikit-image is a dependency

    rects = [(np.array(b.lo[:2]), np.array(b.hi[:2])) for b in scene.boxes if b.part not in STRUCTURAL_PARTS]
    step = 0.025
    xs, ys, d = _field(spec, rects, step)
    target = min(WALK_CLEAR if spec.path == "walk" else LOOP_CLEAR, 0.8 * d.max())
    pole = None if spec.path == "walk" else _best_pole(spec, rects)
    field = _region(spec, xs, ys, d, target, pole)
    best, best_area = None, 0.0
    for contour in find_contours(field, 0.0):
        if len(contour) < 4 or np.any(contour[0] != contour[-1]):
            continue
        xy = np.stack([contour[:, 1] * step, contour[:, 0] * step], -1)[:-1]
        area = 0.5 * abs(np.sum(xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1]))
        if area > best_area:
            best, best_area = xy, area
    if best is None:
        raise AssertionError(f"{spec.name}: no camera loop fits")
    pole = best.mean(axis=0) if pole is None else pole
    # smooth (circular moving average over ~0.25 m), keep the raw point where clearance drops
    smooth = np.mean([np.roll(best, k, axis=0) for k in range(-5, 6)], axis=0)
    ok = _clearance(smooth, spec.size, rects) >= 0.9 * target
    return np.where(ok[:, None], smooth, best), pole


def _coprime_near(n: int, x: float) -> int:
    """The k in 1..n coprime with n closest to x."""
    return min((k for k in range(1, n + 1) if math.gcd(k, n) == 1), key=lambda k: abs(k - x))


def suite_cameras(spec: SuiteSpec, scene: SyntheticScene) -> np.ndarray:
    """[n_views, 4, 4] OpenGL camera-to-world on one closed, interleaved loop (deterministic).

    The loop is the boundary of the free floor space where a camera keeps a clearance from
    walls and furniture (2D, so also from table tops below the eye): "walk" 0.6 m, along the
    walls and furniture fronts; "orbit" 0.5 m, within a 0.5-1.4 m circle round a point near the
    room centre (it may circle a central table); "handheld" 0.5 m, within a wobbling star round
    a free point. The region is opened (no spikes), its boundary traced (marching squares),
    smoothed and sampled at equal arc length (jittered). Eye heights 1.0-1.8 m. Walk cameras
    look inward +-0.9 rad (across and along the walls), orbit cameras turn from outward over
    sideways to across within every ~3 views, handheld cameras look across +-0.8 rad; a view
    whose horizontal central ray hits something closer than 1.5 m turns away. "forward":
    :func:`forward_cameras`. Targets lie 2 m
    ahead at heights between about 0.1 m and ceiling - 0.2 m, alternating up / down from one
    view to the next, so floor and ceiling are seen by training views.
    Raises AssertionError if a camera is outside the room or within CAMERA_CLEARANCE of a box.
    """
    _check_spec(spec)
    if spec.path == "forward":
        return forward_cameras(spec, scene)
    h, n = spec.size[2], spec.n_views
    rng = np.random.default_rng([spec.seed, 3])
    loop, pole = loop_positions(spec, scene)
    seg = np.linalg.norm(np.roll(loop, -1, axis=0) - loop, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    length = cum[-1]
    s = (rng.uniform(0, length) + (np.arange(n) + rng.uniform(-0.2, 0.2, n)) * length / n) % length
    closed = np.concatenate([loop, loop[:1]])
    xy = np.stack([np.interp(s, cum, closed[:, 0]), np.interp(s, cum, closed[:, 1])], -1)
    theta = np.arctan2(xy[:, 1] - pole[1], xy[:, 0] - pole[0])  # direction from the pole
    phase = 2 * np.pi * np.arange(n) / n
    z = 1.4 + 0.35 * np.sin(2 * phase + rng.uniform(0, 2 * np.pi)) + rng.uniform(-0.03, 0.03, n)
    eyes = np.concatenate([xy, z[:, None]], axis=1)
    b = rng.uniform(0, 2 * np.pi)
    if spec.path == "walk":
        to_pole = np.arctan2(pole[1] - xy[:, 1], pole[0] - xy[:, 0])
        az = to_pole + 0.9 * np.sin(3 * phase + b)
    elif spec.path == "orbit":
        m = max(2, n // 3)  # the view turns outward / sideways / across within every ~3 views
        az = theta + np.pi / 2 + (np.pi / 2 + 0.25) * np.sin(m * phase + b)
    else:
        az = theta + np.pi + 0.8 * np.sin(5 * phase + b)
    az = _turn_from_close_surfaces(eyes, az, scene, min_depth=1.5)
    k = _coprime_near(n, 0.43 * n)  # ~ half a cycle per view: neighbours alternate up / down
    z_lo, z_hi = 0.1, h - 0.2
    tz = 0.5 * (z_lo + z_hi) + 0.5 * (z_hi - z_lo) * np.sin(k * phase + rng.uniform(0, 2 * np.pi))
    targets = np.stack([xy[:, 0] + 2.0 * np.cos(az), xy[:, 1] + 2.0 * np.sin(az), tz], axis=1)
    check_cameras(spec, scene, eyes)
    return np.stack([look_at(e, t) for e, t in zip(eyes, targets)])


RIG_HALF_WIDTH, RIG_HEIGHTS = 0.3, (1.2, 1.6)  # the forward rig's patch: +-0.3 m across, eyes 1.2-1.6 m
RIG_TURN_DEG = 8.0  # each forward camera turns up to this far (azimuth) from the rig's direction


def forward_cameras(spec: SuiteSpec, scene: SyntheticScene) -> np.ndarray:
    """[n_views, 4, 4] OpenGL camera-to-world of an LLFF-like forward-facing capture (deterministic).

    The rig stands where the room is deepest ahead: among the floor points with 2D clearance
    RIG_HALF_WIDTH + CAMERA_CLEARANCE + 0.05 m and the four wall-normal directions, the pair with
    the longest view to the opposite wall (less half the point's offset from the room's centre line),
    whose horizontal central ray travels at least 1.5 m. The cameras fill a patch +-RIG_HALF_WIDTH
    across and RIG_HEIGHTS high in a serpentine (view i between views i - 1 and i + 1), jittered;
    each looks RIG_TURN_DEG or less to either side of the rig's direction, down at a point 0.6-1.4 m
    high at 60 % of the depth ahead.
    """
    sx, sy, _ = spec.size
    rng = np.random.default_rng([spec.seed, 4])
    rects = [(np.array(b.lo[:2]), np.array(b.hi[:2])) for b in scene.boxes if b.part not in STRUCTURAL_PARTS]
    xs, ys, d = _field(spec, rects, 0.05)
    gx, gy = np.meshgrid(xs, ys)
    ok = d >= RIG_HALF_WIDTH + CAMERA_CLEARANCE + 0.05
    best, best_score = None, -np.inf
    for direction in ((1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)):
        ahead = np.where(direction[0] > 0, sx - gx, gx) if direction[0] else np.where(direction[1] > 0, sy - gy, gy)
        lateral = np.abs(gy - sy / 2) if direction[0] else np.abs(gx - sx / 2)
        score = np.where(ok, ahead - 0.5 * lateral, -np.inf)
        for flat in np.argsort(score, axis=None)[::-1][:50]:
            if not np.isfinite(score.flat[flat]) or score.flat[flat] <= best_score:
                break
            eye = np.array([gx.flat[flat], gy.flat[flat], sum(RIG_HEIGHTS) / 2])
            if cast_rays(eye[None], np.array([[*direction, 0.0]]), scene.boxes).depth[0] >= 1.5:
                best, best_score = (eye, np.array(direction), float(ahead.flat[flat])), float(score.flat[flat])
                break
    if best is None:
        raise AssertionError(f"{spec.name}: no place for the forward rig")
    anchor, forward, ahead = best
    side = np.array([-forward[1], forward[0]])
    n, rows = spec.n_views, 3
    cols = math.ceil(n / rows)
    index = np.arange(n)
    row, col = index // cols, index % cols
    col = np.where(row % 2 == 1, cols - 1 - col, col)  # serpentine: neighbours in order are neighbours on the patch
    u = (col + 0.5) / cols * 2 - 1 + rng.uniform(-0.3, 0.3, n) / cols
    z = RIG_HEIGHTS[0] + (row + 0.5 + rng.uniform(-0.3, 0.3, n)) / rows * (RIG_HEIGHTS[1] - RIG_HEIGHTS[0])
    xy = anchor[:2] + RIG_HALF_WIDTH * u[:, None] * side + rng.uniform(-0.05, 0.05, n)[:, None] * forward
    eyes = np.concatenate([xy, z[:, None]], axis=1)
    az = np.arctan2(forward[1], forward[0]) + np.radians(rng.uniform(-RIG_TURN_DEG, RIG_TURN_DEG, n))
    reach = 0.6 * ahead
    targets = np.stack(
        [xy[:, 0] + reach * np.cos(az), xy[:, 1] + reach * np.sin(az), rng.uniform(0.6, 1.4, n)], axis=1
    )
    check_cameras(spec, scene, eyes)
    return np.stack([look_at(e, t) for e, t in zip(eyes, targets)])


def _turn_from_close_surfaces(eyes: np.ndarray, az: np.ndarray, scene: SyntheticScene, min_depth: float) -> np.ndarray:
    """Azimuths turned by the smallest offset whose horizontal central ray travels >= min_depth."""
    offsets = np.array([0.0] + [s * k * 0.15 for k in range(1, 22) for s in (1, -1)])
    cand = az[:, None] + offsets[None]
    dirs = np.stack([np.cos(cand), np.sin(cand), np.zeros_like(cand)], -1).reshape(-1, 3)
    origins = np.repeat(eyes, len(offsets), axis=0)
    depth = cast_rays(origins, dirs, scene.boxes).depth.reshape(len(eyes), len(offsets))
    good = depth >= min_depth
    pick = np.where(good.any(axis=1), good.argmax(axis=1), depth.argmax(axis=1))
    return cand[np.arange(len(eyes)), pick]


def check_cameras(spec: SuiteSpec, scene: SyntheticScene, eyes: np.ndarray) -> None:
    sx, sy, h = spec.size
    inside = (eyes > 0).all(axis=1) & (eyes[:, 0] < sx) & (eyes[:, 1] < sy) & (eyes[:, 2] < h)
    if not inside.all():
        raise AssertionError(f"{spec.name}: camera {eyes[~inside][0]} outside the room")
    if not ((eyes[:, 2] >= 1.0) & (eyes[:, 2] <= 1.8)).all():
        raise AssertionError(f"{spec.name}: eye height outside 1.0-1.8 m")
    for box in scene.boxes:
        lo, hi = np.asarray(box.lo), np.asarray(box.hi)
        dist = np.linalg.norm(np.maximum(0.0, np.maximum(lo - eyes, eyes - hi)), axis=1)
        if dist.min() < CAMERA_CLEARANCE:
            raise AssertionError(f"{spec.name}: camera {eyes[dist.argmin()]} within {CAMERA_CLEARANCE} m of {box.part}")


def write_suite_scene(path: str | Path, spec_or_name: SuiteSpec | str) -> Path:
    """Write the suite room (a :class:`SuiteSpec` or a :data:`SUITE` name) to the folder ``path``.

    Uses :func:`scenelabel.data.synthetic.write_scene` with ``bounds_in_file=False`` (no per-frame
    near/far, no aabb) and a horizontal FOV of FOV_X_DEG. Returns the folder.
    """
    spec = suite_spec(spec_or_name) if isinstance(spec_or_name, str) else spec_or_name
    scene = suite_geometry(spec)
    c2ws = suite_cameras(spec, scene)
    return write_scene(path, scene, c2ws, spec.width, spec.height, FOV_X_DEG, bounds_in_file=False)
