//! # diffphys-candle
//!
//! diffphys's operators inside [candle](https://docs.rs/candle-core): the
//! implicit Poisson solve and one upwind advection step as candle custom ops with
//! backward, so that a candle model can put a physics solve in its loss and get
//! gradients from `Tensor::backward`.
//!
//! Every diffphys operator is first a pair of plain functions on ndarray views,
//! its forward and its vector–Jacobian product (`poisson_solve` and
//! `poisson_solve_vjp`, `upwind1` and `upwind1_vjp`); the tape's ops and
//! these candle ops are two thin adapters over the same pair. The forward reads
//! candle's contiguous buffer in place (an ndarray view) and hands its result
//! vector to candle without a copy; the backward copies the incoming gradient
//! out of candle once (`to_vec1`) and hands the result over likewise. A
//! non-contiguous input is made contiguous first (one more copy, only then).
//! The interop example measures what the copy costs.
//!
//! ```
//! use std::sync::Arc;
//! use candle_core::{Device, Tensor, Var};
//! use diffphys_candle::CandlePoisson;
//! use diffphys_ops::cg::CgParams;
//! use diffphys_ops::stencil::Laplacian2;
//! use diffphys_ops::{Boundary, Grid2};
//!
//! let grid = Grid2::new(8, 8, 1.0, 1.0, Boundary::ZeroDirichlet)?;
//! let solve = CandlePoisson::new(Arc::new(Laplacian2::negative(grid)), CgParams::default());
//! let b = Var::from_tensor(&Tensor::ones((8, 8), candle_core::DType::F64, &Device::Cpu)?)?;
//! let x = solve.apply(b.as_tensor())?; // x = (−∇²)⁻¹ b
//! let loss = x.sqr()?.sum_all()?;
//! let grads = loss.backward()?; // ∂loss/∂b = (−∇²)⁻¹ (2 x), one adjoint CG solve
//! assert_eq!(grads.get(b.as_tensor()).unwrap().dims(), &[8, 8]);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
#![warn(missing_docs)]

use std::sync::Arc;

use candle_core::backend::BackendStorage;
use candle_core::{
    CpuStorage, CustomOp1, CustomOp2, DType, Error, Layout, Result, Shape, Tensor, WithDType,
};
use diffphys_ops::advection::{upwind1, upwind1_vjp, AdvectionParams, Wants};
use diffphys_ops::cg::CgParams;
use diffphys_ops::poisson::{poisson_solve, poisson_solve_vjp};
use diffphys_ops::{Grid1, LinearOperator};
use diffphys_tape::Real;
use ndarray::{ArrayD, ArrayView1, ArrayViewD, IxDyn};

/// The contiguous values of a CPU buffer under `layout`.
fn values<'a, T: WithDType>(
    op: &'static str,
    storage: &'a CpuStorage,
    layout: &Layout,
) -> Result<&'a [T]> {
    let data = storage.as_slice::<T>()?;
    match layout.contiguous_offsets() {
        Some((start, end)) => Ok(&data[start..end]),
        None => Err(Error::RequiresContiguous { op }),
    }
}

/// A view of the buffer as an ndarray array of `shape`.
fn view<'a, T: WithDType>(
    op: &'static str,
    storage: &'a CpuStorage,
    layout: &Layout,
) -> Result<ArrayViewD<'a, T>> {
    let data = values::<T>(op, storage, layout)?;
    ArrayViewD::from_shape(IxDyn(layout.dims()), data).map_err(Error::wrap)
}

/// A tensor's values copied into an ndarray array (the copy out of candle).
fn to_array<T: WithDType>(t: &Tensor) -> Result<ArrayD<T>> {
    let data = t.flatten_all()?.to_vec1::<T>()?;
    ArrayD::from_shape_vec(IxDyn(t.dims()), data).map_err(Error::wrap)
}

/// An ndarray array copied into a tensor on `like`'s device (the copy into candle).
fn to_tensor<T: WithDType>(a: ArrayD<T>, like: &Tensor) -> Result<Tensor> {
    let shape = a.shape().to_vec();
    Tensor::from_vec(into_vec(a), shape, like.device())
}

