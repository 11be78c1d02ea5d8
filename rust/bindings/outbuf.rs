//! Output arrays of the rollouts: numpy arrays whose memory avll owns, recycled
//! through a small cache of freed blocks, so that a call does not pay for fresh
//! pages.
//!
//! A fresh block costs its pages: the kernel maps and zeroes every 4 KiB page on
//! first touch (measured on the 2-core benchmark machine: 0.8-1.6 us per page, more
//! than the rollout's own stepping at 1e5 samples). glibc recycles freed memory only
//! below its adaptive mmap threshold and trims the heap top beyond twice that, so
//! whether a numpy array's pages are fresh depends on what the process did before.
//! Here an output array's base object owns an avll block; when numpy frees the
//! array, the block goes back to a cache (at most [`DEFAULT_LIMIT`] bytes, oldest
//! blocks released first) from which the next call takes it, its pages already
//! mapped (see [`pooled`] for which outputs). Nothing process-wide changes: the cache holds only avll's own output
//! blocks, and `output_cache(limit)` bounds or empties it.
//!
//! A fresh block of 2 MiB or more is 2 MiB-aligned, a multiple of 2 MiB, and advised
//! for transparent huge pages (`madvise(MADV_HUGEPAGE)`; the kernel then maps and
//! zeroes one 2 MiB page per fault: 0.2-0.5 us per 4 KiB measured, against 0.9-1.6);
//! a smaller one is pre-faulted in one call (`MADV_POPULATE_WRITE`, about half the
//! cost of faulting page by page). Outputs below [`SMALL`] bytes are ordinary numpy
//! arrays: glibc serves them from its heap, whose pages are reused.

use numpy::ndarray::{ArrayView1, ArrayView2, ArrayView3};
use numpy::{PyArray1, PyArray2, PyArray3};
use pyo3::prelude::*;
use std::alloc::{alloc, dealloc, Layout};
use std::ptr::NonNull;
use std::sync::Mutex;

/// Outputs below this many bytes are plain numpy arrays (glibc's initial mmap
/// threshold: below it glibc serves them from its heap).
pub(super) const SMALL: usize = 128 << 10;
/// glibc's largest adaptive mmap threshold on 64-bit systems (32 MiB): one freed
/// chunk up to this size is kept in its heap and reused.
pub(super) const GLIBC_MAX: usize = 32 << 20;
/// Default bound of the cache of freed blocks (bytes).
pub const DEFAULT_LIMIT: usize = 128 << 20;
const HUGE: usize = 2 << 20;
const PAGE: usize = 4096;

/// One owned block of memory.
struct Block {
    ptr: NonNull<u8>,
    layout: Layout,
}

// SAFETY: a block is plain memory owned by exactly one holder at a time.
unsafe impl Send for Block {}

impl Block {
    fn fresh(bytes: usize) -> Option<Block> {
        let (size, align) = if bytes >= HUGE {
            (bytes.div_ceil(HUGE) * HUGE, HUGE)
        } else {
            (bytes.div_ceil(PAGE) * PAGE, PAGE)
        };
        let layout = Layout::from_size_align(size, align).ok()?;
        // SAFETY: the size is non-zero (callers ask for at least `SMALL` bytes).
        let ptr = NonNull::new(unsafe { alloc(layout) })?;
        advise(ptr.as_ptr(), size, size >= HUGE);
        Some(Block { ptr, layout })
    }
}

impl Drop for Block {
    fn drop(&mut self) {
        // SAFETY: allocated by `alloc` with this layout.
        unsafe { dealloc(self.ptr.as_ptr(), self.layout) }
    }
}

#[cfg(target_os = "linux")]
fn advise(ptr: *mut u8, len: usize, huge: bool) {
    // madvise(2) from the C library (advice values from <linux/mman.h>); advice is a
    // hint: a kernel without it returns EINVAL and the pages fault as usual.
    const MADV_HUGEPAGE: i32 = 14;
    const MADV_POPULATE_WRITE: i32 = 23;
    extern "C" {
        fn madvise(addr: *mut std::ffi::c_void, len: usize, advice: i32) -> i32;
    }
    let advice = if huge {
        MADV_HUGEPAGE
    } else {
        MADV_POPULATE_WRITE
    };
    // SAFETY: [ptr, ptr + len) is one live allocation, page-aligned (see `fresh`).
    unsafe {
        madvise(ptr.cast(), len, advice);
    }
}

#[cfg(not(target_os = "linux"))]
fn advise(_ptr: *mut u8, _len: usize, _huge: bool) {}

/// The cache of freed blocks, oldest first.
struct Cache {
    blocks: Vec<Block>,
    held: usize,
    limit: usize,
}

static CACHE: Mutex<Cache> = Mutex::new(Cache {
    blocks: Vec::new(),
    held: 0,
    limit: DEFAULT_LIMIT,
});

fn cache() -> std::sync::MutexGuard<'static, Cache> {
    // a poisoned lock only means a panic elsewhere while holding it: the data are
    // still a valid list of blocks
    CACHE.lock().unwrap_or_else(|e| e.into_inner())
}

/// A block of at least `bytes` bytes: the smallest cached block that fits and is at
/// most twice as large, else a fresh one.
fn take(bytes: usize) -> Option<Block> {
    {
        let mut c = cache();
        let best = c
            .blocks
            .iter()
            .enumerate()
            .filter(|(_, b)| b.layout.size() >= bytes && b.layout.size() <= 2 * bytes.max(PAGE))
            .min_by_key(|(_, b)| b.layout.size())
            .map(|(i, _)| i);
        if let Some(i) = best {
            let b = c.blocks.remove(i);
            c.held -= b.layout.size();
            return Some(b);
        }
    }
    Block::fresh(bytes)
}

