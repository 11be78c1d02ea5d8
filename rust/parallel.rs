//! Thread pools: `threads = 0` uses rayon's global pool (all cores); any other
//! value runs the work in a cached pool of exactly that many threads.

use crate::error::{AvllError, Result};
use std::sync::{Arc, Mutex};

static POOL: Mutex<Option<(usize, Arc<rayon::ThreadPool>)>> = Mutex::new(None);

/// Runs `f` with `threads` worker threads (0 = all cores).
pub fn with_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> Result<T> {
    if threads == 0 {
        return Ok(f());
    }
    let pool = {
        let mut guard = POOL.lock().unwrap_or_else(|e| e.into_inner());
        match guard.as_ref() {
            Some((n, p)) if *n == threads => p.clone(),
            _ => {
                let p = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .map_err(|e| AvllError::new("threads", e.to_string()))?;
                let p = Arc::new(p);
                *guard = Some((threads, p.clone()));
                p
            }
        }
    };
    Ok(pool.install(f))
}
