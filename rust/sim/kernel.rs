//! The one step kernel. Every rollout (open loop, closed loop, platoon), every cost
//! (linear or with effects, open or closed loop) and so the GA and the diagnosis run
//! through [`Stepper`]: generic over the model order `M`, the state size `N` (model
//! states plus integrators), the block structure `D` (diagonal modal block or full
//! canonical block) and the effect chain `C` ([`NoEffects`] compiles every hook
//! away).
//!
//! Per sample `n` (the convention of [`crate::sim::discretize`]):
//! 1. [`Stepper::observe`]: the lower level's linear response `y_lin = C x`, and
//!    for an acceleration command the actual acceleration
//!    `a = output(y_lin, v) + disturbance(v, n)` with the actual speed and position
//!    `v = v_lin + dv`, `p = p_lin + dp` (`dv, dp` integrate `a - y_lin` with the same
//!    hold; zero without effects); for a speed command the actual speed
//!    `v = y_lin + dv` and position `p = p_lin + dp`;
//! 2. the command `u[n]` (recorded, or the upper law of the actual `p, v`);
//! 3. [`Stepper::step`]: `u' = command(u, y)`, `u_ref = reference(u' + K y)` into the
//!    dead-time line (branch-free ring buffer), and the exact step
//!    `x[n+1] = Phi x[n] + G0 u_ref[n-i] + G1 u_ref[n-i-1]`, with the braking maps
//!    while braking when an effect switches the dynamics. For a speed command the
//!    acceleration-level hooks act on the acceleration that integrates into the
//!    speed, the interval's mean `abar = (y_lin[n+1] - y_lin[n]) / dt`:
//!    `e = output(abar, v) + disturbance(v, n) - abar`, `dv, dp` integrate `e`
//!    (so `v[n+1] - v[n] = dt (abar + e)` exactly) and the recorded acceleration is
//!    the linear right-limit derivative plus `e`;
//! 4. the sample's acceleration as observed, `measure(a)` (the sinks record it and
//!    the costs compare it; the dynamics above use the true `a`).
//!
//! The structural zeros and ones of the transition (model rows never read the
//! integrators; `v' = v + ...`, `p' = p + dt v + ...`) are used as such, so each
//! integrator adds one addition to its own dependency chain and a diagonal modal
//! block one multiply-add per mode.

use super::chain::{Chain, NoEffects};
use super::plant::Plant;

/// Responses beyond this magnitude (m/s² or m/s) count as divergence.
pub const DIVERGED: f64 = 1e6;

/// `a b + c`: one fused multiply-add when `F` (the caller runs with the `fma`
/// target feature, see [`crate::sim::fma`]), else a multiply and an add.
#[inline(always)]
pub fn madd<const F: bool>(a: f64, b: f64, c: f64) -> f64 {
    if F {
        a.mul_add(b, c)
    } else {
        a * b + c
    }
}

/// Samples between two checks of a sink (divergence, early abandoning).
pub const CHUNK: usize = 64;

/// What the vehicle shows at a sample, before that sample's command acts.
#[derive(Debug, Clone, Copy, Default)]
pub struct Obs {
    /// The linear part's response `C x` (acceleration or speed).
    pub y_lin: f64,
    /// The actual response fed back by the inner loop (`y_lin` after the output
    /// maps and disturbances for an acceleration command; `y_lin` for a speed one).
    pub y: f64,
    /// Actual speed and position (0 when the stepper carries no integrators).
    pub v: f64,
    pub p: f64,
}

/// One vehicle's lower level being stepped.
#[derive(Debug, Clone)]
pub struct Stepper<const M: usize, const N: usize, const D: bool, const F: bool, C: Chain> {
    pub plant: Plant<M, N>,
    /// Braking maps and the state scaling into them (effects that switch dynamics).
    brake: Option<(Plant<M, N>, [f64; 2])>,
    pub chain: C,
    buf: Vec<f64>,
    pub x: [f64; N],
    dv: f64,
    dp: f64,
    wp: f64,
    b0: f64,
}

impl<const M: usize, const N: usize, const D: bool, const F: bool> Stepper<M, N, D, F, NoEffects> {
    /// A linear stepper (no effect).
    pub fn linear(plant: Plant<M, N>, accel: bool, x0: [f64; N], w_hist: f64) -> Self {
        Self::new(plant, None, NoEffects, accel, 0.0, x0, w_hist, 0.0)
    }
}

