//! The discretized lower level in the coordinates the kernel steps, and the one
//! initial-state routine.
//!
//! A [`Plant`] is a [`Discrete`] (exact ZOH, fractional dead time, see
//! [`crate::sim::discretize`]) with the model states changed to *modal*
//! coordinates when that is safe: for a second-order rational part whose discrete
//! transition has two real, well-separated eigenvalues, `x_model = T z` makes the
//! model block diagonal, so each step's state-to-state dependency is one
//! multiply-add per mode instead of a 2 x 2 product. Complex or nearly repeated
//! eigenvalues (an ill-conditioned `T`) keep the controllable canonical form. The
//! integrator rows (speed, position) are carried along (`Phi' = S^-1 Phi S`,
//! `S = diag(T, I)`), so the trajectories are the same up to rounding (the tests
//! hold them to the canonical form to 1e-12 relative).

use super::discretize::{discretize, equilibrium, Discrete, Integrators};
use crate::error::{AvllError, Result};
use crate::model::Linear;

/// Largest condition number `|T|_F |T^-1|_F` of the modal basis accepted: the
/// change of basis then costs at most a few digits beyond 1e-16 (far inside the
/// 1e-9 the rollouts are held to).
pub const MAX_MODAL_COND: f64 = 1e4;

/// How the lower level starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Init {
    /// Zero model state, zero input history, `y[0] = 0`.
    Rest,
    /// The lower level at the equilibrium of the first command sample held forever.
    Steady,
}

impl Init {
    pub fn from_name(name: &str) -> Result<Self> {
        match name {
            "rest" => Ok(Init::Rest),
            "steady" => Ok(Init::Steady),
            _ => Err(AvllError::new(
                "init",
                format!("must be 'rest' or 'steady', got {name:?}"),
            )),
        }
    }
}

/// The start of a run: model state (canonical coordinates), the reference input
/// assumed before the run (fills the dead-time line) and the command assumed before
/// the run (what stateful effects reset to).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Start {
    pub x: [f64; 2],
    pub w_hist: f64,
    pub u_hist: f64,
}

/// The one initial-state routine (the rollouts, the costs and `avll.reference`
/// apply the same rule):
/// * [`Init::Rest`]: zero model state, zero history;
/// * [`Init::Steady`]: the first command `u0` held forever, so `w = u0 / (1 - K b0)`
///   fills the history and the model sits at `A x + B w = 0` (`y[0] = b0 w`).
pub fn start(lin: &Linear, init: Init, u0: f64) -> Result<Start> {
    match init {
        Init::Rest => Ok(Start {
            x: [0.0; 2],
            w_hist: 0.0,
            u_hist: 0.0,
        }),
        Init::Steady => {
            let den = 1.0 - lin.k * lin.b0;
            if den.abs() < 1e-12 {
                return Err(AvllError::new(
                    "init",
                    "no steady state: K * K0 = 1 (the inner loop has a pole at s = 0)",
                ));
            }
            let w = u0 / den;
            Ok(Start {
                x: equilibrium(lin, w),
                w_hist: w,
                u_hist: u0,
            })
        }
    }
}

/// A discretized lower level with `M` model states and `N - M` integrators, in the
/// kernel's coordinates (see the module documentation).
#[derive(Debug, Clone, Copy)]
pub struct Plant<const M: usize, const N: usize> {
    pub phi: [[f64; N]; N],
    pub g0: [f64; N],
    pub g1: [f64; N],
    pub c: [f64; N],
    pub ca: [f64; N],
    pub cb: f64,
    /// `x_model = t z_model` (identity when not modal).
    pub t: [[f64; 2]; 2],
    /// `z_model = tinv x_model`.
    pub tinv: [[f64; 2]; 2],
    /// The model block is diagonal (modal coordinates).
    pub diag: bool,
    pub delay: usize,
    pub frac: f64,
    pub k: f64,
    pub dt: f64,
}

const EYE: [[f64; 2]; 2] = [[1.0, 0.0], [0.0, 1.0]];

impl<const M: usize, const N: usize> Plant<M, N> {
    /// Discretizes `lin` for `dt` with `ints` (`N = M + ints.count()`, `M` the model
    /// order); `modal` allows the modal change of basis.
    pub fn new(lin: &Linear, ints: Integrators, dt: f64, modal: bool) -> Result<Self> {
        if lin.order() != M {
            return Err(AvllError::new(
                "model",
                format!("internal: model order {} != {M}", lin.order()),
            ));
        }
        if N == M {
            if let Some(p) = Self::analytic(lin, dt, modal) {
                return Ok(p);
            }
        }
        let d = discretize::<N>(lin, ints, dt)?;
        let mut p = Self::from_discrete(&d, dt);
        if modal && M == 2 {
            if let Some((t, tinv)) = modal_basis(&d) {
                p.change_basis(t, tinv);
            }
        }
        Ok(p)
    }

