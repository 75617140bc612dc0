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
//! The kernel lowers each batch element to columns (`im2col`: one row per
//! `(c, p, q)` tap, one column per output cell) and multiplies by the weight
//! matrix `[c_out, c_in·k_y·k_x]`; the backward sweep rebuilds the columns rather
//! than keep them, so the tape holds only the op's inputs and output.
//!
//! # References
//! K. Chellapilla, S. Puri, P. Simard, *High performance convolutional neural
//! networks for document processing*, IWFHR 2006 (the `im2col` lowering).

use diffphys_tape::{ArrayD, ArrayViewD, BackwardArgs, IxDyn, Op, Real, Result, TapeError};
use ndarray::linalg::general_mat_mul;
use ndarray::{Array2, ArrayView2, ArrayViewMut2, Ix2};

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

    /// The source row of output row `y` under tap row `p`, if it exists.
    fn source_row(&self, y: usize, p: usize, padding: Padding) -> Option<usize> {
        let s = y as isize + p as isize - (self.k_y / 2) as isize;
        wrap(s, self.height, padding)
    }

    fn shift_x(&self, q: usize) -> isize {
        q as isize - (self.k_x / 2) as isize
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

/// The range of `j` in `0..n` with `j + shift` in `0..n`.
fn inner_range(n: usize, shift: isize) -> std::ops::Range<usize> {
    let lo = (-shift).clamp(0, n as isize) as usize;
    let hi = (n as isize - shift).clamp(0, n as isize) as usize;
    lo..hi.max(lo)
}

/// `dst[j] = x̃[j + shift]` for one row.
fn read_shifted<T: Real>(dst: &mut [T], src: &[T], shift: isize, padding: Padding) {
    let n = src.len();
    let inner = inner_range(n, shift);
    let offset = |j: usize| (j as isize + shift) as usize;
    dst[inner.clone()]
        .copy_from_slice(&src[offset(inner.start)..offset(inner.start) + inner.len()]);
    for j in (0..inner.start).chain(inner.end..n) {
        dst[j] = match wrap(j as isize + shift, n, padding) {
            Some(s) => src[s],
            None => T::zero(),
        };
    }
}

/// The adjoint of [`read_shifted`]: `grad_src[j + shift] += g[j]`, folded back
/// by the padding rule.
fn add_shifted<T: Real>(grad_src: &mut [T], g: &[T], shift: isize, padding: Padding) {
    let n = g.len();
    let inner = inner_range(n, shift);
    let start = (inner.start as isize + shift) as usize;
    for (d, &v) in grad_src[start..start + inner.len()]
        .iter_mut()
        .zip(&g[inner.clone()])
    {
        *d += v;
    }
    for j in (0..inner.start).chain(inner.end..n) {
        if let Some(s) = wrap(j as isize + shift, n, padding) {
            grad_src[s] += g[j];
        }
    }
}

/// The columns of one batch element `x_b` (`c_in·H·W` values): row `(c, p, q)`,
/// column `(i, j)` holds `x̃[c, i + p − r_y, j + q − r_x]`.
fn im2col<T: Real>(geo: &Geometry, padding: Padding, x_b: &[T], cols: &mut ArrayViewMut2<'_, T>) {
    let (h, w) = (geo.height, geo.width);
    let cols = cols.as_slice_mut().expect("columns are contiguous");
    let cells = geo.cells();
    for c in 0..geo.c_in {
        for p in 0..geo.k_y {
            for q in 0..geo.k_x {
                let row = &mut cols[((c * geo.k_y + p) * geo.k_x + q) * cells..][..cells];
                let shift = geo.shift_x(q);
                for y in 0..h {
                    let dst = &mut row[y * w..(y + 1) * w];
                    match geo.source_row(y, p, padding) {
                        Some(sy) => {
                            read_shifted(dst, &x_b[(c * h + sy) * w..][..w], shift, padding)
                        }
                        None => dst.fill(T::zero()),
                    }
                }
            }
        }
    }
}

/// The adjoint of [`im2col`]: adds the column gradients into `grad_x_b`.
fn col2im<T: Real>(
    geo: &Geometry,
    padding: Padding,
    grad_cols: &ArrayView2<'_, T>,
    grad_x_b: &mut [T],
) {
    let (h, w) = (geo.height, geo.width);
    let cells = geo.cells();
    let grad_cols = grad_cols
        .as_slice()
        .expect("column gradients are contiguous");
    for c in 0..geo.c_in {
        for p in 0..geo.k_y {
            for q in 0..geo.k_x {
                let row = &grad_cols[((c * geo.k_y + p) * geo.k_x + q) * cells..][..cells];
                let shift = geo.shift_x(q);
                for y in 0..h {
                    if let Some(sy) = geo.source_row(y, p, padding) {
                        add_shifted(
                            &mut grad_x_b[(c * h + sy) * w..][..w],
                            &row[y * w..(y + 1) * w],
                            shift,
                            padding,
                        );
                    }
                }
            }
        }
    }
}

fn weight_matrix<'a, T: Real>(geo: &Geometry, w: &'a ArrayD<T>) -> ArrayView2<'a, T> {
    w.view()
        .into_shape_with_order((geo.c_out, geo.taps()))
        .expect("standard layout, sizes checked")
        .into_dimensionality::<Ix2>()
        .expect("2-D")
}