impl<const M: usize, const N: usize, const D: bool, const F: bool, C: Chain>
    Stepper<M, N, D, F, C>
{
    /// A stepper at state `x0` (kernel coordinates) with the dead-time line filled
    /// with `reference(w_hist)` and the chain reset to `u_hist`.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        plant: Plant<M, N>,
        brake: Option<(Plant<M, N>, [f64; 2])>,
        mut chain: C,
        accel: bool,
        b0: f64,
        x0: [f64; N],
        w_hist: f64,
        u_hist: f64,
    ) -> Self {
        debug_assert!(D == plant.diag || !D);
        debug_assert!(N == M || accel == accel_kind::<M, N>());
        let _ = accel;
        chain.reset(u_hist, plant.dt);
        let cap = (plant.delay + 2).next_power_of_two();
        let h = chain.reference(w_hist);
        Self {
            plant,
            brake: if C::NONE { None } else { brake },
            chain,
            buf: vec![h; cap],
            x: x0,
            dv: 0.0,
            dp: 0.0,
            wp: h,
            b0,
        }
    }

    /// Whether the state (with the effects' speed and position corrections) and the
    /// dead-time line are all finite.
    ///
    /// A run's non-finite input sample makes its reference non-finite, and IEEE
    /// arithmetic never turns a non-finite value finite again (`inf 0` and
    /// `NaN 0` are NaN): after a run, that reference is either still in the
    /// dead-time line (the last samples) or has entered the state. So a finite
    /// stepper after a run proves every input sample finite, and a run checks its
    /// inputs only when this is false (divergence, or a bad input to be named)
    /// instead of reading them all in a separate pass first.
    pub fn finite(&self) -> bool {
        self.x.iter().all(|v| v.is_finite())
            && self.dv.is_finite()
            && self.dp.is_finite()
            && self.wp.is_finite()
            && self.buf.iter().all(|v| v.is_finite())
    }

    /// The response and the actual speed and position at sample `n`.
    #[inline(always)]
    pub fn observe(&self, n: usize) -> Obs {
        observe::<M, N, F, C>(&self.plant, &self.chain, &self.x, self.dv, self.dp, n)
    }

    /// Applies the command `u` of sample `n` (observed as `o`) and steps to `n + 1`.
    /// Returns the observed acceleration of sample `n` (`measure` of `o.y` for an
    /// acceleration command; of the right-limit derivative of the actual speed for a
    /// speed command).
    #[inline(always)]
    pub fn step(&mut self, n: usize, o: &Obs, u: f64) -> f64 {
        let mut reg = Regs {
            x: self.x,
            dv: self.dv,
            dp: self.dp,
            wp: self.wp,
        };
        let a = step::<M, N, D, F, C>(self.parts(), &mut reg, n, o, u);
        self.x = reg.x;
        self.dv = reg.dv;
        self.dp = reg.dp;
        self.wp = reg.wp;
        a
    }

    /// Copies the dead-time line's references before sample `n` (`u_ref[n-1]`, ...,
    /// as many as the stepper keeps) into `line`, a power-of-two ring indexed by the
    /// sample (`u_ref[m]` at `m & (line.len() - 1)`, at least as long as the
    /// stepper's own): a block form's copy of the line.
    pub(crate) fn line_out(&self, line: &mut [f64], n: usize) {
        debug_assert!(line.len().is_power_of_two() && line.len() >= self.buf.len());
        let (mask, smask) = (line.len() - 1, self.buf.len() - 1);
        for q in 1..=self.buf.len() {
            let m = n.wrapping_sub(q);
            line[m & mask] = self.buf[m & smask];
        }
    }

    /// The inverse of [`Stepper::line_out`]: takes the references before sample `n`
    /// back from a block form's `line`, and with them the next sample's `w1`
    /// (`u_ref[n-1-i]`), so that the stepper continues at sample `n`. Requires a
    /// whole-sample dead time `i >= 1` (with `i == 0` the line's last output is not
    /// yet in it).
    pub(crate) fn line_in(&mut self, line: &[f64], n: usize) {
        debug_assert!(line.len().is_power_of_two() && line.len() >= self.buf.len());
        debug_assert!(self.plant.delay >= 1);
        let (mask, smask) = (line.len() - 1, self.buf.len() - 1);
        for q in 1..=self.buf.len() {
            let m = n.wrapping_sub(q);
            self.buf[m & smask] = line[m & mask];
        }
        self.wp = line[n.wrapping_sub(1 + self.plant.delay) & mask];
    }

    /// The stepper's parts, borrowed separately (plant and braking maps shared, chain
    /// and dead-time line mutable).
    #[inline(always)]
    fn parts(&mut self) -> Parts<'_, M, N, C> {
        Parts {
            p: &self.plant,
            brake: self.brake.as_ref(),
            chain: &mut self.chain,
            buf: &mut self.buf,
            b0: self.b0,
        }
    }
}

/// The state a run keeps in registers.
#[derive(Clone, Copy)]
struct Regs<const N: usize> {
    x: [f64; N],
    dv: f64,
    dp: f64,
    /// The previous sample's `w0` (`u_ref[n-i-1]`, this sample's `w1`).
    wp: f64,
}

struct Parts<'a, const M: usize, const N: usize, C: Chain> {
    p: &'a Plant<M, N>,
    brake: Option<&'a (Plant<M, N>, [f64; 2])>,
    chain: &'a mut C,
    buf: &'a mut [f64],
    b0: f64,
}

/// Whether a stepper with `M` model states and `N` states in all drives an
/// acceleration response: a speed response carries exactly one integrator
/// (position). Without integrators the response is `y` either way (the rollouts
/// that read only `y` use `N == M` for both kinds).
#[inline(always)]
pub const fn accel_kind<const M: usize, const N: usize>() -> bool {
    N != M + 1
}

#[inline(always)]
pub(crate) fn observe<const M: usize, const N: usize, const F: bool, C: Chain>(
    p: &Plant<M, N>,
    chain: &C,
    x: &[f64; N],
    dv: f64,
    dp: f64,
    n: usize,
) -> Obs {
    let mut y_lin = p.c[0] * x[0];
    for j in 1..M {
        y_lin = madd::<F>(p.c[j], x[j], y_lin);
    }
    if !accel_kind::<M, N>() {
        let pos = if N > M { x[M] } else { 0.0 };
        if C::NONE {
            return Obs {
                y_lin,
                y: y_lin,
                v: y_lin,
                p: pos,
            };
        }
        let v = y_lin + dv;
        return Obs {
            y_lin,
            y: v,
            v,
            p: pos + dp,
        };
    }
    if C::NONE {
        return Obs {
            y_lin,
            y: y_lin,
            v: if N > M { x[M] } else { 0.0 },
            p: if N > M + 1 { x[M + 1] } else { 0.0 },
        };
    }
    let v = if N > M { x[M] + dv } else { 0.0 };
    let pos = if N > M + 1 { x[M + 1] + dp } else { 0.0 };
    let y = chain.output(y_lin, v) + chain.disturbance(v, n);
    Obs {
        y_lin,
        y,
        v,
        p: pos,
    }
}

