"""Building a shape model on a Dask cluster (``facecorr model build RESULTS -o m.npz --scheduler ADDRESS``).

The arithmetic is the local build's (:func:`.build.fit_model`): the same Procrustes mean update
(:func:`.procrustes.procrustes_mean`), the same final pose (:func:`.procrustes.final_pose`) and
the same PCA by the Gram matrix (:func:`.pca.pca_from_gram`); only where the shapes live differs.

Where the work is done
    The client picks the results (:func:`.results.select_results`: the result JSONs and the
    flag policy, no mesh read) and cuts them into chunks of consecutive shapes. Each chunk is
    read by a worker (the result meshes, at the absolute paths the client sees: the workers need
    the results folder at the same path, a shared filesystem; checked on every worker first) and
    stays in that worker's memory as a Dask future for the whole build. Then, per chunk, on the
    workers:

    * every Procrustes iteration: each shape fitted onto the current mean (a 3 x 3 SVD per
      shape), and the sum of the fitted shapes ((N, 3), the only thing sent back);
    * the final alignment of every shape, kept there as rows of 3N mm;
    * the Gram matrix X X^T of the centred aligned shapes, block by block (pairs of chunks);
    * the two products with the data the PCA needs: X^T V (a (3N, K) sum over the chunks) and
      X Q (the chunk's rows of (S, K)).

    The client does the small dense algebra: the (S, S) eigen-decomposition, the QR of the
    (3N, K) directions and the SVD of the (S, K) projection. So the client holds O(S^2 + 3N K)
    numbers, never the (S, 3N) shapes. (Above S = 3N shapes, about 16,000 faces, the local build
    switches to an SVD of the data; the cluster build stays with the Gram matrix, the same PCA,
    and its client then holds S^2 numbers: 2 GB at 16,000.)

Agreement with the local build
    Sums over chunks round differently from one sum over all the shapes: the models agree to
    round-off (tests/test_model_dask.py holds every field to 1e-9; BENCHMARKS.md, "Batch on a Dask
    cluster", has the measured difference on 140 and 700 results: 1e-14 relative).

Errors
    A result that cannot be read is the local build's one-line ShapeModelError, found on the
    worker and raised by the client (the first in the results' order); a worker that dies while
    it holds or computes a chunk (killed, out of memory) stops the build with one line (the chunks
    live in the workers' memory: there is nothing to resume). Ctrl-C / SIGTERM cancel the tasks
    and (:func:`facecorr.pipeline.cluster.connect`) stop a LocalCluster's workers: exit 130 / 143,
    no model written (checked by hand on the 700 stand-ins, not by a test; a Ctrl-C while the
    LocalCluster is still starting lets Dask print its own traceback at exit, as in the batch).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from ..errors import ShapeModelError
from ..options import resolve
from .build import BuildOptions, model_from_pca
from .pca import pca_from_gram
from .procrustes import _transformed, centroid_size, final_pose, fit_onto, procrustes_mean
from .results import read_shape, same_faces, select_results

#: Shapes per chunk at least / at most (the default is the shapes shared between twice the
#: cluster's threads, within these bounds: few enough tasks for the Gram blocks' pairs).
MIN_CHUNK, MAX_CHUNK = 16, 256


# --- on the workers ----------------------------------------------------------------------------------

def _read_chunk(entries, n_vertices: int) -> dict:
    """A chunk of results read and centred: ``{"c": (s, N, 3) mm centred, "sizes": (s,) centroid
    sizes, "faces": (M, 3), "first": the first mesh's name}``, or ``{"error": message}`` for a
    result the local build would refuse (its ShapeModelError's one line: returned, not raised, so
    that the workers do not log it as a failed task). ``entries``: (name, absolute mesh path, mm
    per unit) triples."""
    x = np.empty((len(entries), n_vertices, 3))
    faces = None
    try:
        for i, (_, mesh, to_mm) in enumerate(entries):
            x[i], f = read_shape(Path(mesh), to_mm, n_vertices)
            if faces is None:
                faces = f
            else:
                same_faces(mesh, f, faces, Path(entries[0][1]).name)
    except ShapeModelError as e:
        return {"error": str(e)}
    c = x - x.mean(axis=1)[:, None, :]
    return {"c": c, "sizes": centroid_size(c), "faces": faces, "first": Path(entries[0][1]).name}


def _summary(chunk: dict, with_first: bool) -> dict:
    """What the client needs of a read chunk: sizes, faces, and (chunk 0) its first centred shape;
    or the chunk's error."""
    if "error" in chunk:
        return chunk
    return {"sizes": chunk["sizes"], "faces": chunk["faces"], "first": chunk["first"],
            "shape0": chunk["c"][0] if with_first else None}


def _fitted_sum(chunk: dict, target, scale: bool) -> np.ndarray:
    """(N, 3): the sum of the chunk's shapes, each fitted onto ``target``."""
    c = chunk["c"]
    return _transformed(c, *fit_onto(c, target, scale=scale)).sum(axis=0)


def _align(chunk: dict, target, r0, shift, scale: bool) -> np.ndarray:
    """(s, 3N) the chunk's shapes in the model's frame (fitted onto ``target``, then turned by
    ``r0`` and moved by ``shift``, as :func:`.procrustes.generalized_procrustes` does)."""
    c = chunk["c"]
    rot, s = fit_onto(c, target, scale=scale)
    rot = np.einsum("ij,sjk->sik", r0, rot)
    return (_transformed(c, rot, s) + shift).reshape(len(c), -1)


def _row_sums(rows) -> tuple:
    """(sum of the rows (3N,), sum of their squares)."""
    return rows.sum(axis=0), float(np.sum(rows * rows))


def _gram_block(a, b, mean) -> np.ndarray:
    """(s_a, s_b): (A - mean)(B - mean)^T."""
    ac = a - mean
    return ac @ (ac if b is a else b - mean).T


def _xt_times(rows, mean, v) -> np.ndarray:
    """(3N, K): (rows - mean)^T v, the chunk's part of X^T V."""
    return (rows - mean).T @ v


def _x_times(rows, mean, q) -> np.ndarray:
    """(s, K): (rows - mean) q, the chunk's rows of X Q."""
    return (rows - mean) @ q


# --- on the client -----------------------------------------------------------------------------------

def default_chunk_size(n_shapes: int, threads: int) -> int:
    """Shapes per chunk: the shapes shared between twice the cluster's threads, kept within
    [:data:`MIN_CHUNK`, :data:`MAX_CHUNK`]."""
    return int(min(MAX_CHUNK, max(MIN_CHUNK, math.ceil(n_shapes / max(1, 2 * threads)))))


class _Stage:
    """Submits tasks and runs batches of them under one progress bar; a task's error is raised at
    once. ``made``: the futures submitted and not yet gathered (the chunks held on the workers
    among them), cancelled on an error."""

    def __init__(self, client, bar):
        self.client, self.bar, self.made = client, bar, []

    def run(self, futures):
        from distributed import KilledWorker, as_completed

        futures = list(futures)
        try:
            for f in as_completed(futures):
                if f.status == "error":
                    f.result()  # raises the worker's exception (a ShapeModelError for a bad result)
                self.bar.update()
            out = self.client.gather(futures)
        except KilledWorker:
            raise ShapeModelError("a Dask worker died while it held or built part of the model (killed, or out of "
                                  "memory?): run the build again") from None
        done = {id(f) for f in futures}  # their results are here now: released on the workers with them
        self.made = [f for f in self.made if id(f) not in done]
        return out

    def submit(self, fn, *args):
        f = self.client.submit(fn, *args, pure=False)
        self.made.append(f)
        return f


def build_model_on_cluster(results_dir, client, *, neutral: bool = False, options=None, chunk_size: int | None = None,
                           progress: bool = True, **overrides):
    """The shape model of the results under ``results_dir``, built on ``client``'s Dask cluster.

    Parameters
    ----------
    results_dir : folder written by ``facecorr batch``; the workers read its meshes at the
        absolute paths this machine sees.
    client : a ``distributed.Client`` (:func:`facecorr.pipeline.cluster.connect`).
    neutral : build from the expression-removed shapes ``<stem>_neutral.ply``.
    options / ``**overrides`` : :class:`.build.BuildOptions`.
    chunk_size : shapes per chunk (default :func:`default_chunk_size`).
    progress : one tqdm bar over the cluster's tasks (its total grows with the Procrustes iterations).

    Returns
    -------
    (ShapeModel, skipped, n_failed): the model, as :func:`.build.build_model` makes it (to
    round-off); the results skipped as flagged, (name, flags) pairs; the scans of failures.json.

    Raises
    ------
    ShapeModelError (one line) for an unusable folder or result, or a worker lost mid-build;
    FacecorrError when the workers run another facecorr or cannot read the results.
    """
    from tqdm import tqdm

    from ..pipeline.cluster import check_workers
    from ..template import load_template

    opts = resolve(options, BuildOptions, overrides, "build_model_on_cluster")
    opts.check()
    chosen, skipped, n_failed = select_results(results_dir, neutral=neutral, include_flagged=opts.include_flagged)
    template = load_template()
    n_vertices = template.n_vertices
    entries = [(name, os.path.abspath(mesh), to_mm) for name, mesh, to_mm in chosen]
    check_workers(client, entries[0][1], what="the results folder", fix="")
    if chunk_size is None:
        chunk_size = default_chunk_size(len(entries), sum(client.nthreads().values()))
    chunks = [entries[i:i + chunk_size] for i in range(0, len(entries), chunk_size)]
    k = len(chunks)
    n_blocks = k * (k + 1) // 2
    s_total = len(entries)
    # the tasks: a summary of each chunk read, the row sums, the Gram blocks, the two products
    # (and each Procrustes iteration's, added as they come)
    bar = tqdm(total=4 * k + n_blocks, desc="building on the cluster", unit="task", disable=not progress)
    stage = _Stage(client, bar)
    ok = False
    try:
        read = [stage.submit(_read_chunk, c, n_vertices) for c in chunks]
        summaries = stage.run(stage.submit(_summary, f, i == 0) for i, f in enumerate(read))
        for sm in summaries:
            if "error" in sm:
                raise ShapeModelError(sm["error"])
        faces = summaries[0]["faces"]
        for sm, c in zip(summaries[1:], chunks[1:]):
            same_faces(c[0][1], sm["faces"], faces, summaries[0]["first"])
        sizes = np.concatenate([sm["sizes"] for sm in summaries])

        def fitted_mean(target):
            bar.total += k
            t = client.scatter(target, broadcast=True)
            return sum(stage.run(stage.submit(_fitted_sum, f, t, opts.scale) for f in read)) / s_total

        ref, _, _ = procrustes_mean(summaries[0]["shape0"], sizes, fitted_mean, scale=opts.scale,
                                    max_iterations=opts.max_iterations, tolerance=opts.tolerance)
        r0, shift = final_pose(ref, np.asarray(template.vertices, dtype=np.float64))
        rows = [stage.submit(_align, f, ref, r0, shift, opts.scale) for f in read]
        sums = stage.run(stage.submit(_row_sums, r) for r in rows)
        read = None  # the centred shapes are no longer needed on the workers: released with their futures
        stage.made = [f for f in stage.made if any(f is r for r in rows)]
        mean = sum(s for s, _ in sums) / s_total
        data_norm2 = float(sum(q for _, q in sums))
        mean_f = client.scatter(mean, broadcast=True)
        pairs = [(i, j) for i in range(k) for j in range(i, k)]
        blocks = stage.run(stage.submit(_gram_block, rows[i], rows[j], mean_f) for i, j in pairs)
        bounds = np.cumsum([0] + [len(c) for c in chunks])
        gram = np.empty((s_total, s_total))
        for (i, j), b in zip(pairs, blocks):
            gram[bounds[i]:bounds[i + 1], bounds[j]:bounds[j + 1]] = b
            gram[bounds[j]:bounds[j + 1], bounds[i]:bounds[i + 1]] = b.T

        def xt_times(v):
            return sum(stage.run(stage.submit(_xt_times, r, mean_f, v[bounds[i]:bounds[i + 1]])
                                 for i, r in enumerate(rows)))

        def x_times(q):
            qf = client.scatter(q, broadcast=True)
            return np.concatenate(stage.run(stage.submit(_x_times, r, mean_f, qf) for r in rows))

        pca = pca_from_gram(gram, mean, data_norm2=data_norm2, xt_times=xt_times, x_times=x_times,
                            modes=opts.modes, variance=None if opts.modes is not None else opts.variance)
        bar.total = bar.n  # (a model without modes skips the last two rounds)
        ok = True
    finally:
        bar.close()
        if not ok:  # stopped (an error, Ctrl-C): nothing more is computed or kept for us
            try:
                client.cancel(stage.made, force=True)
            except Exception:  # noqa: BLE001 - a closing or lost client: its futures die with it
                pass
    model = model_from_pca(pca, faces, [c[0] for c in chosen], source="neutral" if neutral else "registered",
                           options=opts)
    return model, skipped, n_failed
