//! The rayon pool the networks run on, in training and in detection.
//!
//! Why: flex runs each tensor operation's loops on rayon. Called from a thread outside any
//! pool (the main thread), every operation is injected into the global pool and the caller
//! parks until the pool's workers finish it: on two cores, two workers and a parked caller
//! per operation, and a sleep and a wake-up each time (a sixth of a Voxel R-CNN training
//! step's profile went to the scheduler). Run from a worker of a pool, the same loops start
//! in that pool and the calling worker takes its share. The data thread's own parallel work
//! (voxelisation, rulebooks) stays on the global pool.

use std::sync::OnceLock;

/// Thread names of the pool's workers: `fusiondet-compute-0`, …
pub const THREAD_PREFIX: &str = "fusiondet-compute-";

/// Runs `f` on a worker of the compute pool (as many threads as the global pool: one per
/// core, or `RAYON_NUM_THREADS`). Where the pool cannot be started `f` runs on the calling
/// thread, as before; the results are the same either way.
pub fn install<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    static POOL: OnceLock<Option<rayon::ThreadPool>> = OnceLock::new();
    let pool = POOL.get_or_init(|| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(rayon::current_num_threads())
            .thread_name(|i| format!("{THREAD_PREFIX}{i}"))
            .build()
            .ok()
    });
    match pool {
        // Already on one of its workers: no second hop.
        Some(pool) if pool.current_thread_index().is_none() => pool.install(f),
        _ => f(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn thread_name() -> String {
        std::thread::current().name().unwrap_or("").to_string()
    }

    /// `install` moves the work onto a pool worker, and a nested `install` stays there.
    #[test]
    fn work_runs_on_a_pool_worker_and_nesting_stays_put() {
        let (outer, inner) = install(|| (thread_name(), install(thread_name)));
        assert!(outer.starts_with(THREAD_PREFIX), "ran on {outer:?}");
        assert_eq!(inner, outer);
    }
}
