//! Simulation: the exact discretization, the one step kernel and everything built
//! on it (rollouts, run sets, the Eq. 6 cost).
//!
//! * [`discretize`]: exact zero-order hold with a fractional dead time;
//! * [`plant`]: the discretized lower level in the kernel's coordinates (modal when
//!   safe) and the one initial-state routine;
//! * [`chain`]: the effect chain (none: the linear fast path);
//! * [`kernel`]: the one stepping loop and its sinks (trajectory, SSE);
//! * [`rollout`]: open loop, closed loop, platoons;
//! * [`closed_blocks`]: the linear closed loop four samples at a time (the kernel's
//!   operations, bit for bit);
//! * [`cost`]: run references, the cost specification, batched costs and batched
//!   simulation.
//!
//! Initial conditions (stated once, applied identically in `avll.reference`):
//! [`Init::Rest`] — zero model state and input history; [`Init::Steady`] — the
//! lower level at the equilibrium of the first command held forever. Integrators
//! (speed, position) start at the given or measured values. Closed loops and
//! platoons start the lower level at rest.

// State-space loops index several arrays by the same state index.
#![allow(clippy::needless_range_loop)]

pub mod chain;
pub mod closed_blocks;
pub mod cost;
pub mod discretize;
pub mod kernel;
pub mod plant;
pub mod rollout;
pub mod synth;

pub use cost::{batch_cost, run_cost, CostSpec, RunRef};
pub use kernel::DIVERGED;
pub use plant::Init;
pub use rollout::{
    closed_loop, platoon, simulate, simulate_full, simulate_into, Trajectory, Upper,
};

/// Whether this CPU has fused multiply-add and AVX2 (checked once, then cached by
/// std): the kernels then run compiled for them.
#[inline]
pub fn fma() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("fma") && std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        cfg!(target_feature = "fma")
    }
}

/// Runs `f` compiled with the `fma` and `avx2` target features: the kernel's
/// `madd::<true>` calls it inlines become single instructions, and lane loops
/// vectorize four wide.
///
/// # Safety
/// The CPU must support FMA and AVX2 ([`fma`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "fma,avx2")]
pub unsafe fn with_fma<R>(f: impl FnOnce() -> R) -> R {
    f()
}

/// Without x86_64 the closure runs as it is.
///
/// # Safety
/// None needed (kept `unsafe` for one signature on every target).
#[cfg(not(target_arch = "x86_64"))]
pub unsafe fn with_fma<R>(f: impl FnOnce() -> R) -> R {
    f()
}

/// Calls `$f::<M, N, D, F>(plant, args...)` with `F` the CPU's FMA support.
macro_rules! call_fma {
    ($f:ident, $m:literal, $n:literal, $d:expr, $p:expr $(, $arg:expr)*) => {{
        if $crate::sim::fma() {
            // SAFETY: the CPU supports FMA and AVX2 (checked just above).
            unsafe {
                $crate::sim::with_fma(
                    #[inline(always)]
                    || $f::<$m, $n, $d, true>($p $(, $arg)*),
                )
            }
        } else {
            $f::<$m, $n, $d, false>($p $(, $arg)*)
        }
    }};
}
pub(crate) use call_fma;

/// Dispatches on the model order and the integrators: builds the [`plant::Plant`]
/// (`with_plant!(cached; ...)`: through [`plant::Plant::cached`]) and calls `$f::<M, N, D, F>(plant, args...)` with `D` telling whether the model
/// block is diagonal (modal coordinates) and `F` whether the CPU has FMA.
macro_rules! with_plant {
    ($lin:expr, $ints:expr, $dt:expr, $modal:expr, $f:ident ( $($arg:expr),* )) => {
        $crate::sim::with_plant!(new; $lin, $ints, $dt, $modal, $f($($arg),*))
    };
    // `new` builds the plant; `cached` takes it from `Plant::cached` (the rollouts).
    ($ctor:ident; $lin:expr, $ints:expr, $dt:expr, $modal:expr, $f:ident ( $($arg:expr),* )) => {{
        use $crate::sim::discretize::Integrators as I;
        use $crate::sim::plant::Plant;
        use $crate::sim::call_fma;
        match ($lin.order(), $ints) {
            (1, I::None) => call_fma!($f, 1, 1, true, Plant::<1, 1>::$ctor($lin, $ints, $dt, false)? $(, $arg)*),
            (1, I::Position) => call_fma!($f, 1, 2, true, Plant::<1, 2>::$ctor($lin, $ints, $dt, false)? $(, $arg)*),
            (1, I::SpeedPosition) => {
                call_fma!($f, 1, 3, true, Plant::<1, 3>::$ctor($lin, $ints, $dt, false)? $(, $arg)*)
            }
            (_, I::None) => {
                let p = Plant::<2, 2>::$ctor($lin, $ints, $dt, $modal)?;
                if p.diag { call_fma!($f, 2, 2, true, p $(, $arg)*) } else { call_fma!($f, 2, 2, false, p $(, $arg)*) }
            }
            (_, I::Position) => {
                let p = Plant::<2, 3>::$ctor($lin, $ints, $dt, $modal)?;
                if p.diag { call_fma!($f, 2, 3, true, p $(, $arg)*) } else { call_fma!($f, 2, 3, false, p $(, $arg)*) }
            }
            (_, I::SpeedPosition) => {
                let p = Plant::<2, 4>::$ctor($lin, $ints, $dt, $modal)?;
                if p.diag { call_fma!($f, 2, 4, true, p $(, $arg)*) } else { call_fma!($f, 2, 4, false, p $(, $arg)*) }
            }
        }
    }};
}
pub(crate) use with_plant;

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_upper;
