//! A real-coded genetic algorithm (GA) over a box, with a bounded Nelder–Mead for
//! its local search and polish. The calibration problem it solves (paper Section
//! III.B, Eq. 6) is in [`super::calibrate`].
//!
//! # Algorithm
//!
//! The search runs in unit coordinates `z ∈ [0, 1]^d`; each parameter maps to its
//! box `[lo, hi]` either linearly or logarithmically ([`Scale`]), so positive
//! scale parameters spanning decades (e.g. `m2`, `m3`) are searched evenly per
//! decade. A parameter with `lo == hi` is fixed.
//!
//! * initial population: a Latin hypercube in `z` (plus optional user points);
//! * selection: tournaments of `tournament` individuals;
//! * crossover: simulated binary crossover (SBX, bounded form) with distribution
//!   index `eta_c`, applied to a pair with probability `crossover_prob`, each gene
//!   exchanged with probability 1/2;
//! * mutation: bounded polynomial mutation with index `eta_m`, each gene with
//!   probability `mutation_prob` (default `1/d`);
//! * survival: (mu + lambda) — the best `pop` distinct individuals of parents and
//!   offspring (elitist by construction) — or generational with `elite` survivors;
//! * local search (memetic): every `local_every` generations a short Nelder–Mead
//!   from the best individual joins the population;
//! * stopping: `max_generations`; stall (the best improved by at most
//!   `ftol * |best|` over the last `stall_generations` generations); tolerance (the
//!   population collapsed: every coordinate's spread `< xtol` in unit coordinates);
//!   an optional `target` value; or the per-generation callback returning `false`;
//! * early abandoning: with (mu + lambda) survival, offspring are evaluated with
//!   the survival threshold as a bound ([`Objective::eval_bounded`]), shared by the
//!   threads and falling as the generation's values arrive ([`Survival`]); the
//!   calibration objective stops a rollout once its partial Eq. 6 sum exceeds it;
//! * answer: the best individual the population held that the objective admits
//!   ([`Objective::admissible`]; every point by default), so the search may pass
//!   through points that cannot be the answer (`history` and the callback follow
//!   the answer, the stall test the search); none admitted: the search's best,
//!   valued `inf`;
//! * polish (optional): a bounded Nelder–Mead (adaptive coefficients, trial points
//!   projected onto the box) from the answer, restarted once, on admissible points.
//!
//! # Reproducibility
//!
//! Every random decision of generation `g` for offspring pair `k` comes from its own
//! ChaCha8 stream keyed by `(seed, g, k)`; the initial population from the stream
//! `(seed, 0, ·)`. Fitness values are pure functions of the individual, evaluated in
//! parallel (rayon) and gathered in order, and ties are broken by index, so the
//! result is bit-identical for any number of threads. Which offspring are abandoned
//! depends on the order in which the threads finish, but only offspring that cannot
//! survive are abandoned, so the result does not.

use crate::error::{AvllError, Result};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// How a parameter maps from unit coordinates onto its bounds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scale {
    /// `x = lo + z (hi - lo)`.
    Linear,
    /// `x = lo (hi/lo)^z`; needs `lo > 0`.
    Log,
}

impl Scale {
    pub fn from_name(name: &str) -> Result<Self> {
        match name {
            "linear" | "lin" => Ok(Scale::Linear),
            "log" => Ok(Scale::Log),
            _ => Err(AvllError::new(
                "scale",
                format!("must be 'linear' or 'log', got {name:?}"),
            )),
        }
    }
}

/// A box with a scale per coordinate.
#[derive(Debug, Clone, PartialEq)]
pub struct Bounds {
    lower: Vec<f64>,
    upper: Vec<f64>,
    scale: Vec<Scale>,
}

impl Bounds {
    /// Validates and builds the box (`lo <= hi`, finite, `lo > 0` for log scale).
    pub fn new(lower: Vec<f64>, upper: Vec<f64>, scale: Vec<Scale>) -> Result<Self> {
        if lower.is_empty() {
            return Err(AvllError::new("bounds", "no parameters"));
        }
        if upper.len() != lower.len() || scale.len() != lower.len() {
            return Err(AvllError::new(
                "bounds",
                format!(
                    "lower, upper and scale have lengths {}, {}, {}",
                    lower.len(),
                    upper.len(),
                    scale.len()
                ),
            ));
        }
        for i in 0..lower.len() {
            let (lo, hi) = (lower[i], upper[i]);
            if !(lo.is_finite() && hi.is_finite()) {
                return Err(AvllError::new(
                    format!("bounds[{i}]"),
                    format!("must be finite, got [{lo}, {hi}]"),
                ));
            }
            if lo > hi {
                return Err(AvllError::new(
                    format!("bounds[{i}]"),
                    format!("lower {lo} > upper {hi}"),
                ));
            }
            if scale[i] == Scale::Log && lo <= 0.0 {
                return Err(AvllError::new(
                    format!("bounds[{i}]"),
                    format!("log scale needs a lower bound > 0, got {lo}"),
                ));
            }
        }
        Ok(Self {
            lower,
            upper,
            scale,
        })
    }

    /// Linear box.
    pub fn linear(lower: Vec<f64>, upper: Vec<f64>) -> Result<Self> {
        let n = lower.len();
        Self::new(lower, upper, vec![Scale::Linear; n])
    }

    pub fn dim(&self) -> usize {
        self.lower.len()
    }

    pub fn lower(&self) -> &[f64] {
        &self.lower
    }

    pub fn upper(&self) -> &[f64] {
        &self.upper
    }

    /// Unit coordinates to parameters.
    pub fn to_user(&self, z: &[f64], x: &mut [f64]) {
        for i in 0..z.len() {
            let (lo, hi) = (self.lower[i], self.upper[i]);
            let zi = z[i].clamp(0.0, 1.0);
            x[i] = if lo == hi {
                lo
            } else {
                match self.scale[i] {
                    Scale::Linear => lo + zi * (hi - lo),
                    Scale::Log => (lo.ln() + zi * (hi / lo).ln()).exp().clamp(lo, hi),
                }
            };
        }
    }

    /// Parameters to unit coordinates (clamped onto the box).
    pub fn to_unit(&self, x: &[f64]) -> Vec<f64> {
        (0..x.len())
            .map(|i| {
                let (lo, hi) = (self.lower[i], self.upper[i]);
                if lo == hi {
                    return 0.0;
                }
                let xi = x[i].clamp(lo, hi);
                match self.scale[i] {
                    Scale::Linear => (xi - lo) / (hi - lo),
                    Scale::Log => (xi / lo).ln() / (hi / lo).ln(),
                }
            })
            .collect()
    }
}

/// The automatic population (`pop_size = 0`): `AUTO_POP.0` individuals per parameter,
/// at least `AUTO_POP.1` (exported to Python as `_core.GA_AUTO_POP`).
pub const AUTO_POP: (usize, usize) = (16, 40);

/// The automatic population of a problem of `d` parameters (even: both numbers are).
pub fn auto_pop(d: usize) -> usize {
    (AUTO_POP.0 * d).max(AUTO_POP.1)
}

