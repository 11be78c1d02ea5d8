//! Tests of the upper-level structures on the kernel: neutral structures are the
//! constant-time-gap law, the time-major platoon with structures equals its followers
//! one by one, the costs with structures equal their rollouts, open loops refuse them,
//! and the small-signal forms of `effects::response` hold in the time domain.

use super::cost::{batch_cost, CostSpec, RunRef};
use super::plant::Init;
use super::rollout::{closed_loop, platoon, simulate_full, EffectsRef, Upper};
use crate::effects::{response, AnyEffect, EffectList, Operating, Terms, UpperLin};
use crate::model::{CommandKind, Linear, ModelKind};

const DT: f64 = 0.05;

/// The proposed model's closed-loop spec with `effects` (three unit weights, from rest).
fn closed_spec(effects: EffectList) -> CostSpec {
    CostSpec {
        effects,
        ..CostSpec::linear(
            ModelKind::Proposed,
            CommandKind::Acceleration,
            [1.0, 1.0, 1.0],
            Init::Rest,
            true,
            vec![],
        )
    }
}

/// A closed-loop run behind the leader `(lx, lv)` (sampled at [`DT`]) with the
/// measured `a`, `v`, `x` and the law `up`.
fn closed_run<'a>(
    lx: &'a [f64],
    lv: &'a [f64],
    a: &'a [f64],
    v: &'a [f64],
    x: &'a [f64],
    up: Upper,
) -> RunRef<'a> {
    RunRef {
        dt: DT,
        command: None,
        lead_x: Some(lx),
        lead_v: Some(lv),
        a,
        v: Some(v),
        x: Some(x),
        upper: up,
        exo: vec![],
    }
}

fn proposed() -> Linear {
    Linear {
        b1: 6.7893,
        b0: 0.3479,
        a2: 1.2824,
        a1: 8.8157,
        td: 0.7903,
        k: 0.1008,
    }
}

const UP: Upper = Upper {
    kg: 0.2,
    kv: 0.4,
    tg: 1.5,
    gmin: 3.0,
};

/// Effects from (name, parameters) pairs in any order (built in the canonical order).
fn effects(given: &[(&str, &[f64])]) -> Vec<AnyEffect> {
    let k = CommandKind::Acceleration;
    let names: Vec<&str> = given.iter().map(|(n, _)| *n).collect();
    let list = EffectList::from_names(&names, k).unwrap();
    let p = canonical_row(given);
    list.build(&p, k).unwrap()
}

/// The effects' parameters in the canonical order.
fn canonical_row(given: &[(&str, &[f64])]) -> Vec<f64> {
    let names: Vec<&str> = given.iter().map(|(n, _)| *n).collect();
    let list = EffectList::from_names(&names, CommandKind::Acceleration).unwrap();
    list.0
        .iter()
        .flat_map(|k| {
            given
                .iter()
                .find(|(n, _)| *n == k.name())
                .unwrap()
                .1
                .to_vec()
        })
        .collect()
}

fn neutral(names: &[&str]) -> Vec<AnyEffect> {
    let list = EffectList::from_names(names, CommandKind::Acceleration).unwrap();
    let p: Vec<f64> = list.0.iter().flat_map(|k| k.neutral().to_vec()).collect();
    list.build(&p, CommandKind::Acceleration).unwrap()
}

/// A leader at `v` m/s with a sinusoid of `amp` m/s at `f` Hz (after a smooth start).
fn leader(n: usize, v: f64, amp: f64, f: f64) -> (Vec<f64>, Vec<f64>) {
    let lv: Vec<f64> = (0..n)
        .map(|k| {
            let t = k as f64 * DT;
            let ramp = if t < 20.0 {
                0.5 * (1.0 - (std::f64::consts::PI * t / 20.0).cos())
            } else {
                1.0
            };
            v + amp * ramp * (2.0 * std::f64::consts::PI * f * t).sin()
        })
        .collect();
    let mut lx = vec![200.0; n];
    for k in 1..n {
        lx[k] = lx[k - 1] + 0.5 * DT * (lv[k] + lv[k - 1]);
    }
    (lx, lv)
}

fn max_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

const ALL: [&str; 5] = [
    "perception",
    "speed_gains",
    "closing",
    "feedforward",
    "comfort",
];

