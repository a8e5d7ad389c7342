"""Picture the web viewer for the docs: build (or reuse) the toy scene, serve ``scenelabel view``,
open it in a headless Chromium, answer a point query and render the view, and save the page.

    .venv/bin/python tools/screenshots.py                       # docs/images/viewer.png
    .venv/bin/python tools/screenshots.py --build toy_scene/scenelabel --out /tmp/viewer.png

Also prints what it measured: the page's ready time after ``scenelabel view BUILD`` is started
(the command in its own process, the browser already running, as a user's is: the time until a
screenshot of the page shows every class's colour, taken when that screenshot arrived, polled every
0.05 s; and when the command printed its URL): the freshly started browser's first page, then the
median of COMMAND_RUNS more once the browser has drawn it (a user's browser has drawn pages before);
the ready time after the URL is opened with the server already running in this process, a point
query's latency through the API, and a 320 x 240 render from the browser's camera with each method
(the page at rest, the field baked apart).
Needs a chromium (Debian: ``apt-get install chromium``; tools/setup.sh installs it where it can).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
COMMAND_RUNS = 5
"""Runs of ``scenelabel view BUILD`` timed after the browser's first page (their median is reported):
the machine is noisy."""
RENDER_RUNS = 3
"""Renders timed per method (their median is reported)."""
REST_SECONDS = 3.0
"""Seconds the page is left to finish drawing before renders are timed, as a user looks before pressing Render."""
DEFAULT_WORK = Path("/tmp/scenelabel-screenshots")
# viser warns in the page that WebGL runs in software (SwiftShader, as headless Chromium does): close it
DISMISS_SOFTWARE_WEBGL = """(() => {
  for (const note of document.querySelectorAll('.mantine-Notification-root')) {
    if (note.textContent.includes('Software WebGL')) { const b = note.querySelector('button'); if (b) b.click(); }
  }
  return true;
})()"""


def toy_build(work: Path, steps: int) -> Path:
    """The toy scene built with the quick preset under ``work`` (reused when already there)."""
    from scenelabel import build, preset, write_toy_scene

    out = work / "toy" / "scenelabel"
    if (out / "checkpoint.pt").is_file():
        return out
    scene = write_toy_scene(work / "toy")
    print(f"building the toy scene ({steps} steps) into {out} ...", flush=True)
    build(scene, out, preset("quick", {"train": {"steps": steps}}), progress=False)
    return out


def shows_every_class(palette: dict, classes: list[int]) -> Callable[[np.ndarray], bool]:
    """A page's readiness test: every one of ``classes`` covers some of the image in its colour."""
    from scenelabel.viz.browser import colour_fraction

    return lambda image: all(colour_fraction(image, palette[c]) > 0.001 for c in classes)