#[inline(always)]
fn step<const M: usize, const N: usize, const D: bool, const F: bool, C: Chain>(
    s: Parts<'_, M, N, C>,
    reg: &mut Regs<N>,
    n: usize,
    o: &Obs,
    u: f64,
) -> f64 {
    let p = s.p;
    let r = if C::NONE {
        // Without inner feedback (K = 0: the first-order lag, the second-order model)
        // the response does not feed the reference: kept off the step's chain.
        if p.k == 0.0 {
            u
        } else {
            u + p.k * o.y
        }
    } else {
        let uc = s.chain.command(u, o.y);
        s.chain.reference(uc + p.k * o.y)
    };
    let i = p.delay;
    // A power-of-two ring buffer: the mask derives from its length, so the indexing
    // needs no bounds check.
    let mask = s.buf.len() - 1;
    s.buf[n & mask] = r;
    // Without a whole-sample delay the input is the value just computed: kept in a
    // register (a load of the slot just stored would put a store-to-load forwarding on
    // the step's dependency chain; the branch is the same for every sample of a run).
    let w0 = if i == 0 {
        r
    } else {
        s.buf[n.wrapping_sub(i) & mask]
    };
    // u_ref[n-i-1] is the previous sample's w0: a register, not a second load.
    let w1 = reg.wp;
    reg.wp = w0;
    let wf = if p.frac > 0.0 { w1 } else { w0 };
    if !C::NONE {
        if let Some((bp, sc)) = s.brake {
            let demand = if accel_kind::<M, N>() {
                w0
            } else {
                s.b0 * w0 - o.y_lin
            };
            if demand < 0.0 {
                let mut xb = reg.x;
                for j in 0..M {
                    xb[j] *= sc[j];
                }
                let a = if accel_kind::<M, N>() {
                    o.y
                } else {
                    deriv::<M, N>(bp, &xb, wf)
                };
                let mut nx = advance::<M, N, false, F>(bp, &xb, w0, w1);
                for j in 0..M {
                    nx[j] /= sc[j];
                }
                reg.x = nx;
                return settle::<M, N, F, C>(s.chain, p, reg, o, n, a);
            }
        }
    }
    let a = if accel_kind::<M, N>() {
        o.y
    } else {
        deriv::<M, N>(p, &reg.x, wf)
    };
    reg.x = advance::<M, N, D, F>(p, &reg.x, w0, w1);
    settle::<M, N, F, C>(s.chain, p, reg, o, n, a)
}

/// After the exact step of sample `n` (`reg.x` holds `x[n+1]`) with the linear
/// acceleration `a`: `o.y` for an acceleration command (already through the output
/// maps and disturbances); the right-limit derivative of the linear speed for a
/// speed command. Integrates the difference `e` between the actual and the linear
/// acceleration into the speed and position corrections and returns the
/// acceleration as observed. The identity without effects.
///
/// For a speed command the output maps and disturbances act on the interval's mean
/// linear acceleration `abar = (y_lin[n+1] - y_lin[n]) / dt`, so the actual speed
/// moves by exactly `dt (output(abar, v) + disturbance(v, n))` over the interval; the
/// recorded acceleration is the linear derivative plus the same difference `e`
/// (the linear model's own when `e = 0`).
#[inline(always)]
fn settle<const M: usize, const N: usize, const F: bool, C: Chain>(
    chain: &mut C,
    p: &Plant<M, N>,
    reg: &mut Regs<N>,
    o: &Obs,
    n: usize,
    a: f64,
) -> f64 {
    if C::NONE {
        return a;
    }
    let dt = p.dt;
    let (a, e) = if accel_kind::<M, N>() {
        (a, o.y - o.y_lin)
    } else {
        let mut y1 = p.c[0] * reg.x[0];
        for j in 1..M {
            y1 = madd::<F>(p.c[j], reg.x[j], y1);
        }
        let abar = (y1 - o.y_lin) / dt;
        let e = chain.output(abar, o.v) + chain.disturbance(o.v, n) - abar;
        (a + e, e)
    };
    if N > M {
        reg.dp += dt * reg.dv + 0.5 * dt * dt * e;
        reg.dv += dt * e;
    }
    chain.measure(a)
}

/// The derivative of a speed response at `t_n+`: `ca x + cb w(t_n+)`.
#[inline(always)]
fn deriv<const M: usize, const N: usize>(p: &Plant<M, N>, x: &[f64; N], wf: f64) -> f64 {
    let mut s = p.cb * wf;
    for j in 0..M {
        s += p.ca[j] * x[j];
    }
    s
}

/// One exact step in the kernel's coordinates, using the structure of `Phi`: each
/// state's own term is added last, so its dependency chain is one multiply-add.
#[inline(always)]
pub(crate) fn advance<const M: usize, const N: usize, const D: bool, const F: bool>(
    p: &Plant<M, N>,
    x: &[f64; N],
    w0: f64,
    w1: f64,
) -> [f64; N] {
    let mut o = [0.0; N];
    for r in 0..M {
        let t = madd::<F>(p.g1[r], w1, p.g0[r] * w0);
        o[r] = if D || M == 1 {
            madd::<F>(p.phi[r][r], x[r], t)
        } else {
            madd::<F>(p.phi[r][r], x[r], madd::<F>(p.phi[r][1 - r], x[1 - r], t))
        };
    }
    if N > M {
        // First integrator (speed, or position for a speed command): s' = s + ...
        let mut t = madd::<F>(p.g1[M], w1, p.g0[M] * w0);
        for j in 0..M {
            t = madd::<F>(p.phi[M][j], x[j], t);
        }
        o[M] = x[M] + t;
    }
    if N > M + 1 {
        // Position behind speed: p' = p + dt v + ...
        let mut t = madd::<F>(p.g1[M + 1], w1, p.g0[M + 1] * w0);
        t = madd::<F>(p.phi[M + 1][M], x[M], t);
        for j in 0..M {
            t = madd::<F>(p.phi[M + 1][j], x[j], t);
        }
        o[M + 1] = x[M + 1] + t;
    }
    o
}

