//! Unit tests of the stability engine against the paper's expanded forms and the
//! Appendix closed form.

use super::poly::Poly;
use super::*;
use crate::model::ModelKind;

struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-12 * (1.0 + a.abs().max(b.abs()))
}

/// Eq. 14 (a1..a7) and Eq. 17 (b1'..b5') against the product form, random parameters.
#[test]
#[allow(clippy::needless_range_loop)]
fn paper_eq14_eq17_equal_products() {
    let mut r = Lcg(7);
    let (p1, p2) = (0.5, 1.0 / 12.0);
    for _ in 0..500 {
        let (m1, m2, m3, k0, td, k) = (
            r.range(0.0, 10.0),
            r.range(0.01, 3.0),
            r.range(0.0, 10.0),
            r.range(0.05, 2.0),
            r.range(0.0, 2.0),
            r.range(-1.0, 1.0),
        );
        let (kg, tg, kv) = (r.range(0.0, 2.0), r.range(0.0, 10.0), r.range(-1.0, 2.0));
        let lin = ModelKind::Proposed
            .linear(&[m1, m2, m3, k0, td, k])
            .unwrap();
        let lm = LoopModel::new(&lin, 2).unwrap();
        let (n, d) = lm.closed_loop(kg, tg, kv);
        let mu = kv + tg * kg;
        let t2 = td * td;
        let a = [
            m2 * t2 * p2,
            -t2 * k * m1 * p2 + t2 * m3 * p2 + td * m2 * p1,
            -k * k0 * t2 * p2 + k * m1 * td * p1 + t2 * p2 + m3 * td * p1 + m2 + m1 * t2 * p2 * mu,
            k * k0 * td * p1 + td * p1 - k * m1
                + m3
                + (k0 * t2 * p2 - td * m1 * p1) * mu
                + m1 * t2 * p2 * kg,
            -k * k0 + (-k0 * td * p1 + m1) * mu + (k0 * t2 * p2 - td * m1 * p1) * kg + 1.0,
            k0 * mu + (-k0 * td * p1 + m1) * kg,
            k0 * kg,
        ];
        assert_eq!(d.deg, 6);
        for i in 0..7 {
            assert!(
                close(d.c[6 - i], a[i]),
                "a{}: {} vs {}",
                i + 1,
                d.c[6 - i],
                a[i]
            );
        }
        let b = [
            t2 * kv * m1 * p2,
            k0 * t2 * kv * p2 + t2 * kg * m1 * p2 - td * kv * m1 * p1,
            k0 * t2 * kg * p2 - k0 * td * kv * p1 - td * kg * m1 * p1 + kv * m1,
            -k0 * td * kg * p1 + k0 * kv + kg * m1,
            k0 * kg,
        ];
        assert_eq!(n.deg, 4);
        for i in 0..5 {
            assert!(
                close(n.c[4 - i], b[i]),
                "b{}': {} vs {}",
                i + 1,
                n.c[4 - i],
                b[i]
            );
        }
        // Eq. 19: c1'..c6' against R(x) = P(x)/x.
        let c = [
            a[0] * a[0],
            a[1] * a[1] - 2.0 * a[0] * a[2],
            2.0 * a[0] * a[4] - 2.0 * a[1] * a[3] + a[2] * a[2] - b[0] * b[0],
            -2.0 * a[0] * a[6] + 2.0 * a[1] * a[5] - 2.0 * a[2] * a[4]
                + 2.0 * b[0] * b[2]
                + a[3] * a[3]
                - b[1] * b[1],
            2.0 * a[2] * a[6] - 2.0 * a[3] * a[5] - 2.0 * b[0] * b[4]
                + 2.0 * b[1] * b[3]
                + a[4] * a[4]
                - b[2] * b[2],
            -2.0 * a[4] * a[6] + 2.0 * b[2] * b[4] + a[5] * a[5] - b[3] * b[3],
        ];
        let rx = lm.string_poly(kg, tg, kv);
        let scale = c.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        for i in 0..6 {
            let got = rx.c.get(5 - i).copied().unwrap_or(0.0);
            assert!(
                (got - c[i]).abs() <= 1e-10 * (1.0 + scale),
                "c{}': {} vs {}",
                i + 1,
                got,
                c[i]
            );
        }
    }
}

