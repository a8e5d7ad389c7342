"""Display colours of classes: their own colours, else one fixed colour per class id, the same in
maps, exports and renders (:func:`default_color`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = [
    "default_color",
    "class_palette",
    "color_lookup",
]


def default_color(class_id: int) -> tuple[int, int, int]:
    """A deterministic, well-spread colour for a class id without one (golden-ratio hues), 0-255 RGB."""
    hue = (class_id * 0.618033988749895) % 1.0
    h6 = hue * 6
    x = 1 - abs(h6 % 2 - 1)
    rgb = [(1, x, 0), (x, 1, 0), (0, 1, x), (0, x, 1), (x, 0, 1), (1, 0, x)][int(h6) % 6]
    return tuple(int(40 + 200 * c) for c in rgb)


def class_palette(
    classes: Mapping[int, str], class_colors: Mapping[int, Any] | None = None
) -> dict[int, tuple[int, int, int]]:
    """Display colour of every class: its own colour, else :func:`default_color` of its id.

    Args:
        classes: class id -> name.
        class_colors: class id -> (r, g, b) 0-255 for the classes that have one, or None.
    Returns:
        class id -> (r, g, b) 0-255, for every id of ``classes``.
    """
    own = dict(class_colors or {})
    return {
        cid: tuple(int(c) for c in own[cid]) if cid in own else default_color(cid) for cid in sorted(classes)
    }


def color_lookup(palette: Mapping[int, tuple[int, int, int]], ids: np.ndarray) -> np.ndarray:
    """[N] class ids -> [N, 3] uint8 colours (every id must be in ``palette``)."""
    keys = np.array(sorted(palette), dtype=np.int64)
    table = np.array([palette[k] for k in keys.tolist()], dtype=np.uint8).reshape(-1, 3)
    return table[np.searchsorted(keys, ids)]
