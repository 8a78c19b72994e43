"""CPU seconds of ``predict_landmarks`` on one scan (min of 3, after a warm-up of the mesh's caches),
and the first bytes of the landmark positions (to check that two checkouts agree bit for bit).

    FACECORR_THREADS=1 [PYTHONPATH=OTHER/python] python benches/predict_cpu.py SCAN
"""
import sys, time
import numpy as np
from facecorr.io import load_mesh
from facecorr.landmarks import predict_landmarks, load_model
m = load_mesh(sys.argv[1]); w,_ = m.centred_outward(); w.vertex_normals; w.kdtree
model = load_model(None)
def cpu(f, n=3):
    ts=[]
    for _ in range(n):
        t=time.process_time(); r=f(); ts.append(time.process_time()-t)
    return min(ts), r
t, r = cpu(lambda: predict_landmarks(w, model=model))
print("predict_landmarks CPU", round(t,3), {k: round(v,3) for k,v in r.timings_s.items()})
print(np.array([r.positions[k] for k in sorted(r.positions)]).tobytes().hex()[:64])
