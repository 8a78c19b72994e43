"""The Rust PLY fast path against trimesh on 3,000 mutated PLY files: the loader's outcome (mesh or
error message) with the fast path must equal the outcome without it. Prints the counts by
(fast path took it, outcome) and the number of differences.

    python benches/ply_fastpath_fuzz.py        # from the repository root
"""
import sys, random, collections
sys.path.insert(0, 'tests')
from pathlib import Path
import test_ply_reader as T
from facecorr import _core
random.seed(1)
seeds = T._MORE_SEEDS + T.SEEDS["ply"]
stats = collections.Counter(); bad = 0
p = Path('/tmp/speed_fz.ply')
for it in range(3000):
    d = bytearray(random.choice(seeds))
    for _ in range(random.randint(1, 3)):
        k = random.randrange(len(d)) if d else 0
        kind = random.choice(["truncate", "flip", "insert", "flip"])
        if kind == "truncate": d = d[:k]
        elif kind == "flip" and d: d[k] = random.randrange(256)
        else: d[k:k] = random.choice([b" ", b"\n", b"-1", b"1e999", b"nan", b"4 ", b"\r", b"3", b"0", b"\t"])
    p.write_bytes(bytes(d))
    fast = _core.read_ply(str(p)) is not None
    a, b = T._outcome(p, True), T._outcome(p, False)
    stats[(fast, a[0])] += 1
    if a != b:
        bad += 1
        if bad < 5: print("DIFF", a[:2], b[:2], a[-1] if a[0]=='error' else '', b[-1] if b[0]=='error' else '')
print(stats, "diffs", bad)
