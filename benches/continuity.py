"""Is the registration continuous in its input? Each scan is registered as stored and with its
vertices rounded as a float32 file in cm would hold them (~5e-6 mm); prints the largest vertex
difference per scan (issue 13, #15).

    python benches/continuity.py DB [--every 25] [--n 12]
"""

import argparse
import json
from pathlib import Path

import numpy as np

from facecorr.geometry.mesh import Mesh
from facecorr.io import load_mesh
from facecorr.pipeline import correspond


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("db", help="a `facecorr synth` folder")
    ap.add_argument("--every", type=int, default=25, help="every n-th test scan")
    ap.add_argument("--n", type=int, default=12, help="scans at most")
    a = ap.parse_args()
    recs = [r for r in json.loads((Path(a.db) / "index.json").read_text())["scans"] if r["split"] == "test"]
    jumps = []
    for r in recs[:: a.every][: a.n]:
        m = load_mesh(Path(a.db) / r["scan"], units="mm")
        rounded = Mesh((m.vertices / 10.0).astype(np.float32).astype(np.float64) * 10.0, m.faces)
        x, y = correspond(m), correspond(rounded)
        d = float(np.linalg.norm(x.vertices - y.vertices, axis=1).max())
        jumps.append(d)
        print(f"{r['scan']}: largest vertex difference {d:.2e} mm (MHD {x.mhd:.3f} / {y.mhd:.3f})", flush=True)
    print(f"{sum(d <= 1e-4 for d in jumps)} of {len(jumps)} continuous (<= 1e-4 mm); worst {max(jumps):.2f} mm")


if __name__ == "__main__":
    main()