/// Samples stepped together by [`response_blocks`].
pub const BLOCK: usize = 4;

/// The block form of the linear open-loop response: the maps that take the state
/// `x[n0]` and the dead-time line's outputs `g[n0-1..n0+3]` (`g[n] = u_ref[n-i]`, the
/// step's `w0`; `g[n-1]` its `w1`) to the responses `y[n0..n0+4]` and the state
/// `x[n0+4]`. From `x[n+1] = Phi x[n] + G0 g[n] + G1 g[n-1]` and `y = C x`:
///
/// * `y[n0+j] = C Phi^j x[n0] + sum_{k=-1}^{j-1} H[j][k] g[n0+k]` with
///   `H[j][k] = [k >= 0] C Phi^(j-1-k) G0 + [k+1 <= j-1] C Phi^(j-2-k) G1`;
/// * `x[n0+4] = Phi^4 x[n0] + sum_{k=-1}^{3} S[k] g[n0+k]` with
///   `S[k] = [k >= 0] Phi^(3-k) G0 + [k <= 2] Phi^(2-k) G1`.
///
/// With a whole-sample dead time `i >= BLOCK` every `g` a block reads was written
/// before the block starts, so the four responses are independent of each other:
/// they are computed side by side (one four-wide operation per term) and the
/// state's own dependency chain is one multiply-add per block instead of one per
/// sample.
struct BlockMaps<const M: usize> {
    /// `yx[m][j] = (C Phi^j)[m]`.
    yx: [[f64; BLOCK]; M],
    /// `yg[k + 1][j] = H[j][k]`, `k = -1..=2`.
    yg: [[f64; BLOCK]; BLOCK],
    /// `Phi^4` (row-major).
    p4: [[f64; M]; M],
    /// `s[k + 1] = S[k]`, `k = -1..=3`.
    s: [[f64; M]; BLOCK + 1],
}

impl<const M: usize> BlockMaps<M> {
    fn new<const N: usize, const D: bool>(p: &Plant<M, N>) -> Self {
        let mul = |a: &[[f64; M]; M], b: &[[f64; M]; M]| {
            let mut o = [[0.0; M]; M];
            for r in 0..M {
                for c in 0..M {
                    o[r][c] = (0..M).map(|q| a[r][q] * b[q][c]).sum();
                }
            }
            o
        };
        // `Phi` as `advance` applies it: only its diagonal in modal coordinates.
        let mut phi = [[0.0; M]; M];
        for r in 0..M {
            for c in 0..M {
                if !(D || M == 1) || r == c {
                    phi[r][c] = p.phi[r][c];
                }
            }
        }
        // pw[e] = Phi^e, e = 0..=4.
        let mut pw = [[[0.0; M]; M]; BLOCK + 1];
        for r in 0..M {
            pw[0][r][r] = 1.0;
        }
        for e in 1..=BLOCK {
            pw[e] = mul(&pw[e - 1], &phi);
        }
        let mv = |a: &[[f64; M]; M], g: &[f64; N]| -> [f64; M] {
            let mut o = [0.0; M];
            for r in 0..M {
                o[r] = (0..M).map(|q| a[r][q] * g[q]).sum();
            }
            o
        };
        let cv = |v: &[f64; M]| -> f64 { (0..M).map(|q| p.c[q] * v[q]).sum() };
        let mut yx = [[0.0; BLOCK]; M];
        let mut yg = [[0.0; BLOCK]; BLOCK];
        for j in 0..BLOCK {
            for m in 0..M {
                yx[m][j] = (0..M).map(|q| p.c[q] * pw[j][q][m]).sum();
            }
            for k in -1i64..=2 {
                let mut h = 0.0;
                let j = j as i64;
                if k >= 0 && k < j {
                    h += cv(&mv(&pw[(j - 1 - k) as usize], &p.g0));
                }
                if k + 1 < j {
                    h += cv(&mv(&pw[(j - 2 - k) as usize], &p.g1));
                }
                yg[(k + 1) as usize][j as usize] = h;
            }
        }
        let mut s = [[0.0; M]; BLOCK + 1];
        for k in -1i64..=3 {
            let mut v = [0.0; M];
            if k >= 0 {
                let a = mv(&pw[(3 - k) as usize], &p.g0);
                (0..M).for_each(|r| v[r] += a[r]);
            }
            if k <= 2 {
                let b = mv(&pw[(2 - k) as usize], &p.g1);
                (0..M).for_each(|r| v[r] += b[r]);
            }
            s[(k + 1) as usize] = v;
        }
        Self {
            yx,
            yg,
            p4: pw[BLOCK],
            s,
        }
    }
}

/// Whether [`response_blocks`] applies to a stepper: no effects, no integrators
/// (the response alone) and a whole-sample dead time of at least [`BLOCK`] samples.
pub fn blocks_apply<const M: usize, const N: usize>(p: &Plant<M, N>) -> bool {
    N == M && p.delay >= BLOCK
}