/// The convolution `y = w ⋆ x + bias` (see the module docs). `name` labels errors.
///
/// # Errors
/// [`TapeError::InvalidArgument`] or [`TapeError::ShapeMismatch`] naming `name` if
/// the shapes do not fit together or a kernel size is even.
pub fn conv_forward<T: Real>(
    name: &str,
    x: ArrayViewD<'_, T>,
    w: ArrayViewD<'_, T>,
    bias: ArrayViewD<'_, T>,
    padding: Padding,
) -> Result<ArrayD<T>> {
    let geo = Geometry::of(name, x.shape(), w.shape(), bias.shape())?;
    let x = x.as_standard_layout();
    let x = x.as_slice().expect("standard layout");
    let w = w.as_standard_layout().into_owned();
    let wm = weight_matrix(&geo, &w);
    let mut out = vec![T::zero(); geo.batch * geo.c_out * geo.cells()];
    let mut cols = Array2::<T>::zeros((geo.taps(), geo.cells()));
    let in_len = geo.c_in * geo.cells();
    let out_len = geo.c_out * geo.cells();
    for b in 0..geo.batch {
        im2col(
            &geo,
            padding,
            &x[b * in_len..(b + 1) * in_len],
            &mut cols.view_mut(),
        );
        let mut y = ArrayViewMut2::from_shape(
            (geo.c_out, geo.cells()),
            &mut out[b * out_len..(b + 1) * out_len],
        )
        .expect("sizes match");
        for (o, mut row) in y.rows_mut().into_iter().enumerate() {
            row.fill(bias[o]);
        }
        general_mat_mul(T::one(), &wm, &cols, T::one(), &mut y);
    }
    ArrayD::from_shape_vec(IxDyn(&geo.shape(geo.c_out)), out)
        .map_err(|e| TapeError::invalid(name, e.to_string()))
}

/// The gradients of the convolution's inputs `(x, w, bias)` from `grad_y`, each
/// computed only where `needs` asks (see the module docs for the formulas).
///
/// # Errors
/// As [`conv_forward`], and [`TapeError::ShapeMismatch`] if `grad_y` does not have
/// the output's shape.
#[allow(clippy::type_complexity)]
pub fn conv_vjp<T: Real>(
    name: &str,
    x: ArrayViewD<'_, T>,
    w: ArrayViewD<'_, T>,
    grad_y: ArrayViewD<'_, T>,
    padding: Padding,
    needs: [bool; 3],
) -> Result<(Option<ArrayD<T>>, Option<ArrayD<T>>, Option<ArrayD<T>>)> {
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
    let w_owned = w.as_standard_layout().into_owned();
    let wm = weight_matrix(&geo, &w_owned);
    let g = grad_y.as_standard_layout();
    let g = g.as_slice().expect("standard layout");
    let in_len = geo.c_in * geo.cells();
    let out_len = geo.c_out * geo.cells();

    let mut grad_x = needs[0].then(|| vec![T::zero(); x.len()]);
    let mut grad_w = needs[1].then(|| Array2::<T>::zeros((geo.c_out, geo.taps())));
    let mut grad_bias = needs[2].then(|| ndarray::Array1::<T>::zeros(geo.c_out));
    let mut cols = Array2::<T>::zeros((geo.taps(), geo.cells()));
    let mut grad_cols = Array2::<T>::zeros((geo.taps(), geo.cells()));
    for b in 0..geo.batch {
        let g_b =
            ArrayView2::from_shape((geo.c_out, geo.cells()), &g[b * out_len..(b + 1) * out_len])
                .expect("sizes match");
        if let Some(gw) = grad_w.as_mut() {
            im2col(
                &geo,
                padding,
                &x[b * in_len..(b + 1) * in_len],
                &mut cols.view_mut(),
            );
            general_mat_mul(T::one(), &g_b, &cols.t(), T::one(), gw);
        }
        if let Some(gb) = grad_bias.as_mut() {
            for (o, row) in g_b.rows().into_iter().enumerate() {
                gb[o] += row.sum();
            }
        }
        if let Some(gx) = grad_x.as_mut() {
            general_mat_mul(T::one(), &wm.t(), &g_b, T::zero(), &mut grad_cols);
            col2im(
                &geo,
                padding,
                &grad_cols.view(),
                &mut gx[b * in_len..(b + 1) * in_len],
            );
        }
    }
    let grad_x = grad_x
        .map(|v| ArrayD::from_shape_vec(IxDyn(&geo.shape(geo.c_in)), v))
        .transpose()
        .map_err(|e| TapeError::invalid(name, e.to_string()))?;
    let grad_w = grad_w
        .map(|m| m.into_shape_with_order(IxDyn(w.shape())))
        .transpose()
        .map_err(|e| TapeError::invalid(name, e.to_string()))?;
    Ok((grad_x, grad_w, grad_bias.map(|b| b.into_dyn())))
}

/// The convolution as a tape op over inputs `(x, w, bias)`; see the module docs.
/// Keeps nothing beyond its inputs and output.
#[derive(Debug, Clone)]
pub struct ConvOp {
    /// Names the op (the layer) in errors and statistics.
    pub name: String,
    /// The padding rule.
    pub padding: Padding,
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
        )?;
        Ok(vec![gx, gw, gb])
    }
}
