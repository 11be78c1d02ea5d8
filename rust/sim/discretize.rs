//! Exact zero-order-hold discretization with a fractional dead time.
//!
//! Convention (shared by the Rust core, `avll.reference` and every test):
//! * the reference input `u_ref[n] = u[n] + K y[n]` is held over `[t_n, t_{n+1})`;
//! * the rational part is driven by `w(t) = u_ref(t - Td)`; with `Td/dt = i + f`
//!   (`0 <= f < 1`) the interval's first `f dt` carries `u_ref[n-i-1]` and the rest
//!   `u_ref[n-i]` (the modified z-transform), so the result is smooth in `Td`;
//! * `x[n+1] = Phi x[n] + G0 u_ref[n-i] + G1 u_ref[n-i-1]`, `y[n] = C x[n]`;
//! * the input-to-state maps come from the matrix exponential of the augmented
//!   matrix `[[A, B], [0, 0]] tau`, which also handles the integrators exactly.
//!
//! The continuous realization of `(b1 s + b0)/(a2 s^2 + a1 s + 1)` is the
//! controllable canonical form; integrators for speed and position are appended
//! after the model states (`v' = y, p' = v` for an acceleration response; `p' = y`
//! for a speed response).

use crate::error::{AvllError, Result};
use crate::model::{CommandKind, Linear};
use nalgebra::DMatrix;

/// Which integrators are appended to the model states.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Integrators {
    /// Model states only.
    None,
    /// Acceleration response: speed and position (`v' = y`, `p' = v`).
    SpeedPosition,
    /// Speed response: position (`p' = y`).
    Position,
}

impl Integrators {
    pub fn count(self) -> usize {
        match self {
            Integrators::None => 0,
            Integrators::SpeedPosition => 2,
            Integrators::Position => 1,
        }
    }

    /// The integrators that go with a command kind when speed/position are wanted.
    pub fn for_kind(kind: CommandKind) -> Self {
        match kind {
            CommandKind::Acceleration => Integrators::SpeedPosition,
            CommandKind::Speed => Integrators::Position,
        }
    }
}

/// A discretized model of state dimension `N` (model order plus integrators).
#[derive(Debug, Clone, Copy)]
pub struct Discrete<const N: usize> {
    pub phi: [[f64; N]; N],
    /// Input map of `u_ref[n-i]` (held over the last `(1-f) dt` of the interval).
    pub g0: [f64; N],
    /// Input map of `u_ref[n-i-1]` (held over the first `f dt`); zero when `f = 0`.
    pub g1: [f64; N],
    /// Response row: `y = c x`.
    pub c: [f64; N],
    /// Time derivative of the response at `t_n+`: `ca x + cb w(t_n+)`.
    pub ca: [f64; N],
    pub cb: f64,
    /// Whole samples of dead time (`i`).
    pub delay_steps: usize,
    /// Fractional part of the dead time in samples (`f`).
    pub frac: f64,
    /// Inner feedback gain.
    pub k: f64,
    /// Model order (number of model states, before the integrators).
    pub order: usize,
}

/// Continuous realization `(A, B, C)` of the rational part plus integrators.
pub fn continuous(lin: &Linear, ints: Integrators) -> (DMatrix<f64>, Vec<f64>, Vec<f64>) {
    let m = lin.order();
    let n = m + ints.count();
    let mut a = DMatrix::<f64>::zeros(n, n);
    let mut b = vec![0.0; n];
    let mut c = vec![0.0; n];
    if m == 1 {
        a[(0, 0)] = -1.0 / lin.a1;
        b[0] = 1.0;
        c[0] = lin.b0 / lin.a1;
    } else {
        a[(0, 1)] = 1.0;
        a[(1, 0)] = -1.0 / lin.a2;
        a[(1, 1)] = -lin.a1 / lin.a2;
        b[1] = 1.0;
        c[0] = lin.b0 / lin.a2;
        c[1] = lin.b1 / lin.a2;
    }
    match ints {
        Integrators::None => {}
        Integrators::SpeedPosition => {
            for j in 0..m {
                a[(m, j)] = c[j]; // v' = y
            }
            a[(m + 1, m)] = 1.0; // p' = v
        }
        Integrators::Position => {
            for j in 0..m {
                a[(m, j)] = c[j]; // p' = y
            }
        }
    }
    (a, b, c)
}

