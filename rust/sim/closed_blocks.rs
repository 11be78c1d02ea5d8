//! The linear closed loop (no effect) four samples at a time, with the very
//! operations of the one kernel, so bit for bit the trajectory of
//! [`super::kernel::run`].
//!
//! A closed-loop step is a few dozen floating-point operations, all of them needed at
//! every sample, and the kernel's loop issues them one sample after the other: the
//! two multiply-add units bound it, not its dependency chains. Only three operations
//! sit on a chain from one sample to the next: each mode's `z' = phi z + t` (one
//! multiply-add), the speed's `v' = v + t` and the position's `p' = p + t` (one
//! addition each). Everything else at sample `n` (the input terms of the dead-time
//! line's outputs, the response `C z`, the speed and position increments, the upper
//! law's command, the reference into the line) reads the state at `n` and line
//! outputs written at least `i` samples earlier. With a whole-sample dead time of
//! `i >= 4` samples the four line outputs a block of four samples reads were all
//! written before the block starts, so per block (AVX2, one sample per lane):
//!
//! 1. the modes' input terms of the four samples side by side (one four-wide
//!    operation per term), then the two modes' chains together (both modes in one
//!    two-wide register), one multiply-add per sample; the four responses and speed
//!    increments side by side;
//! 2. the speed's chain (three additions give the block's speeds, a fourth the next
//!    block's), the four position increments side by side, the position's chain;
//! 3. the four commands and references side by side, into the outputs and the line.
//!
//! Each lane performs exactly the kernel's operations for its sample, in the same
//! order (the kernel's `observe`, the upper law, `step` and `advance`), so the
//! trajectory is the kernel's to the bit (tested: `closed_blocks_equal_the_kernel`),
//! and every identity built on the kernel holds (a platoon equals its followers
//! simulated one by one, neutral effects equal the linear path, a closed-loop cost is
//! the rollout's). What changes is the work per sample: the operations off the
//! chains take a quarter of the instructions.
//!
//! What bounds it then is latency: a block's stages form one long dependency path
//! (line outputs, modes, speeds, positions, commands, references), and the dead-time
//! line closes it into a loop (a block's references are the line outputs of the
//! blocks a dead time later). So the blocks are software-pipelined (stage 1 of the
//! next block is issued before stage 2 of this one, which needs a dead time of at
//! least two blocks), each block reads the line as the two whole blocks of references
//! its outputs lie in (loads that match earlier stores, which the CPU forwards), or,
//! when those lie three or four blocks back (dead times of 8 to 15 samples), from the
//! last four blocks of references kept in registers; the divergence test runs lane by
//! lane in registers (the speed once per chunk); the speed's and the position's
//! running values are scalar additions, each lane's value taken as soon as it is
//! made.
//!
//! The loop's length in blocks is set by the first sample that reads the newest
//! block of references: a vector waits for its slowest lane. When only sample 3
//! reads it (`(i + 1)` a multiple of four: 11 and 15 samples, the latter the paper's
//! proposed model at 20 Hz), samples 0 to 2 are computed from the older block alone
//! and sample 3's terms apart, and the loop spans one block more (measured on an
//! AMD Zen 5: 15 samples went from 35 to 32 cycles per block, 11 from 49 to 36).
//!
//! Applies to the second-order models with a dead time of at least eight samples on
//! a CPU with FMA and AVX2. On a CPU with AVX-512VL the same instructions are compiled
//! with its 32 vector registers (the loop's constants and pipelined values no longer
//! spill to the stack); the results are the same bit for bit. The other models step
//! through the kernel's loop.

use super::chain::NoEffects;
use super::kernel::{Record, Stepper, BLOCK};
use super::rollout::Upper;

/// Whether [`closed_blocks`] applies: FMA and AVX2 (`F`, and the CPU), a
/// second-order model with speed and position (`M == 2`, `N == 4`), and a
/// whole-sample dead time of at least `2 BLOCK` samples (a block's line outputs are
/// then written before the block ahead of it starts: the software pipeline's
/// condition).
pub fn closed_blocks_apply<const M: usize, const N: usize, const F: bool>(
    p: &super::plant::Plant<M, N>,
) -> bool {
    cfg!(target_arch = "x86_64") && F && M == 2 && N == 4 && p.delay >= 2 * BLOCK && super::fma()
}

