//! Convolution with "same" padding over a leading batch axis: 1D fields
//! `[batch, channels, n]` and 2D fields `[batch, channels, height, width]`.
//!
//! Forward (stride 1, odd kernel sizes, radius `r = (k − 1)/2`):
//!
//! `y[b, o, i, j] = bias[o] + Σ_{c, p, q} w[o, c, p, q] · x̃[b, c, i + p − r_y, j + q − r_x]`
//!
//! where `x̃` extends `x` by zeros ([`Padding::Zero`]) or periodically
//! ([`Padding::Periodic`]). A 1D field is the 2D case with height 1 and a kernel
//! of height 1.
//!
//! Adjoint, with `g = ∂L/∂y`:
//!
//! - `∂L/∂x[b, c, s, t] = Σ_{o, p, q} w[o, c, p, q] · g[b, o, i, j]` over the `(i, j)`
//!   whose tap `(p, q)` reads `(s, t)` (a correlation with the flipped kernel,
//!   with the padding rule folded back: zero padding drops, periodic wraps);
//! - `∂L/∂w[o, c, p, q] = Σ_{b, i, j} g[b, o, i, j] · x̃[b, c, i + p − r_y, j + q − r_x]`;
//! - `∂L/∂bias[o] = Σ_{b, i, j} g[b, o, i, j]`.
//!
//! The kernel pads each batch element by the kernel's radius and flattens it
//! row by row, so that every tap is a fixed offset into one flat array. The
//! forward correlation and `∂L/∂x` (the same correlation of `g` with the
//! flipped, channel-transposed kernel) run as one loop over blocks of output
//! cells and channels whose sums stay in vector registers; `∂L/∂w` is a dot
//! product per tap over the flat cells, its lanes in registers too. No column
//! matrix is built, and the tape holds only the op's inputs and output. The
//! products and sums run in the tape's type or, with [`Arithmetic::Single`],
//! in `f32` on any tape.
//!
//! The forward pass can split each batch element's flat cells over several
//! threads (scoped, started per call): every cell's sums run in the same order
//! whatever the split, so the output is the single-threaded one bit for bit.
//! The backward pass runs on one thread (trainings run side by side, one per
//! core).
//!
//! # References
//! K. Chellapilla, S. Puri, P. Simard, *High performance convolutional neural
//! networks for document processing*, IWFHR 2006 (the column lowering this
//! kernel replaces: it copies each input value once per tap).

use diffphys_tape::{ArrayD, ArrayViewD, BackwardArgs, IxDyn, Op, Real, Result, TapeError};
use ndarray::Array2;

/// How a convolution sees past the edge of the field.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Padding {
    /// Zeros outside the field.
    Zero,
    /// The field repeats (a periodic domain).
    Periodic,
}

/// The sizes of one convolution, checked against each other.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Geometry {
    rank: usize,
    batch: usize,
    c_in: usize,
    c_out: usize,
    height: usize,
    width: usize,
    k_y: usize,
    k_x: usize,
}

impl Geometry {
    /// Reads the sizes from `x` (`[B, C, N]` or `[B, C, H, W]`), `w`
    /// (`[O, C, K]` or `[O, C, K_y, K_x]`, the same rank as `x`) and `bias` (`[O]`).
    fn of(name: &str, x: &[usize], w: &[usize], bias: &[usize]) -> Result<Self> {
        let rank = x.len();
        if rank != 3 && rank != 4 {
            return Err(TapeError::invalid(
                name,
                format!(
                    "input of shape {x:?}: expected [batch, channels, n] or \
                     [batch, channels, height, width]"
                ),
            ));
        }
        if w.len() != rank {
            return Err(TapeError::shape(
                &format!("{name} (input vs weight rank)"),
                x,
                w,
            ));
        }
        let (k_y, k_x) = if rank == 3 { (1, w[2]) } else { (w[2], w[3]) };
        if k_y % 2 == 0 || k_x % 2 == 0 {
            return Err(TapeError::invalid(
                name,
                format!("kernel {w:?}: sizes must be odd for \"same\" padding"),
            ));
        }
        if x[1] != w[1] {
            let mut expected = x.to_vec();
            expected[1] = w[1];
            return Err(TapeError::shape(&format!("{name} input"), &expected, x));
        }
        if bias != [w[0]] {
            return Err(TapeError::shape(&format!("{name} bias"), &[w[0]], bias));
        }
        let (height, width) = if rank == 3 { (1, x[2]) } else { (x[2], x[3]) };
        Ok(Geometry {
            rank,
            batch: x[0],
            c_in: x[1],
            c_out: w[0],
            height,
            width,
            k_y,
            k_x,
        })
    }

