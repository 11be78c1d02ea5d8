//! Tests of the one kernel: analytic responses, modal vs canonical coordinates, the
//! effect chain at neutral parameters vs the linear fast path, time-major platoons
//! vs followers stepped one by one, batched simulation vs the single rollouts, and
//! the cost's early abandoning.

use super::chain::NoEffects;
use super::cost::{batch_cost, run_cost, simulate_batch, CostSpec, RunRef};
use super::discretize::Integrators;
use super::kernel::{run, Record};
use super::plant::{Init, Plant};
use super::rollout::{
    closed_loop, closed_loop_into, platoon, simulate, simulate_full, stepper, EffectsRef, Out,
    Trajectory, Upper,
};
use crate::effects::{EffectKind, EffectList, Operating};
use crate::model::{CommandKind, Linear, ModelKind};

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

fn second() -> Linear {
    Linear {
        b1: 0.0,
        b0: 0.7292,
        a2: 0.0445,
        a1: 0.1305,
        td: 0.7796,
        k: 0.0,
    }
}

fn cmd(n: usize) -> Vec<f64> {
    (0..n)
        .map(|k| {
            let t = k as f64 * 0.05;
            1.5 * (0.3 * t).sin() + 0.7 * (1.1 * t).cos()
        })
        .collect()
}

/// Largest difference relative to the signal's size (at least 1).
fn max_diff(a: &[f64], b: &[f64]) -> f64 {
    let scale = b.iter().fold(1.0f64, |m, y| m.max(y.abs()));
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
        / scale
}

fn leader(n: usize, dt: f64) -> (Vec<f64>, Vec<f64>) {
    let lv: Vec<f64> = (0..n)
        .map(|k| 10.0 + 2.0 * (0.2 * k as f64 * dt).sin())
        .collect();
    let mut lx = vec![100.0; n];
    for k in 1..n {
        lx[k] = lx[k - 1] + 0.5 * dt * (lv[k] + lv[k - 1]);
    }
    (lx, lv)
}

const UP: Upper = Upper {
    kg: 0.5,
    kv: 0.1,
    tg: 2.0,
    gmin: 9.5,
};

/// A law under which the paper's proposed model diverges (string and loop unstable).
const WILD: Upper = Upper {
    kg: 40.0,
    kv: 0.0,
    tg: 0.1,
    gmin: 2.0,
};

#[test]
fn first_order_step_is_analytic() {
    let lin = Linear {
        b1: 0.0,
        b0: 1.0,
        a2: 0.0,
        a1: 1.0758,
        td: 0.0,
        k: 0.0,
    };
    let y = simulate(&lin, &[1.0; 200], 0.05, Init::Rest).unwrap();
    for (n, yn) in y.iter().enumerate() {
        let t = n as f64 * 0.05;
        assert!((yn - (1.0 - (-t / 1.0758).exp())).abs() < 1e-12, "n={n}");
    }
}

#[test]
fn second_order_step_with_fractional_delay_is_analytic() {
    // 1/((s+1)(s+2)) * 2 -> a2 = 0.5, a1 = 1.5 (real modes: the modal path).
    for td in [0.3, 0.137] {
        let lin = Linear {
            b1: 0.0,
            b0: 0.8,
            a2: 0.5,
            a1: 1.5,
            td,
            k: 0.0,
        };
        let y = simulate(&lin, &[1.0; 300], 0.05, Init::Rest).unwrap();
        for (n, yn) in y.iter().enumerate() {
            let t = n as f64 * 0.05 - td;
            let want = if t <= 0.0 {
                0.0
            } else {
                0.8 * (1.0 - 2.0 * (-t).exp() + (-2.0 * t).exp())
            };
            assert!((yn - want).abs() < 1e-12, "td={td} n={n} {yn} {want}");
        }
    }
}

/// The open-loop response in canonical coordinates (the modal form switched off).
fn canonical_response(lin: &Linear, u: &[f64], init: Init) -> Vec<f64> {
    let p = Plant::<2, 4>::new(lin, Integrators::SpeedPosition, 0.05, false).unwrap();
    let s = super::plant::start(lin, init, u[0]).unwrap();
    let mut st = stepper::<2, 4, false, false, _>(
        p,
        lin,
        Integrators::SpeedPosition,
        NoEffects,
        true,
        &s,
        [0.0; 2],
    )
    .unwrap();
    let mut tr = Trajectory::filled(u.len(), 0.0);
    let mut rec = Record::<false, false>::new(&mut tr.a, &mut tr.v, &mut tr.x);
    run(&mut st, u.len(), |n, _| u[n], &mut rec);
    tr.a
}