/// The linear open-loop response `y[n] = C x[n]` to the command `u` for the first
/// `u.len() / BLOCK * BLOCK` samples of a run that starts at sample 0, four samples
/// at a time (the block form of [`BlockMaps`]); returns how many samples it stepped
/// (the caller steps the rest one by one). The stepper ends in the state and with
/// the dead-time line the sample-by-sample loop would leave (to rounding: the block
/// maps group the same sums differently, a relative difference of the order of the
/// machine epsilon per block on a stable plant), so a run continues from it.
///
/// Requires [`blocks_apply`].
#[inline(always)]
pub fn response_blocks<const M: usize, const N: usize, const D: bool, const F: bool>(
    st: &mut Stepper<M, N, D, F, NoEffects>,
    u: &[f64],
    y: &mut [f64],
) -> usize {
    debug_assert!(blocks_apply(&st.plant));
    let len = u.len().min(y.len()) / BLOCK * BLOCK;
    if len == 0 {
        return 0;
    }
    let bm = BlockMaps::<M>::new::<N, D>(&st.plant);
    let (i, k) = (st.plant.delay, st.plant.k);
    // A local copy of the dead-time line, a power of two long plus a mirror of its
    // first slots, so that a block reads its five `g` as one contiguous slice and
    // writes its four references without wrapping (blocks start at multiples of 4).
    let cap = (i + 2 * BLOCK).next_power_of_two();
    let mut line = vec![0.0; cap + 2 * BLOCK];
    st.line_out(&mut line[..cap], 0);
    for q in 0..2 * BLOCK {
        line[cap + q] = line[q];
    }
    let mut x = [0.0; M];
    x.copy_from_slice(&st.x[..M]);
    // Without inner feedback the reference is the command itself (not `u + 0 y`,
    // which a diverging response would turn into NaN): a choice made once, not per
    // block.
    let (u, y) = (&u[..len], &mut y[..len]);
    #[cfg(target_arch = "x86_64")]
    if M == 2 && F && super::fma() {
        // The same operations in AVX2 intrinsics (compiled for FMA whatever the caller
        // was, and laid out as written: the line's outputs broadcast from the line).
        let x2 = [x[0], x[1 % M]];
        // SAFETY: the CPU has FMA and AVX2 (checked just above).
        let n = unsafe {
            if k == 0.0 {
                blocks_avx2::<M, D, true>(&bm, x2, i, k, u, y, &mut line)
            } else {
                blocks_avx2::<M, D, false>(&bm, x2, i, k, u, y, &mut line)
            }
        };
        x[0] = n[0];
        x[1 % M] = n[1];
        st.x[..M].copy_from_slice(&x);
        st.line_in(&line[..cap], len);
        return len;
    }
    x = if k == 0.0 {
        blocks_loop::<M, D, F, true>(&bm, x, i, k, u, y, &mut line)
    } else {
        blocks_loop::<M, D, F, false>(&bm, x, i, k, u, y, &mut line)
    };
    st.x[..M].copy_from_slice(&x);
    // The next sample's `w1` is this block's last `g` (`u_ref[len - 1 - i]`), and the
    // stepper's line holds the last references in its own layout.
    st.line_in(&line[..cap], len);
    len
}

/// The blocks of [`response_blocks`] over `u` (a whole number of blocks) into `y`,
/// from the model state `x`, with the line copy `line` (`cap` slots, a power of two,
/// then a mirror of the first `2 BLOCK`); returns the state after the last block.
/// `KZ`: without inner feedback (`k == 0`).
#[inline(always)]
fn blocks_loop<const M: usize, const D: bool, const F: bool, const KZ: bool>(
    bm: &BlockMaps<M>,
    mut x: [f64; M],
    i: usize,
    k: f64,
    u: &[f64],
    y: &mut [f64],
    line: &mut [f64],
) -> [f64; M] {
    let cap = line.len() - 2 * BLOCK;
    debug_assert!(cap.is_power_of_two() && cap >= i + 2 * BLOCK);
    debug_assert!(u.len() == y.len() && u.len().is_multiple_of(BLOCK));
    let mask = cap - 1;
    let lp = line.as_mut_ptr();
    for (b, (bu, by)) in u
        .chunks_exact(BLOCK)
        .zip(y.chunks_exact_mut(BLOCK))
        .enumerate()
    {
        let n0 = b * BLOCK;
        let base = n0.wrapping_sub(i + 1) & mask;
        // SAFETY: `base < cap`, so `base + BLOCK + 1 <= cap + 2 BLOCK`, the line's
        // length.
        let g: [f64; BLOCK + 1] = std::array::from_fn(|q| unsafe { *lp.add(base + q) });
        let mut yv = [0.0; BLOCK];
        for j in 0..BLOCK {
            let mut t = bm.yg[0][j] * g[0];
            for q in 1..BLOCK {
                t = madd::<F>(bm.yg[q][j], g[q], t);
            }
            for m in (0..M).rev() {
                t = madd::<F>(bm.yx[m][j], x[m], t);
            }
            yv[j] = t;
        }
        let mut nx = [0.0; M];
        for m in 0..M {
            let mut t = bm.s[0][m] * g[0];
            for q in 1..=BLOCK {
                t = madd::<F>(bm.s[q][m], g[q], t);
            }
            nx[m] = if D || M == 1 {
                madd::<F>(bm.p4[m][m], x[m], t)
            } else {
                madd::<F>(bm.p4[m][m], x[m], madd::<F>(bm.p4[m][1 - m], x[1 - m], t))
            };
        }
        by.copy_from_slice(&yv);
        let r: [f64; BLOCK] = std::array::from_fn(|j| {
            if KZ {
                bu[j]
            } else {
                madd::<F>(k, yv[j], bu[j])
            }
        });
        let w = n0 & mask;
        // SAFETY: `w + BLOCK <= cap` (`w` and `cap` are multiples of BLOCK), and the
        // mirror's `cap + w + BLOCK <= cap + 2 BLOCK` when `w < 2 BLOCK`.
        unsafe {
            std::ptr::copy_nonoverlapping(r.as_ptr(), lp.add(w), BLOCK);
            if w < 2 * BLOCK {
                std::ptr::copy_nonoverlapping(r.as_ptr(), lp.add(cap + w), BLOCK);
            }
        }
        x = nx;
    }
    x
}

