"""A room's layout from its masks and poses: the floor and ceiling planes and Manhattan walls, found
where the masks' floor, wall and ceiling meet; their depth for the pixels those classes cover.

Without sensor depth a field learns a room's large plain surfaces from colour alone, and they come
out soft (docs/depth_suite.md's `-` rows, built before this module). The masks already say where
the floor meets the walls and the walls meet the ceiling in every view; with known poses those
lines fix the planes to a few millimetres. The assumption is the Manhattan world's (planar floor
and ceiling normal to "up", walls along two perpendicular horizontal directions), which
Manhattan-SDF (Guo et al., CVPR 2022) also takes from 2D semantic masks of floor and wall.

Conventions (docs/conventions.md): cameras are :class:`scenelabel.Cameras` (OpenCV axes, world
frame); a label image is [H, W] external class ids; depth is the distance along the unit ray.

The steps (numpy only):

1. :func:`boundary_rays`: the rays through the pixel edges between a ``lower`` pixel and an
   ``upper`` one (floor below wall, wall below ceiling; left-right pairs either way).
2. :func:`plane_offset`: the height ``h`` along ``up`` at which those rays, cut by the plane
   ``x . up = h``, land on the fewest distinct places: the walls' base (or top) lines seen from
   every camera agree only at the true height. The spread is counted in bins that grow with the
   distance from the cameras' mean height (so that heights near the cameras, where every ray's
   cut collapses onto its camera, do not win); in 2D bins, or, once the walls' direction is
   known, in 1D bins along each of the walls' two axes (a wall's cuts then share one bin).
3. :func:`room_layout`: ``up`` from the cameras' mean up direction, tilted a few degrees to where
   the floor's and the ceiling's cuts, each at its own best height, agree best together: walls
   are vertical, so only the true up puts a wall's base and its top on one line. (The floor's
   cuts alone are not enough: where far walls are seen at grazing angles their cuts are loose,
   and a plane tilted by ten degrees bunches them better than the true one.) Then the walls'
   direction (the horizontal rotation whose two axes bunch the cuts most); up, the floor and that
   direction refined along the walls; the ceiling; the walls (the peaks of the cuts' coordinates
   along each axis that stand out of the even spread of the cuts on the walls across, with the
   stretch their cuts cover). Once more from the world axis nearest to the cameras' up; and, where
   the photos' straight lines give a vertical (:mod:`scenelabel.geometry.vanishing`), once more
   from it, refined within a degree or so, after ruling out the layouts more than
   :data:`MAX_OFF_VERTICAL` from it; that layout comes first. The first layout stays unless
   another puts clearly more of the cuts on its walls (``RoomLayout.on_walls``,
   :func:`better_layout`). A plane is looked for only where boundaries of its kind show in
   :data:`MIN_BOUNDARY_VIEWS` views.
4. :func:`scenelabel.data.layout_depth.depth_from_layout`: per pixel labelled floor, ceiling or
   wall, the distance along its ray to that plane; NaN elsewhere.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from scenelabel.errors import InputError
from scenelabel.geometry.bin_agreement import bin_spreads
from scenelabel.geometry.cameras import Cameras
from scenelabel.geometry.rays import rays_from_cameras
from scenelabel.geometry.vanishing import tilted, vertical_from_images, world_axis_across

__all__ = [
    "LAYOUT_CLASSES",
    "BIN",
    "MAX_BOUNDARY_RAYS",
    "MAX_SEARCH_RAYS",
    "MIN_ON_WALLS",
    "CLEARLY_MORE_ON_WALLS",
    "MIN_NEAR_WALLS",
    "MIN_BOUNDARY_VIEWS",
    "MAX_OFF_VERTICAL",
    "MIN_WALL_SUPPORT",
    "WALL_BAND",
    "SEARCH_SPAN",
    "Wall",
    "RoomLayout",
    "layout_class_ids",
    "WALL_MOUNTED_CLASSES",
    "mounted_class_ids",
    "boundary_rays",
    "plane_offset",
    "room_layout",
    "better_layout",
]

LAYOUT_CLASSES = ("floor", "wall", "ceiling")
"""The classes a layout is made of, matched by name: a class named ``floor``, or starting with it
followed by a non-letter (``floor-wood``, ``floor_other``), is the floor; likewise wall and ceiling."""

WALL_MOUNTED_CLASSES = ("picture", "painting", "poster", "whiteboard", "blackboard", "mirror")
"""Classes that hang flat on a wall, matched by name as :data:`LAYOUT_CLASSES` are: with
``data.layout_mounted`` their pixels get the depth of the wall behind them
(:func:`scenelabel.data.layout_depth.depth_from_layout`). A flat picture's colour says little of its
depth: hall-10x6's far picture came out in front of its wall, while the wall around it, which the
layout supervises, sat on it (docs/models.md). Doors and windows are left out (a door may stand
open, a window shows what lies beyond it)."""

BIN = 0.02
"""Bin side (world units, at 1.5 units from the cameras' mean height) in which :func:`plane_offset`
counts where the boundary rays land; half of it in the search at 2 mm steps."""

MAX_BOUNDARY_RAYS = 20_000
"""At most this many boundary rays of each kind (an even subsample) enter a layout."""

MAX_SEARCH_RAYS = 5_000
"""At most this many floor boundary rays (an even subsample) enter the search for up."""

MIN_ON_WALLS = 0.55
"""A layout with less than this share of its boundary cuts on its walls (:attr:`RoomLayout.on_walls`)
gives way to any other with more in :func:`better_layout`."""

CLEARLY_MORE_ON_WALLS = 0.05
""":func:`room_layout`'s second start (the world axis) replaces a usable first layout only where it
puts at least this much more of the cuts on its walls. Chosen on tuning rooms: office-5x4-forward's
rig, pitched at the floor, gets 0.088 more from the world axis (its first layout tilted 2.7
degrees, the floor 0.2 m off); on the suite rooms seen from inside the two starts differ by at
most 0.005. Taking whichever had more there (docs/suite_layout_starts.md, code fb8be17) left
studio-3x3's map labelling 0.853 of its surface points, 0.851-0.866 over training seeds 1 and 2
(docs/studio_seeds.md), against 0.968 with its first start's layout (docs/suite_decay.md)."""

MIN_WALL_SUPPORT = 0.02
"""A wall is a peak holding at least this fraction of the boundary points within :data:`WALL_BAND`
of it, over the even spread of the points around it."""

SEARCH_SPAN = 4.0
"""World units from the cameras within which :func:`plane_offset` looks for a floor or ceiling."""

WALL_BAND = 0.03
"""World units: boundary cuts this close to a wall's line belong to it."""

MIN_NEAR_WALLS = 0.55
"""A layout with less than this share of its boundary cuts within a pixel's reach of its walls
(:attr:`RoomLayout.near_walls`) is not what the room is: :mod:`scenelabel.data.layout_depth` does
not use it. Every layout of docs/layout.md has at least 0.97 there; masks strewn at random, none.
(The share within :data:`WALL_BAND` alone, ``on_walls``, is 0.54-0.68 on most forward rigs, whose
far walls are seen at grazing angles, and 0.45 on the bench room at 80x60, whose layout is as
good as at 160x120: that share refused right layouts.)"""

MIN_BOUNDARY_VIEWS = 3
"""A plane is looked for only where its boundary rays come from at least this many views (each
with :data:`_VIEW_RAYS` or more): the rays of one view meet every plane in the same line, seen
from the camera, and agree at any height (studio-3x3-forward-51 shows its ceiling in one training
photo: its layout has none, docs/layout.md)."""

MAX_OFF_VERTICAL = 1.0
"""Degrees: a layout whose up is further than this from the vertical of the photos' lines
(:func:`scenelabel.geometry.vanishing.vertical_from_images`) is not taken. That vertical came
within 0.62 degrees of the true one on every room of docs/layout.md; the layouts it rules out
were tilted by 1.6 to 5 degrees."""

# (half range, step) in degrees of the passes refining up: in the plane from the cameras' mean up,
# then along the walls; from the vertical of the photos' lines (vanishing.vertical_from_images)
# along the walls alone, and half as far
_TILTS_PLANE = ((4.0, 1.0), (1.0, 0.25))
_TILTS_WALLS = ((1.0, 0.25), (0.25, 0.05))
_TILTS_FROM_LINES = ((0.5, 0.25), (0.25, 0.05))
_VIEW_RAYS = 10  # boundary rays a view must hold to count towards MIN_BOUNDARY_VIEWS
_EDGE_SLACK = 0.1  # world units a wall is taken to reach past its outermost boundary points
_FAR = 1e3  # world units: boundary rays meeting a plane farther than this tell nothing about it
_HEIGHT_REACH = 0.3  # world units about the starting up's heights a tilted up's are searched within
_WALLS_CHUNK = 1 << 20  # boundary cuts x angles binned at once in :func:`_walls`' search
_WALL_GAP = 0.2  # world units: two walls along one axis are at least this far apart
_BACKGROUND = 0.5  # world units each side over which the cuts' background count is a mean


@dataclass(frozen=True)
class Wall:
    """A wall: the plane ``coordinate[axis] = offset`` in the layout's horizontal basis, covering
    ``extent`` (lo, hi) along the other axis; ``support`` boundary points found it."""

    axis: int
    offset: float
    extent: tuple[float, float]
    support: int


@dataclass(frozen=True)
class RoomLayout:
    """A room's planes, world frame.

    up: [3] unit vector; heights are ``point . up``.
    floor, ceiling: heights of the floor and ceiling planes (None: not found).
    basis: [2, 3] the walls' two horizontal unit directions (rows; each normal to ``up``).
    walls: the walls along those directions.
    on_walls: the share of the boundary rays' cuts (floor and ceiling) that lie on a wall, within
        :data:`WALL_BAND` of it and inside its extent: how :func:`better_layout` compares layouts.
    near_walls: the same share within a pixel's reach of a wall (or :data:`WALL_BAND` where that
        is less): how far across the wall the cut moves where its ray turns by one pixel, which a
        far wall seen at a grazing angle makes tens of centimetres. Near 1 where the room is what
        the layout says, at any resolution and distance: whether a build uses the layout
        (:data:`MIN_NEAR_WALLS`).
    """

    up: np.ndarray
    floor: float | None
    ceiling: float | None
    basis: np.ndarray
    walls: tuple[Wall, ...]
    on_walls: float = 1.0
    near_walls: float = 1.0


def _named(name: str, kind: str) -> bool:
    """``name`` is ``kind``, or starts with it followed by a non-letter (``floor-wood``, ``picture frame``)."""
    return re.fullmatch(rf"{kind}([^a-z].*)?", str(name).strip().lower()) is not None


def layout_class_ids(classes: Mapping[int, str]) -> dict[str, int]:
    """{"floor": id, "wall": id, "ceiling": id} for the classes of :data:`LAYOUT_CLASSES` present in
    ``classes`` (id -> name); the first id in ascending order where several names match."""
    found: dict[str, int] = {}
    for cid in sorted(classes):
        for kind in LAYOUT_CLASSES:
            if kind not in found and _named(classes[cid], kind):
                found[kind] = int(cid)
    return found


def mounted_class_ids(classes: Mapping[int, str]) -> list[int]:
    """The ids of ``classes`` (id -> name) named as one of :data:`WALL_MOUNTED_CLASSES`, ascending."""
    return [int(cid) for cid in sorted(classes) if any(_named(classes[cid], kind) for kind in WALL_MOUNTED_CLASSES)]


def boundary_rays(
    cameras: Cameras, labels: Sequence[np.ndarray | None], lower: int, upper: int
) -> tuple[np.ndarray, np.ndarray]:
    """World rays through the pixel edges where a ``lower`` pixel meets an ``upper`` one.

    Vertical neighbours count with ``upper`` above (smaller row): the edge between rows r - 1 and r
    at v = r, u = c + 0.5. Horizontal neighbours count either way round: the edge at u = c + 1,
    v = r + 0.5 (pixel centres at + 0.5, docs/conventions.md).

    Args:
        cameras: n cameras.
        labels: n label images ([H, W] class ids) or None (a view without labels: no rays).
        lower, upper: the class ids.
    Returns:
        origins [m, 3], directions [m, 3] (unit), float64.
    """
    if len(labels) != len(cameras):
        raise InputError(f"{len(labels)} label images for {len(cameras)} cameras", field="labels")
    origins, directions = [np.zeros((0, 3))], [np.zeros((0, 3))]
    for i, label in enumerate(labels):
        if label is None:
            continue
        label = np.asarray(label)
        r, c = np.nonzero((label[:-1] == upper) & (label[1:] == lower))
        vertical = np.column_stack([c + 0.5, r + 1.0])
        a, b = label[:, :-1], label[:, 1:]
        r, c = np.nonzero(((a == upper) & (b == lower)) | ((a == lower) & (b == upper)))
        pixels = np.concatenate([vertical, np.column_stack([c + 1.0, r + 0.5])])
        if len(pixels):
            o, d = rays_from_cameras(cameras, i, pixels)
            origins.append(o)
            directions.append(d)
    return np.concatenate(origins), np.concatenate(directions)


def _horizontal(up: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """[2, 3]: ``direction`` made normal to ``up`` (unit), and ``up x`` it."""
    b1 = direction - (direction @ up) * up
    b1 /= np.linalg.norm(b1)
    return np.stack([b1, np.cross(up, b1)])


def _cut_cells(
    rays: tuple[np.ndarray, np.ndarray], up: np.ndarray, heights: np.ndarray, sizes: np.ndarray, basis: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The bins where the rays meet the planes ``x . up = heights[j]``: their coordinates along the
    rows of ``basis`` [2, 3] divided by ``sizes[j]``, floored. Returns cells [m, n, 2] (int64) and
    valid [m, n]: the plane met in front of the ray's origin, within :data:`_FAR` (a ray nearly
    parallel to the plane meets it too far away to tell anything; bins beyond 2^30 are clipped)."""
    origins, directions = rays
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t = (heights[:, None] - origins @ up) / (directions @ up)  # [m, n]
        valid = (t > 0) & (t < _FAR)
        t = np.where(valid, t, 0.0)
    q = (origins @ basis.T + (directions @ basis.T) * t[..., None]) / sizes[:, None, None]
    return np.floor(np.clip(q, -(1 << 30), 1 << 30)).astype(np.int64), valid


def _agreement(cells: np.ndarray, valid: np.ndarray, along_walls: bool) -> np.ndarray:
    """[m] :func:`bin_spreads` of 2D cells, or (``along_walls``) the sum of their two coordinates'
    (one call: the rows of both coordinates at once)."""
    if not along_walls:
        return bin_spreads(cells, valid)
    m = len(valid)
    spreads = bin_spreads(np.concatenate([cells[..., :1], cells[..., 1:]]), np.concatenate([valid, valid]))
    return spreads[:m] + spreads[m:]


def _cut_agreements(
    rays: tuple[np.ndarray, np.ndarray], up: np.ndarray, heights: np.ndarray, bin_size: float,
    walls: np.ndarray | None = None,
) -> np.ndarray:
    """[m]: how well the rays, cut by each plane ``x . up = heights[j]``, agree: :func:`bin_spreads` of
    the cuts in the plane (2D bins), or, given the walls' direction ``walls`` [3], the sum of the
    spreads of their two coordinates along the walls (1D bins: a wall's points share one bin at the
    true height and up, which counts far more points per bin than 2D bins). Bins scale with the
    plane's distance from the rays' mean height / 1.5."""
    sizes = bin_size * np.maximum(np.abs(float((rays[0] @ up).mean()) - heights), 1e-6) / 1.5
    return _agreement(*_cut_cells(rays, up, heights, sizes, _cut_basis(up, walls)), walls is not None)


def _cut_basis(up: np.ndarray, walls: np.ndarray | None) -> np.ndarray:
    """[2, 3] the axes the cuts are binned along: normal to ``up``, one along ``walls`` when given."""
    return _horizontal(up, world_axis_across(up) if walls is None else walls)


def plane_offset(
    origins: np.ndarray, directions: np.ndarray, up: np.ndarray, below: bool,
    near: float | None = None, walls: np.ndarray | None = None, reach: float = 0.05,
) -> tuple[float, float]:
    """The height (along unit ``up``) of the plane on which the boundary rays agree
    (:func:`_cut_agreements`): searched at 5 cm from 0.3 to :data:`SEARCH_SPAN` units below the
    lowest ray origin (``below``) or above the highest, or within ``reach`` of ``near`` when given;
    then at 1 cm within 5 cm of the best, and at 2 mm within 1 cm of that.

    Args:
        origins, directions: [m, 3] boundary rays (:func:`boundary_rays`).
        up: [3] unit vector.
        below: the plane lies below the cameras (a floor) or above them (a ceiling).
        near: a height to search around (the best of a slightly different ``up``).
        walls: [3] a direction along the walls (their agreement is then counted along the walls).
        reach: how far from ``near`` to search.
    Returns:
        (height, agreement): the agreement is :func:`_cut_agreements`', in (0, 2].
    """
    if len(origins) == 0:
        raise InputError("no boundary rays to find a plane from", field="origins")
    if near is None:
        heights = origins @ up
        lo, hi = (heights.min() - SEARCH_SPAN, heights.min() - 0.3) if below else (heights.max() + 0.3, heights.max() + SEARCH_SPAN)
        coarse = np.arange(lo, hi, 0.05)
    else:
        coarse = np.arange(near - reach, near + reach + 1e-9, 0.05) if reach > 0.05 else np.array([near])
    if len(coarse) > 1:
        near = float(coarse[int(np.argmax(_cut_agreements((origins, directions), up, coarse, BIN, walls)))])
    for span, step in ((0.05, 0.01), (0.01, 0.002)):
        fine = np.arange(near - span, near + span + 1e-9, step)
        scores = _cut_agreements((origins, directions), up, fine, BIN / 2, walls)
        near = float(fine[int(np.argmax(scores))])
    k = int(np.argmax(scores))
    return float(fine[k]), float(scores[k])


def _refined_up(
    floor_rays: tuple[np.ndarray, np.ndarray], ceiling_rays: tuple[np.ndarray, np.ndarray] | None,
    up: np.ndarray, walls: np.ndarray | None, passes: tuple[tuple[float, float], ...], tilt: bool = True,
) -> tuple[np.ndarray, float, np.ndarray | None]:
    """``up`` tilted to where the boundary rays agree best: one tilt at a time, in passes of
    (half range, step) degrees. Each candidate's floor (and ceiling) height is its own best
    (:func:`plane_offset`: in the first pass within :data:`_HEIGHT_REACH` of the best at the
    starting ``up``, then near the best so far); the candidate's score is how well the floor's
    and the ceiling's cuts agree together (:func:`_joint_agreement`: walls are vertical, so only
    the true up puts a wall's base and top on one line), or the floor's alone without ceiling
    rays. Without ``walls``, agreement in the plane; with ``walls`` (a direction along them),
    along the walls, the walls' direction turned about up as a third angle. ``passes``: (half
    range, step) degrees each (none: up as given); ``tilt`` False turns the walls alone.
    Returns (up, floor height, walls)."""
    angles = np.zeros(3)  # tilts about two axes normal to up; the walls' turn about up

    def placed(angles: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        tilted_up = tilted(up, angles[0], angles[1])
        return tilted_up, None if walls is None else _turned(tilted_up, walls, angles[2])

    heights = [plane_offset(*floor_rays, up, True, None, walls)[0], None]
    if ceiling_rays is not None:
        heights[1] = plane_offset(*ceiling_rays, up, False, None, walls)[0]
    reach = _HEIGHT_REACH

    def scored(angles: np.ndarray) -> tuple[float, list]:
        tilted_up, along = placed(angles)
        floor, agreement = plane_offset(*floor_rays, tilted_up, True, heights[0], along, reach)
        if ceiling_rays is None:
            return agreement, [floor, None]
        ceiling = plane_offset(*ceiling_rays, tilted_up, False, heights[1], along, reach)[0]
        return _joint_agreement(floor_rays, ceiling_rays, tilted_up, (floor, ceiling), along), [floor, ceiling]

    for half, step in passes:
        seen: dict[bytes, tuple[float, list]] = {}  # a pass's scores depend on the angles alone
        for axis in ((0, 1) if walls is None else (0, 1, 2) if tilt else (2,)) * 2:
            candidates = []
            for x in np.arange(-half, half + 1e-9, step):
                c = angles.copy()
                c[axis] += x
                candidates.append(c)
            for c in candidates:
                if c.tobytes() not in seen:
                    seen[c.tobytes()] = scored(c)
            found = [seen[c.tobytes()] for c in candidates]
            k = int(np.argmax([f[0] for f in found]))
            angles = candidates[k]
        heights, reach = found[k][1], 0.05
    return (*placed(angles)[:1], heights[0], placed(angles)[1])


def _joint_agreement(
    floor_rays: tuple[np.ndarray, np.ndarray], ceiling_rays: tuple[np.ndarray, np.ndarray],
    up: np.ndarray, heights: tuple[float, float], walls: np.ndarray | None,
) -> float:
    """How well the floor rays' cuts at ``heights[0]`` and the ceiling rays' at ``heights[1]``
    agree together (:func:`_agreement` in :data:`BIN` bins of the plane normal to ``up``, or, given
    the walls' direction, along its two axes)."""
    basis = _cut_basis(up, walls)
    parts = [_cut_cells(rays, up, np.array([h]), np.array([BIN]), basis)
             for rays, h in zip((floor_rays, ceiling_rays), heights)]
    cells, valid = (np.concatenate([p[k] for p in parts], axis=1) for k in (0, 1))
    return float(_agreement(cells, valid, walls is not None)[0])


def _turned(up: np.ndarray, direction: np.ndarray, degrees: float) -> np.ndarray:
    """``direction`` made normal to ``up`` and turned about it by ``degrees``."""
    b = _horizontal(up, direction)
    t = np.radians(degrees)
    return np.cos(t) * b[0] + np.sin(t) * b[1]


def _subsample(origins: np.ndarray, directions: np.ndarray, limit: int = MAX_BOUNDARY_RAYS) -> tuple[np.ndarray, np.ndarray]:
    """At most ``limit`` of the rays, evenly spread over them."""
    if len(origins) <= limit:
        return origins, directions
    keep = np.linspace(0, len(origins) - 1, limit).astype(np.int64)
    return origins[keep], directions[keep]


def _cuts(origins: np.ndarray, directions: np.ndarray, up: np.ndarray, height: float) -> np.ndarray:
    """[k, 3] where the rays meet the plane ``x . up = height`` in front of their origins, within
    :data:`_FAR`."""
    return _cut_rays(origins, directions, up, height)[0]


def _cut_rays(
    origins: np.ndarray, directions: np.ndarray, up: np.ndarray, height: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_cuts` [k, 3], with the directions [k, 3] and distances [k] of the rays that made them."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (height - origins @ up) / (directions @ up)
    ahead = (t > 0) & (t < _FAR)
    return origins[ahead] + directions[ahead] * t[ahead, None], directions[ahead], t[ahead]


def _pixel_reach(directions: np.ndarray, t: np.ndarray, up: np.ndarray, normal: np.ndarray, pixel: float) -> np.ndarray:
    """[k]: how far across a wall of horizontal unit ``normal`` a cut moves where its ray (unit
    ``directions`` [k, 3], meeting a plane normal to ``up`` at distance ``t`` [k]) turns by ``pixel``
    radians towards or away from the plane: ``t pixel / |d . up|`` along the ray's horizontal
    direction, of which ``|d . normal| / |d_h|`` lies across the wall (the 1e-12s keep a ray
    parallel to the plane, or vertical, finite)."""
    along = np.abs(directions @ up)
    horizontal = np.sqrt(np.maximum(1.0 - along**2, 1e-12))
    return pixel * t * np.abs(directions @ normal) / (horizontal * np.maximum(along, 1e-12))


def _running_mean(counts: np.ndarray, reach: int) -> np.ndarray:
    """[n] the mean of ``counts`` [n] over each entry and its ``reach`` neighbours either side
    (zeros beyond the ends)."""
    total = np.concatenate([[0], np.cumsum(np.concatenate([counts, np.zeros(reach)]))])
    hi = np.arange(len(counts)) + reach + 1
    return (total[hi] - total[np.maximum(hi - 2 * reach - 1, 0)]) / (2 * reach + 1)


def _walls(points: np.ndarray) -> tuple[np.ndarray, tuple[Wall, ...]]:
    """The Manhattan rotation [2, 2] of boundary cuts ``points`` [n, 2] (given in any horizontal
    basis): the angle in [0, 90) degrees, in 0.25 degree steps, whose two axes bunch them most
    (:func:`_spread` of each coordinate, :data:`BIN`); and the walls along those axes: the 1 cm bins
    of a coordinate whose cuts within WALL_BAND, less the count an even spread at the mean density
    of the surrounding metre would put there (the cuts on the walls across the axis), are at least
    MIN_WALL_SUPPORT of all, largest first, each at least _WALL_GAP from a larger one, placed at the
    median of those cuts. No cuts: the identity and no walls."""
    if len(points) == 0:
        return np.eye(2), ()
    angles = np.radians(np.arange(0.0, 90.0, 0.25))

    def rotation(t: float) -> np.ndarray:
        return np.array([[np.cos(t), np.sin(t)], [-np.sin(t), np.cos(t)]])

    def bunched(ts: np.ndarray) -> np.ndarray:  # [k] for k angles at once: one row per angle and axis
        cells = np.stack([np.floor(points @ rotation(t).T / BIN).astype(np.int64) for t in ts])  # [k, n, 2]
        return _agreement(cells, np.ones(cells.shape[:2], bool), along_walls=True)

    chunk = max(1, _WALLS_CHUNK // len(points))
    scores = np.concatenate([bunched(angles[i:i + chunk]) for i in range(0, len(angles), chunk)])
    rot = rotation(float(angles[int(np.argmax(scores))]))
    q = points @ rot.T
    walls = []
    for axis in (0, 1):
        v = q[:, axis]
        cells = np.floor(v / (BIN / 2)).astype(np.int64)
        first = int(cells.min())
        counts = np.bincount(cells - first)
        reach = int(round(WALL_BAND / (BIN / 2)))  # a wall's cuts spread over its band
        support = np.convolve(counts, np.ones(2 * reach + 1, np.int64), mode="same")
        # the cuts on the walls across this axis, spread evenly along it, are not a wall here
        background = (2 * reach + 1) * _running_mean(counts, int(round(_BACKGROUND / (BIN / 2))))
        excess = support - background
        taken: list[float] = []
        for j in np.argsort(-excess, kind="stable"):
            if excess[j] < MIN_WALL_SUPPORT * len(v):
                break
            centre = (first + j + 0.5) * BIN / 2
            if any(abs(centre - t) <= _WALL_GAP for t in taken):  # a peak's own shoulder
                continue
            taken.append(centre)
            near = np.abs(cells - (first + j)) <= reach  # the cuts its support counted: at least one
            along = q[near, 1 - axis]
            extent = (float(np.percentile(along, 1)) - _EDGE_SLACK, float(np.percentile(along, 99)) + _EDGE_SLACK)
            walls.append(Wall(axis, float(np.median(v[near])), extent, int(near.sum())))
    return rot, tuple(walls)


def room_layout(
    cameras: Cameras, labels: Sequence[np.ndarray | None], class_ids: Mapping[str, int],
    images: Sequence[np.ndarray] | None = None,
) -> RoomLayout | None:
    """The layout of a room from its views' masks (see the module docstring).

    The search for up starts from the cameras' mean up direction and again from the world axis
    nearest to it (inputs are often already gravity-aligned). That refinement reaches a few
    degrees from its start, and a capture whose cameras all tilt one way (a forward-facing rig
    pitched at the floor) starts further from the true up than that (office-5x4-forward, whose
    cameras' mean up is 8.8 degrees off: from there alone its layout came out tilted 2.7 degrees
    with the floor 0.2 m off). Where the photos' straight lines give a vertical
    (:func:`scenelabel.geometry.vanishing.vertical_from_images`), the layouts further than
    :data:`MAX_OFF_VERTICAL` from it are ruled out and a third search starts from it, refined
    along the walls within about a degree: the cuts' agreement leans towards planes tilted at the
    cameras, and a forward rig's one or two walls do not hold it (docs/layout.md). That layout
    comes first, as its start does not share the lean; :func:`better_layout` lets the others
    replace it, in order, only where they put clearly more of the cuts on their walls.

    Args:
        cameras: the views' cameras.
        labels: their label images ([H, W] class ids; None: unlabelled).
        class_ids: :func:`layout_class_ids` of the scene's classes.
        images: their photos ([H, W, 3] float in [0, 1]), or None.
    Returns:
        the layout, or None where the masks show no floor-wall boundary (no floor, wall or none
        adjacent) in :data:`MIN_BOUNDARY_VIEWS` views. The ceiling is None without wall-ceiling
        boundaries in that many views.
    """
    if "floor" not in class_ids or "wall" not in class_ids:
        return None
    floor_rays = _subsample(*boundary_rays(cameras, labels, class_ids["floor"], class_ids["wall"]))
    if _views_holding(floor_rays[0]) < MIN_BOUNDARY_VIEWS:
        return None
    ceiling_rays = None
    if "ceiling" in class_ids:
        ceiling_rays = _subsample(*boundary_rays(cameras, labels, class_ids["wall"], class_ids["ceiling"]))
        if _views_holding(ceiling_rays[0]) < MIN_BOUNDARY_VIEWS:
            ceiling_rays = None
    up = -cameras.c2w[:, :3, 1].mean(axis=0)  # the cameras' mean up (OpenCV: y points down)
    up /= np.linalg.norm(up)
    centre = cameras.c2w[:, :3, 3].mean(axis=0)
    axis = np.zeros(3)
    axis[int(np.argmax(np.abs(up)))] = np.sign(up[int(np.argmax(np.abs(up)))])
    pixel = 1.0 / float(np.median(np.concatenate([cameras.fx, cameras.fy])))
    starts = [up] if np.allclose(axis, up) else [up, axis]
    layouts = [_layout_from(floor_rays, ceiling_rays, start, centre, pixel) for start in starts]
    vertical = None if images is None else vertical_from_images(cameras, images, up)
    if vertical is not None:
        layouts = [layout for layout in layouts if layout.up @ vertical >= np.cos(np.radians(MAX_OFF_VERTICAL))]
        # the floor's cuts alone lean towards tilted planes: without a ceiling the lines' up stays
        passes = ((), _TILTS_FROM_LINES)
        from_lines = _layout_from(floor_rays, ceiling_rays, vertical, centre, pixel, passes, ceiling_rays is not None)
        layouts.insert(0, from_lines)
    layout = layouts[0]
    for other in layouts[1:]:
        layout = better_layout(layout, other)
    return layout


def _views_holding(origins: np.ndarray) -> int:
    """How many distinct ray origins (views) hold at least :data:`_VIEW_RAYS` of ``origins`` [m, 3]."""
    if len(origins) == 0:
        return 0
    counts = np.unique(origins, axis=0, return_counts=True)[1]
    return int((counts >= _VIEW_RAYS).sum())


def better_layout(first: RoomLayout, other: RoomLayout) -> RoomLayout:
    """``other`` where it puts more of the cuts on its walls than ``first`` and ``first`` is not
    usable (below :data:`MIN_ON_WALLS`) or ``other`` puts :data:`CLEARLY_MORE_ON_WALLS` more there;
    else ``first``: two layouts that differ by a few thousandths are equally good, and keeping
    the first keeps a build's layout from flipping between them."""
    gain = other.on_walls - first.on_walls
    return other if gain > 0 and (first.on_walls < MIN_ON_WALLS or gain >= CLEARLY_MORE_ON_WALLS) else first


def _layout_from(
    floor_rays: tuple[np.ndarray, np.ndarray], ceiling_rays: tuple[np.ndarray, np.ndarray] | None,
    up: np.ndarray, centre: np.ndarray, pixel: float,
    passes: tuple[tuple[tuple[float, float], ...], ...] = (_TILTS_PLANE, _TILTS_WALLS), tilt: bool = True,
) -> RoomLayout:
    """:func:`room_layout` from one starting ``up``, refined in the plane and then along the walls
    by ``passes`` (:func:`_refined_up`'s, one tuple each; ``tilt`` False: up stays, the walls turn).
    ``pixel``: the angle one pixel spans (radians), for :attr:`RoomLayout.near_walls`. Heights and
    wall offsets are searched about the cameras' centroid ``centre`` (tilting up then barely moves
    a plane's height) and given back about the world's origin."""
    floor_rays = (floor_rays[0] - centre, floor_rays[1])
    # up and the floor where the floor's boundary cuts agree in the plane; the walls' direction from
    # those cuts; then up, the floor and that direction where the cuts agree along the walls
    search = _subsample(*floor_rays, MAX_SEARCH_RAYS)
    ceiling_search = None
    if ceiling_rays is not None and len(ceiling_rays[0]):
        ceiling_search = _subsample(ceiling_rays[0] - centre, ceiling_rays[1], MAX_SEARCH_RAYS)
    up, floor, _ = _refined_up(search, ceiling_search, up, None, passes[0])
    plane = _horizontal(up, world_axis_across(up))
    along = _walls(_cuts(*floor_rays, up, floor) @ plane.T)[0][0] @ plane
    up, floor, along = _refined_up(search, ceiling_search, up, along, passes[1], tilt)
    floor = plane_offset(*floor_rays, up, True, floor, along)[0]
    cut = [_cut_rays(*floor_rays, up, floor)]
    ceiling = None
    if ceiling_rays is not None and len(ceiling_rays[0]):
        ceiling_rays = (ceiling_rays[0] - centre, ceiling_rays[1])
        ceiling = plane_offset(*ceiling_rays, up, below=False)[0]
        ceiling = plane_offset(*ceiling_rays, up, False, ceiling, along)[0]
        cut.append(_cut_rays(*ceiling_rays, up, ceiling))
    points, directions, t = (np.concatenate([c[k] for c in cut]) for k in range(3))
    plane = _horizontal(up, along)
    cuts = points @ plane.T
    rot, walls = _walls(cuts)
    q = cuts @ rot.T
    basis = rot @ plane
    on_walls, near_walls = np.zeros(len(q), bool), np.zeros(len(q), bool)
    for w in walls:
        inside = (q[:, 1 - w.axis] >= w.extent[0]) & (q[:, 1 - w.axis] <= w.extent[1])
        off = np.abs(q[:, w.axis] - w.offset)
        on_walls |= (off < WALL_BAND) & inside
        near_walls |= (off < np.maximum(WALL_BAND, _pixel_reach(directions, t, up, basis[w.axis], pixel))) & inside
    shift = basis @ centre
    walls = tuple(
        dataclasses.replace(w, offset=w.offset + float(shift[w.axis]),
                            extent=(w.extent[0] + float(shift[1 - w.axis]), w.extent[1] + float(shift[1 - w.axis])))
        for w in walls
    )
    lift = float(centre @ up)
    return RoomLayout(up=up, floor=floor + lift, ceiling=None if ceiling is None else ceiling + lift, basis=basis,
                      walls=walls, on_walls=float(on_walls.mean()) if len(q) else 0.0,
                      near_walls=float(near_walls.mean()) if len(q) else 0.0)