/// Largest entry of `[A, B] tau` accepted by [`zoh`]. Beyond it the model's time
/// constants are more than 1e12 times shorter than the sample time (meaningless for
/// a vehicle) and nalgebra's matrix exponential can fail to terminate (observed
/// for entries around 1e50), so such parameters are rejected.
pub const MAX_SCALED_ENTRY: f64 = 1e12;

/// `(e^{A tau}, int_0^tau e^{A s} B ds)` from one matrix exponential.
fn zoh(a: &DMatrix<f64>, b: &[f64], tau: f64) -> Result<(DMatrix<f64>, Vec<f64>)> {
    let n = a.nrows();
    let mut m = DMatrix::<f64>::zeros(n + 1, n + 1);
    for i in 0..n {
        for j in 0..n {
            m[(i, j)] = a[(i, j)] * tau;
        }
        m[(i, n)] = b[i] * tau;
    }
    if m.iter().any(|x| x.is_nan() || x.abs() > MAX_SCALED_ENTRY) {
        return Err(AvllError::new(
            "params",
            format!(
                "the model's time constants are out of range for dt (|[A, B] dt| > {MAX_SCALED_ENTRY:e})"
            ),
        ));
    }
    let e = m.exp();
    let phi = e.view((0, 0), (n, n)).into_owned();
    let gam = (0..n).map(|i| e[(i, n)]).collect();
    Ok((phi, gam))
}

/// Splits a dead time into whole samples and a fraction, `td/dt = i + f`.
pub fn split_delay(td: f64, dt: f64) -> (usize, f64) {
    let r = td / dt;
    let i = r.floor();
    let mut f = r - i;
    // Guard against `f` a rounding error below 1 or above 0.
    if f < 1e-12 {
        f = 0.0;
    }
    (i as usize, f)
}

/// A value a [`DelayLine`] can interpolate: `(1 - f) a + f b`.
pub trait Lerp: Copy + Default {
    fn lerp(a: Self, b: Self, f: f64) -> Self;
}

impl Lerp for f64 {
    #[inline(always)]
    fn lerp(a: f64, b: f64, f: f64) -> f64 {
        (1.0 - f) * a + f * b
    }
}

impl Lerp for (f64, f64) {
    #[inline(always)]
    fn lerp(a: Self, b: Self, f: f64) -> Self {
        (f64::lerp(a.0, b.0, f), f64::lerp(a.1, b.1, f))
    }
}

/// A fractional delay of a sampled signal by linear interpolation between its samples:
/// with `tau/dt = i + f`, `x'[n] = (1 - f) x[n-i] + f x[n-i-1]` ([`split_delay`]), in a
/// ring buffer of the last `i + 2` samples (a power of two). The history before the
/// first sample is the value given to [`DelayLine::reset`].
#[derive(Debug, Clone, Default)]
pub struct DelayLine<T> {
    i: usize,
    f: f64,
    n: usize,
    mask: usize,
    buf: Vec<T>,
}

impl<T: Lerp> DelayLine<T> {
    /// Starts the line for delay `tau` at sample time `dt`, its history all `hist`.
    pub fn reset(&mut self, tau: f64, dt: f64, hist: T) {
        let (i, f) = split_delay(tau, dt);
        (self.i, self.f, self.n) = (i, f, 0);
        let cap = (i + 2).next_power_of_two();
        self.mask = cap - 1;
        self.buf.clear();
        self.buf.resize(cap, hist);
    }

    /// Samples pushed since the reset.
    pub fn len(&self) -> usize {
        self.n
    }

    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// Sets the whole history to `x` (e.g. the first sample held).
    pub fn fill(&mut self, x: T) {
        self.buf.fill(x);
    }

    /// Pushes sample `x[n]` and returns the delayed `x'[n]`.
    #[inline(always)]
    pub fn push(&mut self, x: T) -> T {
        let n = self.n;
        self.buf[n & self.mask] = x;
        self.n += 1;
        let x0 = self.buf[n.wrapping_sub(self.i) & self.mask];
        if self.f > 0.0 {
            T::lerp(x0, self.buf[n.wrapping_sub(self.i + 1) & self.mask], self.f)
        } else {
            x0
        }
    }
}

