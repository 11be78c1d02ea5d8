//! Thread pools: `threads = 0` uses rayon's global pool (all cores); any other
//! value runs the work in a pool of exactly that many threads, cached per calling
//! thread, so that callers on different threads (e.g. a Dask worker's threads, each
//! computing one chunk with `threads = 1`) run side by side instead of queueing on
//! one shared pool.
//!
//! The number of threads a call may ask for is bounded by the machine:
//! at most [`THREADS_PER_CORE`] times the available cores ([`max_threads`]). Above
//! that a call fails at once with an error naming `threads`, before any thread is
//! started (a request for thousands of OS threads only starves the machine and
//! delays Ctrl-C). `avll._limits.check_threads` applies the same bound on the
//! Python side, reading it from [`max_threads`].

use crate::error::{AvllError, Result};
use std::cell::RefCell;
use std::sync::Arc;

thread_local! {
    /// This calling thread's pool and its size.
    static POOL: RefCell<Option<(usize, Arc<rayon::ThreadPool>)>> = const { RefCell::new(None) };
}

/// Multiple of the available cores a call may ask for.
pub const THREADS_PER_CORE: usize = 4;

/// Cores available to this process (affinity and cgroup quotas respected; 1 if unknown).
pub fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// The largest accepted `threads`: `THREADS_PER_CORE * cores()`.
pub fn max_threads() -> usize {
    THREADS_PER_CORE * cores()
}

/// Fails unless `threads` is 0 (all cores) or at most [`max_threads`].
pub fn check_threads(threads: usize) -> Result<()> {
    let max = max_threads();
    if threads > max {
        return Err(AvllError::new(
            "threads",
            format!(
                "{threads} is more than {THREADS_PER_CORE} x the {} available cores (at most \
                 {max}); use 0 for all cores",
                cores()
            ),
        ));
    }
    Ok(())
}

/// Runs `f` with `threads` worker threads (0 = all cores); `threads` above
/// [`max_threads`] is an error and nothing runs.
pub fn with_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> Result<T> {
    check_threads(threads)?;
    if threads == 0 {
        return Ok(f());
    }
    let pool = POOL.with(|cell| -> Result<Arc<rayon::ThreadPool>> {
        let mut slot = cell.borrow_mut();
        match slot.as_ref() {
            Some((n, p)) if *n == threads => Ok(p.clone()),
            _ => {
                let p = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .map_err(|e| AvllError::new("threads", e.to_string()))?;
                let p = Arc::new(p);
                *slot = Some((threads, p.clone()));
                Ok(p)
            }
        }
    })?;
    Ok(pool.install(f))
}

/// [`with_threads`] that also runs `f` itself on a worker of the pool: with
/// `threads = 0` and a caller outside rayon's global pool, `f` moves onto one of its
/// workers. For work made of many parallel steps (a calibration: every generation
/// and every Nelder–Mead point is one): a step forked from a worker hands its other
/// half to the next worker directly, whereas a caller outside the pool injects every
/// step into the pool and sleeps until it is done, so each step wakes two threads.
pub fn on_worker<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> Result<T> {
    if threads == 0 && rayon::current_thread_index().is_none() {
        check_threads(threads)?;
        return Ok(rayon::scope(|_| f()));
    }
    with_threads(threads, f)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn threads_are_bounded_by_the_machine() {
        let max = max_threads();
        assert!(max >= THREADS_PER_CORE);
        assert!(check_threads(0).is_ok());
        assert!(check_threads(max).is_ok());
        let e = check_threads(max + 1).unwrap_err();
        assert_eq!(e.arg, "threads");
        let ran = std::sync::atomic::AtomicBool::new(false);
        let r = with_threads(1_000_000, || {
            ran.store(true, std::sync::atomic::Ordering::SeqCst)
        });
        assert!(r.is_err());
        assert!(
            !ran.load(std::sync::atomic::Ordering::SeqCst),
            "nothing may run"
        );
        assert_eq!(with_threads(1, || 7).unwrap(), 7);
        assert!(on_worker(max + 1, || ()).is_err());
    }

    #[test]
    fn on_worker_runs_the_work_on_a_pool_thread() {
        // Called from a thread outside any pool (a test thread), the global pool.
        let outside = std::thread::spawn(|| {
            let at = on_worker(0, rayon::current_thread_index).unwrap();
            (rayon::current_thread_index(), at)
        })
        .join()
        .unwrap();
        assert_eq!(outside.0, None);
        assert!(outside.1.is_some(), "f ran outside the pool");
        // A given number of threads: that pool, as with_threads.
        let n = on_worker(2, rayon::current_num_threads).unwrap();
        assert_eq!(n, 2);
        assert!(on_worker(2, rayon::current_thread_index).unwrap().is_some());
    }

    #[test]
    fn callers_on_different_threads_do_not_share_a_pool() {
        // Two callers asking for one thread each must run at the same time: each
        // announces that it started and waits (bounded) for the other's announcement.
        // On one shared one-thread pool the second could not start while the first
        // waits, and the first would time out.
        use std::sync::mpsc::channel;
        use std::time::Duration;
        let (ta, ra) = channel::<()>();
        let (tb, rb) = channel::<()>();
        let met = std::thread::scope(|s| {
            let a = s.spawn(move || {
                with_threads(1, move || {
                    ta.send(()).unwrap();
                    rb.recv_timeout(Duration::from_secs(10)).is_ok()
                })
                .unwrap()
            });
            let b = s.spawn(move || {
                with_threads(1, move || {
                    tb.send(()).unwrap();
                    ra.recv_timeout(Duration::from_secs(10)).is_ok()
                })
                .unwrap()
            });
            [a.join().unwrap(), b.join().unwrap()]
        });
        assert_eq!(met, [true, true]);
    }
}
