"""Plain numpy reference of the shape-fitting energy and gradient (paper §4.3).

x: (N, 12) transforms T_i = [A_i | t_i] row-major; points (N, 3); edges (E, 2); targets, normals
(N, 3); weights (N,); anchors: ids (L,), positions (L, 3).
Returns (total, e_data, e_smooth, e_rigid, e_landmark, grad (N, 12)) with unweighted parts.
"""

import numpy as np


def shape_energy(x, points, edges, targets, normals, weights, anchor_ids, anchor_points,
                 w_data, w_smooth, w_rigid, w_landmark):
    n = len(points)
    T = x.reshape(n, 3, 4)
    ph = np.hstack([points, np.ones((n, 1))])                      # (N, 4)
    pt = np.einsum("nkc,nc->nk", T, ph)                            # (N, 3)
    r = np.einsum("nk,nk->n", targets - pt, normals)
    e_data = float(np.sum(weights * r * r))
    g = -2.0 * w_data * (weights * r)[:, None, None] * normals[:, :, None] * ph[:, None, :]

    d = T[edges[:, 0]] - T[edges[:, 1]]                           # (E, 3, 4)
    e_smooth = float(np.sum(d * d))
    np.add.at(g, edges[:, 0], 2.0 * w_smooth * d)
    np.add.at(g, edges[:, 1], -2.0 * w_smooth * d)

    A = T[:, :, :3]                                                # columns a_k = A[:, :, k]
    G = np.einsum("nrk,nrl->nkl", A, A)
    off = G[:, 0, 1] ** 2 + G[:, 0, 2] ** 2 + G[:, 1, 2] ** 2
    diag = ((1.0 - np.diagonal(G, axis1=1, axis2=2)) ** 2).sum(axis=1)
    e_rigid = float(np.sum(off + diag))
    # dE/dA = 2 A (G - diag(G)) - 4 A diag(1 - G_kk)
    Goff = G - np.einsum("nkk->nk", G)[:, :, None] * np.eye(3)
    dA = 2.0 * np.einsum("nrl,nlk->nrk", A, Goff) - 4.0 * A * (1.0 - np.einsum("nkk->nk", G))[:, None, :]
    g[:, :, :3] += w_rigid * dA

    e_lmk = 0.0
    for i, l in zip(np.asarray(anchor_ids, int), np.asarray(anchor_points, float)):
        dl = pt[i] - l
        e_lmk += float(dl @ dl)
        g[i] += 2.0 * w_landmark * dl[:, None] * ph[i][None, :]
    total = w_data * e_data + w_smooth * e_smooth + w_rigid * e_rigid + w_landmark * e_lmk
    return total, e_data, e_smooth, e_rigid, e_lmk, g.reshape(n, 12)
