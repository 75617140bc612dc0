//! The tape: an append-only arena of values and the op nodes that produced them.

use std::cell::RefCell;
use std::rc::Rc;
use std::sync::atomic::{AtomicU64, Ordering};

use ndarray::{Array, Array1, Array2, ArrayD, ArrayViewD, Dimension, Ix1, Ix2, IxDyn};
use smallvec::SmallVec;

use crate::{Op, Pass, Real, Result, TapeError};

static NEXT_TAPE_ID: AtomicU64 = AtomicU64::new(1);

/// One value held by the tape.
pub(crate) struct Slot<T: Real> {
    /// Shared, so that [`Var::value`] hands out the value without holding a
    /// borrow of the tape.
    pub(crate) data: Rc<ArrayD<T>>,
    /// True for variables and for everything computed from one.
    pub(crate) requires_grad: bool,
}

/// One recorded op application.
pub(crate) struct Node<T: Real> {
    pub(crate) op: Box<dyn Op<T>>,
    pub(crate) inputs: SmallVec<[usize; 4]>,
    pub(crate) outputs: SmallVec<[usize; 2]>,
}

pub(crate) struct Inner<T: Real> {
    pub(crate) slots: Vec<Slot<T>>,
    pub(crate) nodes: Vec<Node<T>>,
    saved_bytes: usize,
    value_bytes: usize,
    peak_bytes: usize,
}

/// Memory and size of a tape.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct TapeStats {
    /// Recorded op nodes.
    pub nodes: usize,
    /// Values held (leaves and op outputs).
    pub values: usize,
    /// Bytes held now: every value plus what ops saved for their backward.
    pub bytes: usize,
    /// The most bytes held at any time since the tape was created.
    pub peak_bytes: usize,
}

/// A reverse-mode autodiff tape over `ndarray` tensors of a [`Real`] scalar.
///
/// Values are created as variables ([`Tape::var`], which want gradients) or
/// constants ([`Tape::constant`], which never do). Every op on them records a node
/// that keeps its outputs; ops whose inputs are all constant are evaluated but not
/// recorded. [`Tape::backward`] then sweeps the nodes in reverse.
///
/// By default every op's output and every gradient is checked for NaN and infinity
/// and a [`TapeError::NonFinite`] names the op that produced one; see
/// [`Tape::set_check_finite`].
pub struct Tape<T: Real> {
    id: u64,
    check_finite: std::cell::Cell<bool>,
    pub(crate) inner: RefCell<Inner<T>>,
}

impl<T: Real> Default for Tape<T> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T: Real> std::fmt::Debug for Tape<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Tape")
            .field("id", &self.id)
            .field("stats", &self.stats())
            .finish()
    }
}

/// A handle to a value on a tape: small and `Copy`. Ops are methods on it
/// (`x.mul(y)?.exp()?`) and record onto the tape it belongs to.
#[derive(Clone, Copy)]
pub struct Var<'t, T: Real> {
    pub(crate) tape: &'t Tape<T>,
    pub(crate) index: usize,
}

impl<T: Real> std::fmt::Debug for Var<'_, T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Var")
            .field("tape", &self.tape.id)
            .field("index", &self.index)
            .field("shape", &self.shape())
            .finish()
    }
}

fn bytes_of<T>(a: &ArrayD<T>) -> usize {
    a.len() * std::mem::size_of::<T>()
}

/// Counts non-finite entries; the error names `op`.
pub(crate) fn check_finite<T: Real>(op: &str, pass: Pass, a: &ArrayViewD<'_, T>) -> Result<()> {
    let count = match a.as_slice_memory_order() {
        Some(s) => crate::parallel::count_non_finite(s),
        None => a.iter().filter(|x| !x.is_finite()).count(),
    };
    if count == 0 {
        Ok(())
    } else {
        Err(TapeError::NonFinite {
            op: op.to_string(),
            pass,
            count,
            len: a.len(),
        })
    }
}

impl<T: Real> Tape<T> {
    /// An empty tape with a process-unique id.
    pub fn new() -> Self {
        Tape {
            id: NEXT_TAPE_ID.fetch_add(1, Ordering::Relaxed),
            check_finite: std::cell::Cell::new(true),
            inner: RefCell::new(Inner {
                slots: Vec::new(),
                nodes: Vec::new(),
                saved_bytes: 0,
                value_bytes: 0,
                peak_bytes: 0,
            }),
        }
    }

    /// This tape's id, as named in [`TapeError::ForeignVar`].
    pub fn id(&self) -> u64 {
        self.id
    }

