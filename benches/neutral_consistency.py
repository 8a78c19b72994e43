"""--neutral measure (issue 15) on a batch results folder with one sub-folder per subject
(<subject>/<stem>.ply, BU-3DFE names, one *_NE00_* scan each): the mean vertex distance after
Kabsch between each expressive result (raw, and its neutral_shape) and the subject's NE00 result,
per expression.

    python benches/neutral_consistency.py RESULTS_DIR
"""
import glob, sys, json, collections, time
import numpy as np, trimesh
from facecorr.template import load_template
from facecorr.registration.neutral import neutral_shape, NeutralOptions
from facecorr.geometry.transforms import kabsch
tpl=load_template()
def dist(a,b):
    r,t=kabsch(a,b); return np.linalg.norm(a@r.T+t-b,axis=1).mean()
by=collections.defaultdict(list); tt=[]
for subj in sorted(glob.glob(sys.argv[1]+'/*')):
    ne=glob.glob(subj+'/*_NE00_F3D.ply')[0]
    Vne=np.asarray(trimesh.load(ne,process=False).vertices)
    for f in sorted(glob.glob(subj+'/*_F3D.ply')):
        if 'NE00' in f: continue
        V=np.asarray(trimesh.load(f,process=False).vertices)
        t=time.perf_counter(); Vn,_=neutral_shape(V,tpl); tt.append(time.perf_counter()-t)
        by[f.split('_')[-2][:2]].append((dist(V,Vne), dist(Vn,Vne)))
print("| expression | scans | raw registration to the NE registration, mm | neutral shape, mm | ratio |\n|---|---|---|---|---|")
allv=[]
for e,v in sorted(by.items()):
    v=np.array(v); allv+=list(v); print(f"| {e} | {len(v)} | {v[:,0].mean():.2f} | {v[:,1].mean():.2f} | {v[:,0].mean()/v[:,1].mean():.2f} |")
v=np.array(allv); print(f"| all | {len(v)} | {v[:,0].mean():.2f} | {v[:,1].mean():.2f} | {v[:,0].mean()/v[:,1].mean():.2f} |")
print("median seconds per neutral_shape", np.median(tt))