#[test]
fn modal_form_equals_canonical_form() {
    let u = cmd(4000);
    for init in [Init::Rest, Init::Steady] {
        let want = canonical_response(&proposed(), &u, init);
        let got = simulate(&proposed(), &u, 0.05, init).unwrap();
        let d = max_diff(&got, &want);
        assert!(d < 1e-12, "{d}");
        let full = simulate_full(
            &proposed(),
            &EffectsRef::NONE,
            CommandKind::Acceleration,
            &u,
            0.05,
            init,
            0.0,
            0.0,
        )
        .unwrap();
        assert!(max_diff(&full.a, &want) < 1e-12);
    }
}

#[test]
fn proposed_dc_gain_and_steady_start() {
    let lin = proposed();
    let y = simulate(&lin, &vec![1.0; 20000], 0.05, Init::Rest).unwrap();
    assert!((y[19999] - lin.dc_gain()).abs() < 1e-6);
    let y = simulate(&lin, &[2.0; 500], 0.05, Init::Steady).unwrap();
    for yn in &y {
        assert!((yn - 2.0 * lin.dc_gain()).abs() < 1e-9);
    }
}

#[test]
fn closed_loop_reaches_equilibrium_gap() {
    let n = 20000;
    let dt = 0.05;
    let up = Upper { kv: 0.0, ..UP };
    let lv = vec![10.0; n];
    let lx: Vec<f64> = (0..n).map(|k| 100.0 + 10.0 * k as f64 * dt).collect();
    let tr = closed_loop(
        &proposed(),
        &EffectsRef::NONE,
        &up,
        &lx,
        &lv,
        dt,
        10.0,
        100.0 - 29.5 - 5.0,
    )
    .unwrap();
    let gap = lx[n - 1] - tr.x[n - 1];
    assert!((gap - 29.5).abs() < 1e-3, "gap {gap}");
}

fn neutral(names: &[&str]) -> Vec<crate::effects::AnyEffect> {
    neutral_for(names, CommandKind::Acceleration)
}

fn neutral_for(names: &[&str], kind: CommandKind) -> Vec<crate::effects::AnyEffect> {
    let list = EffectList::from_names(names, kind).unwrap();
    let p: Vec<f64> = list
        .0
        .iter()
        .flat_map(|k| k.neutral().iter().copied())
        .collect();
    list.build(&p, kind).unwrap()
}

fn built(names: &[&str], p: &[f64], kind: CommandKind) -> Vec<crate::effects::AnyEffect> {
    EffectList::from_names(names, kind)
        .unwrap()
        .build(p, kind)
        .unwrap()
}

#[test]
fn neutral_vehicle_effects_equal_the_fast_path_for_both_command_kinds() {
    // road_load, power_limit, sensor and (for a speed command) the acceleration-level
    // effects at their neutral parameters.
    let all = [
        "saturation",
        "power_limit",
        "road_load",
        "grade",
        "sensor",
        "delay",
    ];
    let u = cmd(3000);
    let us: Vec<f64> = u.iter().map(|x| 10.0 + x).collect();
    let g = vec![0.02; 3000];
    let exo = [("grade", &g[..])];
    for lin in [proposed(), second()] {
        for (kind, u, init) in [
            (CommandKind::Acceleration, &u, Init::Rest),
            (CommandKind::Speed, &us, Init::Steady),
        ] {
            let effs = neutral_for(&all, kind);
            let eff = EffectsRef {
                effects: &effs,
                exo: &exo,
            };
            let x = simulate_full(&lin, &EffectsRef::NONE, kind, u, 0.05, init, 3.0, 5.0).unwrap();
            let y = simulate_full(&lin, &eff, kind, u, 0.05, init, 3.0, 5.0).unwrap();
            assert!(
                max_diff(&y.a, &x.a) < 1e-11,
                "{kind:?} {}",
                max_diff(&y.a, &x.a)
            );
            assert!(max_diff(&y.v, &x.v) < 1e-11, "{kind:?}");
            assert!(max_diff(&y.x, &x.x) < 1e-11, "{kind:?}");
        }
    }
}

#[test]
fn road_load_without_linear_term_is_speed_drag() {
    let u = cmd(2000);
    let kind = CommandKind::Acceleration;
    let rl = built(&["road_load"], &[0.08, 0.0, 0.001], kind);
    let sd = built(&["speed_drag"], &[0.08, 0.001], kind);
    let run = |e: &[crate::effects::AnyEffect]| {
        let eff = EffectsRef {
            effects: e,
            exo: &[],
        };
        simulate_full(&proposed(), &eff, kind, &u, 0.05, Init::Rest, 8.0, 0.0).unwrap()
    };
    let (a, b) = (run(&rl), run(&sd));
    assert!(max_diff(&a.v, &b.v) < 1e-14 && max_diff(&a.a, &b.a) < 1e-14);
    let rl1 = built(&["road_load"], &[0.08, 0.02, 0.001], kind);
    assert!(max_diff(&run(&rl1).v, &b.v) > 1e-2);
    assert!(EffectList::from_names(&["speed_drag", "road_load"], kind).is_err());
}