    /// Turns the NaN/infinity check of every op output and gradient on or off
    /// (on by default). Off saves one pass over each array; the study of failure
    /// modes turns it off to watch values go non-finite.
    pub fn set_check_finite(&self, on: bool) {
        self.check_finite.set(on);
    }

    /// Whether outputs and gradients are checked for NaN and infinity.
    pub fn checks_finite(&self) -> bool {
        self.check_finite.get()
    }

    /// A leaf that wants gradients. Takes an array of any dimension
    /// (`Array1`, `Array2`, `ArrayD`, …); the tape holds it as an `ArrayD`.
    pub fn var<D: Dimension>(&self, value: Array<T, D>) -> Var<'_, T> {
        self.push_leaf(value.into_dyn(), true)
    }

    /// A leaf that never gets a gradient. Takes an array of any dimension, as
    /// [`Tape::var`].
    pub fn constant<D: Dimension>(&self, value: Array<T, D>) -> Var<'_, T> {
        self.push_leaf(value.into_dyn(), false)
    }

    /// A 0-dimensional constant.
    pub fn scalar(&self, value: T) -> Var<'_, T> {
        self.constant(ArrayD::from_elem(IxDyn(&[]), value))
    }

    fn push_leaf(&self, value: ArrayD<T>, requires_grad: bool) -> Var<'_, T> {
        let mut inner = self.inner.borrow_mut();
        let index = inner.push_slot(value, requires_grad);
        Var { tape: self, index }
    }

    /// Records a single-output `op` applied to `inputs` and returns its output.
    /// This is the one way an op joins the tape: primitives (`x.mul(y)?` is
    /// sugar for it), stencils, solves and network layers alike.
    ///
    /// The tape takes the op by value and keeps it for the backward sweep.
    ///
    /// # Errors
    /// [`TapeError::ForeignVar`] if an input belongs to another tape, whatever the
    /// op's forward returns, [`TapeError::NonFinite`] if the output holds NaN or
    /// infinity while the check is on, and [`TapeError::InvalidArgument`] if the
    /// op returned other than one output (use [`Tape::apply_multi`] for those).
    pub fn apply<O: Op<T> + 'static>(&self, op: O, inputs: &[Var<'_, T>]) -> Result<Var<'_, T>> {
        let mut out = self.apply_multi_boxed(Box::new(op), inputs, Some(1))?;
        Ok(out.remove(0))
    }

    /// Records `op` applied to `inputs` and returns all its outputs, in the order
    /// its forward returned them (a pressure projection's `[u'_x, u'_y, p]`, say).
    ///
    /// # Errors
    /// As [`Tape::apply`], without the check on the number of outputs.
    pub fn apply_multi<O: Op<T> + 'static>(
        &self,
        op: O,
        inputs: &[Var<'_, T>],
    ) -> Result<Vec<Var<'_, T>>> {
        self.apply_multi_boxed(Box::new(op), inputs, None)
    }

    /// [`Tape::apply_multi`] for an op already boxed; with `expect_outputs`, an
    /// op returning another number of outputs is an error and records nothing.
    fn apply_multi_boxed(
        &self,
        mut op: Box<dyn Op<T>>,
        inputs: &[Var<'_, T>],
        expect_outputs: Option<usize>,
    ) -> Result<Vec<Var<'_, T>>> {
        for v in inputs {
            self.check_owned(op.name(), v)?;
        }
        let (outputs, requires_grad) = {
            let inner = self.inner.borrow();
            let views: SmallVec<[ArrayViewD<'_, T>; 4]> = inputs
                .iter()
                .map(|v| inner.slots[v.index].data.view())
                .collect();
            let outputs = op.forward(&views)?;
            let requires_grad = inputs.iter().any(|v| inner.slots[v.index].requires_grad);
            (outputs, requires_grad)
        };
        if let Some(n) = expect_outputs {
            if outputs.len() != n {
                return Err(TapeError::invalid(
                    op.name(),
                    format!("expected one output, the op returned {}", outputs.len()),
                ));
            }
        }
        if self.checks_finite() {
            for out in &outputs {
                check_finite(op.name(), Pass::Forward, &out.view())?;
            }
        }
        let mut inner = self.inner.borrow_mut();
        let indices: SmallVec<[usize; 2]> = outputs
            .into_iter()
            .map(|o| inner.push_slot(o, requires_grad))
            .collect();
        if requires_grad {
            inner.saved_bytes += op.saved_bytes();
            inner.nodes.push(Node {
                op,
                inputs: inputs.iter().map(|v| v.index).collect(),
                outputs: indices.clone(),
            });
            inner.update_peak();
        }
        Ok(indices
            .into_iter()
            .map(|index| Var { tape: self, index })
            .collect())
    }

    pub(crate) fn check_owned(&self, op: &str, v: &Var<'_, T>) -> Result<()> {
        if v.tape.id == self.id {
            Ok(())
        } else {
            Err(TapeError::ForeignVar {
                op: op.to_string(),
                expected: self.id,
                found: v.tape.id,
            })
        }
    }

    /// Nodes, values and bytes held now and at the peak.
    pub fn stats(&self) -> TapeStats {
        let inner = self.inner.borrow();
        TapeStats {
            nodes: inner.nodes.len(),
            values: inner.slots.len(),
            bytes: inner.bytes(),
            peak_bytes: inner.peak_bytes,
        }
    }

    /// Drops every value and node, keeping the id and the peak. Needs `&mut self`,
    /// so no [`Var`] of this tape can outlive it.
    pub fn clear(&mut self) {
        let inner = self.inner.get_mut();
        inner.recycle_values();
        inner.nodes.clear();
        inner.saved_bytes = 0;
        inner.value_bytes = 0;
    }
}

