"""CPU time (load-insensitive) of principal curvatures and umbilics on the same ~50k-vertex,
1 mm face-like height field as benches/mesh_kernels.rs, through the Python API.

Run: FACECORR_THREADS=1 .venv/bin/python benches/mesh_kernels_cpu.py
"""

import time

import numpy as np

from facecorr import _core
from facecorr.geometry import curvature as C


def face_like_grid(n=224, seed=0):
    x, y = np.meshgrid(np.arange(n) - n / 2, np.arange(n) - n / 2)
    rng = np.random.default_rng(seed)
    z = -(x**2 + y**2) / 400 + 25 * np.exp(-(x**2 + (y + 10) ** 2) / 200) + rng.uniform(-0.05, 0.05, x.shape)
    V = np.stack([x, y, z], -1).reshape(-1, 3)
    a = np.arange(n * n).reshape(n, n)[:-1, :-1].ravel()
    F = np.concatenate([np.stack([a, a + 1, a + n + 1], 1), np.stack([a, a + n + 1, a + n], 1)])
    return V, F


def main(repeats=5):
    V, F = face_like_grid()
    k1, k2, _, _ = C.principal_curvatures(V, F)  # warm-up
    cases = {
        "principal_curvatures (2 rings)": lambda: C.principal_curvatures(V, F),
        "principal_curvatures (radius 3 mm)": lambda: C.principal_curvatures(V, F, radius=3.0),
        "umbilics (given k1, k2)": lambda: C.umbilics(V, F, k1, k2),
    }
    print(f"{len(V)} vertices, {len(F)} faces, {_core.n_threads()} thread(s)")
    for name, fn in cases.items():
        t, w = time.process_time(), time.perf_counter()
        for _ in range(repeats):
            fn()
        print(f"{name}: CPU {(time.process_time() - t) / repeats * 1e3:.1f} ms/call, "
              f"wall {(time.perf_counter() - w) / repeats * 1e3:.1f} ms/call")


if __name__ == "__main__":
    main()
