"""The renderer's numerical constants, in a module of their own (no torch) so that the compiled
lattice loops and the baked field, which never import torch, composite by the same rules."""

from __future__ import annotations

__all__ = ["OPACITY_EPS", "EARLY_STOP_TRANS"]

OPACITY_EPS = 1e-10
"""Below this opacity a ray counts as empty: class probs are uniform and depth is ``far``."""

EARLY_STOP_TRANS = 1e-4
"""Queries stop marching a ray once its transmittance is below this
(:func:`scenelabel.render.marcher.render_rays_early_stop`, the baked field's kernels)."""