/// Discretizes `lin` for sample time `dt`, with the given integrators.
/// `N` must equal `lin.order() + ints.count()`.
pub fn discretize<const N: usize>(lin: &Linear, ints: Integrators, dt: f64) -> Result<Discrete<N>> {
    if !(dt.is_finite() && dt > 0.0) {
        return Err(AvllError::new(
            "dt",
            format!("must be finite and > 0, got {dt}"),
        ));
    }
    let m = lin.order();
    if m + ints.count() != N {
        return Err(AvllError::new(
            "model",
            format!("internal: state size {} != {N}", m + ints.count()),
        ));
    }
    let (a, b, c) = continuous(lin, ints);
    let (i, f) = split_delay(lin.td, dt);
    if i > 1 << 24 {
        return Err(AvllError::new("Td", "dead time longer than 2^24 samples"));
    }
    // Last (1-f) dt carries u_ref[n-i]; first f dt carries u_ref[n-i-1].
    let (phi_a, gam_a) = zoh(&a, &b, (1.0 - f) * dt)?;
    let mut d = Discrete::<N> {
        phi: [[0.0; N]; N],
        g0: [0.0; N],
        g1: [0.0; N],
        c: [0.0; N],
        ca: [0.0; N],
        cb: 0.0,
        delay_steps: i,
        frac: f,
        k: lin.k,
        order: m,
    };
    if f > 0.0 {
        let (phi_b, gam_b) = zoh(&a, &b, f * dt)?;
        let phi = &phi_a * &phi_b;
        for r in 0..N {
            for col in 0..N {
                d.phi[r][col] = phi[(r, col)];
            }
            d.g0[r] = gam_a[r];
            d.g1[r] = (0..N).map(|j| phi_a[(r, j)] * gam_b[j]).sum();
        }
    } else {
        for r in 0..N {
            for col in 0..N {
                d.phi[r][col] = phi_a[(r, col)];
            }
            d.g0[r] = gam_a[r];
        }
    }
    for j in 0..N {
        d.c[j] = c[j];
        d.ca[j] = (0..N).map(|r| c[r] * a[(r, j)]).sum();
    }
    d.cb = (0..N).map(|r| c[r] * b[r]).sum();
    if d.phi
        .iter()
        .flatten()
        .chain(d.g0.iter())
        .chain(d.g1.iter())
        .any(|x| !x.is_finite())
    {
        return Err(AvllError::new("params", "discretization is not finite"));
    }
    Ok(d)
}

/// Largest characteristic-polynomial degree (dead time in samples plus model order)
/// for which [`inner_loop_stable`] runs the O(degree^2) Schur-Cohn test; longer dead
/// times with feedback are left to the divergence check of the rollouts.
pub const MAX_STABILITY_DEGREE: usize = 1 << 14;

/// Whether the discretized lower level — the model states of `d` (integrators, which
/// do not feed back, are ignored) with the inner loop `u_ref = u + K y` closed at the
/// samples — is asymptotically stable.
///
/// Without feedback this is the rational part's own stability (`a1 > 0`, `a2 >= 0`).
/// With feedback, the loop's characteristic polynomial
/// `p(z) = z^{i+1} det(zI - Phi) - K (z N0(z) + N1(z))`, `Nk(z) = c adj(zI - Phi) gk`,
/// must have every root strictly inside the unit circle (Schur-Cohn recursion);
/// `K b0 >= 1` is rejected first (a real root `z >= 1`: the loop has no steady state).
pub fn inner_loop_stable<const N: usize>(d: &Discrete<N>, lin: &Linear) -> bool {
    let m = d.order;
    let at = |r: usize, c: usize| if r < m && c < m { d.phi[r][c] } else { 0.0 };
    let v2 = |v: &[f64; N]| [v[0], if m > 1 { v[1] } else { 0.0 }];
    loop_parts_stable(
        lin,
        m,
        d.delay_steps,
        [[at(0, 0), at(0, 1)], [at(1, 0), at(1, 1)]],
        v2(&d.c),
        v2(&d.g0),
        v2(&d.g1),
    )
}