/// The linear closed loop behind the leader `(lead_x, lead_v)` into `rec`, from
/// sample 0 (the stepper's start) to the end of the leader or the first divergence
/// (the recorder's chunk test, as [`super::kernel::run`] does it): returns `false`
/// when the recorder stopped the run. The stepper ends in the state (and with the
/// dead-time line) the kernel's loop would leave, bit for bit.
///
/// Requires [`closed_blocks_apply`] (checked: otherwise the kernel's loop runs) and
/// `lead_v.len() >= lead_x.len()`. Compiled for AVX-512VL when `wide` and the CPU
/// has it, for AVX2 otherwise (the same instructions; the tests run both).
#[cfg_attr(not(target_arch = "x86_64"), allow(unused_variables))]
pub fn closed_blocks<
    const M: usize,
    const N: usize,
    const D: bool,
    const F: bool,
    const U: bool,
>(
    st: &mut Stepper<M, N, D, F, NoEffects>,
    up: &Upper,
    lead_x: &[f64],
    lead_v: &[f64],
    rec: &mut Record<'_, true, U>,
    wide: bool,
) -> bool {
    #[cfg(target_arch = "x86_64")]
    if closed_blocks_apply::<M, N, F>(&st.plant) {
        // The offset of a block's first `w1` in its block of references.
        let o = (st.plant.delay + 1).wrapping_neg() % BLOCK;
        // How many blocks back a block's first line output lies (3 or 4: the line
        // read from registers; further back, from memory).
        let back = (st.plant.delay + 1).div_ceil(BLOCK);
        macro_rules! go {
            ($f:ident, $r:literal) => {
                match o {
                    0 => $f::<M, N, D, F, U, 0, $r>(st, up, lead_x, lead_v, rec),
                    1 => $f::<M, N, D, F, U, 1, $r>(st, up, lead_x, lead_v, rec),
                    2 => $f::<M, N, D, F, U, 2, $r>(st, up, lead_x, lead_v, rec),
                    _ => $f::<M, N, D, F, U, 3, $r>(st, up, lead_x, lead_v, rec),
                }
            };
            ($f:ident) => {
                match back {
                    3 => go!($f, 3),
                    4 => go!($f, 4),
                    _ => go!($f, 0),
                }
            };
        }
        // The same instructions either way; AVX-512VL only gives the compiler 32
        // vector registers instead of 16 (no spills in the loop).
        // SAFETY: `closed_blocks_apply` checked FMA and AVX2, `avx512` AVX-512.
        return unsafe {
            if wide && avx512() {
                go!(closed_avx512)
            } else {
                go!(closed_avx2)
            }
        };
    }
    let law = |n: usize, o: &super::kernel::Obs| up.command(lead_x[n], lead_v[n], o.p, o.v);
    super::kernel::run(st, lead_x.len(), law, rec)
}