/// GA settings. `Default` gives the values documented on each field.
#[derive(Debug, Clone, PartialEq)]
pub struct GaOptions {
    /// Population size (default 0 = [`auto_pop`]; a given size is rounded up to even).
    pub pop_size: usize,
    /// Generation limit (default 300).
    pub max_generations: usize,
    /// Stall window (default 20 generations).
    pub stall_generations: usize,
    /// Relative improvement of the best over the stall window that counts as a
    /// stall (default 1e-4; the polish refines further).
    pub ftol: f64,
    /// Population spread (unit coordinates) that counts as converged (default 1e-8).
    pub xtol: f64,
    /// Stop as soon as the best value is `<= target` (default `-inf`: never).
    pub target: f64,
    /// Tournament size (default 2).
    pub tournament: usize,
    /// Probability of crossing a selected pair (default 0.9).
    pub crossover_prob: f64,
    /// SBX distribution index (default 10).
    pub eta_c: f64,
    /// Per-gene mutation probability (default 0 = `1/d`).
    pub mutation_prob: f64,
    /// Polynomial mutation index (default 20).
    pub eta_m: f64,
    /// Survival: `true` (default) keeps the best `pop` of parents and offspring
    /// together ((mu + lambda), elitist by construction); `false` replaces the
    /// population by its offspring except the `elite` best.
    pub plus: bool,
    /// Individuals kept unchanged each generation when `plus` is false (default
    /// 0 = `max(2, pop/20)`).
    pub elite: usize,
    pub seed: u64,
    /// Nelder–Mead polish of the best individual (default true).
    pub polish: bool,
    /// Evaluation budget of the polish (default 0 = `400 d`).
    pub polish_max_evals: usize,
    /// Every `local_every` generations a short Nelder–Mead from the best individual
    /// joins the population (Lamarckian local search; default 3, 0 = never). It
    /// speeds the crawl along the curved valleys where the model's parameters trade
    /// off, which coordinate-wise crossover handles poorly.
    pub local_every: usize,
    /// Evaluation budget of each local search (default 0 = `20 d`).
    pub local_evals: usize,
    /// Starting points (parameter coordinates) that replace the first individuals.
    pub initial: Vec<Vec<f64>>,
}

impl Default for GaOptions {
    fn default() -> Self {
        Self {
            pop_size: 0,
            max_generations: 300,
            stall_generations: 20,
            ftol: 1e-4,
            xtol: 1e-8,
            target: f64::NEG_INFINITY,
            tournament: 2,
            crossover_prob: 0.9,
            eta_c: 10.0,
            mutation_prob: 0.0,
            eta_m: 20.0,
            plus: true,
            elite: 0,
            seed: 0,
            polish: true,
            polish_max_evals: 0,
            local_every: 3,
            local_evals: 0,
            initial: Vec::new(),
        }
    }
}

impl GaOptions {
    pub(crate) fn validate(&self, d: usize) -> Result<()> {
        let prob = |n: &str, p: f64| -> Result<()> {
            if (0.0..=1.0).contains(&p) {
                Ok(())
            } else {
                Err(AvllError::new(n, format!("must be in [0, 1], got {p}")))
            }
        };
        prob("crossover_prob", self.crossover_prob)?;
        prob("mutation_prob", self.mutation_prob)?;
        crate::error::check_positive("eta_c", self.eta_c)?;
        crate::error::check_positive("eta_m", self.eta_m)?;
        crate::error::check_nonneg("ftol", self.ftol)?;
        crate::error::check_nonneg("xtol", self.xtol)?;
        if self.target.is_nan() {
            return Err(AvllError::new("target", "is NaN"));
        }
        if self.pop_size == 1 || self.pop_size > 1_000_000 {
            return Err(AvllError::new(
                "pop_size",
                format!("must be 0 (automatic) or in 2..=1e6, got {}", self.pop_size),
            ));
        }
        if self.tournament == 0 {
            return Err(AvllError::new("tournament", "must be >= 1"));
        }
        if self.stall_generations == 0 {
            return Err(AvllError::new("stall_generations", "must be >= 1"));
        }
        for (k, x) in self.initial.iter().enumerate() {
            if x.len() != d {
                return Err(AvllError::new(
                    format!("initial[{k}]"),
                    format!("has {} values, expected {d}", x.len()),
                ));
            }
            if x.iter().any(|v| !v.is_finite()) {
                return Err(AvllError::new(format!("initial[{k}]"), "is not finite"));
            }
        }
        Ok(())
    }

    fn pop(&self, d: usize) -> usize {
        let p = if self.pop_size == 0 {
            auto_pop(d)
        } else {
            self.pop_size
        };
        p + p % 2
    }

    fn n_elite(&self, pop: usize) -> usize {
        let e = if self.elite == 0 {
            (pop / 20).max(2)
        } else {
            self.elite
        };
        e.min(pop - 1)
    }
}

/// Which stage reports progress.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    Ga,
    Polish,
}

/// What the callback sees after each generation (and each polish iteration).
#[derive(Debug, Clone, Copy)]
pub struct Progress<'a> {
    pub phase: Phase,
    /// Generation (GA) or iteration (polish) number, from 1.
    pub iteration: usize,
    pub evaluations: usize,
    pub best_f: f64,
    /// The best parameters so far (parameter coordinates).
    pub best_x: &'a [f64],
}

/// Why the run stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopReason {
    MaxGenerations,
    Stall,
    Tolerance,
    Target,
    /// The callback returned `false` (e.g. Ctrl-C); the result is the best so far.
    Callback,
}

impl StopReason {
    pub fn name(self) -> &'static str {
        match self {
            StopReason::MaxGenerations => "max_generations",
            StopReason::Stall => "stall",
            StopReason::Tolerance => "tolerance",
            StopReason::Target => "target",
            StopReason::Callback => "interrupted",
        }
    }
}

/// Result of [`minimize`].
#[derive(Debug, Clone, PartialEq)]
pub struct GaResult {
    /// Best parameters (parameter coordinates) and their value.
    pub x: Vec<f64>,
    pub f: f64,
    /// Best value at the end of the GA, before the polish.
    pub f_ga: f64,
    pub generations: usize,
    pub evaluations: usize,
    pub stop: StopReason,
    /// Best value after each generation (index 0: the initial population).
    pub history: Vec<f64>,
}

const TAG_INIT: u64 = 0x494e_4954;
const TAG_LHS: u64 = 0x004c_4853;
const TAG_BREED: u64 = 0x0042_5245_4544;

/// The random stream of `(seed, generation, index, purpose)`.
fn stream(seed: u64, generation: u64, index: u64, tag: u64) -> ChaCha8Rng {
    let mut key = [0u8; 32];
    key[..8].copy_from_slice(&seed.to_le_bytes());
    key[8..16].copy_from_slice(&generation.to_le_bytes());
    key[16..24].copy_from_slice(&index.to_le_bytes());
    key[24..].copy_from_slice(&tag.to_le_bytes());
    ChaCha8Rng::from_seed(key)
}

/// A sub-seed for problem `k` of a batch.
pub fn derive_seed(seed: u64, k: u64) -> u64 {
    let mut r = stream(seed, u64::MAX, k, 0x0053_5542_5345_4544);
    r.random::<u64>()
}