#[test]
fn sensor_filters_only_the_observation() {
    let u = cmd(2000);
    let kind = CommandKind::Acceleration;
    let e = built(&["sensor"], &[0.3, 0.05], kind);
    let eff = EffectsRef {
        effects: &e,
        exo: &[],
    };
    let lin = proposed();
    let x = simulate_full(
        &lin,
        &EffectsRef::NONE,
        kind,
        &u,
        0.05,
        Init::Rest,
        4.0,
        0.0,
    )
    .unwrap();
    let y = simulate_full(&lin, &eff, kind, &u, 0.05, Init::Rest, 4.0, 0.0).unwrap();
    assert_eq!(x.v, y.v);
    assert_eq!(x.x, y.x);
    let alpha = (-0.05f64 / 0.3).exp();
    let mut f = x.a[0];
    for n in 0..u.len() {
        f = alpha * f + (1.0 - alpha) * x.a[n];
        assert!((y.a[n] - f - 0.05).abs() < 1e-12);
    }
    let (lx, lv) = leader(2000, 0.05);
    let a = closed_loop(&lin, &EffectsRef::NONE, &UP, &lx, &lv, 0.05, 10.0, 70.0).unwrap();
    let b = closed_loop(&lin, &eff, &UP, &lx, &lv, 0.05, 10.0, 70.0).unwrap();
    assert_eq!(a.command, b.command);
    assert_eq!(a.v, b.v);
}

#[test]
fn speed_command_effects_move_the_speed_by_the_mapped_acceleration() {
    // Saturation on a speed command: the actual speed's slope is the clipped
    // interval-mean acceleration of the linear speed response.
    let lin = second();
    let us: Vec<f64> = cmd(2000).iter().map(|x| 10.0 + 3.0 * x).collect();
    let kind = CommandKind::Speed;
    let e = built(&["saturation"], &[0.3, 0.4], kind);
    let eff = EffectsRef {
        effects: &e,
        exo: &[],
    };
    let x = simulate_full(
        &lin,
        &EffectsRef::NONE,
        kind,
        &us,
        0.05,
        Init::Steady,
        0.0,
        0.0,
    )
    .unwrap();
    let y = simulate_full(&lin, &eff, kind, &us, 0.05, Init::Steady, 0.0, 0.0).unwrap();
    let mut bound = [false; 2];
    for n in 0..us.len() - 1 {
        let abar = (x.v[n + 1] - x.v[n]) / 0.05;
        let slope = (y.v[n + 1] - y.v[n]) / 0.05;
        assert!((slope - abar.clamp(-0.4, 0.3)).abs() < 1e-9, "{n}");
        bound[0] |= abar > 0.3;
        bound[1] |= abar < -0.4;
    }
    assert!(bound[0] && bound[1]);
}

#[test]
fn neutral_effects_equal_the_linear_fast_path() {
    let (lx, lv) = leader(4000, 0.05);
    let effs = neutral(&["delay", "deadband", "asymmetric", "grade", "speed_drag"]);
    let g = vec![0.01; lx.len()];
    let exo = [("grade", &g[..])];
    let eff = EffectsRef {
        effects: &effs,
        exo: &exo,
    };
    for lin in [proposed(), second()] {
        let a = closed_loop(&lin, &EffectsRef::NONE, &UP, &lx, &lv, 0.05, 10.0, 70.0).unwrap();
        let b = closed_loop(&lin, &eff, &UP, &lx, &lv, 0.05, 10.0, 70.0).unwrap();
        assert!(max_diff(&b.a, &a.a) < 1e-11, "{}", max_diff(&b.a, &a.a));
        assert!(max_diff(&b.x, &a.x) < 1e-11);
        assert!(max_diff(&b.command, &a.command) < 1e-11);
        let u = cmd(3000);
        for kind in [CommandKind::Acceleration, CommandKind::Speed] {
            let effs = if kind == CommandKind::Speed {
                neutral(&["delay", "deadband"])
            } else {
                effs.clone()
            };
            let eff = EffectsRef {
                effects: &effs,
                exo: &exo[..0],
            };
            let effs_needing_grade = effs.iter().any(|e| e.kind() == EffectKind::Grade);
            let eff = if effs_needing_grade {
                EffectsRef {
                    effects: &effs,
                    exo: &[("grade", &g[..3000])],
                }
            } else {
                eff
            };
            let x = simulate_full(
                &lin,
                &EffectsRef::NONE,
                kind,
                &u,
                0.05,
                Init::Rest,
                3.0,
                5.0,
            )
            .unwrap();
            let y = simulate_full(&lin, &eff, kind, &u, 0.05, Init::Rest, 3.0, 5.0).unwrap();
            assert!(max_diff(&y.a, &x.a) < 1e-11, "{kind:?}");
            assert!(max_diff(&y.v, &x.v) < 1e-11);
            assert!(max_diff(&y.x, &x.x) < 1e-11);
        }
    }
}