/// [`inner_loop_stable`] for a [`crate::sim::plant::Plant`] (in any basis: the
/// characteristic polynomial does not depend on it).
pub fn loop_stable<const M: usize, const N: usize>(
    lin: &Linear,
    p: &crate::sim::plant::Plant<M, N>,
) -> bool {
    let at = |r: usize, c: usize| if r < M && c < M { p.phi[r][c] } else { 0.0 };
    let v2 = |v: &[f64; N]| [v[0], if M > 1 { v[1] } else { 0.0 }];
    loop_parts_stable(
        lin,
        M,
        p.delay,
        [[at(0, 0), at(0, 1)], [at(1, 0), at(1, 1)]],
        v2(&p.c),
        v2(&p.g0),
        v2(&p.g1),
    )
}

fn loop_parts_stable(
    lin: &Linear,
    m: usize,
    delay: usize,
    phi: [[f64; 2]; 2],
    c: [f64; 2],
    g0: [f64; 2],
    g1: [f64; 2],
) -> bool {
    if lin.k == 0.0 {
        return lin.a1 > 0.0 && lin.a2 >= 0.0;
    }
    if lin.k * lin.b0 >= 1.0 {
        return false;
    }
    let deg = delay + 1 + m;
    if deg > MAX_STABILITY_DEGREE {
        return true;
    }
    // Ascending coefficients of p(z).
    let mut p = vec![0.0; deg + 1];
    let (n0, n1) = if m == 1 {
        // det(zI - phi) = z - phi; c adj g = c g
        p[delay + 1] = -phi[0][0];
        p[delay + 2] = 1.0;
        ([c[0] * g0[0], 0.0], [c[0] * g1[0], 0.0])
    } else {
        let (f11, f12, f21, f22) = (phi[0][0], phi[0][1], phi[1][0], phi[1][1]);
        p[delay + 1] = f11 * f22 - f12 * f21;
        p[delay + 2] = -(f11 + f22);
        p[delay + 3] = 1.0;
        // c adj(zI - phi) g = z (c . g) + (c1 (f12 g2 - f22 g1) + c2 (f21 g1 - f11 g2))
        let num = |g: [f64; 2]| {
            let (c1, c2) = (c[0], c[1]);
            [
                c1 * (f12 * g[1] - f22 * g[0]) + c2 * (f21 * g[0] - f11 * g[1]),
                c1 * g[0] + c2 * g[1],
            ]
        };
        (num(g0), num(g1))
    };
    // - K (z N0(z) + N1(z)): N0, N1 have degree <= 1.
    p[0] -= lin.k * n1[0];
    p[1] -= lin.k * (n1[1] + n0[0]);
    p[2] -= lin.k * n0[1];
    schur_stable(&mut p)
}

/// Schur-Cohn: all roots of the real polynomial with ascending coefficients `c`
/// strictly inside the unit circle. With `a0 = c[0]`, `an = c[n]`, `|a0| < |an|` and
/// the roots of `(an p(z) - a0 z^n p(1/z)) / z` (degree `n-1`) all inside are
/// together necessary and sufficient (Rouche on `|z| = 1`). Overwrites `c`.
pub fn schur_stable(c: &mut Vec<f64>) -> bool {
    while c.len() > 1 && c[c.len() - 1] == 0.0 {
        c.pop();
    }
    if c.iter().any(|x| !x.is_finite()) {
        return false;
    }
    let mut n = c.len() - 1;
    let mut q = vec![0.0; c.len()];
    while n > 0 {
        let (a0, an) = (c[0], c[n]);
        if a0.is_nan() || an.is_nan() || a0.abs() >= an.abs() {
            return false;
        }
        for j in 0..n {
            q[j] = an * c[j + 1] - a0 * c[n - 1 - j];
        }
        n -= 1;
        // keep the coefficients O(1): the new leading one is an^2 - a0^2 > 0
        let lead = q[n];
        if !(lead.is_finite() && lead > 0.0) {
            return false;
        }
        for j in 0..=n {
            c[j] = q[j] / lead;
        }
    }
    true
}

