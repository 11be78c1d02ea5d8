//! An upper level with structures hidden from the effect registry, for the synthetic
//! platoons that test whether the library finds the structure of a follower
//! (`avll.synth_platoon`). Written independently of [`crate::effects`]: other
//! mechanisms and other discretisations than the upper-level effects that would
//! explain them, so that a calibration that recovers the truth does not do so by
//! construction.
//!
//! Per sample `n` (time `t = n dt`) of a closed loop run at a fine rate:
//! * **radar**: the gap `x_p - x` and the relative speed `v_p - v` are measured at the
//!   radar's own update times `phase + k period` (at the first sample at or after
//!   each) and become visible `latency` later (at the first sample at or after);
//!   between updates the controller holds the last visible measurement. `period = 0`
//!   measures every sample;
//! * **feedforward**: the perceived predecessor speed `vp = v + dv_seen` (own speed
//!   now, relative speed as seen) is differenced over a window, `(vp(t) - vp(t - W)) /
//!   W` (whole samples, the history before the run held at its first value), times
//!   `ff_gain`;
//! * **asymmetry**: the law's gap term `kg e` and speed term `kv dv` are scaled by a
//!   smooth blend between 1 (opening) and `ratio` (closing):
//!   `b(z) = 1 + (ratio - 1) / (1 + exp(z / width))` of the gap error (width in m) and
//!   of the relative speed (width in m/s).
//!
//! `u = kg e b(e) + kv dv b(dv) + ff_gain (vp(t) - vp(t - W)) / W`, with `e = gap_seen
//! - Tg v - Gmin` and `dv` the relative speed as seen.

use super::chain::Law;
use super::rollout::Upper;
use std::collections::VecDeque;

/// The hidden structures' parameters (neutral: period 0, latency 0, ff_gain 0,
/// ratio 1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HiddenParams {
    /// Radar update period (s), its phase (s, in `[0, period)`) and latency (s).
    pub radar_period: f64,
    pub radar_phase: f64,
    pub radar_latency: f64,
    /// Feedforward gain (s) and differencing window (s).
    pub ff_gain: f64,
    pub ff_window: f64,
    /// Closing-side gain ratio and the blends' widths (gap error in m, relative speed
    /// in m/s).
    pub ratio: f64,
    pub width_gap: f64,
    pub width_speed: f64,
}

impl HiddenParams {
    pub const NAMES: [&'static str; 8] = [
        "radar_period",
        "radar_phase",
        "radar_latency",
        "ff_gain",
        "ff_window",
        "ratio",
        "width_gap",
        "width_speed",
    ];

    /// From the values in [`Self::NAMES`] order, checked.
    pub fn from_slice(p: &[f64]) -> crate::error::Result<Self> {
        use crate::error::{check_finite, AvllError};
        if p.len() != Self::NAMES.len() {
            return Err(AvllError::new(
                "hidden",
                format!("expected {} values, got {}", Self::NAMES.len(), p.len()),
            ));
        }
        for (x, n) in p.iter().zip(Self::NAMES) {
            check_finite(&format!("hidden.{n}"), *x)?;
        }
        let h = Self {
            radar_period: p[0],
            radar_phase: p[1],
            radar_latency: p[2],
            ff_gain: p[3],
            ff_window: p[4],
            ratio: p[5],
            width_gap: p[6],
            width_speed: p[7],
        };
        let bad = |n: &str, m: &str| Err(AvllError::new(format!("hidden.{n}"), m.to_string()));
        if h.radar_period < 0.0 || h.radar_latency < 0.0 || h.radar_phase < 0.0 {
            return bad(
                "radar_period",
                "radar period, phase and latency must be >= 0",
            );
        }
        if h.radar_period > 0.0 && h.radar_phase >= h.radar_period {
            return bad("radar_phase", "must be in [0, radar_period)");
        }
        if h.ff_window <= 0.0 {
            return bad("ff_window", "must be > 0");
        }
        if h.ratio <= 0.0 || h.width_gap <= 0.0 || h.width_speed <= 0.0 {
            return bad("ratio", "ratio and widths must be > 0");
        }
        Ok(h)
    }
}