    /// The shape of a field of this geometry with `channels` channels.
    fn shape(&self, channels: usize) -> Vec<usize> {
        if self.rank == 3 {
            vec![self.batch, channels, self.width]
        } else {
            vec![self.batch, channels, self.height, self.width]
        }
    }

    fn cells(&self) -> usize {
        self.height * self.width
    }

    fn taps(&self) -> usize {
        self.c_in * self.k_y * self.k_x
    }
}

fn wrap(s: isize, n: usize, padding: Padding) -> Option<usize> {
    if (0..n as isize).contains(&s) {
        Some(s as usize)
    } else {
        match padding {
            Padding::Zero => None,
            Padding::Periodic => Some(s.rem_euclid(n as isize) as usize),
        }
    }
}

/// The arithmetic a convolution computes its products and sums in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Arithmetic {
    /// The tape's own scalar type.
    #[default]
    Native,
    /// `f32`, whatever the tape's type: the input, the kernel and the output
    /// gradient are rounded to `f32` as the kernel pads them, every product and
    /// sum runs in `f32` (twice the vector lanes of `f64`), and the results are
    /// widened back to the tape's type. On an `f64` tape the output then differs
    /// from [`Arithmetic::Native`]'s by `f32` rounding (about `1e-7` relative per
    /// product); the op is still linear in `x` and in `w`, and its gradients are
    /// the exact adjoints of the rounded computation up to that rounding. On an
    /// `f32` tape it is [`Arithmetic::Native`].
    Single,
}

/// Lanes of one 512-bit vector register in `f64`: the lanes of the weight
/// gradient's sums (two registers with AVX2).
const LANES_F64: usize = 8;
/// Lanes of one 512-bit vector register in `f32`.
const LANES_F32: usize = 16;
/// Vectors of output cells one correlation block computes together. With
/// [`CHANNELS`] output channels that is 8 sums in registers, and each tap loads
/// 2 input vectors and 4 weights for 8 vector products: more arithmetic than
/// loads, which one vector of cells (1 + 4 loads for 4 products) is not.
const VECTORS: usize = 2;
/// Output channels one block computes together.
const CHANNELS: usize = 4;

/// `s` in the compute type `U` (rounded to nearest if `U` is narrower).
#[inline(always)]
fn to<S: Real, U: Real>(s: S) -> U {
    U::from_f64(s.as_f64())
}

/// One batch element padded by the kernel's radius on every side and flattened
/// row by row, so that every tap of the kernel is a fixed offset.
///
/// Padded row `s` (`0..ph`), column `t` (`0..pw`) of channel `c` sits at
/// `c · plane + s · pw + t` and holds `x̃[c, s − r_y, t − r_x]`. An output cell
/// `(i, j)` is computed at the flat index `i · pw + j`, and its tap `(p, q)`
/// reads the flat index `i · pw + j + p · pw + q`: the whole correlation runs
/// over one flat range, `span` cells long (a multiple of every block's cell
/// count), with the columns `j ≥ W` computed and dropped. `plane` leaves room
/// for the last block's reads past the field.
#[derive(Debug, Clone, Copy)]
struct Lattice {
    pw: usize,
    span: usize,
    plane: usize,
}

impl Lattice {
    fn of(geo: &Geometry) -> Self {
        let pw = geo.width + geo.k_x - 1;
        let span = (geo.height * pw).div_ceil(LANES_F32 * VECTORS) * LANES_F32 * VECTORS;
        Lattice {
            pw,
            span,
            plane: span + (geo.k_y - 1) * pw + geo.k_x - 1,
        }
    }