/// `x R(x) = |D(j√x)|² − |N(j√x)|²` for every model and Padé order.
#[test]
fn string_poly_is_gain_difference() {
    let mut r = Lcg(11);
    let models = [
        (ModelKind::FirstOrder, vec![1.0758]),
        (ModelKind::SecondOrder, vec![0.7292, 0.0445, 0.1305, 0.7796]),
        (
            ModelKind::Proposed,
            vec![6.7893, 1.2824, 8.8157, 0.3479, 0.7903, 0.1008],
        ),
    ];
    for (kind, p) in &models {
        let lin = kind.linear(p).unwrap();
        for order in 1..=pade::MAX_ORDER {
            let lm = LoopModel::new(&lin, order).unwrap();
            for _ in 0..20 {
                let (kg, tg, kv) = (r.range(0.0, 2.0), r.range(0.0, 10.0), r.range(-1.0, 2.0));
                let (n, d) = lm.closed_loop(kg, tg, kv);
                let rx = lm.string_poly(kg, tg, kv);
                for &w in &[0.05, 0.3, 1.0, 2.5] {
                    let (dr, di) = d.eval_complex(0.0, w);
                    let (nr, ni) = n.eval_complex(0.0, w);
                    let direct = dr * dr + di * di - nr * nr - ni * ni;
                    let via = w * w * rx.eval(w * w);
                    let scale = dr * dr + di * di + nr * nr + ni * ni;
                    assert!(
                        (direct - via).abs() <= 1e-9 * scale,
                        "{:?} order {order}: {direct} vs {via}",
                        kind
                    );
                }
            }
        }
    }
}

/// First-order lag against the Appendix closed form (A.3, A.4).
#[test]
fn first_order_lag_matches_appendix() {
    let td = 1.0758;
    let lin = ModelKind::FirstOrder.linear(&[td]).unwrap();
    let lm = LoopModel::new(&lin, 2).unwrap();
    let mut r = Lcg(3);
    let mut checked = 0;
    let mut counts = [0usize; 3];
    for _ in 0..200_000 {
        let (kg, tg, kv) = (r.range(1e-3, 2.0), r.range(0.0, 6.0), r.range(-0.5, 2.0));
        let mu = kv + tg * kg;
        let local = kv + kg * (tg - td);
        let c0 = tg * kv + tg * tg * kg / 2.0 - 1.0;
        let edge = mu - 1.0 / (2.0 * td);
        let disc = (tg / td - 2.0) * kg - (kv - 1.0 / (2.0 * td)).powi(2);
        // skip points within rounding distance of a boundary of the closed form
        if [local, c0, edge, disc].iter().any(|m| m.abs() < 1e-9) {
            continue;
        }
        let string = (edge <= 0.0 && c0 > 0.0) || (edge >= 0.0 && disc > 0.0);
        let expect = if local <= 0.0 {
            LOCAL_UNSTABLE
        } else if string {
            STABLE
        } else {
            STRING_UNSTABLE
        };
        let got = lm.classify(kg, tg, kv);
        assert_eq!(got, expect, "kg={kg} tg={tg} kv={kv}");
        counts[got as usize] += 1;
        checked += 1;
    }
    assert!(checked > 190_000);
    assert!(counts.iter().all(|&c| c > 10_000), "{counts:?}");
}

#[test]
fn polynomial_degrees_fit_every_order() {
    let lin = ModelKind::Proposed
        .linear(&[6.7893, 1.2824, 8.8157, 0.3479, 0.7903, 0.1008])
        .unwrap();
    for order in 1..=pade::MAX_ORDER {
        let lm = LoopModel::new(&lin, order).unwrap();
        let (n, d) = lm.closed_loop(0.5, 2.0, 0.3);
        assert_eq!(d.deg, 4 + order);
        assert_eq!(n.deg, 2 + order);
        let _ = lm.classify(0.5, 2.0, 0.3);
    }
    assert!(LoopModel::new(&lin, 0).is_err());
    assert!(LoopModel::new(&lin, pade::MAX_ORDER + 1).is_err());
}

