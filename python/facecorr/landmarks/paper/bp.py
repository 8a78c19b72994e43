"""Loopy belief propagation, max-product in the log domain (max-sum), over discrete labels.

Each node i of the Markov network (a landmark) has a discrete candidate set of size K_i (vertex
ids of the scan), a node log-potential ``unary[i]`` (K_i,) and, for every graph edge (i, j), a
pairwise log-potential ``pairwise[(i, j)]`` (K_i, K_j). We look for the joint assignment with the
largest total log-potential (the MAP of the network, paper §3.2).

Why max-product: the paper's output is one position per landmark, i.e. a MAP estimate; max-sum
is exact on trees (the test checks it against brute-force enumeration) and the standard choice on
loopy graphs (Yedidia et al. 2003). Messages are normalised (max = 0) every step, damped
(``damping`` in [0, 1), the weight of the old message) to avoid oscillation on loops, and run in
a synchronous (flooding) schedule until the largest message change is below ``tol`` or
``max_iter`` sweeps. The result is decoded by the argmax of each node's belief; ties/loops can
make independent argmaxes inconsistent, so on loopy graphs we finish with iterated conditional
modes (ICM) started from the belief argmax, which never lowers the joint score.

Confidence: each node's max-marginal belief turned into a distribution by a softmax
(``exp(b - logsumexp b)``), evaluated at the chosen label: 1 = no competing candidate with a
comparable score, 1/K = all candidates are equally good.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp


@dataclass
class BPResult:
    """labels (L,) int chosen candidate per node; beliefs list of (K_i,) max-marginal log-beliefs;
    confidence (L,) float in (0, 1]; score float (total log-potential of ``labels``);
    iterations int; converged bool."""

    labels: np.ndarray
    beliefs: list
    confidence: np.ndarray
    score: float
    iterations: int
    converged: bool


def _check(unary, pairwise):
    n = len(unary)
    unary = [np.asarray(u, dtype=np.float64) for u in unary]
    for i, u in enumerate(unary):
        if u.ndim != 1 or len(u) == 0:
            raise ValueError(f"belief propagation: node {i} needs a non-empty 1-D unary potential, got {u.shape}")
        if np.isnan(u).any() or np.isposinf(u).any():
            raise ValueError(f"belief propagation: node {i} unary potential has NaN or +inf")
    pw = {}
    for (i, j), p in pairwise.items():
        if not (0 <= i < n and 0 <= j < n) or i == j:
            raise ValueError(f"belief propagation: bad edge ({i}, {j}) for {n} nodes")
        p = np.asarray(p, dtype=np.float64)
        if p.shape != (len(unary[i]), len(unary[j])):
            raise ValueError(f"belief propagation: edge ({i}, {j}) potential has shape {p.shape}, "
                             f"expected {(len(unary[i]), len(unary[j]))}")
        if np.isnan(p).any() or np.isposinf(p).any():
            raise ValueError(f"belief propagation: edge ({i}, {j}) potential has NaN or +inf")
        if (j, i) in pw or (i, j) in pw:
            raise ValueError(f"belief propagation: edge ({i}, {j}) given twice")
        pw[(i, j)] = p
    return unary, pw


def joint_score(labels, unary, pairwise) -> float:
    """Total log-potential of an assignment: sum of unaries plus pairwise terms."""
    s = sum(float(unary[i][labels[i]]) for i in range(len(unary)))
    s += sum(float(p[labels[i], labels[j]]) for (i, j), p in pairwise.items())
    return s


def max_product(unary, pairwise, max_iter: int = 100, damping: float = 0.5, tol: float = 1e-6) -> BPResult:
    """MAP assignment of a pairwise Markov network by loopy max-product BP (log domain).

    Parameters
    ----------
    unary : list of L arrays (K_i,), node log-potentials (-inf allowed = forbidden label).
    pairwise : dict (i, j) -> (K_i, K_j) edge log-potentials (each undirected edge once).
    max_iter, damping, tol : schedule (see module docstring).
    """
    unary, pw = _check(unary, pairwise)
    n = len(unary)
    if not 0 <= damping < 1:
        raise ValueError(f"belief propagation: damping must be in [0, 1), got {damping}")
    # Directed messages m[(i, j)] : (K_j,) from i to j; potentials viewed from i -> j.
    pot = {}
    for (i, j), p in pw.items():
        pot[(i, j)] = p
        pot[(j, i)] = p.T
    nbrs = [[] for _ in range(n)]
    for (i, j) in pot:
        nbrs[j].append(i)
    msgs = {e: np.zeros(len(unary[e[1]])) for e in pot}
    is_tree = len(pw) <= n - 1 and _is_forest(n, list(pw))
    converged = False
    it = 0
    for it in range(1, max_iter + 1):
        incoming = [unary[i] + sum((msgs[(k, i)] for k in nbrs[i]), np.zeros(len(unary[i]))) for i in range(n)]
        new = {}
        delta = 0.0
        for (i, j), p in pot.items():
            h = incoming[i] - msgs[(j, i)]  # exclude what j told i
            m = np.max(h[:, None] + p, axis=0)
            top = np.max(m)
            m = m - top if np.isfinite(top) else np.zeros_like(m)
            if not is_tree and damping > 0:
                old = msgs[(i, j)]
                ok = np.isfinite(m) & np.isfinite(old)
                m = np.where(ok, damping * old + (1 - damping) * m, m)
            fin = np.isfinite(m) & np.isfinite(msgs[(i, j)])
            if fin.any():
                delta = max(delta, float(np.max(np.abs(m[fin] - msgs[(i, j)][fin]))))
            if (np.isfinite(m) != np.isfinite(msgs[(i, j)])).any():
                delta = np.inf
            new[(i, j)] = m
        msgs = new
        if delta < tol:
            converged = True
            break
    beliefs = [unary[i] + sum((msgs[(k, i)] for k in nbrs[i]), np.zeros(len(unary[i]))) for i in range(n)]
    labels = np.array([int(np.argmax(b)) for b in beliefs])
    if not is_tree:
        labels = _icm(labels, unary, pw, nbrs, pot)
    conf = np.empty(n)
    for i, b in enumerate(beliefs):
        conf[i] = float(np.exp(b[labels[i]] - logsumexp(b))) if np.isfinite(b[labels[i]]) else 0.0
    return BPResult(labels=labels, beliefs=beliefs, confidence=conf, score=joint_score(labels, unary, pw),
                    iterations=it, converged=converged)


def _is_forest(n, edges) -> bool:
    parent = list(range(n))

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for i, j in edges:
        ri, rj = find(i), find(j)
        if ri == rj:
            return False
        parent[ri] = rj
    return True


def _icm(labels, unary, pw, nbrs, pot, sweeps: int = 20):
    """Iterated conditional modes: each node takes its best label given its neighbours."""
    labels = labels.copy()
    for _ in range(sweeps):
        changed = False
        for i in range(len(unary)):
            s = unary[i].copy()
            for k in nbrs[i]:
                s = s + pot[(i, k)][:, labels[k]]
            best = int(np.argmax(s))
            if s[best] > s[labels[i]] + 1e-12:
                labels[i] = best
                changed = True
        if not changed:
            break
    return labels


def brute_force_map(unary, pairwise):
    """Exhaustive MAP (reference for tests; exponential in the number of nodes)."""
    import itertools

    unary, pw = _check(unary, pairwise)
    best, best_labels = -np.inf, None
    for labels in itertools.product(*[range(len(u)) for u in unary]):
        s = joint_score(labels, unary, pw)
        if s > best:
            best, best_labels = s, np.array(labels)
    return best_labels, best
