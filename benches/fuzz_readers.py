"""Long fuzzing run of the mesh / landmark readers (the short run is tests/test_io_fuzz.py).

    .venv/bin/python benches/fuzz_readers.py --examples 2000 [--seed 0] [--formats wrl,obj]

For each format (wrl (plain and gzipped), bnd, obj, off, ply (ASCII and binary), stl, glb), ``--examples`` mutated valid files are read; the
outcome counts (Mesh / landmarks / each FacecorrError type / FAIL) are printed. A FAIL is any
other exception, a read over the time limit, or an invalid result (NaN vertices, bad indices, a
multi-line message); for each distinct failure the shortest input found is printed (repr) so that
it can be added as a regression test. Exit status 1 if anything failed.
"""

from __future__ import annotations

import argparse
import collections
import sys
import tempfile
import time
import traceback
import logging
import warnings
from pathlib import Path

from hypothesis import HealthCheck, given, seed, settings

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_io_fuzz import SEEDS, check, mutated  # noqa: E402


def fuzz(fmt: str, n: int, rng_seed: int, tmp: Path) -> tuple[collections.Counter, dict]:
    counts: collections.Counter = collections.Counter()
    failures: dict[str, bytes] = {}
    path = tmp / f"fuzz.{fmt}"

    @seed(rng_seed)
    @settings(max_examples=n, deadline=None, database=None, derandomize=False,
              suppress_health_check=list(HealthCheck))
    @given(data=mutated(fmt))
    def run(data):
        path.write_bytes(data)
        try:
            counts[check(path, fmt)] += 1
        except BaseException as e:  # noqa: BLE001 - every failure is recorded, none stops the run
            if isinstance(e, KeyboardInterrupt):
                raise
            tb = traceback.extract_tb(e.__traceback__)[-1]
            key = f"{type(e).__name__} at {Path(tb.filename).name}:{tb.lineno}: {str(e)[:120]}"
            counts["FAIL"] += 1
            if key not in failures or len(data) < len(failures[key]):
                failures[key] = data

    run()
    return counts, failures


def main(argv=None) -> int:
    logging.getLogger("trimesh").setLevel(logging.CRITICAL)  # its tracebacks of refused files
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--examples", type=int, default=2000, help="mutated files per format")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--formats", default=",".join(SEEDS), help="comma-separated subset of "
                    + ",".join(SEEDS))
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    bad = 0
    with tempfile.TemporaryDirectory() as d:
        for fmt in args.formats.split(","):
            t0 = time.perf_counter()
            counts, failures = fuzz(fmt, args.examples, args.seed, Path(d))
            dt = time.perf_counter() - t0
            total = sum(counts.values())
            outcome = ", ".join(f"{k} {v}" for k, v in counts.most_common())
            print(f"{fmt}: {total} files in {dt:.1f} s ({1e3 * dt / max(total, 1):.1f} ms each): {outcome}")
            for key, data in failures.items():
                bad += 1
                print(f"  FAIL {key}\n    shortest input ({len(data)} bytes): {data[:400]!r}")
    print("OK: no failures" if not bad else f"{bad} distinct failures")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
