"""Looking at a build: pictures, rerun recordings, the web viewer.

Above ``query`` and below ``train`` (the build's renders are drawn here). Nothing heavy is imported
with this package: matplotlib, rerun and viser are imported inside the functions that use them.

- :mod:`scenelabel.viz.pictures`: captioned render panels with a class legend and the view's
  metrics (what ``build`` writes to ``renders/<view>.png``), and the floor plan with a legend and
  a scale bar (``export --format nav2 --legend``), drawn with matplotlib (Agg).
- :mod:`scenelabel.viz.rerun_log`: :func:`~scenelabel.viz.rerun_log.log_rerun`, a build (map,
  meshes, views, renders, training curves) as a rerun recording (``export BUILD out.rrd``).
- :mod:`scenelabel.viz.viewer`: :class:`~scenelabel.viz.viewer.ViewerApp`, the web viewer of a build
  or a map (``scenelabel view``, viser; docs/look.md); its panels and the browser camera's pose in
  :mod:`scenelabel.viz.viewer_gui`, its training cameras' photos and frusta in
  :mod:`scenelabel.viz.viewer_cameras`.
- :mod:`scenelabel.viz.browser`: a headless Chromium over the DevTools protocol, to check and
  picture the viewer (tests, ``tools/screenshots.py``).
"""

__all__: list[str] = []