/// The law with hidden structures (a [`Law`] for the closed loop).
#[derive(Debug, Clone)]
pub struct Hidden {
    pub up: Upper,
    pub p: HiddenParams,
    dt: f64,
    n: usize,
    next: f64,
    pending: VecDeque<(f64, f64, f64)>,
    seen: (f64, f64),
    vp: Vec<f64>,
    lag: usize,
}

impl Hidden {
    pub fn new(up: Upper, p: HiddenParams) -> Self {
        Self {
            up,
            p,
            dt: 0.0,
            n: 0,
            next: 0.0,
            pending: VecDeque::new(),
            seen: (0.0, 0.0),
            vp: Vec::new(),
            lag: 1,
        }
    }

    #[inline]
    fn blend(&self, z: f64, width: f64) -> f64 {
        1.0 + (self.p.ratio - 1.0) / (1.0 + (z / width).exp())
    }
}

impl Law for Hidden {
    fn reset(&mut self, dt: f64) {
        self.dt = dt;
        self.n = 0;
        self.next = self.p.radar_phase;
        self.pending.clear();
        self.lag = ((self.p.ff_window / dt).round() as usize).max(1);
        self.vp.clear();
    }

    fn command(&mut self, lead_x: f64, lead_v: f64, x: f64, v: f64) -> f64 {
        let (t, eps) = (self.n as f64 * self.dt, 1e-9 * self.dt);
        let (gap, dv) = (lead_x - x, lead_v - v);
        if self.n == 0 {
            self.seen = (gap, dv);
        }
        if self.p.radar_period > 0.0 {
            while self.next <= t + eps {
                self.pending
                    .push_back((self.next + self.p.radar_latency, gap, dv));
                self.next += self.p.radar_period;
            }
        } else {
            self.pending.push_back((t + self.p.radar_latency, gap, dv));
        }
        while let Some(&(at, g, d)) = self.pending.front() {
            if at <= t + eps {
                self.seen = (g, d);
                self.pending.pop_front();
            } else {
                break;
            }
        }
        let (g, d) = self.seen;
        let up = &self.up;
        let e = g - up.tg * v - up.gmin;
        let mut u = up.kg * e * self.blend(e, self.p.width_gap)
            + up.kv * d * self.blend(d, self.p.width_speed);
        let vp = v + d;
        if self.n == 0 {
            self.vp = vec![vp; self.lag + 1];
        }
        let len = self.vp.len();
        self.vp[self.n % len] = vp;
        let old = self.vp[(self.n + 1) % len];
        u += self.p.ff_gain * (vp - old) / (self.lag as f64 * self.dt);
        self.n += 1;
        u
    }

    fn gap(&self, v: f64) -> f64 {
        self.up.gmin + self.up.tg * v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn neutral_hidden_law_is_eq3_and_the_radar_holds() {
        let up = Upper {
            kg: 0.3,
            kv: 0.5,
            tg: 1.4,
            gmin: 4.0,
        };
        let neutral = HiddenParams::from_slice(&[0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.5]).unwrap();
        let mut h = Hidden::new(up, neutral);
        h.reset(0.01);
        for k in 0..50 {
            let (lx, lv, x, v) = (100.0 + k as f64, 20.0 + 0.1 * k as f64, 70.0, 19.0);
            let want = up.command(lx, lv, x, v);
            assert!((h.command(lx, lv, x, v) - want).abs() < 1e-12);
        }
        // A 0.1 s radar with 0.2 s latency: the gap seen at t is the one measured at
        // the last update at or before t - 0.2.
        let p = HiddenParams::from_slice(&[0.1, 0.0, 0.2, 0.0, 1.0, 1.0, 1.0, 0.5]).unwrap();
        let mut h = Hidden::new(Upper { kv: 0.0, ..up }, p);
        h.reset(0.01);
        let mut seen = vec![];
        for k in 0..60 {
            let lx = 100.0 + k as f64; // the gap grows by 1 m per sample
            let u = h.command(lx, 19.0, 70.0, 19.0);
            seen.push(u / 0.3 + 1.4 * 19.0 + 4.0 + 70.0 - 100.0);
        }
        assert!((seen[25] - 0.0).abs() < 1e-9, "{}", seen[25]); // update 0 until t = 0.3
        assert!((seen[30] - 10.0).abs() < 1e-9, "{}", seen[30]); // the 0.1 s update at 0.3 s
        assert!((seen[45] - 20.0).abs() < 1e-9, "{}", seen[45]);
    }
}
