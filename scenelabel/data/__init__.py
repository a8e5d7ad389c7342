"""Inputs: the Scene (images, labels, cameras, classes), loaders of every input layout (io/), structure
from motion, segmenters, and the synthetic scenes and scene suite.
"""