/// [`blocks_loop`] for a second-order model (`M == 2`) with FMA, in AVX2 intrinsics:
/// the four responses of a block side by side (one lane each), the two modes' next
/// states side by side, each lane the same operations in the same order
/// (`_mm256_fmadd_pd(a, b, c)` is `madd::<true>(a, b, c)`), so the same bits.
///
/// # Safety
/// The CPU must support FMA and AVX2; `M == 2`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn blocks_avx2<const M: usize, const D: bool, const KZ: bool>(
    bm: &BlockMaps<M>,
    x: [f64; 2],
    i: usize,
    k: f64,
    u: &[f64],
    y: &mut [f64],
    line: &mut [f64],
) -> [f64; 2] {
    use std::arch::x86_64::*;
    debug_assert!(M == 2);
    let cap = line.len() - 2 * BLOCK;
    debug_assert!(cap.is_power_of_two() && cap >= i + 2 * BLOCK);
    debug_assert!(u.len() == y.len() && u.len().is_multiple_of(BLOCK));
    let mask = cap - 1;
    let lp = line.as_mut_ptr();
    let ld = |a: &[f64; BLOCK]| _mm256_loadu_pd(a.as_ptr());
    // yg[q] (lane j: H[j][q - 1]), yx[m] (lane j: (C Phi^j)[m]).
    let yg: [__m256d; BLOCK] = std::array::from_fn(|q| ld(&bm.yg[q]));
    let (yx0, yx1) = (ld(&bm.yx[0]), ld(&bm.yx[1 % M]));
    // s[q] (lane m: S[q - 1][m]), the modes' own and cross terms of Phi^4.
    let sq: [__m128d; BLOCK + 1] = std::array::from_fn(|q| _mm_set_pd(bm.s[q][1 % M], bm.s[q][0]));
    let p4d = _mm_set_pd(bm.p4[1 % M][1 % M], bm.p4[0][0]);
    let p4o = _mm_set_pd(bm.p4[1 % M][0], bm.p4[0][1 % M]);
    let kk = _mm256_set1_pd(k);
    let mut xs = _mm_set_pd(x[1], x[0]);
    let (pu, py) = (u.as_ptr(), y.as_mut_ptr());
    for n0 in (0..u.len()).step_by(BLOCK) {
        let base = n0.wrapping_sub(i + 1) & mask;
        // SAFETY: `base < cap`, so `base + BLOCK + 1 <= cap + 2 BLOCK`, the line's
        // length; `n0 + BLOCK <= u.len() == y.len()`.
        let g = lp.add(base);
        // The responses: sum_q yg[q] g[q], then the modes (mode 1 first, as
        // `blocks_loop`).
        let mut t = _mm256_mul_pd(yg[0], _mm256_broadcast_sd(&*g));
        for q in 1..BLOCK {
            t = _mm256_fmadd_pd(yg[q], _mm256_broadcast_sd(&*g.add(q)), t);
        }
        let x1 = _mm256_broadcastsd_pd(_mm_unpackhi_pd(xs, xs));
        t = _mm256_fmadd_pd(yx1, x1, t);
        let yv = _mm256_fmadd_pd(yx0, _mm256_broadcastsd_pd(xs), t);
        // The state after the block, both modes side by side.
        let mut s = _mm_mul_pd(sq[0], _mm_loaddup_pd(g));
        for q in 1..=BLOCK {
            s = _mm_fmadd_pd(sq[q], _mm_loaddup_pd(g.add(q)), s);
        }
        xs = if D {
            _mm_fmadd_pd(p4d, xs, s)
        } else {
            _mm_fmadd_pd(p4d, xs, _mm_fmadd_pd(p4o, _mm_permute_pd::<1>(xs), s))
        };
        _mm256_storeu_pd(py.add(n0), yv);
        let uv = _mm256_loadu_pd(pu.add(n0));
        let r = if KZ { uv } else { _mm256_fmadd_pd(kk, yv, uv) };
        let w = n0 & mask;
        // SAFETY: `w + BLOCK <= cap` (`w` and `cap` are multiples of BLOCK), and the
        // mirror's `cap + w + BLOCK <= cap + 2 BLOCK` when `w < 2 BLOCK`.
        _mm256_storeu_pd(lp.add(w), r);
        if w < 2 * BLOCK {
            _mm256_storeu_pd(lp.add(cap + w), r);
        }
    }
    [_mm_cvtsd_f64(xs), _mm_cvtsd_f64(_mm_unpackhi_pd(xs, xs))]
}

/// Where the samples of a run go.
pub trait Sink {
    /// Records sample `n`: acceleration, speed, position, command and the linear
    /// response.
    fn put(&mut self, n: usize, a: f64, v: f64, p: f64, u: f64, y_lin: f64);
    /// Called after samples `from..to`; `false` stops the run.
    fn proceed(&mut self, from: usize, to: usize) -> bool;
    /// How many samples the sink can take (its slices' common length): the run
    /// loop bounds itself by it, which also lets the compiler drop the per-sample
    /// bounds checks.
    fn capacity(&self) -> usize;
}