#[inline]
fn clean(f: f64) -> f64 {
    if f.is_nan() {
        f64::INFINITY
    } else {
        f
    }
}

/// Bounded SBX on one gene pair in [0, 1].
fn sbx(p1: f64, p2: f64, eta: f64, u: f64) -> (f64, f64) {
    let (y1, y2) = if p1 < p2 { (p1, p2) } else { (p2, p1) };
    let dy = y2 - y1;
    if dy < 1e-14 {
        return (p1, p2);
    }
    let e1 = 1.0 / (eta + 1.0);
    let betaq = |beta: f64| {
        let alpha = 2.0 - beta.powf(-(eta + 1.0));
        if u <= 1.0 / alpha {
            (u * alpha).powf(e1)
        } else {
            (1.0 / (2.0 - u * alpha)).powf(e1)
        }
    };
    let c1 = 0.5 * (y1 + y2 - betaq(1.0 + 2.0 * y1 / dy) * dy);
    let c2 = 0.5 * (y1 + y2 + betaq(1.0 + 2.0 * (1.0 - y2) / dy) * dy);
    (c1.clamp(0.0, 1.0), c2.clamp(0.0, 1.0))
}

/// Bounded polynomial mutation of one gene in [0, 1].
fn poly_mutation(y: f64, eta: f64, u: f64) -> f64 {
    let p = eta + 1.0;
    let dq = if u < 0.5 {
        let xy = 1.0 - y;
        (2.0 * u + (1.0 - 2.0 * u) * xy.powf(p)).powf(1.0 / p) - 1.0
    } else {
        let xy = y;
        1.0 - (2.0 * (1.0 - u) + 2.0 * (u - 0.5) * xy.powf(p)).powf(1.0 / p)
    };
    (y + dq).clamp(0.0, 1.0)
}

/// An objective for [`minimize`]. Any `Fn(&[f64]) -> f64 + Sync` is one; an
/// objective may also implement `eval_bounded`, which may stop early and return
/// any value `>= bound` once the result is known to be at least `bound` (the GA
/// uses it for offspring that cannot survive).
pub trait Objective: Sync {
    fn eval(&self, x: &[f64]) -> f64;
    fn eval_bounded(&self, x: &[f64], bound: f64) -> f64 {
        let _ = bound;
        self.eval(x)
    }
    /// The values of many points: `eval` (infinite `bound`) or `eval_bounded` of each,
    /// in order. The default evaluates them in parallel one by one; an objective may
    /// batch them (e.g. several points stepped together) as long as every value is
    /// the one `eval`/`eval_bounded` would give, so the result does not depend on how
    /// the points are grouped or on the number of threads.
    fn eval_many(&self, xs: &[Vec<f64>], bound: f64) -> Vec<f64> {
        xs.par_iter()
            .map(|x| {
                if bound.is_finite() {
                    self.eval_bounded(x, bound)
                } else {
                    self.eval(x)
                }
            })
            .collect()
    }
    /// The values of a generation's offspring (distinct points, none equal to a
    /// parent), each `eval_bounded` at the survival bound current when it starts
    /// (or read again between parts of its evaluation), every value offered to
    /// `survival` as soon as it is known. The default evaluates the points in
    /// parallel one by one. Which points are abandoned depends on timing, but only
    /// points that cannot survive are (see [`Survival`]), so the GA's result does not.
    fn eval_offspring(&self, xs: &[Vec<f64>], survival: &Survival) -> Vec<f64> {
        xs.par_iter().map(|x| survival.evaluate(self, x)).collect()
    }
    /// Whether `x` (parameter coordinates) may be the answer. The GA searches on the
    /// values alone and returns the best admissible individual its population held
    /// (see [`minimize`]); the polish stays on admissible points. The default admits
    /// every point. The calibration's closed loop admits only locally stable loops: an
    /// unstable one that fits the record steers the search, it is never the answer.
    fn admissible(&self, x: &[f64]) -> bool {
        let _ = x;
        true
    }
}

/// The (mu + lambda) survival threshold of one generation while its offspring are
/// evaluated, shared by the threads evaluating them: the `n`-th best distinct value
/// among the parents (clones — equal individuals with equal values — counted once)
/// and the offspring whose values are known so far; `inf` while there are fewer
/// than `n`. It only falls as values arrive and it is never below the threshold of
/// the whole generation, so an offspring whose value exceeds it is not among the
/// survivors, whenever during the generation the comparison is made: the `n`
/// individuals at or below the threshold rank before it whatever their index.
///
/// [`Survival::bound`] is the threshold raised by a relative `1e-9` (plus the
/// smallest normal number): a value that reaches it exceeds the threshold
/// strictly even after the rounding of an objective's partial sums, so an
/// offspring tied with a later one (which it would outrank by index) is never
/// abandoned.
pub struct Survival {
    n: usize,
    /// The parents' distinct finite values, sorted.
    parents: Vec<f64>,
    /// The offspring's finite values offered so far that are below the threshold
    /// of the moment, sorted.
    kids: std::sync::Mutex<Vec<f64>>,
    /// `bound()`'s bits.
    bound: std::sync::atomic::AtomicU64,
}

impl Survival {
    /// The threshold of selecting `n` from the parents `pop` with values `fit`.
    pub fn new(pop: &[Vec<f64>], fit: &[f64], n: usize) -> Self {
        let mut idx: Vec<usize> = (0..pop.len()).filter(|&i| fit[i].is_finite()).collect();
        idx.sort_by(|&a, &b| fit[a].total_cmp(&fit[b]).then(a.cmp(&b)));
        let mut parents = Vec::with_capacity(idx.len());
        for (q, &i) in idx.iter().enumerate() {
            let clone = idx[..q]
                .iter()
                .rev()
                .take_while(|&&k| fit[k] == fit[i])
                .any(|&k| pop[k] == pop[i]);
            if !clone {
                parents.push(fit[i]);
            }
        }
        let s = Self {
            n,
            parents,
            kids: std::sync::Mutex::new(Vec::new()),
            bound: std::sync::atomic::AtomicU64::new(0),
        };
        s.bound.store(
            Self::raised(s.threshold_with(&[])).to_bits(),
            std::sync::atomic::Ordering::Relaxed,
        );
        s
    }

    /// The value at which an offspring's evaluation may stop (see the type).
    pub fn bound(&self) -> f64 {
        f64::from_bits(self.bound.load(std::sync::atomic::Ordering::Relaxed))
    }

    /// `f`'s value of one offspring, `eval_bounded` at the current bound (`eval`
    /// while it is infinite), offered.
    pub fn evaluate<F: Objective + ?Sized>(&self, f: &F, x: &[f64]) -> f64 {
        let bound = self.bound();
        let v = if bound.is_finite() {
            f.eval_bounded(x, bound)
        } else {
            f.eval(x)
        };
        self.offer(v);
        v
    }