    /// The modal discretization in closed form, without integrators: a first-order
    /// part (`p = -1/a1`, canonical basis) or a second-order part with real poles
    /// `p1, p2` at least `1/MAX_MODAL_COND` apart relative to their size
    /// (`z_k' = p_k z_k + w`, `y = sum r_k z_k`, `x = T z`). Each mode's hold maps
    /// are `g0 = (e^{p (1-f) dt} - 1)/p`, `g1 = e^{p (1-f) dt} (e^{p f dt} - 1)/p`, the
    /// same exact ZOH as the matrix exponential (to rounding) at a fraction of its
    /// cost. `None` when the closed form does not apply.
    fn analytic(lin: &Linear, dt: f64, modal: bool) -> Option<Self> {
        if !(dt.is_finite() && dt > 0.0 && lin.td.is_finite()) || lin.td < 0.0 {
            return None;
        }
        let (i, f) = super::discretize::split_delay(lin.td, dt);
        if i > 1 << 24 {
            return None;
        }
        // The range the matrix exponential accepts (else it reports the error).
        let scale = if M == 1 {
            (1.0 / lin.a1).abs()
        } else {
            (1.0 / lin.a2).abs().max((lin.a1 / lin.a2).abs())
        };
        let limit = super::discretize::MAX_SCALED_ENTRY;
        let scaled = scale.max(1.0) * dt;
        if scaled.is_nan() || scaled > limit {
            return None;
        }
        let (poles, res, t, tinv) = if M == 1 {
            if !(lin.a1.is_finite() && lin.a1 != 0.0) {
                return None;
            }
            let p = -1.0 / lin.a1;
            ([p, 0.0], [lin.b0 / lin.a1, 0.0], EYE, EYE)
        } else {
            if !modal || lin.a2.is_nan() || lin.a2 <= 0.0 {
                return None;
            }
            let disc = lin.a1 * lin.a1 - 4.0 * lin.a2;
            if disc.is_nan() || disc <= 0.0 {
                return None;
            }
            let q = -0.5 * (lin.a1 + disc.sqrt().copysign(lin.a1));
            let (p1, p2) = (q / lin.a2, 1.0 / q);
            let gap = (p1 - p2).abs();
            if !(gap.is_finite() && gap * MAX_MODAL_COND >= p1.abs().max(p2.abs())) {
                return None;
            }
            let d = p1 - p2;
            let r1 = (lin.b0 + lin.b1 * p1) / (lin.a2 * d);
            let r2 = -(lin.b0 + lin.b1 * p2) / (lin.a2 * d);
            let t = [[1.0 / d, -1.0 / d], [p1 / d, -p2 / d]];
            let tinv = [[-p2, 1.0], [-p1, 1.0]];
            ([p1, p2], [r1, r2], t, tinv)
        };
        let mut pl = Self {
            phi: [[0.0; N]; N],
            g0: [0.0; N],
            g1: [0.0; N],
            c: [0.0; N],
            ca: [0.0; N],
            cb: 0.0,
            t,
            tinv,
            diag: true,
            delay: i,
            frac: f,
            k: lin.k,
            dt,
        };
        for j in 0..M {
            let p = poles[j];
            let a = (p * (1.0 - f) * dt).exp();
            pl.phi[j][j] = (p * dt).exp();
            pl.g0[j] = (p * (1.0 - f) * dt).exp_m1() / p;
            pl.g1[j] = if f > 0.0 {
                a * (p * f * dt).exp_m1() / p
            } else {
                0.0
            };
            pl.c[j] = res[j];
            // Speed response derivative: y' = sum r_k (p_k z_k + w).
            pl.ca[j] = res[j] * p;
            pl.cb += res[j];
        }
        if pl
            .phi
            .iter()
            .flatten()
            .chain(&pl.g0)
            .chain(&pl.g1)
            .chain(&pl.c)
            .any(|x| !x.is_finite())
        {
            return None;
        }
        Some(pl)
    }