#[test]
fn neutral_structures_are_the_constant_time_gap_law() {
    let (lx, lv) = leader(4000, 15.0, 1.0, 0.05);
    let effs = neutral(&ALL);
    let eff = EffectsRef {
        effects: &effs,
        exo: &[],
    };
    let x0 = lx[0] - (UP.gmin + UP.tg * lv[0]);
    let a = closed_loop(&proposed(), &EffectsRef::NONE, &UP, &lx, &lv, DT, lv[0], x0).unwrap();
    let b = closed_loop(&proposed(), &eff, &UP, &lx, &lv, DT, lv[0], x0).unwrap();
    for (p, q) in [
        (&a.a, &b.a),
        (&a.v, &b.v),
        (&a.x, &b.x),
        (&a.command, &b.command),
    ] {
        assert!(max_diff(p, q) < 1e-11, "{}", max_diff(p, q));
    }
    let pa = platoon(&proposed(), &EffectsRef::NONE, &UP, &lx, &lv, DT, 4).unwrap();
    let pb = platoon(&proposed(), &eff, &UP, &lx, &lv, DT, 4).unwrap();
    for (p, q) in pa.iter().zip(&pb) {
        assert!(max_diff(&p.v, &q.v) < 1e-11 && max_diff(&p.x, &q.x) < 1e-10);
    }
}

#[test]
fn platoon_with_structures_equals_followers_one_by_one() {
    let (lx, lv) = leader(3000, 15.0, 1.5, 0.04);
    let effs = effects(&[
        ("perception", &[0.33]),
        ("speed_gains", &[0.01, 0.005]),
        ("closing", &[1.4, 2.0]),
        ("feedforward", &[0.5, 0.8]),
        ("comfort", &[1.2, 1.6, 3.0]),
        ("saturation", &[1.5, 2.0]),
    ]);
    let eff = EffectsRef {
        effects: &effs,
        exo: &[],
    };
    let trs = platoon(&proposed(), &eff, &UP, &lx, &lv, DT, 5).unwrap();
    // The equilibrium gap at the leader's first speed, speed_gains' time gap included.
    let gap = UP.gmin + (UP.tg + 0.01 * lv[0]) * lv[0];
    let (mut px, mut pv) = (lx.clone(), lv.clone());
    for (j, tr) in trs.iter().enumerate() {
        let one = closed_loop(&proposed(), &eff, &UP, &px, &pv, DT, lv[0], px[0] - gap).unwrap();
        for (a, b) in [(&tr.a, &one.a), (&tr.v, &one.v), (&tr.x, &one.x)] {
            assert_eq!(a, b, "follower {j}: bit-identical");
        }
        px = one.x;
        pv = one.v;
    }
    // each structure acts
    let plain = platoon(&proposed(), &EffectsRef::NONE, &UP, &lx, &lv, DT, 5).unwrap();
    assert!(max_diff(&trs[0].v, &plain[0].v) > 1e-2);
}

#[test]
fn upper_structures_need_a_closed_loop() {
    let effs = effects(&[("perception", &[0.3])]);
    let eff = EffectsRef {
        effects: &effs,
        exo: &[],
    };
    let u = vec![0.1; 100];
    let e = simulate_full(
        &proposed(),
        &eff,
        CommandKind::Acceleration,
        &u,
        DT,
        Init::Rest,
        0.0,
        0.0,
    )
    .unwrap_err();
    assert_eq!(e.arg, "effects");
    assert!(e.msg.contains("closed loop"), "{}", e.msg);
    let a = vec![0.0; 100];
    let run = RunRef {
        dt: DT,
        command: Some(&u),
        lead_x: None,
        lead_v: None,
        a: &a,
        v: None,
        x: None,
        upper: UP,
        exo: vec![],
    };
    let spec = CostSpec {
        effects: EffectList::from_names(&["perception"], CommandKind::Acceleration).unwrap(),
        ..CostSpec::linear(
            ModelKind::Proposed,
            CommandKind::Acceleration,
            [1.0, 0.0, 0.0],
            Init::Rest,
            false,
            vec![],
        )
    };
    let row = [6.7893, 1.2824, 8.8157, 0.3479, 0.7903, 0.1008, 0.3];
    assert!(batch_cost(&spec, &row, &[run]).is_err());
    // comfort and rate_limit are one slew limit: refused together
    assert!(EffectList::from_names(&["comfort", "rate_limit"], CommandKind::Acceleration).is_err());
}