    /// Records an offspring's value (an abandoned or infinite one changes nothing).
    pub fn offer(&self, v: f64) {
        if v.is_nan() || v >= self.bound() {
            return;
        }
        // A poisoned lock only means another evaluating thread panicked; the values
        // it holds are still valid.
        let mut kids = self.kids.lock().unwrap_or_else(|e| e.into_inner());
        let at = kids.partition_point(|&k| k <= v);
        kids.insert(at, v);
        let t = self.threshold_with(&kids);
        if kids.len() > self.n {
            kids.truncate(self.n);
        }
        self.bound.store(
            Self::raised(t).to_bits(),
            std::sync::atomic::Ordering::Relaxed,
        );
    }

    /// The `n`-th smallest of the parents' distinct values and `kids` (sorted).
    fn threshold_with(&self, kids: &[f64]) -> f64 {
        let (mut i, mut j) = (0, 0);
        for _ in 1..self.n {
            match (self.parents.get(i), kids.get(j)) {
                (Some(p), Some(k)) if p <= k => i += 1,
                (Some(_), None) => i += 1,
                (_, Some(_)) => j += 1,
                (None, None) => return f64::INFINITY,
            }
        }
        match (self.parents.get(i), kids.get(j)) {
            (Some(&p), Some(&k)) => p.min(k),
            (Some(&p), None) => p,
            (None, Some(&k)) => k,
            (None, None) => f64::INFINITY,
        }
    }

    fn raised(t: f64) -> f64 {
        if t.is_finite() {
            t + t.abs() * 1e-9 + f64::MIN_POSITIVE
        } else {
            f64::INFINITY
        }
    }

    /// The threshold itself (without the margin of [`Survival::bound`]).
    #[cfg(test)]
    fn threshold(&self) -> f64 {
        let kids = self.kids.lock().unwrap_or_else(|e| e.into_inner());
        self.threshold_with(&kids)
    }
}

impl<F: Fn(&[f64]) -> f64 + Sync> Objective for F {
    fn eval(&self, x: &[f64]) -> f64 {
        self(x)
    }
}

/// `f` on its admissible points, `inf` elsewhere: the polish's objective.
struct AdmissibleOnly<'a, F: ?Sized>(&'a F);

impl<F: Objective + ?Sized> Objective for AdmissibleOnly<'_, F> {
    fn eval(&self, x: &[f64]) -> f64 {
        if self.0.admissible(x) {
            self.0.eval(x)
        } else {
            f64::INFINITY
        }
    }
    fn eval_bounded(&self, x: &[f64], bound: f64) -> f64 {
        if self.0.admissible(x) {
            self.0.eval_bounded(x, bound)
        } else {
            f64::INFINITY
        }
    }
}

/// The best admissible individual the population has held ([`Objective::admissible`]):
/// the GA's answer. Each distinct individual is tested once.
struct Answer {
    z: Option<Vec<f64>>,
    f: f64,
    tested: std::collections::HashMap<Vec<u64>, bool>,
}

impl Answer {
    fn new() -> Self {
        Self {
            z: None,
            f: f64::INFINITY,
            tested: std::collections::HashMap::new(),
        }
    }

    /// Takes the best admissible individual of `pop` (sorted by `fit`) that is better
    /// than the answer so far.
    fn update<F: Objective + ?Sized>(
        &mut self,
        f: &F,
        bounds: &Bounds,
        pop: &[Vec<f64>],
        fit: &[f64],
    ) {
        let mut x = vec![0.0; bounds.dim()];
        for (z, &v) in pop.iter().zip(fit) {
            if v.partial_cmp(&self.f) != Some(std::cmp::Ordering::Less) {
                return; // sorted: no better one follows (inf and NaN included)
            }
            let key: Vec<u64> = z.iter().map(|c| c.to_bits()).collect();
            let ok = *self.tested.entry(key).or_insert_with(|| {
                bounds.to_user(z, &mut x);
                f.admissible(&x)
            });
            if ok {
                self.z = Some(z.clone());
                self.f = v;
                return;
            }
        }
    }
}

struct Evaluator<'a, F: ?Sized> {
    f: &'a F,
    bounds: &'a Bounds,
    evaluations: usize,
}

impl<F: Objective + ?Sized> Evaluator<'_, F> {
    fn one(&mut self, z: &[f64]) -> f64 {
        self.evaluations += 1;
        let mut x = vec![0.0; z.len()];
        self.bounds.to_user(z, &mut x);
        clean(self.f.eval(&x))
    }

    fn many(&mut self, zs: &[Vec<f64>]) -> Vec<f64> {
        self.many_bounded(zs, f64::INFINITY)
    }

    fn many_bounded(&mut self, zs: &[Vec<f64>], bound: f64) -> Vec<f64> {
        self.many_known(zs, bound, &[], &[])
    }

    /// [`Self::many_bounded`] that evaluates each distinct point once: a point equal
    /// (in parameter coordinates, bit for bit) to one of `known` (with values
    /// `known_f`, exact) or to an earlier point of `zs` takes that value without
    /// an evaluation. Only distinct new points count as evaluations.
    fn many_known(
        &mut self,
        zs: &[Vec<f64>],
        bound: f64,
        known: &[Vec<f64>],
        known_f: &[f64],
    ) -> Vec<f64> {
        let f = self.f;
        self.dedup_eval(zs, known, known_f, |todo| f.eval_many(todo, bound))
    }

    /// A generation's offspring `zs` against the parents `pop` (values `fit`, exact)
    /// with (mu + lambda) survival of `n`: [`Self::many_known`] with the shared
    /// survival bound ([`Objective::eval_offspring`]).
    fn offspring(&mut self, zs: &[Vec<f64>], pop: &[Vec<f64>], fit: &[f64], n: usize) -> Vec<f64> {
        let survival = Survival::new(pop, fit, n);
        let f = self.f;
        self.dedup_eval(zs, pop, fit, |todo| f.eval_offspring(todo, &survival))
    }

    /// `zs`' values, each distinct point not in `known` evaluated once by `eval`.
    fn dedup_eval(
        &mut self,
        zs: &[Vec<f64>],
        known: &[Vec<f64>],
        known_f: &[f64],
        eval: impl FnOnce(&[Vec<f64>]) -> Vec<f64>,
    ) -> Vec<f64> {
        let b = self.bounds;
        let user = |z: &Vec<f64>| {
            let mut x = vec![0.0; z.len()];
            b.to_user(z, &mut x);
            x
        };
        let key = |x: &[f64]| x.iter().map(|v| v.to_bits()).collect::<Vec<u64>>();
        let mut seen: std::collections::HashMap<Vec<u64>, usize> =
            std::collections::HashMap::with_capacity(known.len() + zs.len());
        let mut vals: Vec<f64> = Vec::with_capacity(known.len() + zs.len());
        for (z, &f) in known.iter().zip(known_f) {
            if f.is_finite() {
                seen.entry(key(&user(z))).or_insert_with(|| {
                    vals.push(f);
                    vals.len() - 1
                });
            }
        }
        let mut todo: Vec<Vec<f64>> = Vec::with_capacity(zs.len());
        let mut slot: Vec<usize> = Vec::with_capacity(zs.len());
        for z in zs {
            let x = user(z);
            let n = vals.len() + todo.len();
            let s = *seen.entry(key(&x)).or_insert_with(|| {
                todo.push(x);
                n
            });
            slot.push(s);
        }
        self.evaluations += todo.len();
        let fresh = eval(&todo);
        vals.extend(fresh.into_iter().map(clean));
        slot.into_iter().map(|s| vals[s]).collect()
    }
}

