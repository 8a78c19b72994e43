//! The rayon thread pool: 2 threads by default, `FACECORR_THREADS` overrides.

use std::sync::OnceLock;

static POOL: OnceLock<rayon::ThreadPool> = OnceLock::new();

/// Number of worker threads: `FACECORR_THREADS` if set to a positive integer, else 2.
pub fn n_threads() -> usize {
    std::env::var("FACECORR_THREADS")
        .ok()
        .and_then(|s| s.trim().parse::<usize>().ok())
        .filter(|&n| n > 0)
        .unwrap_or(2)
}

/// facecorr's own pool (not rayon's global one, so a host application's pool is left alone).
pub fn pool() -> &'static rayon::ThreadPool {
    POOL.get_or_init(|| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n_threads())
            .thread_name(|i| format!("facecorr-{i}"))
            .build()
            .expect("failed to build the facecorr thread pool")
    })
}

/// Run `f` inside facecorr's pool (parallel iterators in `f` use its threads).
pub fn install<R: Send, F: FnOnce() -> R + Send>(f: F) -> R {
    pool().install(f)
}
