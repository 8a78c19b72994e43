"""Process pools that are safe with the Rust core.

The Rust core keeps a rayon thread pool; a process forked after that pool started inherits its
locks but not its threads and can deadlock on the first parallel call. Worker processes are
therefore always started with the "spawn" method.
"""

import multiprocessing


def spawn_context():
    """The multiprocessing context facecorr's process pools use ("spawn")."""
    return multiprocessing.get_context("spawn")


def process_map(fn, jobs, *, workers=2, desc="working", progress=True) -> list:
    """``[fn(j) for j in jobs]`` over ``workers`` spawned processes (in order), with a progress bar.

    ``fn`` must be a module-level function (picklable); with one worker or one job it runs here.
    """
    from tqdm import tqdm

    jobs = list(jobs)
    bar = tqdm(total=len(jobs), desc=desc, unit="scan", disable=not progress)
    out = []
    try:
        if workers > 1 and len(jobs) > 1:
            from concurrent.futures import ProcessPoolExecutor

            with ProcessPoolExecutor(max_workers=workers, mp_context=spawn_context()) as ex:
                for r in ex.map(fn, jobs):
                    out.append(r)
                    bar.update()
        else:
            for j in jobs:
                out.append(fn(j))
                bar.update()
    finally:
        bar.close()
    return out
