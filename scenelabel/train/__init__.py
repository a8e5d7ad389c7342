"""Training: the optimisation loop (trainer.py), its losses, data-parallel helpers, and the build
pipeline (build, evaluate, resume) and many-scene batches on top of it.
"""