    /// The flat offset of each tap `(p, q)`, in the weights' order.
    fn offsets(&self, geo: &Geometry) -> Vec<usize> {
        (0..geo.k_y)
            .flat_map(|p| (0..geo.k_x).map(move |q| p * self.pw + q))
            .collect()
    }

    /// Writes `channels` channels of `field` (`channels · H · W` values) padded
    /// by `padding` into `out` (`channels · plane` values), in `out`'s type.
    fn pad<S: Real, U: Real>(
        &self,
        geo: &Geometry,
        padding: Padding,
        channels: usize,
        field: &[S],
        out: &mut [U],
    ) {
        let (h, w) = (geo.height, geo.width);
        let (r_y, r_x) = ((geo.k_y / 2) as isize, (geo.k_x / 2) as isize);
        let ph = h + geo.k_y - 1;
        for c in 0..channels {
            let plane = &mut out[c * self.plane..(c + 1) * self.plane];
            plane[ph * self.pw..].fill(U::zero());
            for s in 0..ph {
                let row = &mut plane[s * self.pw..(s + 1) * self.pw];
                let Some(sy) = wrap(s as isize - r_y, h, padding) else {
                    row.fill(U::zero());
                    continue;
                };
                let src = &field[(c * h + sy) * w..][..w];
                for (d, &v) in row[geo.k_x / 2..geo.k_x / 2 + w].iter_mut().zip(src) {
                    *d = to(v);
                }
                for t in (0..geo.k_x / 2).chain(geo.k_x / 2 + w..self.pw) {
                    row[t] = wrap(t as isize - r_x, w, padding).map_or(U::zero(), |sx| to(src[sx]));
                }
            }
        }
    }
}

/// `out[o, t] = bias[o] + Σ_{c, k} w[o, c, k] · x[c, t + offsets[k]]` for `t` in
/// `0..lat.span`: the correlation over the flat padded layout of [`Lattice`].
/// `w` is `[c_out, c_in · taps]` row-major, `x` holds `c_in` planes, `out` holds
/// `c_out` rows of `span` values.
struct Correlation<'a, U> {
    w: &'a [U],
    bias: Option<&'a [U]>,
    offsets: &'a [usize],
    c_in: usize,
    c_out: usize,
    lat: Lattice,
}

