"""The compiled loop (numba) behind :func:`scenelabel.maps.visibility.visible_from_cameras` for
pinhole cameras: one point at a time, camera after camera until one sees it, the rule of
:mod:`scenelabel.maps.visibility` with the same float64 operations as its numpy form. Imported on
first use, like :mod:`scenelabel.maps.raycast_kernels` (whose :func:`in_threads` splits a batch
over the cores).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["visibility_kernel"]


@njit(cache=True, nogil=True)
def visibility_kernel(points, c2w, lens, limits, depth, offsets, margins, seen):  # pragma: no cover - compiled
    """seen[p] = some camera i sees points[p] (module docstring of scenelabel.maps.visibility).

    Args:
        points: [N, 3] world points.
        c2w: [n, 4, 4] camera-to-world (OpenCV axes).
        lens: [n, 8] (fx, fy, cx, cy, k1, k2, p1, p2) of each pinhole.
        limits: [n, 4] (near, far, width, height); near 0 and far inf where unknown.
        depth: all depth maps, row-major, one after the other; camera i's starts at offsets[i].
        offsets: [n] int64.
        margins: (margin, pixel_margin).
        seen: [N] bool, written.
    """
    margin, pixel_margin = margins[0], margins[1]
    for p in range(points.shape[0]):
        seen[p] = False
        for i in range(c2w.shape[0]):
            rx = points[p, 0] - c2w[i, 0, 3]
            ry = points[p, 1] - c2w[i, 1, 3]
            rz = points[p, 2] - c2w[i, 2, 3]
            z = rx * c2w[i, 0, 2] + ry * c2w[i, 1, 2] + rz * c2w[i, 2, 2]
            if not z > 0.0:
                continue
            a = (rx * c2w[i, 0, 0] + ry * c2w[i, 1, 0] + rz * c2w[i, 2, 0]) / z
            b = (rx * c2w[i, 0, 1] + ry * c2w[i, 1, 1] + rz * c2w[i, 2, 1]) / z
            k1, k2, p1, p2 = lens[i, 4], lens[i, 5], lens[i, 6], lens[i, 7]
            if k1 != 0.0 or k2 != 0.0 or p1 != 0.0 or p2 != 0.0:
                r2 = a * a + b * b
                radial = 1.0 + r2 * (k1 + r2 * k2)
                a, b = (
                    a * radial + 2.0 * p1 * a * b + p2 * (r2 + 2.0 * a * a),
                    b * radial + p1 * (r2 + 2.0 * b * b) + 2.0 * p2 * a * b,
                )
            u = lens[i, 0] * a + lens[i, 2]
            v = lens[i, 1] * b + lens[i, 3]
            width, height = limits[i, 2], limits[i, 3]
            if not (u >= 0.0 and u < width and v >= 0.0 and v < height):
                continue
            dist = np.sqrt(rx * rx + ry * ry + rz * rz)
            if not (dist >= limits[i, 0] and dist <= limits[i, 1]):
                continue
            surface = depth[offsets[i] + int(np.floor(v)) * int(width) + int(np.floor(u))]
            focal = lens[i, 0] if lens[i, 0] <= lens[i, 1] else lens[i, 1]
            if dist <= surface + (margin + pixel_margin * dist / focal):
                seen[p] = True
                break
