"""The real captures in ../shared/data (tests that need them skip when it is absent), and a reader
for what pycolmap cannot read alone."""

import struct
from pathlib import Path

import numpy as np

DATA = Path(__file__).parents[1] / ".." / "shared" / "data"


def read_points3d_bin(path: Path) -> np.ndarray:
    """[n, 3] xyz of a COLMAP points3D.bin, from its fixed binary layout (pycolmap needs images.bin
    beside it, which fern's snapshot lacks)."""
    data = path.read_bytes()
    (count,) = struct.unpack_from("<Q", data, 0)
    offset, xyz = 8, []
    record = struct.Struct("<QdddBBBd")  # id, x, y, z, r, g, b, reprojection error
    for _ in range(count):
        values = record.unpack_from(data, offset)
        xyz.append(values[1:4])
        offset += record.size
        (track_length,) = struct.unpack_from("<Q", data, offset)
        offset += 8 + 8 * track_length  # (image_id int32, point2D_idx int32) per track element
    assert offset == len(data)
    return np.asarray(xyz)