#[test]
fn closed_loop_cost_with_structures_equals_its_rollout() {
    let n = 2500;
    let (lx, lv) = leader(n, 15.0, 1.0, 0.06);
    let given: [(&str, &[f64]); 3] = [
        ("perception", &[0.4]),
        ("feedforward", &[0.6, 0.7]),
        ("closing", &[1.5, 2.0]),
    ];
    let names = ["perception", "feedforward", "closing"];
    let effs = effects(&given);
    let eff = EffectsRef {
        effects: &effs,
        exo: &[],
    };
    let x0 = lx[0] - 25.0;
    let truth = closed_loop(&proposed(), &eff, &UP, &lx, &lv, DT, lv[0], x0).unwrap();
    let a: Vec<f64> = truth.a.iter().map(|x| x + 0.01).collect();
    let run = closed_run(&lx, &lv, &a, &truth.v, &truth.x, UP);
    let spec = closed_spec(EffectList::from_names(&names, CommandKind::Acceleration).unwrap());
    let mut row = vec![6.7893, 1.2824, 8.8157, 0.3479, 0.7903, 0.1008];
    row.extend(canonical_row(&given));
    let c = batch_cost(&spec, &row, &[run]).unwrap();
    // the measured speed and position are the truth's: only the offset of a remains
    assert!((c[0] - 1e-4).abs() < 1e-12, "{}", c[0]);
}

/// The steady amplitude ratio of the follower's speed to the leader's at `f` Hz
/// (least squares on the last `m` samples).
fn ratio(v: &[f64], lv: &[f64], f: f64, m: usize) -> f64 {
    let fit = |y: &[f64]| {
        let n = y.len();
        let (mut ss, mut sc, mut cc, mut ys, mut yc) = (0.0, 0.0, 0.0, 0.0, 0.0);
        let mean = y[n - m..].iter().sum::<f64>() / m as f64;
        for k in n - m..n {
            let w = 2.0 * std::f64::consts::PI * f * k as f64 * DT;
            let (s, c) = w.sin_cos();
            ss += s * s;
            sc += s * c;
            cc += c * c;
            ys += (y[k] - mean) * s;
            yc += (y[k] - mean) * c;
        }
        let det = ss * cc - sc * sc;
        let a = (ys * cc - yc * sc) / det;
        let b = (yc * ss - ys * sc) / det;
        a.hypot(b)
    };
    fit(v) / fit(lv)
}

#[test]
fn small_signal_forms_hold_in_the_time_domain() {
    // A small oscillation about 15 m/s (whole periods in the window): the follower's
    // amplitude ratio equals |H| of `response` with each structure's small-signal form,
    // to the O(dt) error of evaluating the law at the samples (the base's own).
    let (f, v0) = (0.05, 15.0);
    let (lx, lv) = leader(12_000, v0, 0.05, f);
    let op = Operating { v: v0, side: 0 };
    let cases: [&[(&str, &[f64])]; 6] = [
        &[],
        &[("perception", &[0.45])],
        &[("speed_gains", &[0.02, 0.02])],
        &[("closing", &[1.8, 0.5])],
        &[("feedforward", &[0.8, 0.6])],
        &[("comfort", &[1.0, 1.5, 2.0])],
    ];
    let base = {
        let h = response(
            &proposed(),
            &Terms::default(),
            &UpperLin::of(&UP),
            2.0 * std::f64::consts::PI * f,
        );
        h.norm()
    };
    let mut moved = 0;
    for given in cases {
        let effs = effects(given);
        let eff = EffectsRef {
            effects: &effs,
            exo: &[],
        };
        let ul = crate::effects::linearize_upper(&UP, &effs, &op).unwrap();
        let h = response(
            &proposed(),
            &Terms::default(),
            &ul,
            2.0 * std::f64::consts::PI * f,
        )
        .norm();
        let gap = UP.gmin + ul.tg_eq * lv[0];
        let tr = closed_loop(&proposed(), &eff, &UP, &lx, &lv, DT, lv[0], lx[0] - gap).unwrap();
        let r = ratio(&tr.v, &lv, f, 8000);
        assert!(
            (r / h - 1.0).abs() < 6e-3,
            "{given:?}: simulated {r}, |H| {h}"
        );
        if (h / base - 1.0).abs() > 0.02 {
            moved += 1;
        }
    }
    assert!(moved >= 4, "the structures must change |H| ({moved} did)");
}

