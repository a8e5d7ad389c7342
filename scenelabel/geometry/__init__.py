"""Geometry every stage shares: cameras (OpenCV axes) and their records, rays from pixels, the
normalised scene frame and bounds, space warps, lattices of voxels. No scene data, no fields.
"""