/// Sorts a population by value (stable: ties keep their order).
fn sort_pop(pop: &mut Vec<Vec<f64>>, fit: &mut Vec<f64>) {
    let mut idx: Vec<usize> = (0..pop.len()).collect();
    idx.sort_by(|&a, &b| fit[a].total_cmp(&fit[b]).then(a.cmp(&b)));
    *pop = idx.iter().map(|&i| std::mem::take(&mut pop[i])).collect();
    *fit = idx.iter().map(|&i| fit[i]).collect();
}

/// Initial Nelder–Mead steps per coordinate: the spread of the best tenth of the
/// population, clamped to [1e-4, 0.05] in unit coordinates.
fn simplex_steps(pop: &[Vec<f64>], n: usize, d: usize) -> Vec<f64> {
    let top = (n / 10).max(d + 1).min(n);
    (0..d)
        .map(|j| {
            let (lo, hi) = pop[..top]
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |s, z| {
                    (s.0.min(z[j]), s.1.max(z[j]))
                });
            (hi - lo).clamp(1e-4, 0.05)
        })
        .collect()
}

/// Keeps the best `n` of a sorted population, preferring distinct individuals
/// (clones of a kept individual only fill up when too few distinct ones remain).
fn survive_unique(pop: &mut Vec<Vec<f64>>, fit: &mut Vec<f64>, n: usize) {
    let mut keep: Vec<usize> = Vec::with_capacity(pop.len());
    let mut dup: Vec<usize> = Vec::new();
    for i in 0..pop.len() {
        let clone = keep
            .iter()
            .rev()
            .take_while(|&&k| fit[k] == fit[i])
            .any(|&k| pop[k] == pop[i]);
        if clone {
            dup.push(i);
        } else {
            keep.push(i);
        }
    }
    keep.extend(dup);
    keep.truncate(n);
    keep.sort_unstable();
    *pop = keep.iter().map(|&i| std::mem::take(&mut pop[i])).collect();
    *fit = keep.iter().map(|&i| fit[i]).collect();
}

/// Minimises `f` over `bounds` (see the module documentation). `callback` runs after
/// every generation and polish iteration on the calling thread; returning `false`
/// stops the run, which then returns the best so far with [`StopReason::Callback`].
/// Fitness evaluations run in parallel on the current rayon pool.
pub fn minimize<F>(
    f: &F,
    bounds: &Bounds,
    opts: &GaOptions,
    mut callback: impl FnMut(&Progress) -> bool,
) -> Result<GaResult>
where
    F: Objective + ?Sized,
{
    let d = bounds.dim();
    opts.validate(d)?;
    let n = opts.pop(d);
    let n_elite = opts.n_elite(n);
    let pm = if opts.mutation_prob > 0.0 {
        opts.mutation_prob
    } else {
        1.0 / d as f64
    };
    let mut ev = Evaluator {
        f,
        bounds,
        evaluations: 0,
    };

    // Initial population: Latin hypercube, then the user's points.
    let mut lhs = stream(opts.seed, 0, 0, TAG_LHS);
    let mut pop = vec![vec![0.0; d]; n];
    for j in 0..d {
        let mut perm: Vec<usize> = (0..n).collect();
        for i in (1..n).rev() {
            let k = lhs.random_range(0..=i);
            perm.swap(i, k);
        }
        for (i, ind) in pop.iter_mut().enumerate() {
            let mut r = stream(opts.seed, 0, i as u64, TAG_INIT ^ j as u64);
            ind[j] = (perm[i] as f64 + r.random::<f64>()) / n as f64;
        }
    }
    for (ind, x) in pop.iter_mut().zip(&opts.initial) {
        *ind = bounds.to_unit(x);
    }
    let mut fit = ev.many(&pop);
    sort_pop(&mut pop, &mut fit);
    let mut answer = Answer::new();
    answer.update(f, bounds, &pop, &fit);
    let mut history = vec![answer.f];
    // The search's own best per generation (the stall test): below `history` where
    // inadmissible individuals lead the population.
    let mut search = vec![fit[0]];
    let mut x_best = vec![0.0; d];
    let mut stop = StopReason::MaxGenerations;
    let mut generation = 0;

    let mut stopped_by_callback = false;
    while generation < opts.max_generations {
        if answer.f <= opts.target {
            stop = StopReason::Target;
            break;
        }
        generation += 1;
        let n_off = if opts.plus { n } else { n - n_elite };
        let pairs = n_off.div_ceil(2);
        let g = generation as u64;
        let (popr, fitr) = (&pop, &fit);
        // Breeding is cheap: on the calling thread (no rendezvous of threads).
        let children: Vec<[Vec<f64>; 2]> = (0..pairs)
            .map(|k| {
                let mut r = stream(opts.seed, g, k as u64, TAG_BREED);
                let mut pick = || {
                    let mut best = r.random_range(0..n);
                    for _ in 1..opts.tournament {
                        let c = r.random_range(0..n);
                        if fitr[c] < fitr[best] || (fitr[c] == fitr[best] && c < best) {
                            best = c;
                        }
                    }
                    best
                };
                let (a, b) = (pick(), pick());
                let mut c1 = popr[a].clone();
                let mut c2 = popr[b].clone();
                if r.random::<f64>() < opts.crossover_prob {
                    for j in 0..d {
                        let u = r.random::<f64>();
                        if r.random::<f64>() < 0.5 {
                            let (y1, y2) = sbx(c1[j], c2[j], opts.eta_c, u);
                            if r.random::<f64>() < 0.5 {
                                c1[j] = y1;
                                c2[j] = y2;
                            } else {
                                c1[j] = y2;
                                c2[j] = y1;
                            }
                        }
                    }
                }
                for c in [&mut c1, &mut c2] {
                    for v in c.iter_mut() {
                        let u = r.random::<f64>();
                        if r.random::<f64>() < pm {
                            *v = poly_mutation(*v, opts.eta_m, u);
                        }
                    }
                }
                [c1, c2]
            })
            .collect();
        let mut kids: Vec<Vec<f64>> = children.into_iter().flatten().take(n_off).collect();
        // (mu + lambda): an offspring whose value exceeds the survival threshold (the
        // n-th best distinct value among the parents and the offspring evaluated so
        // far, shared by the threads and falling as values arrive) cannot survive,
        // so its evaluation may stop early (exact values otherwise).
        let kid_fit = if opts.plus {
            ev.offspring(&kids, &pop, &fit, n)
        } else {
            ev.many_known(&kids, f64::INFINITY, &pop, &fit)
        };
        if !opts.plus {
            pop.truncate(n_elite);
            fit.truncate(n_elite);
        }
        pop.append(&mut kids);
        fit.extend(kid_fit);
        sort_pop(&mut pop, &mut fit);
        if opts.plus {
            survive_unique(&mut pop, &mut fit, n);
        }
        if opts.local_every > 0
            && generation % opts.local_every == 0
            && fit[0].is_finite()
            && fit[0] > opts.target
        {
            // Lamarckian local search: a short Nelder–Mead from the best individual,
            // whose result joins the population (the worst individual leaves). It
            // stops at the target, like the generations.
            let step = simplex_steps(&pop, n, d);
            let budget = if opts.local_evals == 0 {
                20 * d
            } else {
                opts.local_evals
            };
            let (z, fz) = nelder_mead(&mut ev, &pop[0], fit[0], &step, budget, |_, _, fb| {
                fb > opts.target
            });
            if fz < fit[0] {
                pop.insert(0, z);
                fit.insert(0, fz);
                pop.truncate(n);
                fit.truncate(n);
            }
        }
        answer.update(f, bounds, &pop, &fit);
        history.push(answer.f);
        search.push(fit[0]);

        bounds.to_user(answer.z.as_ref().unwrap_or(&pop[0]), &mut x_best);
        let go_on = callback(&Progress {
            phase: Phase::Ga,
            iteration: generation,
            evaluations: ev.evaluations,
            best_f: answer.f,
            best_x: &x_best,
        });
        if !go_on {
            stop = StopReason::Callback;
            stopped_by_callback = true;
            break;
        }
        if generation >= opts.stall_generations {
            let old = search[generation - opts.stall_generations];
            let new = fit[0];
            let stalled = if old.is_finite() {
                old - new <= opts.ftol * new.abs().max(1e-300)
            } else {
                !new.is_finite()
            };
            if stalled {
                stop = StopReason::Stall;
                break;
            }
        }
        let spread = (0..d)
            .map(|j| {
                let (lo, hi) = pop.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |s, z| {
                    (s.0.min(z[j]), s.1.max(z[j]))
                });
                hi - lo
            })
            .fold(0.0, f64::max);
        if spread < opts.xtol {
            stop = StopReason::Tolerance;
            break;
        }
    }
    if stop == StopReason::MaxGenerations && answer.f <= opts.target {
        stop = StopReason::Target;
    }
    // No admissible individual: the search's best, valued `inf` (the caller's cost of
    // an inadmissible point; e.g. a locally unstable closed loop).
    let f_ga = answer.f;
    let mut f_best = answer.f;
    let mut z_best = answer.z.take().unwrap_or_else(|| pop[0].clone());
    let only = AdmissibleOnly(f);
    let mut ev = Evaluator {
        f: &only,
        bounds,
        evaluations: ev.evaluations,
    };

    if opts.polish && !stopped_by_callback && stop != StopReason::Target && f_best.is_finite() {
        let step = simplex_steps(&pop, n, d);
        let budget = if opts.polish_max_evals == 0 {
            400 * d
        } else {
            opts.polish_max_evals
        };
        let mut it = 0usize;
        let mut interrupted = false;
        let start_evals = ev.evaluations;
        for restart in 0..2 {
            let used = ev.evaluations - start_evals;
            if used >= budget || interrupted {
                break;
            }
            let scale = if restart == 0 { 1.0 } else { 0.2 };
            let steps: Vec<f64> = step.iter().map(|s| s * scale).collect();
            let (z, fz) = nelder_mead(
                &mut ev,
                &z_best,
                f_best,
                &steps,
                budget - used,
                |e, zb, fb| {
                    it += 1;
                    bounds.to_user(zb, &mut x_best);
                    let ok = callback(&Progress {
                        phase: Phase::Polish,
                        iteration: it,
                        evaluations: e,
                        best_f: fb,
                        best_x: &x_best,
                    });
                    if !ok {
                        interrupted = true;
                    }
                    ok
                },
            );
            if fz < f_best {
                z_best = z;
                f_best = fz;
            }
        }
        if interrupted {
            stop = StopReason::Callback;
        }
    }
    let mut x = vec![0.0; d];
    bounds.to_user(&z_best, &mut x);
    Ok(GaResult {
        x,
        f: f_best,
        f_ga,
        generations: generation,
        evaluations: ev.evaluations,
        stop,
        history,
    })
}