/// Defines `$name`, the block form in AVX2 intrinsics compiled with the target
/// features `$features` (see [`closed_avx2`]): the same body twice, because an
/// intrinsic is inlined only into a function compiled with its features.
macro_rules! closed_simd {
    ($(#[$doc:meta])* $name:ident, $features:literal) => {
        $(#[$doc])*
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $features)]
        unsafe fn $name<
            const M: usize,
            const N: usize,
            const D: bool,
            const F: bool,
            const U: bool,
            const O: usize,
            const R: usize,
        >(
            st: &mut Stepper<M, N, D, F, NoEffects>,
            up: &Upper,
            lead_x: &[f64],
            lead_v: &[f64],
            rec: &mut Record<'_, true, U>,
        ) -> bool {
    use super::kernel::{Sink, CHUNK, DIVERGED};
    use std::arch::x86_64::*;
    debug_assert!(M == 2 && N == 4 && st.plant.delay >= 2 * BLOCK);
    let len = lead_x.len().min(rec.capacity());
    let split: bool = O == 0 && R != 0;
    let (lead_x, lead_v) = (&lead_x[..len], &lead_v[..len]);
    let p = st.plant;
    let i = p.delay;
    debug_assert_eq!(O, (i + 1).wrapping_neg() % BLOCK);
    // A local copy of the dead-time line in whole blocks of references (a power of
    // two, so a block never wraps), long enough that the blocks written while a
    // block's line outputs wait to be read never overwrite them.
    let cap = (i + 2 * BLOCK).next_power_of_two();
    let mask = cap - 1;
    let mut line = vec![0.0; cap];
    st.line_out(&mut line, 0);
    let c = |x: f64| _mm256_set1_pd(x);
    // Input maps of the line's outputs (mode 0, mode 1, speed, position).
    let g0: [__m256d; 4] = std::array::from_fn(|r| c(p.g0[r % N]));
    let g1: [__m256d; 4] = std::array::from_fn(|r| c(p.g1[r % N]));
    let (s, q) = (M % N, (M + 1) % N);
    // Speed and position rows on the modes (and the position on the speed).
    let (pv0, pv1) = (c(p.phi[s][0]), c(p.phi[s][1 % N]));
    let (px0, px1, pxv) = (c(p.phi[q][0]), c(p.phi[q][1 % N]), c(p.phi[q][s]));
    let (c0, c1) = (c(p.c[0]), c(p.c[1 % N]));
    // The modes' own terms (lane r: mode r) and, without modal coordinates, each
    // mode's term of the other.
    let ldiag = _mm_set_pd(p.phi[1 % N][1 % N], p.phi[0][0]);
    let loff = _mm_set_pd(p.phi[1 % N][0], p.phi[0][1 % N]);
    let (kg, kv, tg, gmin, k) = (c(up.kg), c(up.kv), c(up.tg), c(up.gmin), c(p.k));
    // Each row's input maps side by side (sample 3's line terms when split).
    let g0r = _mm256_setr_pd(p.g0[0], p.g0[1 % N], p.g0[2 % N], p.g0[3 % N]);
    let g1r = _mm256_setr_pd(p.g1[0], p.g1[1 % N], p.g1[2 % N], p.g1[3 % N]);
    let inner = p.k != 0.0;
    let mut zc = _mm_set_pd(st.x[1 % N], st.x[0]);
    let (mut v, mut pos) = (_mm_set_sd(st.x[s]), _mm_set_sd(st.x[q]));
    let lp = line.as_mut_ptr();
    let (plx, plv) = (lead_x.as_ptr(), lead_v.as_ptr());
    let (pa, pv, px, pu) = (
        rec.a.as_mut_ptr(),
        rec.v.as_mut_ptr(),
        rec.x.as_mut_ptr(),
        rec.u.as_mut_ptr(),
    );
    debug_assert!(len <= rec.a.len() && len <= rec.v.len() && len <= rec.x.len());
    debug_assert!(!U || len <= rec.u.len());
    let step = |z: __m128d, t: __m128d| {
        if D {
            _mm_fmadd_pd(ldiag, z, t)
        } else {
            _mm_fmadd_pd(ldiag, z, _mm_fmadd_pd(loff, _mm_permute_pd::<1>(z), t))
        }
    };
    // Stage 1 of the block at `n0`: from the modes at `n0` (`zc`, advanced to the
    // block's end) and the line, the modes at the four samples, the responses, the
    // speed increments and the position increments' input terms.
    // SAFETY (the line): `base` and `base + BLOCK` (masked) are multiples of BLOCK
    // below `cap`, so each load reads four slots of the line.
    let load = |n0: usize| {
        let base = (n0.wrapping_sub(i + 1) & mask) & !(BLOCK - 1);
        (
            _mm256_loadu_pd(lp.add(base)),
            _mm256_loadu_pd(lp.add((base + BLOCK) & mask)),
        )
    };
    let stage1 = |(ra, rb): (__m256d, __m256d), zc: &mut __m128d| {
        // w1[j] = u_ref[n0+j-i-1], w0[j] = u_ref[n0+j-i]: written before the block,
        // read as the two whole blocks of references they lie in (each load then
        // matches one earlier store, which the CPU forwards) and aligned in registers.
        // With O = 0 and the line in registers, only sample 3 reads the newer block
        // (`w0[3]`, the first reference of `rb`): samples 0 to 2 are computed from
        // `ra` alone (lane 3 of the vectors below is then not used) and sample 3
        // apart, so that the newer block's references are waited for by the last
        // step and the next block only (the loop the dead time closes then spans
        // one block more).
        let (w1, w0) = if split {
            (ra, _mm256_permute4x64_pd::<0b00_11_10_01>(ra))
        } else {
            align::<O>(ra, rb)
        };
        // The modes' input terms, then their chains, both modes per register.
        let tz0 = _mm256_fmadd_pd(g1[0], w1, _mm256_mul_pd(g0[0], w0));
        let tz1 = _mm256_fmadd_pd(g1[1], w1, _mm256_mul_pd(g0[1], w0));
        let a = _mm256_unpacklo_pd(tz0, tz1); // [t0 t1] of samples 0 and 2
        let b = _mm256_unpackhi_pd(tz0, tz1); // of samples 1 and 3
        let z0 = *zc;
        let z1 = step(z0, _mm256_castpd256_pd128(a));
        let z2 = step(z1, _mm256_castpd256_pd128(b));
        let z3 = step(z2, _mm256_extractf128_pd::<1>(a));
        // Sample 3's line terms of the four rows (modes, speed, position).
        let q = _mm256_fmadd_pd(
            g1r,
            _mm256_permute4x64_pd::<0b11_11_11_11>(ra),
            _mm256_mul_pd(g0r, _mm256_broadcastsd_pd(_mm256_castpd256_pd128(rb))),
        );
        *zc = if split {
            step(z3, _mm256_castpd256_pd128(q))
        } else {
            step(z3, _mm256_extractf128_pd::<1>(b))
        };
        let e = _mm256_insertf128_pd::<1>(_mm256_castpd128_pd256(z0), z2);
        let o = _mm256_insertf128_pd::<1>(_mm256_castpd128_pd256(z1), z3);
        let m0 = _mm256_unpacklo_pd(e, o); // mode 0 at the four samples
        let m1 = _mm256_unpackhi_pd(e, o); // mode 1
                                           // Responses (`observe`), speed increments, position increments' inputs.
        let y = _mm256_fmadd_pd(c1, m1, _mm256_mul_pd(c0, m0));
        let tv = _mm256_fmadd_pd(g1[2], w1, _mm256_mul_pd(g0[2], w0));
        let tv = _mm256_fmadd_pd(pv1, m1, _mm256_fmadd_pd(pv0, m0, tv));
        let tp = _mm256_fmadd_pd(g1[3], w1, _mm256_mul_pd(g0[3], w0));
        [m0, m1, y, tv, tp, q, _mm256_castpd128_pd256(z3)]
    };
    // Stage 2 of the block at `n0`: the speed's chain, the position increments and
    // chain, the upper law, the references into the line, the outputs.
    // SAFETY: `(n0 & mask) + 4 <= cap` (`n0` and `cap` are multiples of BLOCK), and
    // `n0 + 4 <= len`, the length of the leader slices and at most that of the
    // outputs (`len <= rec.capacity()`).
    let stage2 = |[m0, m1, y, tv, tp, q, z3]: [__m256d; 7], v: &mut __m128d, pos: &mut __m128d| {
        let (vs, v3, tvh) = chains(*v, tv);
        let tpv = _mm256_fmadd_pd(pxv, vs, tp);
        let tp = _mm256_fmadd_pd(px1, m1, _mm256_fmadd_pd(px0, m0, tpv));
        let (ps, p3, tph) = chains(*pos, tp);
        // The increments of sample 3 into the next block's speed and position.
        if split {
            // Lane 3 of `tv` and `tp` from sample 3's line terms, as the vectors do it.
            let z3 = _mm256_castpd256_pd128(z3);
            let z31 = _mm_permute_pd::<1>(z3);
            let ql = _mm256_extractf128_pd::<1>(q);
            let lo = |x: __m256d| _mm256_castpd256_pd128(x);
            let tv3 = _mm_fmadd_sd(lo(pv1), z31, _mm_fmadd_sd(lo(pv0), z3, ql));
            let tp3 = _mm_fmadd_sd(
                lo(pxv),
                v3,
                _mm_permute_pd::<1>(ql),
            );
            let tp3 = _mm_fmadd_sd(lo(px1), z31, _mm_fmadd_sd(lo(px0), z3, tp3));
            *v = _mm_add_sd(v3, tv3);
            *pos = _mm_add_sd(p3, tp3);
        } else {
            *v = _mm_add_sd(v3, _mm_permute_pd::<1>(tvh));
            *pos = _mm_add_sd(p3, _mm_permute_pd::<1>(tph));
        }
        [vs, ps, y]
    };
    let law = |n0: usize, [vs, ps, y]: [__m256d; 3]| {
        // The upper law (Eq. 3): kg (lx - p - tg v - gmin) + kv (lv - v).
        let lx = _mm256_loadu_pd(plx.add(n0));
        let lv = _mm256_loadu_pd(plv.add(n0));
        let gap = _mm256_sub_pd(
            _mm256_sub_pd(_mm256_sub_pd(lx, ps), _mm256_mul_pd(tg, vs)),
            gmin,
        );
        let u = _mm256_add_pd(
            _mm256_mul_pd(kg, gap),
            _mm256_mul_pd(kv, _mm256_sub_pd(lv, vs)),
        );
        // The reference `u + K y` (the command itself without inner feedback).
        let r = if inner {
            _mm256_add_pd(u, _mm256_mul_pd(k, y))
        } else {
            u
        };
        _mm256_storeu_pd(lp.add(n0 & mask), r);
        _mm256_storeu_pd(pa.add(n0), y);
        _mm256_storeu_pd(pv.add(n0), vs);
        _mm256_storeu_pd(px.add(n0), ps);
        if U {
            _mm256_storeu_pd(pu.add(n0), u);
        }
        r
    };
    // Software-pipelined: stage 1 of the next block is issued before stage 2 of this
    // one (it reads the line up to `u_ref[n0 + 7 - i]`, written before this block
    // when `i >= 2 BLOCK`), so that the two overlap in the CPU.
    let end = len / BLOCK * BLOCK;
    let mut from = 0;
    let mut n0 = 0;
    let mut cur = stage1(load(0), &mut zc);
    // The last four blocks of references (h[k]: the block k + 1 before the current),
    // when a block's line outputs lie 3 or 4 blocks back: read from registers.
    let mut h: [__m256d; 4] = std::array::from_fn(|k| {
        _mm256_loadu_pd(lp.add((BLOCK * (k + 1)).wrapping_neg() & mask))
    });
    let (sign, big) = (c(-0.0), c(DIVERGED));
    let mut ok = _mm256_castsi256_pd(_mm256_set1_epi64x(-1));
    while n0 < end {
        let next = if n0 + BLOCK < end {
            let refs = match R {
                3 => (h[1], h[0]),
                4 => (h[2], h[1]),
                _ => load(n0 + BLOCK),
            };
            stage1(refs, &mut zc)
        } else {
            cur
        };
        let done = stage2(cur, &mut v, &mut pos);
        // The recorder's divergence test (`|a| < DIVERGED`, a finite speed): `|a|`
        // lane by lane in registers, the speed once per chunk (a speed that is not
        // finite stays so: the next is `v + t`), and the outputs scanned only when
        // a sample failed it.
        let y = done[2];
        ok = _mm256_and_pd(
            ok,
            _mm256_cmp_pd::<_CMP_LT_OQ>(_mm256_andnot_pd(sign, y), big),
        );
        let r = law(n0, done);
        h = [r, h[0], h[1], h[2]];
        cur = next;
        n0 += BLOCK;
        if n0.is_multiple_of(CHUNK) {
            if _mm256_movemask_pd(ok) == 0b1111 && _mm_cvtsd_f64(v).is_finite() {
                rec.written = n0;
            } else if !rec.proceed(from, n0) {
                return false;
            }
            from = n0;
        }
    }
    st.x = state::<N>(
        zc,
        _mm_cvtsd_f64(v),
        _mm_cvtsd_f64(pos),
    );
    st.line_in(&line, end);
    // The run's last few samples (fewer than a block): the kernel itself.
    for n in end..len {
        let o = st.observe(n);
        let u = up.command(lead_x[n], lead_v[n], o.p, o.v);
        let a = st.step(n, &o, u);
        rec.put(n, a, o.v, o.p, u, o.y_lin);
    }
    from >= len || rec.proceed(from, len)
}
    };
}

