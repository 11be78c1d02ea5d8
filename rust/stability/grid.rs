//! Dense maps over kg × Tg × kv grids and batches of scattered points (rayon).
//!
//! A map is stored C-order as `(len(kg), len(tg), len(kv))` u8 codes; flat index
//! `i = (i_kg * n_tg + i_tg) * n_kv + i_kv`. The work needs no memory besides the
//! output: each point builds its polynomials on the stack. [`fill_range`] fills any
//! contiguous range of flat indices, so a caller can process a big map in chunks
//! (the Python binding checks for Ctrl-C and reports progress between chunks).

use super::LoopModel;
use crate::error::{check_series, AvllError, Result};
use rayon::prelude::*;

/// Points per rayon task.
const TASK: usize = 2048;

/// The axes of a map.
#[derive(Debug, Clone, Copy)]
pub struct Axes<'a> {
    pub kg: &'a [f64],
    pub tg: &'a [f64],
    pub kv: &'a [f64],
}

impl<'a> Axes<'a> {
    /// Checks the axes (non-empty, finite) and returns them.
    pub fn new(kg: &'a [f64], tg: &'a [f64], kv: &'a [f64]) -> Result<Self> {
        for (n, a) in [("kg", kg), ("tg", tg), ("kv", kv)] {
            if a.is_empty() {
                return Err(AvllError::new(n, "is empty"));
            }
            check_series(n, a)?;
        }
        Ok(Self { kg, tg, kv })
    }

    /// Number of grid points.
    pub fn len(&self) -> usize {
        self.kg.len() * self.tg.len() * self.kv.len()
    }

    /// True when the grid has no points (never, for checked axes).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// `(kg, tg, kv)` at flat index `i`.
    #[inline]
    pub fn point(&self, i: usize) -> (f64, f64, f64) {
        let nkv = self.kv.len();
        let ntg = self.tg.len();
        let ikv = i % nkv;
        let r = i / nkv;
        (self.kg[r / ntg], self.tg[r % ntg], self.kv[ikv])
    }
}

/// Fills `out[j]` with the code of flat index `start + j`, in parallel.
pub fn fill_range(lm: &LoopModel, axes: &Axes<'_>, start: usize, out: &mut [u8]) {
    out.par_chunks_mut(TASK).enumerate().for_each(|(t, chunk)| {
        let base = start + t * TASK;
        for (j, o) in chunk.iter_mut().enumerate() {
            let (kg, tg, kv) = axes.point(base + j);
            *o = lm.classify(kg, tg, kv);
        }
    });
}

/// The whole map as a vector of codes (C-order `(kg, tg, kv)`).
pub fn map(lm: &LoopModel, axes: &Axes<'_>) -> Vec<u8> {
    let mut out = vec![0u8; axes.len()];
    fill_range(lm, axes, 0, &mut out);
    out
}

/// Codes of scattered points `(kg[i], tg[i], kv[i])`, in parallel.
pub fn classify_points(lm: &LoopModel, kg: &[f64], tg: &[f64], kv: &[f64]) -> Result<Vec<u8>> {
    if tg.len() != kg.len() || kv.len() != kg.len() {
        return Err(AvllError::new(
            "tg",
            format!(
                "kg, tg and kv must have one length, got {}, {}, {}",
                kg.len(),
                tg.len(),
                kv.len()
            ),
        ));
    }
    for (n, a) in [("kg", kg), ("tg", tg), ("kv", kv)] {
        check_series(n, a)?;
    }
    let mut out = vec![0u8; kg.len()];
    out.par_chunks_mut(TASK).enumerate().for_each(|(t, chunk)| {
        let base = t * TASK;
        for (j, o) in chunk.iter_mut().enumerate() {
            let i = base + j;
            *o = lm.classify(kg[i], tg[i], kv[i]);
        }
    });
    Ok(out)
}