/// Model-state equilibrium for a constant rational-part input `w`: `A x + B w = 0`.
/// Returns the model states (length `order`); `y = b0 w` there.
pub fn equilibrium(lin: &Linear, w: f64) -> [f64; 2] {
    if lin.order() == 1 {
        [lin.a1 * w, 0.0] // x = a1 w, y = (b0/a1) x = b0 w
    } else {
        [lin.a2 * w, 0.0] // x0 = a2 w, x1 = 0, y = (b0/a2) x0 = b0 w
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lag(td: f64) -> Linear {
        Linear {
            b1: 0.0,
            b0: 1.0,
            a2: 0.0,
            a1: td,
            td: 0.0,
            k: 0.0,
        }
    }

    #[test]
    fn first_order_lag_matches_closed_form() {
        let d = discretize::<1>(&lag(0.8), Integrators::None, 0.05).unwrap();
        let a = (-0.05f64 / 0.8).exp();
        // y = (1/Td) x, x[n+1] = a x + Td (1-a) u => y[n+1] = a y + (1-a) u
        assert!((d.phi[0][0] - a).abs() < 1e-14);
        assert!((d.c[0] * d.g0[0] - (1.0 - a)).abs() < 1e-14);
        assert_eq!(d.delay_steps, 0);
        assert_eq!(d.frac, 0.0);
    }

    #[test]
    fn fractional_delay_splits_input_map() {
        let lin = Linear {
            b1: 0.3,
            b0: 0.7,
            a2: 0.5,
            a1: 1.1,
            td: 0.12,
            k: 0.0,
        };
        let d = discretize::<2>(&lin, Integrators::None, 0.05).unwrap();
        assert_eq!(d.delay_steps, 2);
        assert!((d.frac - 0.4).abs() < 1e-9);
        // The two input maps together equal the full-interval ZOH map.
        let d0 = discretize::<2>(&Linear { td: 0.0, ..lin }, Integrators::None, 0.05).unwrap();
        for r in 0..2 {
            assert!((d.g0[r] + d.g1[r] - d0.g0[r]).abs() < 1e-13);
        }
    }

    #[test]
    fn schur_cohn_counts_roots() {
        // (z - 0.5)(z + 0.9) = z^2 + 0.4 z - 0.45: stable
        assert!(schur_stable(&mut vec![-0.45, 0.4, 1.0]));
        // (z - 1.1)(z + 0.2): unstable
        assert!(!schur_stable(&mut vec![-0.22, -0.9, 1.0]));
        // z^5 - 0.3 (roots of modulus 0.3^(1/5) ~ 0.79): stable
        assert!(schur_stable(&mut vec![-0.3, 0.0, 0.0, 0.0, 0.0, 1.0]));
        // z^5 - 1.3: unstable
        assert!(!schur_stable(&mut vec![-1.3, 0.0, 0.0, 0.0, 0.0, 1.0]));
        // complex pair 0.95 e^{+-j}: z^2 - 1.9 cos(1) z + 0.9025
        assert!(schur_stable(&mut vec![0.9025, -1.9 * 1f64.cos(), 1.0]));
        assert!(!schur_stable(&mut vec![1.1025, -2.1 * 1f64.cos(), 1.0]));
    }

    #[test]
    fn inner_loop_stability_matches_known_cases() {
        let base = Linear {
            b1: 6.7893,
            b0: 0.3479,
            a2: 1.2824,
            a1: 8.8157,
            td: 0.7903,
            k: 0.1008,
        };
        let ok = |lin: Linear| {
            let d = discretize::<2>(&lin, Integrators::None, 0.05).unwrap();
            inner_loop_stable(&d, &lin)
        };
        assert!(ok(base)); // the paper's Table II model
        assert!(!ok(Linear { k: 3.0, ..base })); // K K0 > 1
        assert!(!ok(Linear {
            a1: -0.1,
            k: 0.0,
            ..base
        })); // negative damping
        assert!(!ok(Linear { k: -40.0, ..base })); // strong delayed feedback oscillates
        assert!(ok(Linear {
            a1: -0.1,
            td: 0.0,
            k: -0.5,
            ..base
        })); // feedback stabilizes
    }

    #[test]
    fn split_delay_is_exact_on_integers() {
        assert_eq!(split_delay(0.0, 0.05), (0, 0.0));
        let (i, f) = split_delay(0.7903, 0.05);
        assert_eq!(i, 15);
        assert!((f - 0.806).abs() < 1e-9);
    }
}