closed_simd!(
    /// [`closed_blocks`] in AVX2 intrinsics (see the module documentation). A lane's
    /// `_mm256_fmadd_pd(a, b, c)` is the kernel's `a.mul_add(b, c)` (`madd::<true>`),
    /// and Rust contracts nothing else, so each lane rounds as the kernel does.
    ///
    /// `O` is the offset of a block's first `w1` in its block of references,
    /// `(-(i + 1)) mod 4`.
    ///
    /// # Safety
    /// The CPU must support FMA and AVX2; `M == 2`, `N == 4`, a dead time of at least
    /// `2 BLOCK` samples.
    closed_avx2,
    "avx2,fma"
);

closed_simd!(
    /// [`closed_avx2`] compiled with AVX-512VL: the same instructions (so the same
    /// results bit for bit), with 32 vector registers to hold them instead of 16.
    ///
    /// # Safety
    /// As [`closed_avx2`], and the CPU must support AVX-512F and AVX-512VL.
    closed_avx512,
    "avx2,fma,avx512f,avx512vl"
);

/// Whether the CPU has AVX-512F and AVX-512VL.
#[cfg(target_arch = "x86_64")]
fn avx512() -> bool {
    std::arch::is_x86_feature_detected!("avx512f")
        && std::arch::is_x86_feature_detected!("avx512vl")
}

