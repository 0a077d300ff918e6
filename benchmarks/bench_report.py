"""The report page in headless Chromium: its size and its time to load (navigation start to the page
ready, the 3D scene drawn), against the same page without its 3D scene (what the scene costs), and
against any other report pages given with ``--also`` (for example one written by an older primkit).

    python benchmarks/bench_report.py [--shapes 8] [--loads 3] [--also OLD/index.html ...]

Builds a report of procedural chairs (seed 11) with the bundled chair model, then loads each page
``--loads`` times in a fresh browser (``tests/chromium.py``) and prints the median. WebGL runs on
SwiftShader (the CPU) here, so drawing is slower than in a browser with a GPU.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import tempfile
from pathlib import Path

from _common import table  # noqa: E402

# a page without the scene is ready at once; an older page's canvas viewer sets the same flag
READY = "document.body && (document.body.dataset.ready === '1' || !document.getElementById('scene'))"


def _chromium():
    """The DevTools driver the report's test uses (``tests/chromium.py``), loaded from its file."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("chromium", Path(__file__).resolve().parents[1] / "tests" / "chromium.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.CHROMIUM, module.load_page


def _without_scene(page: str) -> str:
    """The page with its 3D scene (the plotly div, data, library and drawing script) removed."""
    page = re.sub(r'<div id="scene"></div>\s*<script id="scene-data".*?</script>', "", page, count=1, flags=re.S)
    start = page.index("<script>/**\n* plotly.js")  # the library, then the drawing script
    end = page.index("</script>", page.index("Plotly.newPlot", start)) + len("</script>")
    return page[:start] + page[end:]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--shapes", type=int, default=8)
    parser.add_argument("--loads", type=int, default=3)
    parser.add_argument("--also", nargs="*", default=[], help="other report pages to load the same way")
    args = parser.parse_args(argv)

    import torch

    torch.set_num_threads(1)
    CHROMIUM, load_page = _chromium()

    from primkit import synthetic
    from primkit.report import build_report

    if CHROMIUM is None:
        print("chromium is not installed (scripts/setup.sh installs it)")
        return 1
    print(f"load average at start: {os.getloadavg()[0]:.1f}")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        paths = synthetic.write_collection(tmp / "in", "chair", args.shapes, seed=11)
        report, _ = build_report(paths, "chair", tmp / "out", cache_dir=tmp / "cache", workers=1, progress=False)
        bare = tmp / "out" / "no-scene.html"
        bare.write_text(_without_scene(report.path.read_text(encoding="utf-8")), encoding="utf-8")
        pages = [("this primkit (plotly.js scene)", report.path), ("the same page without its 3D scene", bare)]
        pages += [(f"--also {p}", Path(p)) for p in args.also]
        rows = []
        for label, path in pages:
            times, problems = [], set()
            for _ in range(args.loads):
                got = load_page(path, screenshot=False, ready=READY)
                times.append(got.ready_ms if got.ready_ms is not None else float("nan"))
                problems |= set(got.problems())
            rows.append([label, f"{path.stat().st_size / 1e6:.2f} MB", f"{statistics.median(times) / 1000:.2f} s",
                         f"{min(times) / 1000:.2f} s", len(problems)])
        table(f"report page of {args.shapes} chairs: size and time to load (median of {args.loads})",
              ["page", "index.html", "time to load", "fastest", "console problems"], rows,
              note="time to load = performance.now() when the page says it is ready (its 3D scene drawn); "
                   "plotly.js itself is 4.8 MB of the page.")
    print(f"load average at end: {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
