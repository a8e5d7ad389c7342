"""Volume rendering: the compositing maths (volume.py), sample placement and the density grid
(sampling.py), the ray marcher that evaluates a field along rays (marcher.py), compiled lattice loops.
"""
