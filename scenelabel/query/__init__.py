"""Answers from a trained field: SemanticField (points, rays, renders, maps), the baked lattice
(BakedField), label post-processing, and the chunk-by-chunk map writer.
"""