/// Returns a block to the cache (releasing the oldest ones beyond the limit).
fn give(b: Block) {
    let mut released = Vec::new();
    {
        let mut c = cache();
        let size = b.layout.size();
        if size > c.limit {
            released.push(b);
        } else {
            while c.held + size > c.limit {
                let old = c.blocks.remove(0);
                c.held -= old.layout.size();
                released.push(old);
            }
            c.held += size;
            c.blocks.push(b);
        }
    }
    drop(released); // outside the lock
}

/// Sets the cache's bound (`None`: unchanged), releasing blocks beyond it; returns
/// (bytes held, bound).
pub(super) fn set_limit(limit: Option<usize>) -> (usize, usize) {
    let mut released = Vec::new();
    let out = {
        let mut c = cache();
        if let Some(l) = limit {
            c.limit = l;
            while c.held > c.limit {
                let old = c.blocks.remove(0);
                c.held -= old.layout.size();
                released.push(old);
            }
        }
        (c.held, c.limit)
    };
    drop(released);
    out
}

/// The base object of an output array: owns its block and returns it to the cache
/// when numpy frees the array.
#[pyclass(module = "avll._core", frozen)]
pub(super) struct OutputBlock {
    block: Mutex<Option<Block>>,
}

impl Drop for OutputBlock {
    fn drop(&mut self) {
        let b = self
            .block
            .get_mut()
            .unwrap_or_else(|e| e.into_inner())
            .take();
        if let Some(b) = b {
            give(b);
        }
    }
}

/// A new block of `n` doubles wrapped in its Python owner, or `None` when it cannot
/// be had (the caller then allocates through numpy).
fn owner(py: Python<'_>, n: usize) -> Option<(Bound<'_, OutputBlock>, *const f64)> {
    let b = take(n.checked_mul(8)?)?;
    let ptr = b.ptr.as_ptr() as *const f64;
    let o = Bound::new(
        py,
        OutputBlock {
            block: Mutex::new(Some(b)),
        },
    )
    .ok()?;
    Some((o, ptr))
}

/// Whether an output of `n` doubles goes into an avll block: from [`SMALL`] bytes
/// when the call returns `several` arrays, else (one array) above [`GLIBC_MAX`].
///
/// One output array below glibc's largest adaptive mmap threshold is left to numpy
/// (glibc): after the first call glibc serves it from its heap, reusing the chunk
/// the previous result freed, and that chunk is shared with the rest of the
/// program's allocations, so it is often still in cache (measured, open loop at 1e5
/// samples interleaved with numba loops that allocate: median 958-1022 M steps/s
/// through numpy against 852-870 through the cache). Several arrays (four for a
/// trajectory) add up beyond glibc's trim threshold, which returns them to the
/// kernel on every call: those are what the cache is for.
fn pooled(n: usize, several: bool) -> bool {
    let bytes = n.saturating_mul(8);
    bytes >= SMALL && (several || bytes > GLIBC_MAX)
}

/// An uninitialised C-contiguous (n,) float64 array for a rollout to fill (`several`:
/// one of several outputs of the call, see [`pooled`]). The caller must write every
/// element before Python sees the array.
pub(super) fn empty1(py: Python<'_>, n: usize, several: bool) -> Bound<'_, PyArray1<f64>> {
    if pooled(n, several) {
        if let Some((o, ptr)) = owner(py, n) {
            // SAFETY: the block holds n doubles, is owned by `o` (the array's base)
            // and is not reallocated while `o` lives.
            return unsafe {
                let v = ArrayView1::from_shape_ptr(n, ptr);
                PyArray1::borrow_from_array(&v, o.into_any())
            };
        }
    }
    // SAFETY: as above, the caller writes every element.
    unsafe { PyArray1::<f64>::new(py, n, false) }
}

/// As [`empty1`], a C-contiguous (rows, cols) array.
pub(super) fn empty2(
    py: Python<'_>,
    rows: usize,
    cols: usize,
    several: bool,
) -> Bound<'_, PyArray2<f64>> {
    let n = rows.saturating_mul(cols);
    if pooled(n, several) {
        if let Some((o, ptr)) = owner(py, n) {
            // SAFETY: as in `empty1`.
            return unsafe {
                let v = ArrayView2::from_shape_ptr((rows, cols), ptr);
                PyArray2::borrow_from_array(&v, o.into_any())
            };
        }
    }
    // SAFETY: as in `empty1`.
    unsafe { PyArray2::<f64>::new(py, [rows, cols], false) }
}

/// As [`empty1`], a C-contiguous (d0, d1, d2) array.
pub(super) fn empty3(py: Python<'_>, d: [usize; 3], several: bool) -> Bound<'_, PyArray3<f64>> {
    let n = d[0].saturating_mul(d[1]).saturating_mul(d[2]);
    if pooled(n, several) {
        if let Some((o, ptr)) = owner(py, n) {
            // SAFETY: as in `empty1`.
            return unsafe {
                let v = ArrayView3::from_shape_ptr((d[0], d[1], d[2]), ptr);
                PyArray3::borrow_from_array(&v, o.into_any())
            };
        }
    }
    // SAFETY: as in `empty1`.
    unsafe { PyArray3::<f64>::new(py, d, false) }
}

/// Bytes of freed output blocks avll keeps for reuse, and their bound: with `limit`,
/// sets the bound first (0 releases every block and keeps none).
#[pyfunction]
#[pyo3(signature = (limit = None))]
fn output_cache(limit: Option<usize>) -> (usize, usize) {
    set_limit(limit)
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<OutputBlock>()?;
    m.add_function(wrap_pyfunction!(output_cache, m)?)?;
    Ok(())
}