#[test]
fn a_locally_unstable_closed_loop_costs_inf_though_its_record_is_finite() {
    use super::cost::{run_atom_sums, run_cost};
    use crate::stability::delay::DelayLoop;
    let n = 200; // 10 s: too short for the slow divergence to show in the rollout
    let (lx, lv) = leader(n, 15.0, 1.0, 0.06);
    let dl = DelayLoop::new(&proposed()).unwrap();
    let slow = Upper {
        kg: 0.2,
        kv: 0.05,
        tg: 0.3,
        gmin: 3.0,
    };
    assert_eq!(dl.local(slow.kg, slow.tg, slow.kv), Some(false));
    assert_eq!(dl.local(UP.kg, UP.tg, UP.kv), Some(true));
    let x0 = lx[0] - 25.0;
    let spec = closed_spec(EffectList::default());
    let row = [6.7893, 1.2824, 8.8157, 0.3479, 0.7903, 0.1008];
    for (up, stable) in [(UP, true), (slow, false)] {
        let tr = closed_loop(&proposed(), &EffectsRef::NONE, &up, &lx, &lv, DT, lv[0], x0).unwrap();
        assert!(tr.a.iter().chain(&tr.v).chain(&tr.x).all(|v| v.is_finite()));
        let a: Vec<f64> = tr.a.iter().map(|x| x + 0.01).collect();
        let run = closed_run(&lx, &lv, &a, &tr.v, &tr.x, up);
        let c = run_cost(&spec, &row, &run, f64::INFINITY);
        let mut sums = vec![0.0; 4];
        let ok = run_atom_sums(&spec, &row, &run, 50, &mut sums);
        assert_eq!(c.is_finite(), stable, "{c}");
        assert_eq!(ok, stable);
        if stable {
            assert!((c - 1e-4).abs() < 1e-12, "{c}");
        }
    }
}

#[test]
fn with_effects_a_locally_unstable_closed_loop_costs_inf_too() {
    use super::cost::run_cost;
    use crate::effects::follower::{FollowerLoop, Verdict};
    use crate::effects::{linearize_terms, linearize_upper};
    let n = 200;
    let (lx, lv) = leader(n, 15.0, 1.0, 0.06);
    let lin = proposed();
    let list = EffectList::from_names(&["perception"], CommandKind::Acceleration).unwrap();
    let op = Operating {
        v: lv.iter().sum::<f64>() / n as f64,
        side: 0,
    };
    // the stable law UP with a short and a long perception delay: the exact test of
    // every delay calls the first stable and the second unstable
    let verdict = |tau: f64| {
        let effs = list.build(&[tau], CommandKind::Acceleration).unwrap();
        let (l, t) = linearize_terms(&lin, &effs, &op).unwrap();
        let u = linearize_upper(&UP, &effs, &op).unwrap();
        FollowerLoop::new(&l, &t, &u).local()
    };
    let unstable_tau = [1.0, 1.5, 3.0, 6.0]
        .into_iter()
        .find(|&t| verdict(t) == Verdict::No)
        .expect("a perception delay that destabilises the loop");
    assert_eq!(verdict(0.1), Verdict::Yes);
    let x0 = lx[0] - 25.0;
    let tr = closed_loop(&lin, &EffectsRef::NONE, &UP, &lx, &lv, DT, lv[0], x0).unwrap();
    let run = closed_run(&lx, &lv, &tr.a, &tr.v, &tr.x, UP);
    let spec = closed_spec(list);
    let row = |tau: f64| [6.7893, 1.2824, 8.8157, 0.3479, 0.7903, 0.1008, tau];
    assert!(run_cost(&spec, &row(0.1), &run, f64::INFINITY).is_finite());
    assert_eq!(
        run_cost(&spec, &row(unstable_tau), &run, f64::INFINITY),
        f64::INFINITY
    );
}