def page_ready_after_command(browser, build_dir: Path, palette: dict, classes: list[int]) -> tuple[float, float, float]:
    """(seconds until the page shows every class's colour, until the URL was printed, until the
    command said the field was loaded), all from starting ``scenelabel view BUILD --port 0`` in a
    fresh process; the browser is already open."""
    import subprocess
    import threading

    start = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "scenelabel", "view", str(build_dir), "--port", "0", "--timeout", "120"],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    said: dict[str, float] = {}
    urls: list[str] = []
    loaded = threading.Event()

    def read() -> None:
        for line in proc.stdout:
            if " at http" in line and not urls:
                urls.append(line.split(" at ", 1)[1].split()[0])
                said["url"] = time.perf_counter() - start
            if "field loaded" in line:
                said["field"] = time.perf_counter() - start
                loaded.set()
        loaded.set()  # the command ended

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        deadline = time.monotonic() + 60
        while not urls:
            if proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"scenelabel view printed no URL (exit {proc.poll()})")
            time.sleep(0.01)
        browser.open(urls[0])
        browser.wait_for(shows_every_class(palette, classes), timeout=120)
        ready = browser.captured_at - start  # the screenshot that showed it, not the check after it
        loaded.wait(60)
        if "field" not in said:
            raise RuntimeError("scenelabel view never said the field was loaded")
        return ready, said["url"], said["field"]
    finally:
        proc.terminate()
        proc.wait(30)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--build", type=Path, help="a build folder to show (default: the toy scene, built once)")
    parser.add_argument("--work", type=Path, default=DEFAULT_WORK, help=f"where the toy build goes ({DEFAULT_WORK})")
    parser.add_argument("--steps", type=int, default=500, help="training steps of the toy build (default: 500)")
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "images" / "viewer.png")
    parser.add_argument("--size", default="1280x1000", help="browser viewport WxH (default: 1280x1000)")
    parser.add_argument("--timings", type=Path, default=REPO / "docs" / "viewer_timings.md", help="where the timings go")
    args = parser.parse_args(argv)

    from scenelabel.viz.browser import HeadlessBrowser, find_chromium
    from scenelabel.viz.viewer import ViewerApp
    from scenelabel.viz.viewer_gui import camera_pose

    if find_chromium() is None:
        print("no chromium found: install Debian's chromium (or set SCENELABEL_CHROMIUM)", file=sys.stderr)
        return 1
    build_dir = args.build or toy_build(args.work, args.steps)
    width, height = (int(v) for v in args.size.lower().split("x"))
    app = ViewerApp.open(build_dir)
    url = app.start(port=0)
    print(f"viewer of {build_dir} at {url}")
    classes = [c for c in app.palette if app.voxel_counts.get(c, 0) > 0]
    try:
        with HeadlessBrowser(width, height) as browser:
            # the command twice: the browser's first page (Chromium still warming up: its first WebGL
            # page, the viewer's script compiled afresh), then again, as a browser that has drawn it before
            first = page_ready_after_command(browser, build_dir, app.palette, classes)
            again = [page_ready_after_command(browser, build_dir, app.palette, classes) for _ in range(COMMAND_RUNS)]
            after_command, url_printed, field_loaded = (statistics.median(r[k] for r in again) for k in range(3))
            start = time.perf_counter()
            browser.open(url)
            client = app.wait_for_client(60)
            browser.wait_for(shows_every_class(app.palette, classes), timeout=120)
            ready = browser.captured_at - start
            browser.evaluate(DISMISS_SOFTWARE_WEBGL)

            # a click on the first box from above: what the Query panel then says
            box = app.map.world_from_index(np.argwhere(app.map.label == classes[-1])).mean(0)
            hit = app.click_point(box + [0.0, 0.0, 10.0], [0.0, 0.0, -1.0])
            app.show_query(hit if hit is not None else box)
            latencies = []
            for _ in range(20):
                t = time.perf_counter()
                app.query(hit if hit is not None else box)
                latencies.append(time.perf_counter() - t)
            # a user presses Render on a page at rest: let the page finish drawing the query's
            # marker and the field's cameras first (SwiftShader draws on the same cores as torch)
            time.sleep(REST_SECONDS)
            methods = ("baked", "map", "field") if app.field is not None else ("map",)
            bake_seconds = None
            if app.field is not None:
                t = time.perf_counter()
                app.baked()
                bake_seconds = time.perf_counter() - t
            renders = {}
            for method in methods:  # the field last: its rgb stays in the panel
                renders[method] = statistics.median(app.show_render(client, method).seconds for _ in range(RENDER_RUNS))
            app.gui["render_method"].value = methods[-1]
            view = camera_pose(client.camera)
            time.sleep(1.0)
            browser.evaluate(DISMISS_SOFTWARE_WEBGL)
            image = browser.wait_for(shows_every_class(app.palette, classes), 60)
        # the same view again with no browser drawing (SwiftShader WebGL takes CPU from the field)
        alone = {method: statistics.median(app.render_view(*view, method=method).seconds for _ in range(RENDER_RUNS))
                 for method in methods}
    finally:
        app.stop()
    from PIL import Image

    args.out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(image).save(args.out)
    lines = [
        f"page ready {after_command:.2f} s after `scenelabel view BUILD` started (median of {COMMAND_RUNS} runs, "
        f"{min(r[0] for r in again):.2f}-{max(r[0] for r in again):.2f} s; the URL printed after {url_printed:.2f} s, "
        f"the field loaded after {field_loaded:.2f} s; the browser already running: chromium, SwiftShader WebGL, "
        "which had drawn the viewer before)",
        f"page ready {first[0]:.2f} s after `scenelabel view BUILD` started when it is the first page of a freshly "
        f"started browser (the URL printed after {first[1]:.2f} s)",
        f"page ready {ready:.2f} s after the URL was opened (the server already running in this process)",
        f"point query through ViewerApp.query: median of 20 {1000 * statistics.median(latencies):.2f} ms "
        f"({'field' if app.field is not None else 'map'})",
        f"320 x 240 render from the browser's camera (median of {RENDER_RUNS}, the page at rest): "
        + ", ".join(f"{m} {s:.2f} s" for m, s in renders.items())
        + ("" if bake_seconds is None else f" (baking the field for `baked`, once: {bake_seconds:.2f} s)")
        + "; with the browser closed: " + ", ".join(f"{m} {s:.2f} s" for m, s in alone.items()),
    ]
    print(f"wrote {args.out} ({width} x {height})\n" + "\n".join(lines))
    write_timings(args.timings, build_dir, lines)
    return 0


def write_timings(path: Path, build_dir: Path, lines: list[str]) -> None:
    """The run's measurements as a small markdown page (one run: the machine and code are recorded)."""
    import os
    import platform

    from bench_suite import code_version  # tools/bench_suite.py, beside this script

    commit = code_version()
    head = [
        "# Viewer timings",
        "",
        f"Generated by `python tools/screenshots.py` (code {commit}), {time.strftime('%Y-%m-%d')}, on "
        f"{platform.machine()} with {os.cpu_count()} CPU cores, Python {platform.python_version()}; one run, "
        f"build {build_dir.name} of the toy scene. Headless Chromium draws WebGL in software on the same cores.",
        "",
    ]
    path.write_text("\n".join(head + [f"- {line}" for line in lines]) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    sys.exit(main())