#[test]
fn asymmetric_braking_side_equals_scaled_model() {
    let u: Vec<f64> = cmd(2000).iter().map(|x| -x.abs() - 0.1).collect();
    let lin = Linear {
        k: 0.0,
        ..proposed()
    };
    let e = EffectList::from_names(&["asymmetric"], CommandKind::Acceleration)
        .unwrap()
        .build(&[0.7, 1.6], CommandKind::Acceleration)
        .unwrap();
    let eff = EffectsRef {
        effects: &e,
        exo: &[],
    };
    let got = simulate_full(
        &lin,
        &eff,
        CommandKind::Acceleration,
        &u,
        0.05,
        Init::Rest,
        0.0,
        0.0,
    )
    .unwrap();
    let lb = e[0]
        .linearize(&lin, &Operating { v: 0.0, side: -1 })
        .unwrap();
    let want = simulate(&lb, &u, 0.05, Init::Rest).unwrap();
    assert!(max_diff(&got.a, &want) < 1e-10);
}

#[test]
fn saturation_clips_and_speed_integrates_the_clip() {
    let lin = Linear {
        b1: 0.0,
        b0: 1.0,
        a2: 0.0,
        a1: 0.5,
        td: 0.0,
        k: 0.0,
    };
    let e = EffectList::from_names(&["saturation"], CommandKind::Acceleration)
        .unwrap()
        .build(&[1.5, 2.0], CommandKind::Acceleration)
        .unwrap();
    let eff = EffectsRef {
        effects: &e,
        exo: &[],
    };
    let tr = simulate_full(
        &lin,
        &eff,
        CommandKind::Acceleration,
        &[3.0; 400],
        0.05,
        Init::Rest,
        0.0,
        0.0,
    )
    .unwrap();
    assert!(tr.a.iter().all(|a| *a <= 1.5 + 1e-15));
    assert!((tr.a[399] - 1.5).abs() < 1e-12);
    assert!((tr.v[399] - tr.v[398] - 1.5 * 0.05).abs() < 1e-12);
}

#[test]
fn time_major_platoon_equals_followers_one_by_one() {
    let (lx, lv) = leader(3000, 0.05);
    for lin in [proposed(), second()] {
        let trs = platoon(&lin, &EffectsRef::NONE, &UP, &lx, &lv, 0.05, 6).unwrap();
        let (mut px, mut pv) = (lx.clone(), lv.clone());
        for (j, tr) in trs.iter().enumerate() {
            let p0 = px[0] - (UP.gmin + UP.tg * lv[0]);
            let one = closed_loop(&lin, &EffectsRef::NONE, &UP, &px, &pv, 0.05, lv[0], p0).unwrap();
            for (a, b) in [(&tr.a, &one.a), (&tr.v, &one.v), (&tr.x, &one.x)] {
                assert_eq!(a, b, "follower {j}: bit-identical");
            }
            px = one.x;
            pv = one.v;
        }
    }
}

#[test]
fn closed_loop_without_a_command_output_records_the_same() {
    // Recording the command or not is a choice made once per run (two loops): both
    // write the same acceleration, speed and position, bit for bit, for models with
    // and without inner feedback, and when the follower diverges (NaN from there on).
    let (lx, lv) = leader(3000, 0.05);
    for lin in [proposed(), second()] {
        for up in [UP, WILD] {
            let p0 = lx[0] - (up.gmin + up.tg * lv[0]);
            let with =
                closed_loop(&lin, &EffectsRef::NONE, &up, &lx, &lv, 0.05, lv[0], p0).unwrap();
            let mut tr = Trajectory::filled(lx.len(), 0.0);
            let out = Out {
                a: &mut tr.a,
                v: &mut tr.v,
                x: &mut tr.x,
                u: None,
            };
            closed_loop_into(&lin, &EffectsRef::NONE, &up, &lx, &lv, 0.05, lv[0], p0, out).unwrap();
            for (a, b) in [(&tr.a, &with.a), (&tr.v, &with.v), (&tr.x, &with.x)] {
                let bits = |s: &[f64]| s.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(a), bits(b), "k = {}, kg = {}", lin.k, up.kg);
            }
            assert_eq!(tr.command, vec![0.0; lx.len()], "not written");
            let diverged = with.a.iter().any(|a| a.is_nan());
            assert_eq!(diverged, up == WILD, "the wild law diverges, the other not");
        }
    }
}

