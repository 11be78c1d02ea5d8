use avll::model::ModelKind;
use avll::stability::{grid, LoopModel};
use std::time::Instant;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let lin = if args.len() > 1 {
        ModelKind::FirstOrder.linear(&[1.0758]).unwrap()
    } else {
        ModelKind::Proposed
            .linear(&[6.7893, 1.2824, 8.8157, 0.3479, 0.7903, 0.1008])
            .unwrap()
    };
    let lm = LoopModel::new(&lin, 2).unwrap();
    let kg: Vec<f64> = (0..1000).map(|i| 0.001 + 2.0 * i as f64 / 999.0).collect();
    let tg: Vec<f64> = (0..1000).map(|i| 15.0 * i as f64 / 999.0).collect();
    let kv = [0.3];
    let axes = grid::Axes::new(&kg, &tg, &kv).unwrap();
    let mut out = vec![0u8; axes.len()];
    for _ in 0..3 {
        let t = Instant::now();
        for (i, o) in out.iter_mut().enumerate() {
            let (a, b, c) = axes.point(i);
            *o = lm.classify(a, b, c);
        }
        let dt = t.elapsed().as_secs_f64();
        let t2 = Instant::now();
        let mut s = 0usize;
        for i in 0..axes.len() {
            let (a, b, c) = axes.point(i);
            let d = lm.char_poly(a, b, c);
            s += avll::stability::routh::hurwitz(&d) as usize;
        }
        let dt2 = t2.elapsed().as_secs_f64();
        let t3 = Instant::now();
        let mut s3 = 0usize;
        let lm = &lm;
        for i in 0..axes.len() {
            let (a, b, c) = axes.point(i);
            s3 += avll::stability::string_stable(&lm.string_poly_fast(a, b, c)) as usize;
        }
        let dt3 = t3.elapsed().as_secs_f64();
        println!(
            "{:.1} M/s classify; local-only {:.1} M/s ({s}); string-only {:.1} M/s ({s3})",
            1e-6 * axes.len() as f64 / dt,
            1e-6 * axes.len() as f64 / dt2,
            1e-6 * axes.len() as f64 / dt3
        );
    }
}
