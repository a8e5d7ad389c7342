"""tools/fit_time_plan.py: the time plan's constants fitted to made-up suite rows with known answers."""

from __future__ import annotations

import json

import pytest
from tool_modules import load_tool


def _row(views: int, resolution: str, after: float, planned: bool = True) -> dict:
    setup, train = 5.0, 70.0
    row = {"scene": f"room-{views}-{resolution}", "code": "abc", "views": views, "resolution": resolution,
           "build_seconds": setup + train + after, "train_seconds": train}
    if planned:
        row["time_plan"] = {"setup_seconds": setup, "finish_seconds": 6.0}
    return row


def test_fit_recovers_the_constants_and_covers_the_slowest_row(tmp_path):
    tool = load_tool("fit_time_plan")
    # held out: 5 views of 160x120 (0.096 MP, 5 panels), 3 of 640x480 (0.9216 MP), 16 of 160x120 (8 panels)
    shapes = [(40, "160x120"), (24, "640x480"), (128, "160x120")]
    def after(views, res, extra=0.0):
        w, h = (int(v) for v in res.split("x"))
        n = len(range(0, views, 8))
        return 3.0 + 10.0 * n * w * h / 1e6 + tool.PANEL_SECONDS * min(n, 8) + extra
    rows = [_row(v, r, after(v, r)) for v, r in shapes] + [_row(40, "160x120", 99.0, planned=False)]
    path = tmp_path / "run.json"
    path.write_text(json.dumps({"rows": rows}))
    planned = tool.planned_rows([str(path)])
    assert [r["panels"] for r in planned] == [5, 3, 8]  # the row without a plan is left out
    assert tool.fit(planned) == pytest.approx((3.0, 10.0))
    # one row 2 s slower than the line: the fixed part rises to cover it (the slope moves a little)
    slow = [_row(v, r, after(v, r, 2.0 if i == 0 else 0.0)) for i, (v, r) in enumerate(shapes)]
    path.write_text(json.dumps({"rows": slow}))
    fixed, per_mp = tool.fit(tool.planned_rows([str(path)]))
    covered = [fixed + per_mp * r["megapixels"] + tool.PANEL_SECONDS * r["panels"] - r["after"] for r in tool.planned_rows([str(path)])]
    assert min(covered) == pytest.approx(0.0, abs=1e-9) and all(c >= -1e-9 for c in covered)