/// An integrator's running value over a block: `([s, s1, s2, s3], s3, [t2, t3])`
/// with `s` in lane 0, `s1 = s + t0`, `s2 = s1 + t1`, `s3 = s2 + t2` (each the
/// kernel's one addition, in scalar registers: no lane waits for a later one's
/// chain), and the upper half of `t` for the step to the next block.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn chains(
    s: std::arch::x86_64::__m128d,
    t: std::arch::x86_64::__m256d,
) -> (
    std::arch::x86_64::__m256d,
    std::arch::x86_64::__m128d,
    std::arch::x86_64::__m128d,
) {
    use std::arch::x86_64::*;
    let tl = _mm256_castpd256_pd128(t);
    let th = _mm256_extractf128_pd::<1>(t);
    let s1 = _mm_add_sd(s, tl);
    let s2 = _mm_add_sd(s1, _mm_permute_pd::<1>(tl));
    let s3 = _mm_add_sd(s2, th);
    let lo = _mm_unpacklo_pd(s, s1);
    let hi = _mm_unpacklo_pd(s2, s3);
    (
        _mm256_insertf128_pd::<1>(_mm256_castpd128_pd256(lo), hi),
        s3,
        th,
    )
}

/// `(w1, w0)`: lanes `O..O + 4` and `O + 1..O + 5` of the eight references `[a, b]`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn align<const O: usize>(
    a: std::arch::x86_64::__m256d,
    b: std::arch::x86_64::__m256d,
) -> (std::arch::x86_64::__m256d, std::arch::x86_64::__m256d) {
    use std::arch::x86_64::*;
    // [a2 a3 b0 b1]
    let mid = _mm256_permute2f128_pd::<0x21>(a, b);
    match O {
        // [a0 a1 a2 a3], [a1 a2 a3 b0]
        0 => (a, _mm256_shuffle_pd::<0b0101>(a, mid)),
        // [a1 a2 a3 b0], [a2 a3 b0 b1]
        1 => (_mm256_shuffle_pd::<0b0101>(a, mid), mid),
        // [a2 a3 b0 b1], [a3 b0 b1 b2]
        2 => (mid, _mm256_shuffle_pd::<0b0101>(mid, b)),
        // [a3 b0 b1 b2], [b0 b1 b2 b3]
        _ => (_mm256_shuffle_pd::<0b0101>(mid, b), b),
    }
}

