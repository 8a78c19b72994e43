"""The two distances of a registered template to its scan, per result of a batch (issue 16): to
the nearest scan vertex (the MHD's terms, which include the scan's sampling) and to the scan's
surface (the JSON's ``surface_distance``, the report's colour).

    python benches/surface_distance.py SCANS RESULTS     # RESULTS: `facecorr batch SCANS RESULTS`
"""

import json
import sys
from pathlib import Path

import numpy as np

from facecorr.io import load_mesh
from facecorr.pipeline.correspond import decode_distances


def main() -> None:
    scans, results = Path(sys.argv[1]), Path(sys.argv[2])
    for js in sorted(p for p in results.glob("*.json") if p.name != "failures.json"):
        d = json.loads(js.read_text())
        scan = load_mesh(scans / js.with_suffix(".ply").name)
        reg = load_mesh(js.with_suffix(".ply"), units=d["units"], merge_duplicates=False)
        nn = np.asarray(scan.kdtree.query(reg.vertices)[0])
        sd = decode_distances(d["surface_distance"])  # saturated at 5.1 mm
        print(f"{js.stem}: median to the nearest vertex {np.median(nn):.2f} mm, to the surface {np.median(sd):.2f} mm; "
              f"mean {nn.mean():.2f} (the MHD: {d['mhd']:.2f}) vs {sd.mean():.2f} mm")


if __name__ == "__main__":
    main()
