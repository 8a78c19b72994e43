"""CPU and wall time of the pictures `--png` writes for one scan (issue 16): the large one of
`register --png` (matplotlib, painted) against the thumbnail of `batch --png` (z-buffer), and
their sizes.

    python benches/thumbnail_timing.py SCAN [--repeat 3]
"""

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from facecorr.io import load_mesh
from facecorr.names import LANDMARK_NAMES
from facecorr.pipeline import correspond
from facecorr.render import plot_registration, thumbnail_png
from facecorr.template import load_template


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scan")
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    t = load_template()
    mesh = load_mesh(a.scan)
    r = correspond(mesh)
    lms = np.array([r.landmarks[n] for n in LANDMARK_NAMES])
    with tempfile.TemporaryDirectory() as tmp:
        big, small = Path(tmp) / "registration.png", Path(tmp) / "thumbnail.png"
        for name, path, draw in [
            ("register --png (plot_registration)", big, lambda: plot_registration(mesh, r, big, t)),
            ("batch --png (thumbnail_png)", small, lambda: small.write_bytes(
                thumbnail_png(r.vertices, r.faces, r.surface_distance, t, scan=mesh, landmarks=lms)))]:
            draw()  # warm: imports, caches
            c0, w0 = time.process_time(), time.perf_counter()
            for _ in range(a.repeat):
                draw()
            print(f"{name}: {(time.process_time() - c0) / a.repeat:.2f} s CPU, "
                  f"{(time.perf_counter() - w0) / a.repeat:.2f} s wall, {path.stat().st_size / 1e3:.0f} kB")
    print(f"(the registration itself: {r.timings_s['total']:.2f} s)")


if __name__ == "__main__":
    main()