impl<U: Real> Correlation<'_, U> {
    /// The correlation of `x` into `out`, its cells split over up to
    /// `threads` threads.
    fn run(&self, x: &[U], out: &mut [U], threads: usize) {
        if size_of::<U>() == size_of::<f32>() {
            self.run_in::<{ LANES_F32 * VECTORS }>(x, out, threads);
        } else {
            self.run_in::<{ LANES_F64 * VECTORS }>(x, out, threads);
        }
    }

    /// Splits the flat cells into runs of whole `L`-cell blocks, one run per
    /// thread (at most one thread per block), and computes each run's cells of
    /// every output channel on its own thread. A cell's sums do not depend on
    /// which run it falls in, so every split gives the same values bit for bit.
    fn run_in<const L: usize>(&self, x: &[U], out: &mut [U], threads: usize) {
        let span = self.lat.span;
        if span == 0 || self.c_out == 0 {
            return;
        }
        let blocks = span / L;
        let parts = threads.clamp(1, blocks);
        let cells = |p: usize| (blocks / parts + usize::from(p < blocks % parts)) * L;
        // Run p's cells of every output row: disjoint slices of `out`.
        let mut runs: Vec<Vec<&mut [U]>> =
            (0..parts).map(|_| Vec::with_capacity(self.c_out)).collect();
        for mut row in out.chunks_exact_mut(span).take(self.c_out) {
            for (p, run) in runs.iter_mut().enumerate() {
                let (head, tail) = std::mem::take(&mut row).split_at_mut(cells(p));
                run.push(head);
                row = tail;
            }
        }
        let Some((first, rest)) = runs.split_first_mut() else {
            return;
        };
        // The calling thread computes the first run while the others run.
        std::thread::scope(|s| {
            let mut start = cells(0);
            for (p, rows) in (1..).zip(rest) {
                s.spawn(move || self.cells::<L>(x, start, rows));
                start += cells(p);
            }
            self.cells::<L>(x, 0, first);
        });
    }

    /// The cells `start..start + rows[o].len()` of every output channel `o`
    /// into `rows[o]`, [`CHANNELS`] channels at a time.
    fn cells<const L: usize>(&self, x: &[U], start: usize, rows: &mut [&mut [U]]) {
        let full = self.c_out / CHANNELS * CHANNELS;
        for o in (0..full).step_by(CHANNELS) {
            self.block::<CHANNELS, L>(o, x, start, &mut rows[o..o + CHANNELS]);
        }
        for o in full..self.c_out {
            self.block::<1, L>(o, x, start, &mut rows[o..=o]);
        }
    }

    /// Output channels `o0..o0 + OB`, the cells from `start` on (as many as
    /// `rows` holds of each channel), `L` cells at a time with the sums held in
    /// registers.
    #[inline(always)]
    fn block<const OB: usize, const L: usize>(
        &self,
        o0: usize,
        x: &[U],
        start: usize,
        rows: &mut [&mut [U]],
    ) {
        let plane = self.lat.plane;
        let row = self.c_in * self.offsets.len();
        let w: [&[U]; OB] = std::array::from_fn(|k| &self.w[(o0 + k) * row..][..row]);
        for t in (0..rows[0].len()).step_by(L) {
            let t0 = start + t;
            let mut acc: [[U; L]; OB] =
                std::array::from_fn(|k| [self.bias.map_or(U::zero(), |b| b[o0 + k]); L]);
            for c in 0..self.c_in {
                let xc = &x[c * plane + t0..(c + 1) * plane];
                let wc: [&[U]; OB] =
                    std::array::from_fn(|k| &w[k][c * self.offsets.len()..][..self.offsets.len()]);
                for (k, &off) in self.offsets.iter().enumerate() {
                    let xs: &[U; L] = xc[off..off + L].try_into().expect("in the plane");
                    for (a, wk) in acc.iter_mut().zip(&wc) {
                        let wv = wk[k];
                        for (s, &v) in a.iter_mut().zip(xs) {
                            *s += wv * v;
                        }
                    }
                }
            }
            for (dst, a) in rows.iter_mut().zip(&acc) {
                dst[t..t + L].copy_from_slice(a);
            }
        }
    }
}

/// `Σ_t g[t] · x[t]` over `g.len()` cells (a multiple of `L`), as `L` lane
/// sums (lane `l` adds the cells `t ≡ l mod L` in order) folded in lane order.
/// One sum per call leaves the lanes the only dimension LLVM can vectorise:
/// one vector register, one load of each operand and a product and a sum per
/// `L` cells.
#[inline(always)]
fn lane_dot<U: Real, const L: usize>(g: &[U], x: &[U]) -> U {
    let mut acc = [U::zero(); L];
    for (gs, xs) in g.chunks_exact(L).zip(x.chunks_exact(L)) {
        for ((s, &gv), &xv) in acc.iter_mut().zip(gs).zip(xs) {
            *s += gv * xv;
        }
    }
    acc.iter().fold(U::zero(), |s, &v| s + v)
}

/// Adds `∂L/∂w[o, c, k] = Σ_t g[o, t] · x[c, t + offsets[k]]` over the flat
/// cells into `gw[o, c · taps + k]` for every output channel `o`, input
/// channel `c` and tap `k`, `L` lanes wide in the compute type `U` (`g` holds
/// `c_out` rows of `span`, zero on the dropped columns; `x` holds `c_in`
/// planes), a [`lane_dot`] per sum.
///
/// Kernels that held the sums of several taps and output channels together
/// in registers (so that two channels share each load of `x`) were faster or
/// slower by chance: LLVM vectorised some of them across the taps or the
/// channels instead of the lanes, with broadcasts, gathers and shuffles. The
/// 1D kernel of 5 ran 6-10× slower than this, and the same 3 × 3 kernel 10-20 %
/// faster or 2× slower depending on the code around it (docs/08-performance.md).
fn weight_gradients<U: Real, T: Real, const L: usize>(
    g: &[U],
    x: &[U],
    offsets: &[usize],
    geo: &Geometry,
    lat: &Lattice,
    gw: &mut Array2<T>,
) {
    let taps = offsets.len();
    for (o, g_o) in g.chunks_exact(lat.span).take(geo.c_out).enumerate() {
        for (c, x_c) in x.chunks_exact(lat.plane).take(geo.c_in).enumerate() {
            for (k, &off) in offsets.iter().enumerate() {
                gw[[o, c * taps + k]] += to(lane_dot::<U, L>(g_o, &x_c[off..off + lat.span]));
            }
        }
    }
}