#[test]
fn degenerate_points_are_not_stable() {
    let lin = ModelKind::SecondOrder
        .linear(&[0.7292, 0.0445, 0.1305, 0.7796])
        .unwrap();
    let lm = LoopModel::new(&lin, 2).unwrap();
    // kg = 0: a root at s = 0
    assert_eq!(lm.classify(0.0, 2.0, 0.3), LOCAL_UNSTABLE);
    assert_eq!(lm.classify(-0.1, 2.0, 0.3), LOCAL_UNSTABLE);
    // a clearly stable point and a clearly string-unstable one (small Tg)
    assert_eq!(lm.classify(0.05, 6.0, 0.2), STABLE);
    assert_eq!(lm.classify(0.05, 0.5, 0.2), STRING_UNSTABLE);
    let _ = Poly::ZERO;
}

#[test]
fn grid_layout_matches_pointwise() {
    let lin = ModelKind::Proposed
        .linear(&[6.7893, 1.2824, 8.8157, 0.3479, 0.7903, 0.1008])
        .unwrap();
    let lm = LoopModel::new(&lin, 2).unwrap();
    let kg: Vec<f64> = (0..7).map(|i| 0.01 + 0.1 * i as f64).collect();
    let tg: Vec<f64> = (0..5).map(|i| 1.0 * i as f64).collect();
    let kv: Vec<f64> = (0..3).map(|i| 0.2 * i as f64).collect();
    let axes = grid::Axes::new(&kg, &tg, &kv).unwrap();
    let m = grid::map(&lm, &axes);
    for (a, &g) in kg.iter().enumerate() {
        for (b, &t) in tg.iter().enumerate() {
            for (c, &v) in kv.iter().enumerate() {
                assert_eq!(m[(a * tg.len() + b) * kv.len() + c], lm.classify(g, t, v));
            }
        }
    }
    let mut part = vec![9u8; 20];
    grid::fill_range(&lm, &axes, 40, &mut part);
    assert_eq!(&part[..], &m[40..60]);
    assert!(grid::Axes::new(&[], &tg, &kv).is_err());
    assert!(grid::Axes::new(&[f64::NAN], &tg, &kv).is_err());
}

/// The fast (precomputed, bilinear) D and R equal the direct products.
#[test]
fn fast_path_equals_products() {
    let mut r = Lcg(5);
    for _ in 0..300 {
        let p = [
            r.range(0.0, 10.0),
            r.range(0.01, 3.0),
            r.range(0.0, 10.0),
            r.range(0.05, 2.0),
            r.range(0.0, 2.0),
            r.range(-1.0, 1.0),
        ];
        let lin = ModelKind::Proposed.linear(&p).unwrap();
        let order = 1 + (r.next() * 5.0) as usize;
        let lm = LoopModel::new(&lin, order).unwrap();
        let (kg, tg, kv) = (r.range(0.0, 2.0), r.range(0.0, 10.0), r.range(-1.0, 2.0));
        let (_, d) = lm.closed_loop(kg, tg, kv);
        let d2 = lm.char_poly(kg, tg, kv);
        assert_eq!(d.deg, d2.deg);
        for k in 0..=d.deg {
            assert!(close(d.c[k], d2.c[k]));
        }
        let (r1, r2) = (lm.string_poly(kg, tg, kv), lm.string_poly_fast(kg, tg, kv));
        let scale = r1.max_abs();
        assert_eq!(r1.deg, r2.deg);
        for k in 0..=r1.deg {
            assert!((r1.c[k] - r2.c[k]).abs() <= 1e-12 * scale, "{r1:?} {r2:?}");
        }
    }
}
