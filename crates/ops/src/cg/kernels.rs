//! The fused vector kernels of an iteration: lane-split dot products and
//! updates that read each vector once, with deterministic reductions.
//!
//! Every kernel runs over the fixed chunks of [`parallel`] (on all cores for
//! large vectors) and adds per-chunk partial sums in chunk order, so a solve
//! gives bitwise the same iterates on any number of threads.

use diffphys_tape::{parallel, Real};

use crate::linear::wide;

const LANES: usize = 4;

fn lanes_total(acc: [f64; LANES]) -> f64 {
    (acc[0] + acc[1]) + (acc[2] + acc[3])
}

/// `Σ a_i b_i` in f64.
pub(super) fn dot<T: Real>(a: &[T], b: &[T]) -> f64 {
    parallel::dot(a, b)
}

/// A chunk of `chunks_exact(LANES)` as an array, so that the lane loops compile
/// to vector instructions without bounds checks.
#[inline(always)]
pub(super) fn lanes<T: Copy>(chunk: &[T]) -> &[T; LANES] {
    chunk
        .try_into()
        .expect("chunks_exact yields LANES elements")
}

#[inline(always)]
fn lanes_mut<T: Copy>(chunk: &mut [T]) -> &mut [T; LANES] {
    chunk
        .try_into()
        .expect("chunks_exact yields LANES elements")
}

/// `Σ k_i a_i` in f64, `k = 1` if `None`.
pub(super) fn weighted_sum<T: Real>(a: &[T], k: Option<&[T]>) -> f64 {
    match k {
        Some(k) => dot(a, k),
        None => parallel::sum_chunks(a.len(), |r| sum_chunk(&a[r])),
    }
}

fn sum_chunk<T: Real>(a: &[T]) -> f64 {
    let mut acc = [0.0; LANES];
    let ac = a.chunks_exact(LANES);
    let rest: f64 = ac.remainder().iter().map(|&v| wide(v)).sum();
    for a in ac {
        let a = lanes(a);
        for l in 0..LANES {
            acc[l] += wide(a[l]);
        }
    }
    lanes_total(acc) + rest
}

/// `v −= m·k` (`k = 1` if `None`).
pub(super) fn subtract_multiple<T: Real>(v: &mut [T], m: T, k: Option<&[T]>) {
    parallel::for_each_chunk_mut(v, |off, v| match k {
        Some(k) => {
            let k = &k[off..off + v.len()];
            v.iter_mut().zip(k).for_each(|(v, &k)| *v -= m * k);
        }
        None => v.iter_mut().for_each(|v| *v -= m),
    });
}

/// The sums one residual pass produces (f64).
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Sums {
    /// `<r, r>`.
    pub(super) rr: f64,
    /// `<r, z>` (`= rr` without preconditioner).
    pub(super) rz: f64,
    /// `<k, r>`.
    pub(super) kr: f64,
    /// `<k, z>` (`= kr` without preconditioner).
    pub(super) kz: f64,
}

/// `r −= α q`, returning `<r, r>` and `<k, r>` (`k = 1` if `None`).
pub(super) fn update_residual<T: Real>(alpha: T, q: &[T], r: &mut [T], k: Option<&[T]>) -> Sums {
    let parts = parallel::map_chunks_mut(r, |off, r| {
        let range = off..off + r.len();
        update_residual_chunk(alpha, &q[range.clone()], r, k.map(|k| &k[range]))
    });
    let (mut rr, mut kr) = (0.0, 0.0);
    for (a, b) in parts {
        rr += a;
        kr += b;
    }
    Sums {
        rr,
        rz: rr,
        kr,
        kz: kr,
    }
}

/// [`update_residual`] on one chunk: `(<r, r>, <k, r>)`.
fn update_residual_chunk<T: Real>(alpha: T, q: &[T], r: &mut [T], k: Option<&[T]>) -> (f64, f64) {
    let mut rr = [0.0; LANES];
    let mut kr = [0.0; LANES];
    let n = r.len();
    let split = n - n % LANES;
    let (r_main, r_rest) = r.split_at_mut(split);
    let (q_main, q_rest) = q.split_at(split);
    match k {
        None => {
            for (r, q) in r_main
                .chunks_exact_mut(LANES)
                .zip(q_main.chunks_exact(LANES))
            {
                let (r, q) = (lanes_mut(r), lanes(q));
                for l in 0..LANES {
                    let v = r[l] - alpha * q[l];
                    r[l] = v;
                    let v = wide(v);
                    rr[l] += v * v;
                    kr[l] += v;
                }
            }
        }
        Some(k) => {
            for ((r, q), k) in r_main
                .chunks_exact_mut(LANES)
                .zip(q_main.chunks_exact(LANES))
                .zip(k[..split].chunks_exact(LANES))
            {
                let (r, q, k) = (lanes_mut(r), lanes(q), lanes(k));
                for l in 0..LANES {
                    let v = r[l] - alpha * q[l];
                    r[l] = v;
                    let v = wide(v);
                    rr[l] += v * v;
                    kr[l] += v * wide(k[l]);
                }
            }
        }
    }
    for (i, (r, &q)) in r_rest.iter_mut().zip(q_rest).enumerate() {
        *r -= alpha * q;
        let v = wide(*r);
        rr[0] += v * v;
        kr[0] += v * k.map_or(1.0, |k| wide(k[split + i]));
    }
    (lanes_total(rr), lanes_total(kr))
}

