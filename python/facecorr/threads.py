"""Process pools that are safe with the Rust core.

The Rust core keeps a rayon thread pool; a process forked after that pool started inherits its
locks but not its threads and can deadlock on the first parallel call. Worker processes are
therefore always started with the "spawn" method.
"""

import multiprocessing


def spawn_context():
    """The multiprocessing context facecorr's process pools use ("spawn")."""
    return multiprocessing.get_context("spawn")


def process_iter(fn, jobs, *, workers=2, desc="working", progress=True, ordered=True):
    """Yield ``fn(j)`` for each job, computed in ``workers`` spawned processes, with a progress bar.

    ``ordered`` yields in job order, else as each finishes (a batch can record results as they
    come). ``fn`` must be a module-level function (picklable); with one worker or one job it runs
    here.
    """
    from tqdm import tqdm

    jobs = list(jobs)
    with tqdm(total=len(jobs), desc=desc, unit="scan", disable=not progress) as bar:
        if workers > 1 and len(jobs) > 1:
            from concurrent.futures import ProcessPoolExecutor, as_completed

            with ProcessPoolExecutor(max_workers=workers, mp_context=spawn_context()) as ex:
                if ordered:
                    results = ex.map(fn, jobs)
                else:
                    results = (f.result() for f in as_completed([ex.submit(fn, j) for j in jobs]))
                for r in results:
                    bar.update()
                    yield r
        else:
            for j in jobs:
                r = fn(j)
                bar.update()
                yield r


def process_map(fn, jobs, *, workers=2, desc="working", progress=True) -> list:
    """``[fn(j) for j in jobs]`` over ``workers`` spawned processes (in order), with a progress bar."""
    return list(process_iter(fn, jobs, workers=workers, desc=desc, progress=progress))