#[test]
fn unstable_platoon_is_nan_after_divergence_and_behind_it() {
    let (lx, lv) = leader(4000, 0.05);
    let up = WILD;
    let trs = platoon(&proposed(), &EffectsRef::NONE, &up, &lx, &lv, 0.05, 3).unwrap();
    let first = trs[0].a.iter().position(|a| a.is_nan()).expect("diverges");
    assert!(first > 0 && trs[0].a[..first].iter().all(|a| a.is_finite()));
    assert!(trs[1].a.iter().all(|a| a.is_nan()) && trs[2].v.iter().all(|v| v.is_nan()));
    // A follower that diverges later than one behind it still blanks all behind it.
    let up = Upper {
        kg: 0.5,
        kv: 0.0,
        tg: 1.8,
        gmin: 9.5,
    };
    let (lx, lv) = leader(2500, 0.05);
    let trs = platoon(&proposed(), &EffectsRef::NONE, &up, &lx, &lv, 0.05, 20).unwrap();
    let mut dead = false;
    for tr in &trs {
        if dead {
            assert!(tr.x.iter().all(|x| x.is_nan()));
        }
        dead |= tr.x.iter().any(|x| !x.is_finite());
    }
}

fn spec(closed: bool, weights: [f64; 3], free: Vec<usize>) -> CostSpec {
    CostSpec::linear(
        ModelKind::Proposed,
        CommandKind::Acceleration,
        weights,
        Init::Rest,
        closed,
        free,
    )
}

fn open_run<'a>(u: &'a [f64], a: &'a [f64]) -> RunRef<'a> {
    RunRef {
        dt: 0.05,
        command: Some(u),
        lead_x: None,
        lead_v: None,
        a,
        v: None,
        x: None,
        upper: UP,
        exo: vec![],
    }
}

const ROW: [f64; 6] = [6.7893, 1.2824, 8.8157, 0.3479, 0.7903, 0.1008];

#[test]
fn unstable_params_cost_inf() {
    let u = cmd(2000);
    let run = open_run(&u, &u);
    // K K0 > 1: the inner loop is unstable; m2 < 0: invalid.
    let rows = [1.0, 1.0, 1.0, 1.0, 0.1, 5.0, 1.0, -1.0, 1.0, 1.0, 0.1, 0.0];
    let c = batch_cost(&spec(false, [1.0, 0.0, 0.0], vec![]), &rows, &[run]).unwrap();
    assert_eq!(c, vec![f64::INFINITY, f64::INFINITY]);
}

#[test]
fn bounded_cost_is_exact_or_abandons_above_the_bound() {
    let u = cmd(3000);
    let y: Vec<f64> = simulate(&proposed(), &u, 0.05, Init::Rest)
        .unwrap()
        .iter()
        .enumerate()
        .map(|(k, v)| v + 0.05 * ((k * 7919) as f64).sin())
        .collect();
    let run = open_run(&u, &y);
    let sp = spec(false, [1.0, 0.0, 0.0], vec![]);
    let row = [1.0, 0.5, 2.0, 0.8, 0.33, -0.4];
    let exact = run_cost(&sp, &row, &run, f64::INFINITY);
    let sse = exact * u.len() as f64;
    assert_eq!(
        run_cost(&sp, &row, &run, sse * 1.0001).to_bits(),
        exact.to_bits()
    );
    assert_eq!(run_cost(&sp, &row, &run, sse * 0.5), f64::INFINITY);
}

#[test]
fn batched_simulation_equals_single_rollouts() {
    let (lx, lv) = leader(1500, 0.05);
    let tr = closed_loop(
        &proposed(),
        &EffectsRef::NONE,
        &UP,
        &lx,
        &lv,
        0.05,
        10.0,
        70.0,
    )
    .unwrap();
    let run = RunRef {
        dt: 0.05,
        command: None,
        lead_x: Some(&lx),
        lead_v: Some(&lv),
        a: &tr.a,
        v: Some(&tr.v),
        x: Some(&tr.x),
        upper: UP,
        exo: vec![],
    };
    let sp = spec(true, [1.0, 1.0, 1.0], vec![2]);
    let rows: Vec<f64> = [ROW.as_slice(), &[2.0], ROW.as_slice(), &[1.5]].concat();
    let n = lx.len();
    let (mut a, mut v, mut x) = (vec![0.0; 2 * n], vec![0.0; 2 * n], vec![0.0; 2 * n]);
    simulate_batch(
        &sp,
        &rows,
        std::slice::from_ref(&run),
        &mut a,
        &mut v,
        &mut x,
    )
    .unwrap();
    // Row 0 is the data's own model: it reproduces it exactly (same start).
    assert_eq!(&a[..n], &tr.a[..]);
    let other = closed_loop(
        &proposed(),
        &EffectsRef::NONE,
        &Upper { tg: 1.5, ..UP },
        &lx,
        &lv,
        0.05,
        10.0,
        70.0,
    )
    .unwrap();
    assert_eq!(&x[n..], &other.x[..]);
    // And the cost of row 0 is zero.
    let c = batch_cost(&sp, &rows, &[run]).unwrap();
    assert_eq!(c[0], 0.0);
    assert!(c[1] > 0.0 && c[1].is_finite());
}