/// The values of a dropped tape go to the buffer pool for the next one.
impl<T: Real> Drop for Inner<T> {
    fn drop(&mut self) {
        self.recycle_values();
    }
}

impl<T: Real> Inner<T> {
    /// Drops every value, handing the buffers nobody else holds (no
    /// [`Var::value`] outstanding) to [`crate::pool`].
    fn recycle_values(&mut self) {
        for slot in self.slots.drain(..) {
            if let Ok(a) = Rc::try_unwrap(slot.data) {
                crate::pool::recycle_array(a);
            }
        }
    }

    fn push_slot(&mut self, data: ArrayD<T>, requires_grad: bool) -> usize {
        self.value_bytes += bytes_of(&data);
        self.slots.push(Slot {
            data: Rc::new(data),
            requires_grad,
        });
        self.update_peak();
        self.slots.len() - 1
    }

    fn bytes(&self) -> usize {
        self.value_bytes + self.saved_bytes
    }

    fn update_peak(&mut self) {
        self.peak_bytes = self.peak_bytes.max(self.bytes());
    }
}

impl<'t, T: Real> Var<'t, T> {
    /// The tape this variable is recorded on.
    pub fn tape(&self) -> &'t Tape<T> {
        self.tape
    }

    /// Its position on the tape (stable for the tape's life).
    pub fn index(&self) -> usize {
        self.index
    }

    /// The shape of its value.
    pub fn shape(&self) -> Vec<usize> {
        self.tape.inner.borrow().slots[self.index]
            .data
            .shape()
            .to_vec()
    }

    /// Its value, shared with the tape (no copy). Holding it does not block
    /// recording: values on a tape never change.
    pub fn value(&self) -> Rc<ArrayD<T>> {
        Rc::clone(&self.tape.inner.borrow().slots[self.index].data)
    }

    /// A copy of its value.
    pub fn to_array(&self) -> ArrayD<T> {
        self.tape.inner.borrow().slots[self.index]
            .data
            .as_ref()
            .clone()
    }

    /// A copy of its value as a 1-D array.
    ///
    /// # Errors
    /// [`TapeError::InvalidArgument`] if the value is not 1-D.
    pub fn to_array1(&self) -> Result<Array1<T>> {
        self.array_of_rank::<Ix1>("to_array1")
    }

    /// A copy of its value as a 2-D array (the shape of a field on a `Grid2`).
    ///
    /// # Errors
    /// [`TapeError::InvalidArgument`] if the value is not 2-D.
    pub fn to_array2(&self) -> Result<Array2<T>> {
        self.array_of_rank::<Ix2>("to_array2")
    }

    fn array_of_rank<D: Dimension>(&self, what: &str) -> Result<Array<T, D>> {
        self.to_array().into_dimensionality::<D>().map_err(|_| {
            TapeError::invalid(
                what,
                format!("value of shape {:?} has another rank", self.shape()),
            )
        })
    }

    /// Its value if it holds exactly one element.
    ///
    /// # Errors
    /// [`TapeError::InvalidArgument`] if it holds more or fewer.
    pub fn item(&self) -> Result<T> {
        let v = self.value();
        if v.len() == 1 {
            Ok(*v.iter().next().expect("one element"))
        } else {
            Err(TapeError::invalid(
                "item",
                format!("value of shape {:?} is not a single element", v.shape()),
            ))
        }
    }

    /// Whether a gradient can flow to it (a variable, or computed from one).
    pub fn requires_grad(&self) -> bool {
        self.tape.inner.borrow().slots[self.index].requires_grad
    }
}