    /// [`Plant::new`] through a small cache, per thread, of the plants last built:
    /// a loop of rollouts of one model (the same parameters, integrators, `dt` and
    /// choice of basis, compared bit for bit) discretizes it once. With speed and
    /// position the discretization takes two matrix exponentials, about 10 us, a few
    /// percent of a closed loop of 1e5 samples. The plant returned is the one
    /// `Plant::new` returns (a copy of it).
    pub fn cached(lin: &Linear, ints: Integrators, dt: f64, modal: bool) -> Result<Self> {
        let key = CacheKey::of::<M, N>(lin, ints, dt, modal);
        let hit = PLANTS.with(|c| {
            c.borrow()
                .iter()
                .find(|(k, _)| *k == key)
                .and_then(|(_, p)| p.downcast_ref::<Self>().copied())
        });
        if let Some(p) = hit {
            return Ok(p);
        }
        let p = Self::new(lin, ints, dt, modal)?;
        PLANTS.with(|c| {
            let mut c = c.borrow_mut();
            if c.len() >= CACHED_PLANTS {
                c.remove(0);
            }
            c.push((key, Box::new(p)));
        });
        Ok(p)
    }

    fn from_discrete(d: &Discrete<N>, dt: f64) -> Self {
        Self {
            phi: d.phi,
            g0: d.g0,
            g1: d.g1,
            c: d.c,
            ca: d.ca,
            cb: d.cb,
            t: EYE,
            tinv: EYE,
            diag: M == 1,
            delay: d.delay_steps,
            frac: d.frac,
            k: d.k,
            dt,
        }
    }

    /// `Phi' = S^-1 Phi S`, `g' = S^-1 g`, `c' = c S` with `S = diag(t, I)`.
    fn change_basis(&mut self, t: [[f64; 2]; 2], tinv: [[f64; 2]; 2]) {
        let old = *self;
        // Model block: tinv Phi_mm t, set exactly diagonal.
        let pm = [
            [old.phi[0][0], old.phi[0][1]],
            [old.phi[1][0], old.phi[1][1]],
        ];
        let l = mul2(&tinv, &mul2(&pm, &t));
        self.phi[0][0] = l[0][0];
        self.phi[1][1] = l[1][1];
        self.phi[0][1] = 0.0;
        self.phi[1][0] = 0.0;
        // Integrator rows, model columns: Phi_im t.
        for r in 2..N {
            for col in 0..2 {
                self.phi[r][col] = old.phi[r][0] * t[0][col] + old.phi[r][1] * t[1][col];
            }
        }
        // Model rows never read the integrators (exact zeros of the ZOH).
        for (g, og) in [(&mut self.g0, &old.g0), (&mut self.g1, &old.g1)] {
            g[0] = tinv[0][0] * og[0] + tinv[0][1] * og[1];
            g[1] = tinv[1][0] * og[0] + tinv[1][1] * og[1];
        }
        for (c, oc) in [(&mut self.c, &old.c), (&mut self.ca, &old.ca)] {
            c[0] = oc[0] * t[0][0] + oc[1] * t[1][0];
            c[1] = oc[0] * t[0][1] + oc[1] * t[1][1];
        }
        self.t = t;
        self.tinv = tinv;
        self.diag = true;
    }

    /// Kernel coordinates of a canonical model state.
    pub fn to_kernel(&self, x: [f64; 2]) -> [f64; 2] {
        if self.t == EYE {
            return x;
        }
        [
            self.tinv[0][0] * x[0] + self.tinv[0][1] * x[1],
            self.tinv[1][0] * x[0] + self.tinv[1][1] * x[1],
        ]
    }

    /// The initial state vector: model states from `s` (canonical), then the
    /// integrators' initial values.
    pub fn state(&self, s: &Start, ints: [f64; 2]) -> [f64; N] {
        let z = self.to_kernel(s.x);
        let mut x = [0.0; N];
        x[..M].copy_from_slice(&z[..M]);
        x[M..N].copy_from_slice(&ints[..(N - M)]);
        x
    }
}

/// Plants kept per thread by [`Plant::cached`].
const CACHED_PLANTS: usize = 4;

/// What a plant is a function of, bit for bit, and its type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct CacheKey {
    bits: [u64; 7],
    ints: Integrators,
    modal: bool,
    plant: std::any::TypeId,
}

impl CacheKey {
    fn of<const M: usize, const N: usize>(
        lin: &Linear,
        ints: Integrators,
        dt: f64,
        modal: bool,
    ) -> Self {
        let bits = [lin.b1, lin.b0, lin.a2, lin.a1, lin.td, lin.k, dt].map(f64::to_bits);
        Self {
            bits,
            ints,
            modal,
            plant: std::any::TypeId::of::<Plant<M, N>>(),
        }
    }
}

type Cached = (CacheKey, Box<dyn std::any::Any>);

thread_local! {
    /// The last plants built by [`Plant::cached`] on this thread, oldest first.
    static PLANTS: std::cell::RefCell<Vec<Cached>> = const { std::cell::RefCell::new(Vec::new()) };
}