/// Runs `len` samples: the command of sample `n` is `drive(n, &obs)`. Returns
/// `false` if the sink stopped the run. The state lives in registers for the whole
/// run (written back at the end).
#[inline(always)]
pub fn run<const M: usize, const N: usize, const D: bool, const F: bool, C: Chain, S: Sink>(
    st: &mut Stepper<M, N, D, F, C>,
    len: usize,
    mut drive: impl FnMut(usize, &Obs) -> f64,
    sink: &mut S,
) -> bool {
    let mut reg = Regs {
        x: st.x,
        dv: st.dv,
        dp: st.dp,
        wp: st.wp,
    };
    debug_assert!(len <= sink.capacity());
    let len = len.min(sink.capacity());
    let mut from = 0;
    let mut done = true;
    while from < len {
        let to = (from + CHUNK).min(len);
        // The same loop twice: for a linear stepper without inner feedback (`k == 0`)
        // and for the others, so that each copy knows which way `step`'s `k == 0`
        // choice goes and the choice leaves the per-sample work.
        macro_rules! samples {
            () => {
                for n in from..to {
                    let o = observe::<M, N, F, C>(&st.plant, &st.chain, &reg.x, reg.dv, reg.dp, n);
                    let u = drive(n, &o);
                    let a = step::<M, N, D, F, C>(st.parts(), &mut reg, n, &o, u);
                    sink.put(n, a, o.v, o.p, u, o.y_lin);
                }
            };
        }
        #[allow(clippy::if_same_then_else)] // on purpose, see above
        if C::NONE && st.plant.k == 0.0 {
            samples!();
        } else {
            samples!();
        }
        if !sink.proceed(from, to) {
            done = false;
            break;
        }
        from = to;
    }
    st.x = reg.x;
    st.dv = reg.dv;
    st.dp = reg.dp;
    st.wp = reg.wp;
    done
}

/// The one SSE accumulator of the Eq. 6 cost: squared errors of acceleration and,
/// when `FULL`, speed and position against the measurements, with the largest
/// response seen (for the divergence test) and an optional bound on the weighted
/// sum (early abandoning).
pub struct Sse<'a, const FULL: bool> {
    pub a: &'a [f64],
    pub v: &'a [f64],
    pub x: &'a [f64],
    pub w: [f64; 3],
    pub sums: [f64; 3],
    pub peak: f64,
    pub limit: f64,
}

impl<'a, const FULL: bool> Sse<'a, FULL> {
    pub fn new(a: &'a [f64], v: &'a [f64], x: &'a [f64], w: [f64; 3], limit: f64) -> Self {
        Self {
            a,
            v,
            x,
            w,
            sums: [0.0; 3],
            peak: 0.0,
            limit,
        }
    }

    /// The weighted sum `wa sa + wv sv + wx sx`.
    #[inline(always)]
    pub fn weighted(&self) -> f64 {
        self.w[0] * self.sums[0] + self.w[1] * self.sums[1] + self.w[2] * self.sums[2]
    }

    /// The Eq. 6 run cost over `n` samples: `weighted / n`, or `inf` when the run
    /// diverged, was abandoned or is not finite.
    pub fn cost(&self, completed: bool, n: usize) -> f64 {
        let c = self.weighted() / n as f64;
        if completed && self.peak < DIVERGED && c.is_finite() {
            c
        } else {
            f64::INFINITY
        }
    }
}

impl<const FULL: bool> Sink for Sse<'_, FULL> {
    #[inline(always)]
    fn put(&mut self, n: usize, a: f64, v: f64, p: f64, _u: f64, y_lin: f64) {
        let e = a - self.a[n];
        self.sums[0] += e * e;
        if FULL {
            let ev = v - self.v[n];
            let ex = p - self.x[n];
            self.sums[1] += ev * ev;
            self.sums[2] += ex * ex;
            self.peak = bigger(self.peak, v.abs());
        }
        self.peak = bigger(self.peak, a.abs());
        self.peak = bigger(self.peak, y_lin.abs());
    }

    #[inline(always)]
    fn proceed(&mut self, _: usize, _: usize) -> bool {
        // NaN anywhere makes the sums NaN: `!(x < y)` catches it.
        self.peak < DIVERGED && self.weighted() < self.limit
    }

    #[inline(always)]
    fn capacity(&self) -> usize {
        if FULL {
            self.a.len().min(self.v.len()).min(self.x.len())
        } else {
            self.a.len()
        }
    }
}

/// `max` as one compare-select (no NaN handling: a NaN response makes the error
/// sums NaN, which [`Sse::proceed`] and [`Sse::cost`] catch).
#[inline(always)]
fn bigger(m: f64, x: f64) -> f64 {
    if x > m {
        x
    } else {
        m
    }
}

/// Writes the trajectory into caller-provided slices, and the command too when `U`;
/// with `STOP`, stops at the first sample whose acceleration leaves `|a| < DIVERGED`
/// or whose speed is not finite (that sample is written; `written` says how many
/// were). Whether the command is recorded is part of the type, not a per-sample test.
pub struct Record<'a, const STOP: bool, const U: bool> {
    pub a: &'a mut [f64],
    pub v: &'a mut [f64],
    pub x: &'a mut [f64],
    /// The command (empty without `U`).
    pub u: &'a mut [f64],
    pub written: usize,
}

impl<'a, const STOP: bool> Record<'a, STOP, false> {
    /// Acceleration, speed and position.
    pub fn new(a: &'a mut [f64], v: &'a mut [f64], x: &'a mut [f64]) -> Self {
        Self {
            a,
            v,
            x,
            u: &mut [],
            written: 0,
        }
    }
}

impl<'a, const STOP: bool> Record<'a, STOP, true> {
    /// Acceleration, speed, position and the command.
    pub fn with_command(
        a: &'a mut [f64],
        v: &'a mut [f64],
        x: &'a mut [f64],
        u: &'a mut [f64],
    ) -> Self {
        Self {
            a,
            v,
            x,
            u,
            written: 0,
        }
    }
}

