"""tools/suite_compare.py: two runs of the suite, room by room, on made-up rows with known answers."""

from __future__ import annotations

import json

from tool_modules import load_tool


def _row(scene: str, miou: float, build: float, setup: float | None, code: str, map_seconds: float | None = None) -> dict:
    row = {"scene": scene, "variant": "phone-depth", "tuning": scene != "held", "miou": miou, "psnr": 30.0,
           "depth_rel_median": 0.01, "surface_field": 0.9, "surface_map": 0.9, "fscore": 0.9, "free_field": 1.0,
           "miou_common": miou, "samples_per_ray": 8.0, "build_seconds": build, "train_seconds": 60.0,
           "reference_seconds": 0.2, "code": code}
    if setup is not None:
        row["time_plan"] = {"setup_seconds": setup}
    if map_seconds is not None:
        row["map_seconds"] = map_seconds
    return row


def test_compare_counts_rooms_that_came_out_the_same_and_their_setup(tmp_path):
    before = {"rows": [_row("a", 0.9, 100.0, 10.0, "old", 4.0), _row("held", 0.8, 100.0, 8.0, "old", 10.0)]}
    after = {"rows": [_row("a", 0.9, 80.0, 5.0, "new", 2.0), _row("held", 0.85, 90.0, 6.0, "new", 2.5)]}
    paths = [tmp_path / "before.json", tmp_path / "after.json"]
    for path, run in zip(paths, (before, after)):
        path.write_text(json.dumps(run))
    text = "\n".join(load_tool("suite_compare").compare(*paths, tmp_path / "out.md"))
    # a: only timings and the code moved; held: its mIoU rose
    assert "Builds the same in every recorded figure but the timings: 1 of 2 (a)." in text
    assert "| held out | miou | 0.8 -> 0.85 | 0.8 -> 0.85 | 1 / 0 / 0 |" in text
    assert "Build time after / before, same room: median 0.85 (0.80-0.90) (before 100-100 s, after 80-90 s)" in text
    assert "`occupancy_map(0.05)` time after / before, same room: median 0.38 (0.25-0.50) (before 4-10 s, after 2-2.5 s)" in text
    assert "a 10.0 -> 5.0, held 8.0 -> 6.0; after / before median 0.62 (0.50-0.75)." in text


def test_compare_leaves_out_setup_and_map_times_a_run_did_not_record(tmp_path):
    paths = [tmp_path / "before.json", tmp_path / "after.json"]
    for path, setup in zip(paths, (None, 5.0)):
        path.write_text(json.dumps({"rows": [_row("a", 0.9, 100.0, setup, "x")]}))
    lines = load_tool("suite_compare").compare(*paths, tmp_path / "out.md")
    assert not any("Seconds before training" in line or "occupancy_map" in line for line in lines)  # neither run timed a map