fn mul2(a: &[[f64; 2]; 2], b: &[[f64; 2]; 2]) -> [[f64; 2]; 2] {
    std::array::from_fn(|i| std::array::from_fn(|j| a[i][0] * b[0][j] + a[i][1] * b[1][j]))
}

/// A well-conditioned real eigenbasis of the 2 x 2 model block, if any.
/// A 2 x 2 matrix.
type Mat2 = [[f64; 2]; 2];

fn modal_basis<const N: usize>(d: &Discrete<N>) -> Option<(Mat2, Mat2)> {
    let (a, b, c, e) = (d.phi[0][0], d.phi[0][1], d.phi[1][0], d.phi[1][1]);
    let tr = a + e;
    let det = a * e - b * c;
    let disc = 0.25 * tr * tr - det;
    if disc.is_nan() || disc <= 0.0 {
        return None;
    }
    let s = disc.sqrt();
    // Both roots without cancellation.
    let l1 = 0.5 * tr + s.copysign(tr);
    let l2 = if l1 != 0.0 { det / l1 } else { 0.5 * tr - s };
    // Eigenvectors: (b, l - a) or (l - e, c), whichever is larger.
    let vec = |l: f64| {
        let u = [b, l - a];
        let v = [l - e, c];
        let nu = u[0].hypot(u[1]);
        let nv = v[0].hypot(v[1]);
        if nu >= nv {
            [u[0] / nu, u[1] / nu]
        } else {
            [v[0] / nv, v[1] / nv]
        }
    };
    let (v1, v2) = (vec(l1), vec(l2));
    let t = [[v1[0], v2[0]], [v1[1], v2[1]]];
    let dt = t[0][0] * t[1][1] - t[0][1] * t[1][0];
    if dt == 0.0 || !dt.is_finite() {
        return None;
    }
    let tinv = [[t[1][1] / dt, -t[0][1] / dt], [-t[1][0] / dt, t[0][0] / dt]];
    let fro = |m: &[[f64; 2]; 2]| m.iter().flatten().map(|x| x * x).sum::<f64>().sqrt();
    let cond = fro(&t) * fro(&tinv);
    if !(cond.is_finite() && cond <= MAX_MODAL_COND) {
        return None;
    }
    Some((t, tinv))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn modal_basis_diagonalizes_the_proposed_model() {
        let lin = Linear {
            b1: 6.7893,
            b0: 0.3479,
            a2: 1.2824,
            a1: 8.8157,
            td: 0.7903,
            k: 0.1008,
        };
        let canon = Plant::<2, 4>::new(&lin, Integrators::SpeedPosition, 0.05, false).unwrap();
        let modal = Plant::<2, 4>::new(&lin, Integrators::SpeedPosition, 0.05, true).unwrap();
        assert!(modal.diag && !canon.diag);
        // Same eigenvalues (trace and determinant of the model block).
        let tr = |p: &Plant<2, 4>| p.phi[0][0] + p.phi[1][1];
        let det = |p: &Plant<2, 4>| p.phi[0][0] * p.phi[1][1] - p.phi[0][1] * p.phi[1][0];
        assert!((tr(&canon) - tr(&modal)).abs() < 1e-14);
        assert!((det(&canon) - det(&modal)).abs() < 1e-14);
        // c g is basis-invariant (the Markov parameter).
        let cg = |p: &Plant<2, 4>| p.c[0] * p.g0[0] + p.c[1] * p.g0[1];
        assert!((cg(&canon) - cg(&modal)).abs() < 1e-14);
    }

    #[test]
    fn closed_form_equals_the_matrix_exponential() {
        for (lin, m2) in [
            (
                Linear {
                    b1: 6.7893,
                    b0: 0.3479,
                    a2: 1.2824,
                    a1: 8.8157,
                    td: 0.7903,
                    k: 0.1008,
                },
                true,
            ),
            (
                Linear {
                    b1: 0.0,
                    b0: 1.0,
                    a2: 0.0,
                    a1: 1.0758,
                    td: 0.0,
                    k: 0.0,
                },
                false,
            ),
        ] {
            for dt in [0.05, 0.1, 0.013] {
                if m2 {
                    let a = Plant::<2, 2>::new(&lin, Integrators::None, dt, true).unwrap();
                    let mut e = Plant::<2, 2>::from_discrete(
                        &discretize::<2>(&lin, Integrators::None, dt).unwrap(),
                        dt,
                    );
                    let (t, tinv) =
                        modal_basis(&discretize::<2>(&lin, Integrators::None, dt).unwrap())
                            .unwrap();
                    e.change_basis(t, tinv);
                    // Different eigenvector scalings: compare basis-free quantities.
                    for j in 0..2 {
                        let k = if (a.phi[j][j] - e.phi[0][0]).abs() < 1e-9 {
                            0
                        } else {
                            1
                        };
                        assert!((a.phi[j][j] - e.phi[k][k]).abs() < 1e-14);
                        let (ma, me) = (a.c[j] * a.g0[j], e.c[k] * e.g0[k]);
                        assert!((ma - me).abs() < 1e-13 * me.abs().max(1e-3), "{ma} {me}");
                        let (ma, me) = (a.c[j] * a.g1[j], e.c[k] * e.g1[k]);
                        assert!((ma - me).abs() < 1e-13 * me.abs().max(1e-3), "{ma} {me}");
                    }
                    // x = T z maps the closed form's states onto the canonical ones.
                    let x = [0.3, -0.7];
                    let z = a.to_kernel(x);
                    let back = [
                        a.t[0][0] * z[0] + a.t[0][1] * z[1],
                        a.t[1][0] * z[0] + a.t[1][1] * z[1],
                    ];
                    assert!((back[0] - x[0]).abs() < 1e-14 && (back[1] - x[1]).abs() < 1e-14);
                } else {
                    let a = Plant::<1, 1>::new(&lin, Integrators::None, dt, true).unwrap();
                    let e = Plant::<1, 1>::from_discrete(
                        &discretize::<1>(&lin, Integrators::None, dt).unwrap(),
                        dt,
                    );
                    assert!((a.phi[0][0] - e.phi[0][0]).abs() < 1e-15);
                    assert!((a.g0[0] - e.g0[0]).abs() < 1e-15);
                    assert!((a.c[0] - e.c[0]).abs() < 1e-15);
                }
            }
        }
    }

    #[test]
    fn cached_plants_are_the_plants() {
        let lin = Linear {
            b1: 6.7893,
            b0: 0.3479,
            a2: 1.2824,
            a1: 8.8157,
            td: 0.7903,
            k: 0.1008,
        };
        let bits = |p: &Plant<2, 4>| {
            let mut v: Vec<u64> = p.phi.iter().flatten().map(|x| x.to_bits()).collect();
            v.extend(p.g0.iter().chain(&p.g1).chain(&p.c).map(|x| x.to_bits()));
            v.push(p.frac.to_bits());
            v.push(p.delay as u64);
            v
        };
        let ints = Integrators::SpeedPosition;
        let want = Plant::<2, 4>::new(&lin, ints, 0.05, true).unwrap();
        for _ in 0..2 {
            assert_eq!(
                bits(&Plant::cached(&lin, ints, 0.05, true).unwrap()),
                bits(&want)
            );
        }
        // Another dt, basis, model or type is another plant; errors are not kept.
        let other = Plant::<2, 4>::new(&lin, ints, 0.1, true).unwrap();
        assert_eq!(
            bits(&Plant::cached(&lin, ints, 0.1, true).unwrap()),
            bits(&other)
        );
        let canon = Plant::<2, 4>::cached(&lin, ints, 0.05, false).unwrap();
        assert!(!canon.diag);
        let k2 = Linear { k: 0.2, ..lin };
        assert_eq!(
            bits(&Plant::cached(&k2, ints, 0.05, true).unwrap()),
            bits(&Plant::<2, 4>::new(&k2, ints, 0.05, true).unwrap())
        );
        let p2 = Plant::<2, 2>::cached(&lin, Integrators::None, 0.05, true).unwrap();
        assert_eq!(
            p2.c,
            Plant::<2, 2>::new(&lin, Integrators::None, 0.05, true)
                .unwrap()
                .c
        );
        assert!(Plant::<2, 4>::new(&lin, ints, -1.0, true).is_err());
        assert!(Plant::<2, 4>::cached(&lin, ints, -1.0, true).is_err());
        assert!(Plant::<2, 4>::cached(&lin, ints, -1.0, true).is_err());
        assert_eq!(
            bits(&Plant::cached(&lin, ints, 0.05, true).unwrap()),
            bits(&want)
        );
    }

    #[test]
    fn complex_modes_keep_the_canonical_form() {
        // The paper's second-order model: underdamped, complex discrete eigenvalues.
        let lin = Linear {
            b1: 0.0,
            b0: 0.7292,
            a2: 0.0445,
            a1: 0.1305,
            td: 0.7796,
            k: 0.0,
        };
        let p = Plant::<2, 2>::new(&lin, Integrators::None, 0.05, true).unwrap();
        assert!(!p.diag);
    }
}
