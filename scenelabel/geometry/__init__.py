"""Geometry every stage shares: cameras (OpenCV axes) and their records, lens models (pinhole,
fisheye: pixels <-> rays), rays from pixels, the normalised scene frame and bounds, space warps,
lattices of voxels. No scene data, no fields.
"""