/// The kernel's state vector from the two modes, the speed and the position.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn state<const N: usize>(zc: std::arch::x86_64::__m128d, v: f64, pos: f64) -> [f64; N] {
    use std::arch::x86_64::*;
    let mut x = [0.0; N];
    let z = [_mm_cvtsd_f64(zc), _mm_cvtsd_f64(_mm_unpackhi_pd(zc, zc))];
    x[0] = z[0];
    x[1 % N] = z[1];
    x[2 % N] = v;
    x[3 % N] = pos;
    x
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Linear;
    use crate::sim::discretize::Integrators;
    use crate::sim::kernel::run;
    use crate::sim::plant::{start, Init, Plant};
    use crate::sim::rollout::stepper;

    fn leader(n: usize) -> (Vec<f64>, Vec<f64>) {
        let lv: Vec<f64> = (0..n)
            .map(|k| 12.0 + 3.0 * (0.013 * k as f64).sin() + 0.5 * (0.17 * k as f64).cos())
            .collect();
        let mut lx = vec![50.0; n];
        for k in 1..n {
            lx[k] = lx[k - 1] + 0.025 * (lv[k] + lv[k - 1]);
        }
        (lx, lv)
    }

    /// Runs the kernel's loop and the block form on one model (through `$m`, `$n`:
    /// model order and state size) and asserts every output, the samples written and
    /// the final stepper bit-identical.
    macro_rules! compare {
        ($m:literal, $n:literal, $d:expr, $f:literal, $pl:expr, $lin:expr, $up:expr, $len:expr, $u:literal, $wide:expr) => {{
            let pl: Plant<$m, $n> = $pl;
            let (lx, lv) = leader($len);
            let s = start($lin, Init::Rest, 0.0).unwrap();
            let int0 = [lv.first().copied().unwrap_or(0.0), 30.0];
            let mk = || {
                stepper::<$m, $n, $d, $f, _>(
                    pl,
                    $lin,
                    Integrators::SpeedPosition,
                    NoEffects,
                    true,
                    &s,
                    int0,
                )
                .unwrap()
            };
            let mut outs: [[Vec<f64>; 4]; 2] = [
                [
                    vec![0.0; $len],
                    vec![0.0; $len],
                    vec![0.0; $len],
                    vec![0.0; $len],
                ],
                [
                    vec![0.0; $len],
                    vec![0.0; $len],
                    vec![0.0; $len],
                    vec![0.0; $len],
                ],
            ];
            let [ka, kb] = &mut outs;
            let (mut s1, mut s2) = (mk(), mk());
            let (w1, d1, w2, d2);
            {
                let [a, v, x, u] = ka;
                let mut rec = Record::<true, $u> {
                    a,
                    v,
                    x,
                    u: if $u { &mut u[..] } else { &mut [] },
                    written: 0,
                };
                let law =
                    |n: usize, o: &crate::sim::kernel::Obs| $up.command(lx[n], lv[n], o.p, o.v);
                d1 = run(&mut s1, $len, law, &mut rec);
                w1 = rec.written;
            }
            {
                let [a, v, x, u] = kb;
                let mut rec = Record::<true, $u> {
                    a,
                    v,
                    x,
                    u: if $u { &mut u[..] } else { &mut [] },
                    written: 0,
                };
                d2 = closed_blocks(&mut s2, &$up, &lx, &lv, &mut rec, $wide);
                w2 = rec.written;
            }
            assert_eq!((w1, d1), (w2, d2), "written, completed");
            let stopped = usize::from(!d1);
            for (p, q) in outs[0].iter().zip(&outs[1]) {
                for (k, (a, b)) in p.iter().zip(q).enumerate() {
                    assert_eq!(a.to_bits(), b.to_bits(), "sample {k}: {a} vs {b}");
                }
            }
            if d1 {
                let bits = |s: &Stepper<$m, $n, $d, $f, NoEffects>| {
                    let mut v: Vec<u64> = s.x.iter().map(|x| x.to_bits()).collect();
                    let o = s.observe($len);
                    v.push(o.y.to_bits());
                    v
                };
                assert_eq!(bits(&s1), bits(&s2), "final state");
                // The steppers continue identically (the line and w1 came back).
                let (mut a1, mut a2) = (s1.clone(), s2.clone());
                for n in $len..$len + 40 {
                    let (o1, o2) = (a1.observe(n), a2.observe(n));
                    let r1 = a1.step(n, &o1, 0.3);
                    let r2 = a2.step(n, &o2, 0.3);
                    assert_eq!(r1.to_bits(), r2.to_bits(), "continued at {n}");
                }
            }
            stopped
        }};
    }

    /// The block form against the kernel's loop, bit for bit: real poles (modal
    /// coordinates, K > 0), complex poles (the canonical form, K = 0), a real-pole
    /// model with a dead time of exactly eight samples (f = 0) and inner feedback
    /// K < 0, one with a long dead time (40 samples); a following and a diverging
    /// upper law; lengths from 0 to several chunks, ending mid-block and mid-chunk;
    /// with and without the command output. A dead time under eight samples and a
    /// first-order model take the kernel's loop (compared too).
    #[test]
    fn closed_blocks_equal_the_kernel() {
        if !crate::sim::fma() {
            return;
        }
        let lin = |b1, b0, a2, a1, td, k| Linear {
            b1,
            b0,
            a2,
            a1,
            td,
            k,
        };
        let models = [
            (lin(6.7893, 0.3479, 1.2824, 8.8157, 0.7903, 0.1008), true),
            (lin(0.0, 0.7292, 0.0445, 0.1305, 0.7796, 0.0), true),
            (lin(0.5, 1.0, 0.3, 1.4, 0.4, -0.2), true),
            (lin(0.5, 1.0, 0.3, 1.4, 2.03, 0.05), true),
            // Whole-sample dead times 9, 10, 11 (with 8, 15, 40 above: every offset
            // of a block's line outputs in the blocks of references).
            (lin(0.5, 1.0, 0.3, 1.4, 0.47, 0.05), true),
            (lin(0.5, 1.0, 0.3, 1.4, 0.52, 0.05), true),
            (lin(0.5, 1.0, 0.3, 1.4, 0.57, 0.05), true),
            // 12, 13, 14 and 16: the line four blocks back in registers at every
            // offset, and the first dead time read from memory.
            (lin(0.5, 1.0, 0.3, 1.4, 0.62, 0.05), true),
            (lin(0.5, 1.0, 0.3, 1.4, 0.67, -0.1), true),
            (lin(0.5, 1.0, 0.3, 1.4, 0.72, 0.05), true),
            (lin(0.5, 1.0, 0.3, 1.4, 0.82, 0.05), true),
            (lin(0.5, 1.0, 0.3, 1.4, 0.3, 0.1), false),
            (lin(0.5, 1.0, 0.3, 1.4, 0.12, 0.1), false),
        ];
        let ups = [
            Upper {
                kg: 0.5,
                kv: 0.1,
                tg: 2.0,
                gmin: 9.5,
            },
            // diverges
            Upper {
                kg: 40.0,
                kv: 0.0,
                tg: 0.1,
                gmin: 2.0,
            },
        ];
        let mut diverged = 0;
        // AVX2 and (where the CPU has it) AVX-512VL.
        for wide in [false, true] {
            for (lin, blocks) in &models {
                for up in &ups {
                    for len in [0, 1, 3, 4, 5, 63, 64, 65, 67, 130, 1001, 3000] {
                        let pl = Plant::<2, 4>::new(lin, Integrators::SpeedPosition, 0.05, true)
                            .unwrap();
                        assert_eq!(closed_blocks_apply::<2, 4, true>(&pl), *blocks);
                        diverged += if pl.diag {
                            compare!(2, 4, true, true, pl, lin, up, len, true, wide)
                                + compare!(2, 4, true, true, pl, lin, up, len, false, wide)
                        } else {
                            compare!(2, 4, false, true, pl, lin, up, len, true, wide)
                                + compare!(2, 4, false, true, pl, lin, up, len, false, wide)
                        };
                    }
                }
            }
        }
        assert!(diverged > 0, "the wild law diverges");
        // First order: the kernel's loop.
        let fo = lin(0.0, 1.0, 0.0, 0.45, 0.33, 0.0);
        let pl = Plant::<1, 3>::new(&fo, Integrators::SpeedPosition, 0.05, false).unwrap();
        assert!(!closed_blocks_apply::<1, 3, true>(&pl));
        compare!(1, 3, true, true, pl, &fo, &ups[0], 300, true, false);
    }
}
