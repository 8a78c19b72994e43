"""How `facecorr report` scales (issue 16): a batch folder grown to N results from the real results
of a smaller one (cycled, with varied numbers and flags), then the page's build time and size,
the time to render every thumbnail when the batch wrote none, and how long headless Chromium
takes to open it (navigation until the page's script has run).

    facecorr batch SCANS RESULTS --png          # a few real results with thumbnails
    python benches/report_scale.py RESULTS [--n 700] [--workers 2] [--only png|render|cpu]

``--only cpu``: the CPU time of rendering one thumbnail, in this process (30 renders).
"""

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from headless_chromium import Browser, find_chromium  # noqa: E402

from facecorr.report import build_report  # noqa: E402

FLAGS = ["low_confidence:nose_tip", "low_coverage:55% of the template has scan under it", "retried_wider_search",
         "implausible_fit:fit_rms_1.7mm", "landmark_off_surface:subnasal (6.1 mm from the scan)"]


def grow(src: Path, dst: Path, n: int, with_png: bool) -> None:
    """``n`` results in ``dst`` made from the results in ``src`` (mesh, JSON and, if asked, PNG)."""
    stems = sorted(p.with_suffix("") for p in src.glob("*.json") if p.name != "failures.json")
    rng = np.random.default_rng(0)
    for k in range(n):
        s = stems[k % len(stems)]
        d = json.loads(s.with_suffix(".json").read_text())
        d["mhd"] = float(d["mhd"] * rng.lognormal(0, 0.3))
        d["coverage"] = float(np.clip(d["coverage"] - abs(rng.normal(0, 0.05)), 0, 1))
        d["flags"] = list(rng.choice(FLAGS, size=rng.poisson(0.4), replace=False))
        out = dst / f"S{k:05d}"
        shutil.copy(s.with_suffix(".ply"), out.with_suffix(".ply"))
        out.with_suffix(".json").write_text(json.dumps(d))
        if with_png:
            shutil.copy(s.with_suffix(".png"), out.with_suffix(".png"))


def open_time(page_path: Path) -> float:
    with Browser() as b:
        page = b.new_page(1400, 1000)
        seconds = page.navigate(page_path.resolve().as_uri(), ready="document.documentElement.dataset.ready === '1'")
        rows = page.evaluate("document.querySelectorAll('#results tbody tr').length")
        t0 = time.monotonic()
        page.click("#results thead th:nth-child(4)")  # sort by MHD
        page.evaluate("document.querySelector('#results tbody tr').cells[3].dataset.v")
        sort_s = time.monotonic() - t0
    print(f"  chromium: opened in {seconds:.2f} s ({rows} rows), a sort by click {sort_s:.2f} s")
    return seconds


def render_cpu(src: Path, n: int = 30) -> None:
    from facecorr.names import LANDMARK_NAMES
    from facecorr.report.collect import render_job
    from facecorr.template import load_template

    load_template()
    jobs = []
    for p in sorted(src.glob("*.json")):
        if p.name != "failures.json":
            d = json.loads(p.read_text())
            jobs.append((str(p.with_suffix(".ply")), d["units"], d["surface_distance"],
                         [d["landmarks"][k] for k in LANDMARK_NAMES]))
    jobs = (jobs * n)[:n]
    c0, w0 = time.process_time(), time.perf_counter()
    for j in jobs:
        assert render_job(j)[2] is None
    print(f"{n} thumbnails rendered in one process: {(time.process_time() - c0) / n:.3f} s CPU, "
          f"{(time.perf_counter() - w0) / n:.3f} s wall each")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", help="a `facecorr batch --png` output folder (its results are cycled)")
    ap.add_argument("--n", type=int, default=700)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--only", choices=["png", "render", "cpu"],
                    help="only the case with the batch's thumbnails, or without, or the rendering's CPU time")
    a = ap.parse_args()
    if a.only == "cpu":
        render_cpu(Path(a.results))
        return
    with tempfile.TemporaryDirectory() as tmp:
        for with_png in {None: (True, False), "png": (True,), "render": (False,)}[a.only]:
            folder = Path(tmp) / ("png" if with_png else "nopng")
            folder.mkdir()
            grow(Path(a.results), folder, a.n, with_png)
            page = Path(tmp) / f"report_{folder.name}.html"
            t0 = time.perf_counter()
            rep = build_report(folder, page, workers=a.workers, progress=False)
            dt = time.perf_counter() - t0
            kind = "thumbnails from the batch" if with_png else f"every thumbnail rendered ({a.workers} workers)"
            print(f"{a.n} results, {kind}: built in {dt:.1f} s, {page.stat().st_size / 1e6:.1f} MB, "
                  f"{len(rep.rows)} rows")
            if find_chromium():
                open_time(page)


if __name__ == "__main__":
    main()