/// Adds (or writes, with `add` false) the valid cells of `rows` (`channels` rows
/// of `lat.span` flat cells, in the compute type) into the field `field`
/// (`channels · H · W` values).
fn unflatten<U: Real, T: Real>(
    geo: &Geometry,
    lat: &Lattice,
    rows: &[U],
    field: &mut [T],
    add: bool,
) {
    let (h, w) = (geo.height, geo.width);
    for (c, dst) in field.chunks_exact_mut(h * w).enumerate() {
        for i in 0..h {
            let src = &rows[c * lat.span + i * lat.pw..][..w];
            let dst = &mut dst[i * w..(i + 1) * w];
            if add {
                dst.iter_mut().zip(src).for_each(|(d, &s)| *d += to(s));
            } else {
                dst.iter_mut().zip(src).for_each(|(d, &s)| *d = to(s));
            }
        }
    }
}

/// The convolution `y = w ⋆ x + bias` (see the module docs), computed in
/// `arithmetic`, each batch element's cells split over up to `threads` threads
/// (one per block of 16 or 32 flat cells at most; the values do not depend on
/// the split, bit for bit). `name` labels errors.
///
/// # Errors
/// [`TapeError::InvalidArgument`] or [`TapeError::ShapeMismatch`] naming `name` if
/// the shapes do not fit together or a kernel size is even;
/// [`TapeError::InvalidArgument`] for zero `threads`.
pub fn conv_forward<T: Real>(
    name: &str,
    x: ArrayViewD<'_, T>,
    w: ArrayViewD<'_, T>,
    bias: ArrayViewD<'_, T>,
    padding: Padding,
    arithmetic: Arithmetic,
    threads: usize,
) -> Result<ArrayD<T>> {
    let geo = Geometry::of(name, x.shape(), w.shape(), bias.shape())?;
    if threads == 0 {
        return Err(TapeError::invalid(
            name,
            "0 threads: the forward pass needs at least one",
        ));
    }
    let x = x.as_standard_layout();
    let x = x.as_slice().expect("standard layout");
    let w = w.as_standard_layout();
    let w = w.as_slice().expect("standard layout");
    let bias = bias.as_standard_layout();
    let bias = bias.as_slice().expect("standard layout");
    let out = match arithmetic {
        Arithmetic::Native => forward_in::<T, T>(&geo, padding, x, w, bias, threads),
        Arithmetic::Single => forward_in::<T, f32>(&geo, padding, x, w, bias, threads),
    };
    ArrayD::from_shape_vec(IxDyn(&geo.shape(geo.c_out)), out)
        .map_err(|e| TapeError::invalid(name, e.to_string()))
}

/// The forward convolution's values, computed in `U` on up to `threads`
/// threads.
fn forward_in<T: Real, U: Real>(
    geo: &Geometry,
    padding: Padding,
    x: &[T],
    w: &[T],
    bias: &[T],
    threads: usize,
) -> Vec<T> {
    let lat = Lattice::of(geo);
    let offsets = lat.offsets(geo);
    let w: Vec<U> = w.iter().map(|&v| to(v)).collect();
    let bias: Vec<U> = bias.iter().map(|&v| to(v)).collect();
    let correlation = Correlation {
        w: &w,
        bias: Some(&bias),
        offsets: &offsets,
        c_in: geo.c_in,
        c_out: geo.c_out,
        lat,
    };
    let mut out = vec![T::zero(); geo.batch * geo.c_out * geo.cells()];
    let mut padded = vec![U::zero(); geo.c_in * lat.plane];
    let mut rows = vec![U::zero(); geo.c_out * lat.span];
    let in_len = geo.c_in * geo.cells();
    let out_len = geo.c_out * geo.cells();
    for b in 0..geo.batch {
        lat.pad(
            geo,
            padding,
            geo.c_in,
            &x[b * in_len..][..in_len],
            &mut padded,
        );
        correlation.run(&padded, &mut rows, threads);
        unflatten(geo, &lat, &rows, &mut out[b * out_len..][..out_len], false);
    }
    out
}