/// The GA's bounded Nelder–Mead alone, from the point `x0` (parameter coordinates)
/// whose value `f0` is known: initial steps `step` in unit coordinates (one per
/// coordinate), at most `budget` evaluations. `callback(evaluations, best)` runs
/// after every iteration; `false` stops. Returns the best point (parameter
/// coordinates), its value and the evaluations used. A second stage after the GA
/// (e.g. refits of resampled costs warm-started from the full-data optimum).
pub fn local_search<F: Objective + ?Sized>(
    f: &F,
    bounds: &Bounds,
    x0: &[f64],
    f0: f64,
    step: &[f64],
    budget: usize,
    mut callback: impl FnMut(usize, f64) -> bool,
) -> (Vec<f64>, f64, usize) {
    let mut ev = Evaluator {
        f,
        bounds,
        evaluations: 0,
    };
    let z0 = bounds.to_unit(x0);
    let (z, fz) = nelder_mead(&mut ev, &z0, clean(f0), step, budget, |e, _, fb| {
        callback(e, fb)
    });
    let mut x = vec![0.0; z.len()];
    bounds.to_user(&z, &mut x);
    (x, fz, ev.evaluations)
}

/// Bounded Nelder–Mead in unit coordinates with the adaptive coefficients of Gao
/// and Han (2012); trial points are projected onto `[0, 1]^d`. Stops on the budget,
/// a collapsed simplex (size `< 1e-10`, values within `1e-12` relative) or the
/// callback returning `false`.
fn nelder_mead<F: Objective + ?Sized>(
    ev: &mut Evaluator<'_, F>,
    z0: &[f64],
    f0: f64,
    step: &[f64],
    budget: usize,
    mut callback: impl FnMut(usize, &[f64], f64) -> bool,
) -> (Vec<f64>, f64) {
    let d = z0.len();
    let nd = d as f64;
    let (alpha, gamma) = (1.0, 1.0 + 2.0 / nd);
    let (rho, sigma) = (0.75 - 0.5 / nd, 1.0 - 1.0 / nd.max(2.0));
    let proj = |z: &mut Vec<f64>| z.iter_mut().for_each(|v| *v = v.clamp(0.0, 1.0));
    let mut simplex: Vec<Vec<f64>> = vec![z0.to_vec()];
    for j in 0..d {
        let mut z = z0.to_vec();
        z[j] = if z[j] + step[j] <= 1.0 {
            z[j] + step[j]
        } else {
            z[j] - step[j]
        };
        simplex.push(z);
    }
    let start = ev.evaluations;
    let mut fs = vec![f0];
    fs.extend(ev.many(&simplex[1..]));
    let order = |s: &mut Vec<Vec<f64>>, f: &mut Vec<f64>| sort_pop(s, f);
    order(&mut simplex, &mut fs);
    while ev.evaluations - start < budget {
        let size = (1..=d)
            .map(|i| {
                simplex[i]
                    .iter()
                    .zip(&simplex[0])
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max)
            })
            .fold(0.0, f64::max);
        let frange = fs[d] - fs[0];
        if size < 1e-10 || (fs[d].is_finite() && frange <= 1e-12 * fs[0].abs().max(1e-300)) {
            break;
        }
        let mut cen = vec![0.0; d];
        for z in &simplex[..d] {
            for j in 0..d {
                cen[j] += z[j] / nd;
            }
        }
        let towards = |t: f64| {
            let mut z: Vec<f64> = (0..d)
                .map(|j| cen[j] + t * (simplex[d][j] - cen[j]))
                .collect();
            proj(&mut z);
            z
        };
        let zr = towards(-alpha);
        let fr = ev.one(&zr);
        if fr < fs[0] {
            let ze = towards(-gamma);
            let fe = ev.one(&ze);
            if fe < fr {
                simplex[d] = ze;
                fs[d] = fe;
            } else {
                simplex[d] = zr;
                fs[d] = fr;
            }
        } else if fr < fs[d - 1] {
            simplex[d] = zr;
            fs[d] = fr;
        } else {
            let (zc, fc) = if fr < fs[d] {
                let z = towards(-rho * alpha);
                let f = ev.one(&z);
                (z, f)
            } else {
                let z = towards(rho);
                let f = ev.one(&z);
                (z, f)
            };
            if fc < fs[d].min(fr) {
                simplex[d] = zc;
                fs[d] = fc;
            } else {
                let best = simplex[0].clone();
                for z in simplex.iter_mut().skip(1) {
                    for j in 0..d {
                        z[j] = best[j] + sigma * (z[j] - best[j]);
                    }
                }
                let new = ev.many(&simplex[1..]);
                fs[1..].copy_from_slice(&new);
            }
        }
        order(&mut simplex, &mut fs);
        if !callback(ev.evaluations, &simplex[0], fs[0]) {
            break;
        }
    }
    (simplex.swap_remove(0), fs[0])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sphere(x: &[f64]) -> f64 {
        x.iter().map(|v| (v - 0.3) * (v - 0.3)).sum()
    }

    fn rosenbrock(x: &[f64]) -> f64 {
        x.windows(2)
            .map(|w| 100.0 * (w[1] - w[0] * w[0]).powi(2) + (1.0 - w[0]).powi(2))
            .sum()
    }

    #[test]
    fn sphere_converges() {
        let b = Bounds::linear(vec![-5.0; 5], vec![5.0; 5]).unwrap();
        let o = GaOptions {
            polish: false,
            max_generations: 400,
            ..Default::default()
        };
        let r = minimize(&sphere, &b, &o, |_| true).unwrap();
        // The GA alone gets close (it finds the basin); the polish finishes.
        assert!(r.f < 1e-4, "f = {} {:?} {}", r.f, r.stop, r.generations);
        for v in &r.x {
            assert!((v - 0.3).abs() < 1e-2);
        }
        assert!(r.history.windows(2).all(|w| w[1] <= w[0]), "elitism");
        let p = minimize(&sphere, &b, &GaOptions::default(), |_| true).unwrap();
        assert!(p.f < 1e-12 && p.f <= p.f_ga, "polished f = {}", p.f);
    }

    /// A sphere centred at 0.3 whose answers must lie in `x[0] <= cut`.
    struct Fenced {
        cut: f64,
    }

    impl Objective for Fenced {
        fn eval(&self, x: &[f64]) -> f64 {
            sphere(x)
        }
        fn admissible(&self, x: &[f64]) -> bool {
            x[0] <= self.cut
        }
    }

    #[test]
    fn the_answer_is_the_best_admissible_point() {
        let b = Bounds::linear(vec![-5.0; 3], vec![5.0; 3]).unwrap();
        let free = minimize(&sphere, &b, &GaOptions::default(), |_| true).unwrap();
        assert!((free.x[0] - 0.3).abs() < 1e-3);
        // The unconstrained minimum is not admissible: the answer is on the fence's
        // side, and the polish takes it to the constrained minimum (x0 = 0).
        let r = minimize(&Fenced { cut: 0.0 }, &b, &GaOptions::default(), |_| true).unwrap();
        assert!(r.x[0] <= 0.0, "{:?}", r.x);
        assert!(
            (r.x[0]).abs() < 1e-3 && (r.x[1] - 0.3).abs() < 1e-3,
            "{:?}",
            r.x
        );
        assert!((r.f - sphere(&r.x)).abs() < 1e-15);
        assert!(r.f <= r.f_ga && r.f > free.f);
        assert!(r.history.windows(2).all(|w| w[1] <= w[0]));
        assert_eq!(*r.history.last().unwrap(), r.f_ga);
        // Without the polish the answer is still admissible.
        let o = GaOptions {
            polish: false,
            ..Default::default()
        };
        let g = minimize(&Fenced { cut: 0.0 }, &b, &o, |_| true).unwrap();
        assert!(g.x[0] <= 0.0 && g.f == g.f_ga && g.f.is_finite());
        // Nothing admissible: the search's best, valued inf.
        let none = minimize(&Fenced { cut: -6.0 }, &b, &o, |_| true).unwrap();
        assert!(none.f.is_infinite() && none.f_ga.is_infinite());
        assert!(none.history.iter().all(|h| h.is_infinite()));
        assert!(none.x.iter().all(|v| v.is_finite() && v.abs() <= 5.0));
    }

    #[test]
    fn rosenbrock_converges_with_polish() {
        let b = Bounds::linear(vec![-2.0; 4], vec![2.0; 4]).unwrap();
        let o = GaOptions {
            seed: 7,
            ..Default::default()
        };
        let r = minimize(&rosenbrock, &b, &o, |_| true).unwrap();
        assert!(r.f < 1e-8, "f = {} (ga {})", r.f, r.f_ga);
        assert!(r.f <= r.f_ga);
        for v in &r.x {
            assert!((v - 1.0).abs() < 1e-3, "{:?}", r.x);
        }
    }

    #[test]
    fn log_scale_and_fixed_coordinates() {
        let b = Bounds::new(
            vec![1e-3, 2.0, -1.0],
            vec![1e3, 2.0, 1.0],
            vec![Scale::Log, Scale::Linear, Scale::Linear],
        )
        .unwrap();
        let f = |x: &[f64]| (x[0].ln() - 3f64.ln()).powi(2) + (x[2] - 0.5).powi(2) + x[1];
        let r = minimize(&f, &b, &GaOptions::default(), |_| true).unwrap();
        assert!((r.x[0] - 3.0).abs() < 1e-4 && r.x[1] == 2.0 && (r.x[2] - 0.5).abs() < 1e-4);
        assert!(Bounds::new(vec![0.0], vec![1.0], vec![Scale::Log]).is_err());
        assert!(Bounds::linear(vec![1.0], vec![0.0]).is_err());
    }

    #[test]
    fn same_seed_same_result_for_any_thread_count() {
        let b = Bounds::linear(vec![-2.0; 4], vec![2.0; 4]).unwrap();
        let o = GaOptions {
            seed: 42,
            max_generations: 60,
            ..Default::default()
        };
        let run = |t: usize| {
            crate::parallel::with_threads(t, || minimize(&rosenbrock, &b, &o, |_| true))
                .unwrap()
                .unwrap()
        };
        let (r1, r2, r3) = (run(1), run(2), run(3));
        assert_eq!(r1, r2);
        assert_eq!(r1, r3);
        let other = minimize(
            &rosenbrock,
            &b,
            &GaOptions {
                seed: 43,
                ..o.clone()
            },
            |_| true,
        )
        .unwrap();
        assert_ne!(r1.history, other.history);
    }

    #[test]
    fn callback_stops_and_returns_best_so_far() {
        let b = Bounds::linear(vec![-5.0; 3], vec![5.0; 3]).unwrap();
        let mut seen = 0;
        let r = minimize(&sphere, &b, &GaOptions::default(), |p| {
            seen += 1;
            assert_eq!(p.phase, Phase::Ga);
            p.iteration < 5
        })
        .unwrap();
        assert_eq!(seen, 5);
        assert_eq!(r.generations, 5);
        assert_eq!(r.stop, StopReason::Callback);
        assert_eq!(r.f, r.history[5]);
        assert!((sphere(&r.x) - r.f).abs() < 1e-15);
    }

    #[test]
    fn stall_and_target_stop() {
        let b = Bounds::linear(vec![-1.0; 2], vec![1.0; 2]).unwrap();
        let flat = |_: &[f64]| 1.0;
        let r = minimize(&flat, &b, &GaOptions::default(), |_| true).unwrap();
        assert_eq!(r.stop, StopReason::Stall);
        assert_eq!(r.generations, 20);
        let o = GaOptions {
            target: 1e-2,
            ..Default::default()
        };
        let r = minimize(&sphere, &b, &o, |_| true).unwrap();
        assert_eq!(r.stop, StopReason::Target);
        assert!(r.f <= 1e-2);
    }

    #[test]
    fn local_search_stops_at_the_target() {
        // The local search (every generation here) stops as soon as its best reaches
        // the target, and none starts once the best has: the target run evaluates
        // fewer points than the same generations without a target would.
        let b = Bounds::linear(vec![-1.0; 4], vec![1.0; 4]).unwrap();
        let base = GaOptions {
            seed: 3,
            local_every: 1,
            polish: false,
            ..Default::default()
        };
        let target = 1e-3;
        let t = minimize(
            &sphere,
            &b,
            &GaOptions {
                target,
                ..base.clone()
            },
            |_| true,
        )
        .unwrap();
        assert_eq!(t.stop, StopReason::Target);
        assert!(t.f <= target);
        let free = GaOptions {
            max_generations: t.generations,
            ..base
        };
        let u = minimize(&sphere, &b, &free, |_| true).unwrap();
        assert!(
            t.evaluations < u.evaluations,
            "{} >= {}",
            t.evaluations,
            u.evaluations
        );
    }

    #[test]
    fn nan_counts_as_infinite() {
        let b = Bounds::linear(vec![-1.0; 2], vec![1.0; 2]).unwrap();
        let f = |x: &[f64]| if x[0] < 0.0 { f64::NAN } else { sphere(x) };
        let r = minimize(&f, &b, &GaOptions::default(), |_| true).unwrap();
        assert!(r.f.is_finite() && r.x[0] >= 0.0);
    }

    /// Abandons every value of its function that reaches the bound (the most an
    /// objective may do).
    struct Abandoning(fn(&[f64]) -> f64);

    impl Objective for Abandoning {
        fn eval(&self, x: &[f64]) -> f64 {
            (self.0)(x)
        }
        fn eval_bounded(&self, x: &[f64], bound: f64) -> f64 {
            let f = (self.0)(x);
            if f >= bound {
                f64::INFINITY
            } else {
                f
            }
        }
    }

    /// The search of `f` abandoning at the survival bound equals the exact one, for
    /// each seed and number of threads (0: the calling thread's pool).
    fn same_search_when_abandoning(f: fn(&[f64]) -> f64, seeds: u64, threads: &[usize]) {
        // Coarse bounds on a small box make clones and ties frequent.
        let b = Bounds::linear(vec![-2.0; 3], vec![2.0; 3]).unwrap();
        for seed in 0..seeds {
            let o = GaOptions {
                seed,
                max_generations: 40,
                pop_size: 24,
                polish: false,
                ..Default::default()
            };
            let exact = minimize(&f, &b, &o, |_| true).unwrap();
            for &t in threads {
                let got =
                    crate::parallel::with_threads(t, || minimize(&Abandoning(f), &b, &o, |_| true))
                        .unwrap()
                        .unwrap();
                assert_eq!(exact.x, got.x, "seed {seed}, {t} threads");
                assert_eq!(exact.history, got.history, "seed {seed}, {t} threads");
                assert_eq!(exact.evaluations, got.evaluations, "seed {seed}");
            }
        }
    }

    #[test]
    fn abandoning_at_the_survival_bound_does_not_change_the_search() {
        same_search_when_abandoning(rosenbrock, 6, &[0]);
        let pop = vec![vec![0.1], vec![0.1], vec![0.2], vec![0.3]];
        let threshold = |fit: &[f64], n: usize| Survival::new(&pop, fit, n).threshold();
        // The clone of 0.1 counts once: the 3rd best distinct is 0.3's value.
        assert_eq!(threshold(&[1.0, 1.0, 2.0, 3.0], 3), 3.0);
        assert_eq!(threshold(&[1.0, 1.0, 2.0, 3.0], 4), f64::INFINITY);
        assert_eq!(threshold(&[1.0, 5.0, 2.0, 3.0], 2), 2.0);
        // Offspring values join: it falls, never rises, and infinite or abandoned
        // values change nothing.
        let s = Survival::new(&pop, &[1.0, 1.0, 2.0, 3.0], 4);
        assert_eq!(s.bound(), f64::INFINITY);
        s.offer(f64::INFINITY);
        assert_eq!(s.threshold(), f64::INFINITY);
        s.offer(2.5);
        assert_eq!(s.threshold(), 3.0);
        assert!(s.bound() > 3.0 && s.bound() < 3.0 + 1e-8);
        s.offer(0.5);
        assert_eq!(s.threshold(), 2.5);
        s.offer(7.0);
        s.offer(s.bound());
        assert_eq!(s.threshold(), 2.5);
        // A second offspring valued 1.0 is another individual (offspring are
        // distinct points): 0.5, 1, 1, 2.
        s.offer(1.0);
        assert_eq!(s.threshold(), 2.0);
        assert!(s.bound() > 2.0);
    }

    /// Rosenbrock rounded to a coarse grid: distinct individuals often share a value.
    fn plateaus(x: &[f64]) -> f64 {
        (rosenbrock(x) * 4.0).floor() / 4.0
    }

    #[test]
    fn abandoning_at_the_shared_bound_keeps_the_search_with_ties_on_any_thread_count() {
        // Ties between distinct individuals are frequent here. The search must be the
        // exact one on any number of threads (a threshold that counted a value twice,
        // or one below the generation's, changes it). The strict margin that keeps an
        // offspring tied with a later one from being abandoned is checked directly in
        // `abandoning_at_the_survival_bound_does_not_change_the_search`: which thread
        // finishes first is not under a test's control.
        same_search_when_abandoning(plateaus, 4, &[1, 2, 3]);
    }
}