#[test]
fn lanes_equal_the_kernel_bit_for_bit() {
    let u = cmd(3000);
    let y: Vec<f64> = simulate(&proposed(), &u, 0.05, Init::Rest)
        .unwrap()
        .iter()
        .enumerate()
        .map(|(k, v)| v + 0.05 * ((k * 7919) as f64).sin())
        .collect();
    for init in [Init::Rest, Init::Steady] {
        let sp = CostSpec::linear(
            ModelKind::Proposed,
            CommandKind::Acceleration,
            [1.0, 0.0, 0.0],
            init,
            false,
            vec![],
        );
        let run = open_run(&u, &y);
        // Modal and complex-pole rows, different dead times, an unstable and an
        // invalid row, and a partial group.
        let rows: Vec<Vec<f64>> = vec![
            ROW.to_vec(),
            vec![0.0, 0.0445, 0.1305, 0.7292, 0.7796, 0.0],
            vec![1.0, 0.5, 2.0, 0.8, 0.33, -0.4],
            vec![1.0, 1.0, 1.0, 1.0, 0.1, 5.0],
            vec![1.0, -1.0, 1.0, 1.0, 0.1, 0.0],
            vec![0.2, 0.8, 1.9, 1.1, 0.05, 0.3],
        ];
        let flat: Vec<f64> = rows.concat();
        let got = batch_cost(&sp, &flat, std::slice::from_ref(&run)).unwrap();
        for (row, g) in rows.iter().zip(&got) {
            let want = run_cost(&sp, row, &run, f64::INFINITY);
            assert_eq!(g.to_bits(), want.to_bits(), "{row:?}: {g} vs {want}");
        }
        assert!(got[0].is_finite() && got[3].is_infinite() && got[4].is_infinite());
        // Four variants of ROW: dead times `tds`, parameter `k` scaled by 1 + step i.
        let vary = |tds: [f64; 4], k: usize, step: f64| -> Vec<Vec<f64>> {
            let mut rows = vec![ROW.to_vec(); 4];
            for (i, r) in rows.iter_mut().enumerate() {
                r[4] = tds[i];
                r[k] *= 1.0 + step * i as f64;
            }
            rows
        };
        // A group whose dead times are the same whole number of samples (15 at
        // dt = 0.05 s) with different fractions: the lanes read one row of the line.
        let same_delay = vary([0.751, 0.7796, 0.7903, 0.7999], 1, 0.1);
        // Four modal (real-pole) rows with different whole-sample dead times: the
        // diagonal lanes, each gathering its own delayed input.
        let modal = vary([0.2, 0.45, 0.7903, 1.3], 2, 0.2);
        for group in [&same_delay, &modal] {
            let got = batch_cost(&sp, &group.concat(), std::slice::from_ref(&run)).unwrap();
            for (row, g) in group.iter().zip(&got) {
                let want = run_cost(&sp, row, &run, f64::INFINITY);
                assert!(want.is_finite());
                assert_eq!(g.to_bits(), want.to_bits(), "{row:?}: {g} vs {want}");
            }
        }
        // Several runs (plants shared across them), and runs of another dt.
        let other = RunRef {
            dt: 0.1,
            ..open_run(&u[1000..], &y[1000..])
        };
        // Nine runs: a last partial group of rows goes through the runs stepped
        // together (groups of equal dt and length: four, three, one and one).
        let mut nine = vec![run.clone(), other.clone()];
        for k in 0..7 {
            let from = if k < 4 { 500 } else { 700 };
            nine.push(open_run(&u[from..], &y[from..]));
        }
        for runs in [
            vec![run.clone(), open_run(&u[500..], &y[500..])],
            vec![run.clone(), other],
            nine,
        ] {
            for n in [1, 2, 3, 5, rows.len()] {
                let flat: Vec<f64> = rows[..n].concat();
                let got = batch_cost(&sp, &flat, &runs).unwrap();
                for (i, row) in rows[..n].iter().enumerate() {
                    for (j, r) in runs.iter().enumerate() {
                        let want = run_cost(&sp, row, r, f64::INFINITY);
                        assert_eq!(
                            got[i * runs.len() + j].to_bits(),
                            want.to_bits(),
                            "{n} rows, row {i}, run {j}"
                        );
                    }
                }
            }
        }
    }
}