fn check_dtype(op: &'static str, dtype: DType) -> Result<()> {
    match dtype {
        DType::F32 | DType::F64 => Ok(()),
        other => Err(Error::Msg(format!(
            "{op}: dtype {other:?} is not supported, use f32 or f64"
        ))),
    }
}

/// The implicit Poisson solve `x = A⁻¹ b` (a symmetric positive definite `A`,
/// or semidefinite with its null space in the [`CgParams`]) as a candle op.
///
/// Forward: conjugate gradient from zero. Backward: `∂L/∂b = A⁻¹ ∂L/∂x`, one
/// more CG solve with the same operator (the implicit function theorem; `A` is
/// symmetric), never the iterates of the forward solve. A solve that does not
/// converge is a candle error carrying the CG error's message.
#[derive(Debug)]
pub struct CandlePoisson<A> {
    op: Arc<A>,
    params: CgParams,
}

impl<A> Clone for CandlePoisson<A> {
    fn clone(&self) -> Self {
        CandlePoisson {
            op: Arc::clone(&self.op),
            params: self.params.clone(),
        }
    }
}

impl<A> CandlePoisson<A>
where
    A: LinearOperator<f32> + LinearOperator<f64> + Send + Sync + 'static,
{
    /// The solve with operator `op` and CG parameters `params` (forward and
    /// adjoint alike).
    pub fn new(op: Arc<A>, params: CgParams) -> Self {
        CandlePoisson { op, params }
    }

    /// `A⁻¹ b` for a tensor `b` of the operator's shape, recorded for candle's
    /// backward.
    ///
    /// # Errors
    /// A candle error for a dtype other than f32/f64, a shape other than the
    /// operator's, or a CG failure.
    pub fn apply(&self, b: &Tensor) -> Result<Tensor> {
        b.contiguous()?.apply_op1(self.clone())
    }

    fn solve<T: Real + WithDType>(&self, b: ArrayViewD<'_, T>) -> Result<ArrayD<T>>
    where
        A: LinearOperator<T>,
    {
        let expected = LinearOperator::<T>::input_shape(&*self.op);
        if b.shape() != expected {
            return Err(Error::Msg(format!(
                "{}: right-hand side of shape {:?}, the operator takes {expected:?}",
                NAME_POISSON,
                b.shape()
            )));
        }
        let (x, _info) = poisson_solve(&*self.op, b, &self.params).map_err(Error::wrap)?;
        Ok(x)
    }
}

const NAME_POISSON: &str = "diffphys-poisson-solve";

impl<A> CustomOp1 for CandlePoisson<A>
where
    A: LinearOperator<f32> + LinearOperator<f64> + Send + Sync + 'static,
{
    fn name(&self) -> &'static str {
        NAME_POISSON
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> Result<(CpuStorage, Shape)> {
        let shape = Shape::from(layout.dims());
        let out = match storage {
            CpuStorage::F64(_) => CpuStorage::F64(into_vec(self.solve(view::<f64>(
                NAME_POISSON,
                storage,
                layout,
            )?)?)),
            CpuStorage::F32(_) => CpuStorage::F32(into_vec(self.solve(view::<f32>(
                NAME_POISSON,
                storage,
                layout,
            )?)?)),
            other => {
                return Err(Error::Msg(format!(
                    "{NAME_POISSON}: dtype {:?} is not supported, use f32 or f64",
                    other.dtype()
                )))
            }
        };
        Ok((out, shape))
    }

    fn bwd(&self, _arg: &Tensor, _res: &Tensor, grad_res: &Tensor) -> Result<Option<Tensor>> {
        check_dtype(NAME_POISSON, grad_res.dtype())?;
        let grad_b = if grad_res.dtype() == DType::F64 {
            let g = to_array::<f64>(grad_res)?;
            to_tensor(
                poisson_solve_vjp(&*self.op, g.view(), &self.params, None)
                    .map_err(Error::wrap)?
                    .0,
                grad_res,
            )?
        } else {
            let g = to_array::<f32>(grad_res)?;
            to_tensor(
                poisson_solve_vjp(&*self.op, g.view(), &self.params, None)
                    .map_err(Error::wrap)?
                    .0,
                grad_res,
            )?
        };
        Ok(Some(grad_b))
    }
}

fn into_vec<T: Clone>(a: ArrayD<T>) -> Vec<T> {
    if a.is_standard_layout() {
        a.into_raw_vec_and_offset().0
    } else {
        a.iter().cloned().collect()
    }
}

/// One first-order upwind step `d' = d − dt·[u⁺ (d_{i+1} − d_i) + u⁻ (d_i − d_{i−1})]`
/// of a field `d` by a velocity `u` on a 1D grid (see
/// [`diffphys_ops::advection`]) as a candle op of `(d, u)`, with both gradients
/// in backward (`upwind1_vjp`). A CFL violation is a candle error.
#[derive(Debug, Clone)]
pub struct CandleUpwind1 {
    grid: Grid1,
    params: AdvectionParams,
}

const NAME_UPWIND: &str = "diffphys-upwind-1d";

impl CandleUpwind1 {
    /// The step on `grid` with time step and CFL policy `params`.
    pub fn new(grid: Grid1, params: AdvectionParams) -> Self {
        CandleUpwind1 { grid, params }
    }

    /// `d` advected one step by `u` (both of shape `[n]`), recorded for candle's
    /// backward.
    ///
    /// # Errors
    /// A candle error for a dtype other than f32/f64, mismatched dtypes or
    /// shapes, or a CFL violation.
    pub fn apply(&self, d: &Tensor, u: &Tensor) -> Result<Tensor> {
        d.contiguous()?.apply_op2(&u.contiguous()?, self.clone())
    }

    fn step<T: Real + WithDType>(
        &self,
        d: ArrayViewD<'_, T>,
        u: ArrayViewD<'_, T>,
    ) -> Result<Vec<T>> {
        let (d, u) = (vector(d)?, vector(u)?);
        Ok(upwind1(&self.grid, &self.params, d, u)
            .map_err(Error::wrap)?
            .to_vec())
    }

    fn vjp<T: Real + WithDType>(
        &self,
        d: &Tensor,
        u: &Tensor,
        g: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let (da, ua, ga) = (to_array::<T>(d)?, to_array::<T>(u)?, to_array::<T>(g)?);
        let grads = upwind1_vjp(
            &self.grid,
            &self.params,
            vector(da.view())?,
            vector(ua.view())?,
            vector(ga.view())?,
            Wants {
                field: true,
                velocity: true,
            },
        )
        .map_err(Error::wrap)?;
        let back =
            |a: Option<ndarray::Array1<T>>| a.map(|a| to_tensor(a.into_dyn(), g)).transpose();
        Ok((back(grads.field)?, back(grads.velocity)?))
    }
}

fn vector<T>(a: ArrayViewD<'_, T>) -> Result<ArrayView1<'_, T>> {
    let shape = a.shape().to_vec();
    a.into_dimensionality().map_err(|_| {
        Error::Msg(format!(
            "{NAME_UPWIND}: expected a 1-D field, got shape {shape:?}"
        ))
    })
}

impl CustomOp2 for CandleUpwind1 {
    fn name(&self) -> &'static str {
        NAME_UPWIND
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let shape = Shape::from(l1.dims());
        let out = match (s1, s2) {
            (CpuStorage::F64(_), CpuStorage::F64(_)) => CpuStorage::F64(self.step(
                view::<f64>(NAME_UPWIND, s1, l1)?,
                view::<f64>(NAME_UPWIND, s2, l2)?,
            )?),
            (CpuStorage::F32(_), CpuStorage::F32(_)) => CpuStorage::F32(self.step(
                view::<f32>(NAME_UPWIND, s1, l1)?,
                view::<f32>(NAME_UPWIND, s2, l2)?,
            )?),
            (a, b) => {
                return Err(Error::Msg(format!(
                    "{NAME_UPWIND}: field {:?} and velocity {:?}: both must be f32 or both f64",
                    a.dtype(),
                    b.dtype()
                )))
            }
        };
        Ok((out, shape))
    }

    fn bwd(
        &self,
        d: &Tensor,
        u: &Tensor,
        _res: &Tensor,
        grad_res: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        match grad_res.dtype() {
            DType::F64 => self.vjp::<f64>(d, u, grad_res),
            DType::F32 => self.vjp::<f32>(d, u, grad_res),
            other => Err(Error::Msg(format!(
                "{NAME_UPWIND}: dtype {other:?} is not supported"
            ))),
        }
    }
}
