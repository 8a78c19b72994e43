"""Process pools that are safe with the Rust core.

The Rust core keeps a rayon thread pool; a process forked after that pool started inherits its
locks but not its threads and can deadlock on the first parallel call. Worker processes are
therefore always started with the "spawn" method.
"""

import multiprocessing


def spawn_context():
    """The multiprocessing context facecorr's process pools use ("spawn")."""
    return multiprocessing.get_context("spawn")