/// The gradients of one convolution's inputs, each where it was asked for.
type ConvGradients<T> = (Option<ArrayD<T>>, Option<ArrayD<T>>, Option<ArrayD<T>>);

/// The gradients of the convolution's inputs `(x, w, bias)` from `grad_y`, each
/// computed only where `needs` asks (see the module docs for the formulas), in
/// `arithmetic` (`∂L/∂bias`, a plain sum of `grad_y`, always in `T`).
///
/// # Errors
/// As [`conv_forward`], and [`TapeError::ShapeMismatch`] if `grad_y` does not have
/// the output's shape.
pub fn conv_vjp<T: Real>(
    name: &str,
    x: ArrayViewD<'_, T>,
    w: ArrayViewD<'_, T>,
    grad_y: ArrayViewD<'_, T>,
    padding: Padding,
    needs: [bool; 3],
    arithmetic: Arithmetic,
) -> Result<ConvGradients<T>> {
    let c_out = w.shape().first().copied().unwrap_or(0);
    let geo = Geometry::of(name, x.shape(), w.shape(), &[c_out])?;
    let y_shape = geo.shape(geo.c_out);
    if grad_y.shape() != y_shape.as_slice() {
        return Err(TapeError::shape(
            &format!("{name} output gradient"),
            &y_shape,
            grad_y.shape(),
        ));
    }
    let x = x.as_standard_layout();
    let x = x.as_slice().expect("standard layout");
    let w_std = w.as_standard_layout();
    let w_flat = w_std.as_slice().expect("standard layout");
    let g = grad_y.as_standard_layout();
    let g = g.as_slice().expect("standard layout");
    let (grad_x, grad_w) = match arithmetic {
        Arithmetic::Native => vjp_in::<T, T>(&geo, padding, x, w_flat, g, needs),
        Arithmetic::Single => vjp_in::<T, f32>(&geo, padding, x, w_flat, g, needs),
    };
    let grad_bias = needs[2].then(|| {
        let mut gb = ndarray::Array1::<T>::zeros(geo.c_out);
        for g_b in g.chunks_exact(geo.c_out * geo.cells()) {
            for (o, row) in g_b.chunks_exact(geo.cells()).enumerate() {
                gb[o] += row.iter().fold(T::zero(), |s, &v| s + v);
            }
        }
        gb.into_dyn()
    });
    let grad_x = grad_x
        .map(|v| ArrayD::from_shape_vec(IxDyn(&geo.shape(geo.c_in)), v))
        .transpose()
        .map_err(|e| TapeError::invalid(name, e.to_string()))?;
    let grad_w = grad_w
        .map(|m| m.into_shape_with_order(IxDyn(w.shape())))
        .transpose()
        .map_err(|e| TapeError::invalid(name, e.to_string()))?;
    Ok((grad_x, grad_w, grad_bias))
}

