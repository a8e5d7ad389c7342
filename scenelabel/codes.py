"""Label codes for space without a class, shared by every layer (docs/conventions.md, "Labels").

A label (of a pixel, a point, a ray or a map voxel) is an external class id >= 0 or one of these.
"""

from __future__ import annotations

__all__ = ["FREE", "UNKNOWN", "CODE_NAMES"]

FREE = -1
"""Label code of space modelled as empty; in a view's labels, a pixel whose ray meets nothing (the
background of an object capture, the sky: classes.json's ``free_index``)."""
UNKNOWN = -2
"""Label code of unobserved space: outside the modelled bounds where no training camera saw
through (docs/conventions.md, "Observed space outside the bounds"), or in maps (``unknown_rule``
"visibility") seen by no training camera."""
CODE_NAMES = {FREE: "FREE", UNKNOWN: "UNKNOWN"}
"""How answers, the viewer and recordings name the codes."""