#[test]
fn time_major_outputs_equal_per_follower_outputs() {
    let (lx, lv) = leader(1500, 0.05);
    for up in [UP, WILD] {
        let trs = platoon(&proposed(), &EffectsRef::NONE, &up, &lx, &lv, 0.05, 4).unwrap();
        let n = lx.len();
        let mut bufs = [
            vec![0.0; 4 * n],
            vec![0.0; 4 * n],
            vec![0.0; 4 * n],
            vec![0.0; 4 * n],
        ];
        let [a, v, x, u] = &mut bufs;
        let mut tm = super::rollout::TimeMajor {
            followers: 4,
            a,
            v,
            x,
            u,
        };
        super::rollout::platoon_into(&proposed(), &EffectsRef::NONE, &up, &lx, &lv, 0.05, &mut tm)
            .unwrap();
        for (j, tr) in trs.iter().enumerate() {
            for k in 0..n {
                assert_eq!(tr.a[k].to_bits(), bufs[0][k * 4 + j].to_bits());
                assert_eq!(tr.x[k].to_bits(), bufs[2][k * 4 + j].to_bits());
                assert_eq!(tr.command[k].to_bits(), bufs[3][k * 4 + j].to_bits());
            }
        }
    }
}

#[test]
fn run_lanes_equal_the_kernel_bit_for_bit() {
    use super::cost::{run_groups, run_lanes};
    let u = cmd(3000);
    let y: Vec<f64> = simulate(&proposed(), &u, 0.05, Init::Rest)
        .unwrap()
        .iter()
        .enumerate()
        .map(|(k, v)| v + 0.05 * ((k * 7919) as f64).sin())
        .collect();
    // Five runs of 1000 samples (two lane groups), one shorter run and one of another
    // dt (each alone), different first commands (the steady start differs per lane).
    let mut runs: Vec<RunRef> = (0..5)
        .map(|q| open_run(&u[q * 300..q * 300 + 1000], &y[q * 300..q * 300 + 1000]))
        .collect();
    runs.push(open_run(&u[..700], &y[..700]));
    runs.push(RunRef {
        dt: 0.1,
        ..open_run(&u[1000..2000], &y[1000..2000])
    });
    let refs: Vec<&RunRef> = runs.iter().collect();
    let groups = run_groups(&refs);
    assert_eq!(groups, vec![vec![0, 1, 2, 3], vec![4], vec![5], vec![6]]);
    let two: Vec<&RunRef> = refs[..3].iter().chain(&refs[4..5]).copied().collect();
    assert_eq!(run_groups(&two), vec![vec![0, 1, 2, 3]]);
    for init in [Init::Rest, Init::Steady] {
        let sp = CostSpec::linear(
            ModelKind::Proposed,
            CommandKind::Acceleration,
            [1.0, 0.0, 0.0],
            init,
            false,
            vec![],
        );
        for row in [
            ROW.to_vec(),
            vec![0.0, 0.0445, 0.1305, 0.7292, 0.7796, 0.0],
            vec![1.0, 0.5, 2.0, 0.8, 0.33, -0.4],
            vec![1.0, 1.0, 1.0, 1.0, 0.1, 5.0],
            vec![1.0, -1.0, 1.0, 1.0, 0.1, 0.0],
        ] {
            let exact: Vec<f64> = refs
                .iter()
                .map(|r| run_cost(&sp, &row, r, f64::INFINITY))
                .collect();
            // Unbounded, and with limits that abandon some runs and not others.
            let tight: Vec<f64> = exact
                .iter()
                .enumerate()
                .map(|(q, c)| c * 1000.0 * if q % 2 == 0 { 0.5 } else { 1.0001 })
                .collect();
            for limits in [vec![f64::INFINITY; refs.len()], tight] {
                let got = run_lanes(&sp, &row, &refs, &limits);
                for (q, r) in refs.iter().enumerate() {
                    let want = run_cost(&sp, &row, r, limits[q]);
                    assert_eq!(got[q].to_bits(), want.to_bits(), "{row:?} run {q}");
                }
                // The five alike runs alone: one group of five lanes.
                let got = run_lanes(&sp, &row, &refs[..5], &limits[..5]);
                for (q, r) in refs[..5].iter().enumerate() {
                    let want = run_cost(&sp, &row, r, limits[q]);
                    assert_eq!(got[q].to_bits(), want.to_bits(), "{row:?} of five, run {q}");
                }
            }
        }
    }
}