/// `r −= α q; z = d⁻¹ ⊙ r`, returning all four sums.
pub(super) fn update_residual_jacobi<T: Real>(
    alpha: T,
    q: &[T],
    r: &mut [T],
    inv_d: &[T],
    z: &mut [T],
    k: Option<&[T]>,
) -> Sums {
    let parts = parallel::map_chunks_mut2(r, z, |off, r, z| {
        let mut s = Sums::default();
        let range = off..off + r.len();
        let (q, inv_d) = (&q[range.clone()], &inv_d[range.clone()]);
        let k = k.map(|k| &k[range]);
        for (i, (((r, &q), &d), z)) in r.iter_mut().zip(q).zip(inv_d).zip(z).enumerate() {
            *r -= alpha * q;
            *z = *r * d;
            let (rv, zv) = (wide(*r), wide(*z));
            let kv = k.map_or(1.0, |k| wide(k[i]));
            s.rr += rv * rv;
            s.rz += rv * zv;
            s.kr += kv * rv;
            s.kz += kv * zv;
        }
        s
    });
    parts.into_iter().fold(Sums::default(), |a, b| Sums {
        rr: a.rr + b.rr,
        rz: a.rz + b.rz,
        kr: a.kr + b.kr,
        kz: a.kz + b.kz,
    })
}

/// `x += α p; p = (z − m k) + β p` (`k = 1` if `None`).
pub(super) fn update_direction<T: Real>(
    alpha: T,
    beta: T,
    m: T,
    z: &[T],
    p: &mut [T],
    x: &mut [T],
    k: Option<&[T]>,
) {
    parallel::map_chunks_mut2(p, x, |off, p, x| {
        let range = off..off + p.len();
        let z = &z[range.clone()];
        match k {
            None => {
                for ((p, x), &z) in p.iter_mut().zip(x.iter_mut()).zip(z) {
                    *x += alpha * *p;
                    *p = (z - m) + beta * *p;
                }
            }
            Some(k) => {
                for (((p, x), &z), &k) in p.iter_mut().zip(x.iter_mut()).zip(z).zip(&k[range]) {
                    *x += alpha * *p;
                    *p = (z - m * k) + beta * *p;
                }
            }
        }
    });
}

/// `x += α p`.
pub(super) fn axpy<T: Real>(alpha: T, p: &[T], x: &mut [T]) {
    parallel::for_each_chunk_mut(x, |off, x| {
        let p = &p[off..off + x.len()];
        x.iter_mut().zip(p).for_each(|(x, &p)| *x += alpha * p);
    });
}

// Stays here: the kernels are private to the solver.
#[cfg(test)]
mod tests {
    use super::*;

    /// The fused kernels against their one-loop-per-operation definitions, for
    /// lengths that exercise the four-lane remainder.
    #[test]
    fn fused_kernels_match_plain_loops() {
        for n in 0..11 {
            let q: Vec<f64> = (0..n).map(|i| (i as f64 * 0.7).sin()).collect();
            let r0: Vec<f64> = (0..n).map(|i| (i as f64 * 0.3).cos()).collect();
            let k: Vec<f64> = (0..n).map(|i| f64::from(u8::from(i % 3 != 0))).collect();
            let alpha = 0.37;
            let expect_r: Vec<f64> = r0.iter().zip(&q).map(|(r, q)| r - alpha * q).collect();
            let rr: f64 = expect_r.iter().map(|v| v * v).sum();
            let sr: f64 = expect_r.iter().sum();
            let kr: f64 = expect_r.iter().zip(&k).map(|(r, k)| r * k).sum();
            for (kv, expect_kr) in [(None, sr), (Some(k.as_slice()), kr)] {
                let mut r = r0.clone();
                let s = update_residual(alpha, &q, &mut r, kv);
                assert_eq!(r, expect_r);
                assert!((s.rr - rr).abs() < 1e-12 && (s.kr - expect_kr).abs() < 1e-12);
                assert_eq!((s.rz, s.kz), (s.rr, s.kr));
                let inv_d: Vec<f64> = (0..n).map(|i| 1.0 / (1.0 + i as f64)).collect();
                let (mut r, mut z) = (r0.clone(), vec![0.0; n]);
                let s = update_residual_jacobi(alpha, &q, &mut r, &inv_d, &mut z, kv);
                let rz: f64 = expect_r.iter().zip(&inv_d).map(|(r, d)| r * r * d).sum();
                assert!((s.rr - rr).abs() < 1e-12 && (s.rz - rz).abs() < 1e-12);
            }
            assert!(
                (dot(&q, &r0) - q.iter().zip(&r0).map(|(a, b)| a * b).sum::<f64>()).abs() < 1e-12
            );
            assert!((weighted_sum(&q, None) - q.iter().sum::<f64>()).abs() < 1e-12);
            let (mut p, mut x) = (r0.clone(), q.clone());
            update_direction(0.5, 2.0, 0.25, &q, &mut p, &mut x, Some(&k));
            for i in 0..n {
                assert_eq!(x[i], q[i] + 0.5 * r0[i]);
                assert_eq!(p[i], (q[i] - 0.25 * k[i]) + 2.0 * r0[i]);
            }
        }
    }
}