impl<const STOP: bool, const U: bool> Record<'_, STOP, U> {
    /// Fills the outputs from sample `written` on with NaN (after a stopped run).
    pub fn blank_rest(&mut self) {
        let w = self.written;
        self.a[w..].fill(f64::NAN);
        self.v[w..].fill(f64::NAN);
        self.x[w..].fill(f64::NAN);
        if U {
            self.u[w..].fill(f64::NAN);
        }
    }
}

impl<const STOP: bool, const U: bool> Sink for Record<'_, STOP, U> {
    #[inline(always)]
    fn put(&mut self, n: usize, a: f64, v: f64, p: f64, u: f64, _y_lin: f64) {
        self.a[n] = a;
        self.v[n] = v;
        self.x[n] = p;
        if U {
            self.u[n] = u;
        }
    }

    #[inline(always)]
    fn proceed(&mut self, from: usize, to: usize) -> bool {
        if STOP {
            // One branch-free (vectorizable) pass over the chunk; the first bad sample
            // is looked for only when there is one.
            let (a, v) = (&self.a[from..to], &self.v[from..to]);
            let ok = a
                .iter()
                .zip(v)
                .fold(true, |ok, (a, v)| ok & (a.abs() < DIVERGED) & v.is_finite());
            if !ok {
                let k = a
                    .iter()
                    .zip(v)
                    .position(|(a, v)| !(a.abs() < DIVERGED && v.is_finite()))
                    .unwrap_or(to - from - 1);
                self.written = from + k + 1;
                return false;
            }
        }
        self.written = to;
        true
    }

    #[inline(always)]
    fn capacity(&self) -> usize {
        let n = self.a.len().min(self.v.len()).min(self.x.len());
        if U {
            n.min(self.u.len())
        } else {
            n
        }
    }
}

/// Only the response (`simulate`): acceleration for an acceleration command, speed
/// for a speed command.
pub struct Response<'a>(pub &'a mut [f64]);

impl Sink for Response<'_> {
    #[inline(always)]
    fn put(&mut self, n: usize, _a: f64, _v: f64, _p: f64, _u: f64, y_lin: f64) {
        self.0[n] = y_lin;
    }

    #[inline(always)]
    fn proceed(&mut self, _: usize, _: usize) -> bool {
        true
    }

    #[inline(always)]
    fn capacity(&self) -> usize {
        self.0.len()
    }
}

// The block form exists on x86_64 only.
#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;
    use crate::model::Linear;
    use crate::sim::discretize::Integrators;

    /// The open loop's block form in AVX2 intrinsics equals its plain form bit for
    /// bit: real poles (modal) and complex poles (canonical), with and without inner
    /// feedback, dead times from 4 to 40 samples, from a nonzero state and line.
    #[test]
    fn avx2_blocks_equal_the_plain_blocks() {
        if !crate::sim::fma() {
            return;
        }
        let n = 4 * 301;
        let u: Vec<f64> = (0..n)
            .map(|j| (0.013 * j as f64).sin() + 0.4 * (0.31 * j as f64).cos())
            .collect();
        let lins = [
            Linear {
                b1: 6.7893,
                b0: 0.3479,
                a2: 1.2824,
                a1: 8.8157,
                td: 0.7903,
                k: 0.1008,
            },
            Linear {
                b1: 0.4,
                b0: 1.0,
                a2: 0.5,
                a1: 0.3,
                td: 0.31,
                k: -0.2,
            },
        ];
        let mut forms = 0;
        for lin0 in lins {
            for td in [0.2, 0.27, 0.79, 2.03] {
                for k in [0.0, lin0.k] {
                    let lin = Linear { td, k, ..lin0 };
                    let p = Plant::<2, 2>::new(&lin, Integrators::None, 0.05, true).unwrap();
                    let i = p.delay;
                    let cap = (i + 2 * BLOCK).next_power_of_two();
                    let mut line0 = vec![0.0; cap + 2 * BLOCK];
                    for (q, v) in line0.iter_mut().enumerate().take(cap) {
                        *v = 0.1 * (q as f64).cos();
                    }
                    for q in 0..2 * BLOCK {
                        line0[cap + q] = line0[q];
                    }
                    let x0 = [0.3, -0.2];
                    macro_rules! both {
                        ($d:literal, $kz:literal) => {{
                            let bm = BlockMaps::<2>::new::<2, $d>(&p);
                            let (mut l1, mut l2) = (line0.clone(), line0.clone());
                            let (mut y1, mut y2) = (vec![0.0; n], vec![0.0; n]);
                            let a = blocks_loop::<2, $d, true, $kz>(
                                &bm, x0, i, k, &u, &mut y1, &mut l1,
                            );
                            // SAFETY: the CPU has FMA and AVX2 (checked above).
                            let b = unsafe {
                                crate::sim::with_fma(|| {
                                    blocks_avx2::<2, $d, $kz>(&bm, x0, i, k, &u, &mut y2, &mut l2)
                                })
                            };
                            let bits =
                                |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                            assert_eq!(bits(&y1), bits(&y2), "td {td}, k {k}");
                            assert_eq!(bits(&l1), bits(&l2), "line, td {td}, k {k}");
                            assert_eq!(bits(&a), bits(&b), "state, td {td}, k {k}");
                            forms += 1;
                        }};
                    }
                    match (p.diag, k == 0.0) {
                        (true, true) => both!(true, true),
                        (true, false) => both!(true, false),
                        (false, true) => both!(false, true),
                        (false, false) => both!(false, false),
                    }
                }
            }
        }
        assert_eq!(forms, 16);
    }
}