/// The rollouts check their inputs after the run (a finite stepper proves them
/// finite): a bad sample anywhere — first, inside the dead time at the end, or with
/// zero gains in front of it — is still named, for every model, delay and init.
#[test]
fn a_bad_input_sample_anywhere_is_named() {
    let first = Linear {
        b1: 0.0,
        b0: 1.0,
        a2: 0.0,
        a1: 0.4,
        td: 0.0,
        k: 0.0,
    };
    let frac = Linear {
        td: 0.33,
        ..second()
    };
    let n = 300;
    for lin in [first, second(), frac, proposed()] {
        for init in [Init::Rest, Init::Steady] {
            for at in [0, 1, 2, 150, n - 20, n - 2, n - 1] {
                for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
                    let mut u = cmd(n);
                    u[at] = bad;
                    let e = simulate(&lin, &u, 0.05, init).unwrap_err().to_string();
                    assert!(
                        e.contains("command") && e.contains(&format!("sample {at} ")),
                        "{e}"
                    );
                }
            }
        }
        for at in [0, 1, 150, n - 2, n - 1] {
            for which in 0..2 {
                // kg = 0 too: 0 x inf is NaN, the bad sample still reaches the state.
                for up in [UP, Upper { kg: 0.0, ..UP }] {
                    let (mut lx, mut lv) = leader(n, 0.05);
                    if which == 0 {
                        lx[at] = f64::INFINITY;
                    } else {
                        lv[at] = f64::NAN;
                    }
                    let e = closed_loop(&lin, &EffectsRef::NONE, &up, &lx, &lv, 0.05, 10.0, 0.0)
                        .unwrap_err()
                        .to_string();
                    let name = ["lead_x", "lead_v"][which];
                    assert!(
                        e.contains(name) && e.contains(&format!("sample {at} ")),
                        "{e}"
                    );
                }
            }
        }
    }
    // A diverging model with finite inputs is no error: NaN after the divergence.
    let (lx, lv) = leader(n, 0.05);
    let wild = Upper {
        kg: 50.0,
        kv: 0.0,
        tg: 0.1,
        gmin: 2.0,
    };
    let tr = closed_loop(
        &proposed(),
        &EffectsRef::NONE,
        &wild,
        &lx,
        &lv,
        0.05,
        10.0,
        0.0,
    )
    .unwrap();
    assert!(tr.a[n - 1].is_nan());
}

/// The sample-by-sample open-loop response (the step loop the block form replaces).
fn stepped_n<const M: usize, const N: usize, const D: bool, const F: bool>(
    plant: Plant<M, N>,
    lin: &Linear,
    u: &[f64],
    init: Init,
    y: &mut [f64],
) -> crate::error::Result<bool> {
    let applies = super::kernel::blocks_apply(&plant);
    let s = super::plant::start(lin, init, u[0])?;
    let mut st =
        stepper::<M, N, D, F, _>(plant, lin, Integrators::None, NoEffects, true, &s, [0.0; 2])?;
    run(
        &mut st,
        u.len(),
        |n, _| u[n],
        &mut super::kernel::Response(y),
    );
    Ok(applies)
}

#[test]
fn block_response_equals_the_step_loop() {
    let underdamped = Linear {
        b1: 0.4,
        b0: 1.0,
        a2: 0.5,
        a1: 0.3,
        td: 0.31,
        k: -0.2,
    };
    let first = Linear {
        b1: 0.0,
        b0: 1.0,
        a2: 0.0,
        a1: 0.45,
        td: 0.43,
        k: 0.0,
    };
    let (mut blocked, mut stepped) = (0, 0);
    for lin in [proposed(), second(), underdamped, first] {
        for (dt, td) in [
            (0.05, lin.td),
            (0.01, lin.td),
            (0.1, 0.4),
            (0.1, 0.45),
            (0.05, 0.1),
        ] {
            let lin = Linear { td, ..lin };
            for len in [1usize, 3, 4, 5, 7, 8, 9, 63, 64, 65, 1001, 4099] {
                let u: Vec<f64> = cmd(len).iter().map(|v| v + 0.3).collect();
                for init in [Init::Rest, Init::Steady] {
                    let got = simulate(&lin, &u, dt, init).unwrap();
                    let mut want = vec![0.0; len];
                    let applies = if lin.order() == 1 {
                        let p = Plant::<1, 1>::new(&lin, Integrators::None, dt, true).unwrap();
                        stepped_n::<1, 1, true, false>(p, &lin, &u, init, &mut want)
                    } else {
                        let p = Plant::<2, 2>::new(&lin, Integrators::None, dt, true).unwrap();
                        if p.diag {
                            stepped_n::<2, 2, true, false>(p, &lin, &u, init, &mut want)
                        } else {
                            stepped_n::<2, 2, false, false>(p, &lin, &u, init, &mut want)
                        }
                    }
                    .unwrap();
                    if applies {
                        blocked += 1;
                    } else {
                        stepped += 1;
                    }
                    let d = max_diff(&got, &want);
                    assert!(
                        d < 1e-12,
                        "{lin:?} dt {dt} len {len} {init:?}: block form differs by {d:e}"
                    );
                }
            }
        }
    }
    // Both paths were exercised (dead times of 2 to 79 samples).
    assert!(
        blocked > 100 && stepped > 20,
        "{blocked} blocked, {stepped} stepped"
    );
}