/// `∂L/∂x` (flat) and `∂L/∂w` (`[c_out, c_in · taps]`) where `needs` asks,
/// computed in `U`.
fn vjp_in<T: Real, U: Real>(
    geo: &Geometry,
    padding: Padding,
    x: &[T],
    w: &[T],
    g: &[T],
    needs: [bool; 3],
) -> (Option<Vec<T>>, Option<Array2<T>>) {
    let in_len = geo.c_in * geo.cells();
    let out_len = geo.c_out * geo.cells();
    let lat = Lattice::of(geo);
    let offsets = lat.offsets(geo);
    let taps = offsets.len();

    // ∂L/∂x correlates g with the kernel flipped in space and transposed in
    // channels: w'[c, o, k] = w[o, c, taps − 1 − k].
    let mut flipped = vec![U::zero(); geo.c_in * geo.c_out * taps];
    for o in 0..geo.c_out {
        for c in 0..geo.c_in {
            for k in 0..taps {
                flipped[(c * geo.c_out + o) * taps + taps - 1 - k] =
                    to(w[(o * geo.c_in + c) * taps + k]);
            }
        }
    }
    let adjoint = Correlation {
        w: &flipped,
        bias: None,
        offsets: &offsets,
        c_in: geo.c_out,
        c_out: geo.c_in,
        lat,
    };

    let mut grad_x = needs[0].then(|| vec![T::zero(); x.len()]);
    let mut grad_w = needs[1].then(|| Array2::<T>::zeros((geo.c_out, geo.taps())));
    let scratch = |n: usize, needed: bool| {
        if needed {
            vec![U::zero(); n]
        } else {
            Vec::new()
        }
    };
    let mut padded_x = scratch(geo.c_in * lat.plane, needs[1]);
    let mut flat_g = scratch(geo.c_out * lat.span, needs[1]);
    let mut padded_g = scratch(geo.c_out * lat.plane, needs[0]);
    let mut rows = scratch(geo.c_in * lat.span, needs[0]);
    for b in 0..geo.batch {
        let g_b = &g[b * out_len..][..out_len];
        if let Some(gw) = grad_w.as_mut() {
            // ∂L/∂w[o, c, k] = Σ_t g[o, t] · x̃[c, t + offsets[k]] over the flat
            // cells, g zero on the dropped columns: one product per tap.
            lat.pad(
                geo,
                padding,
                geo.c_in,
                &x[b * in_len..][..in_len],
                &mut padded_x,
            );
            for (o, row) in g_b.chunks_exact(geo.cells()).enumerate() {
                let dst = &mut flat_g[o * lat.span..(o + 1) * lat.span];
                dst.fill(U::zero());
                for (i, src) in row.chunks_exact(geo.width).enumerate() {
                    for (d, &v) in dst[i * lat.pw..][..geo.width].iter_mut().zip(src) {
                        *d = to(v);
                    }
                }
            }
            if size_of::<U>() == size_of::<f32>() {
                weight_gradients::<U, T, LANES_F32>(&flat_g, &padded_x, &offsets, geo, &lat, gw);
            } else {
                weight_gradients::<U, T, LANES_F64>(&flat_g, &padded_x, &offsets, geo, &lat, gw);
            }
        }
        if let Some(gx) = grad_x.as_mut() {
            lat.pad(geo, padding, geo.c_out, g_b, &mut padded_g);
            adjoint.run(&padded_g, &mut rows, 1);
            unflatten(geo, &lat, &rows, &mut gx[b * in_len..][..in_len], true);
        }
    }
    (grad_x, grad_w)
}

/// The convolution as a tape op over inputs `(x, w, bias)`; see the module docs.
/// Keeps nothing beyond its inputs and output.
#[derive(Debug, Clone)]
pub struct ConvOp {
    /// Names the op (the layer) in errors and statistics.
    pub name: String,
    /// The padding rule.
    pub padding: Padding,
    /// The arithmetic of the products and sums.
    pub arithmetic: Arithmetic,
    /// Threads the forward pass splits its cells over (at least 1; see
    /// [`conv_forward`]). The backward pass runs on the calling thread.
    pub threads: usize,
}

impl<T: Real> Op<T> for ConvOp {
    fn name(&self) -> &str {
        &self.name
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> Result<Vec<ArrayD<T>>> {
        TapeError::check_arity(&self.name, 3, inputs.len())?;
        Ok(vec![conv_forward(
            &self.name,
            inputs[0].view(),
            inputs[1].view(),
            inputs[2].view(),
            self.padding,
            self.arithmetic,
            self.threads,
        )?])
    }

    fn backward(&self, args: &BackwardArgs<'_, T>) -> Result<Vec<Option<ArrayD<T>>>> {
        let (gx, gw, gb) = conv_vjp(
            &self.name,
            args.input(0).view(),
            args.input(1).view(),
            args.grad_out().view(),
            self.padding,
            [args.needs(0), args.needs(1), args.needs(2)],
            self.arithmetic,
        )?;
        Ok(vec![gx, gw, gb])
    }
}
