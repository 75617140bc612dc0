//! `+ − × ÷` and unary `−` on [`Var`], returning [`Result`] as the named methods
//! do (candle's tensors do the same): `let y = ((a * b)? + c)?;`. A scalar on the
//! right applies to every element: `(x * 2.0)?`.

use std::ops::{Add, Div, Mul, Neg, Sub};

use crate::{Real, Result, Var};

macro_rules! binary_operator {
    ($trait:ident, $method:ident, $scalar:expr) => {
        impl<'t, T: Real> $trait<Var<'t, T>> for Var<'t, T> {
            type Output = Result<Var<'t, T>>;
            fn $method(self, rhs: Var<'t, T>) -> Self::Output {
                Var::$method(self, rhs)
            }
        }

        impl<'t, T: Real> $trait<T> for Var<'t, T> {
            type Output = Result<Var<'t, T>>;
            fn $method(self, rhs: T) -> Self::Output {
                let scalar: fn(Var<'t, T>, T) -> Result<Var<'t, T>> = $scalar;
                scalar(self, rhs)
            }
        }
    };
}

binary_operator!(Add, add, |x, c| x.add_scalar(c));
binary_operator!(Sub, sub, |x, c| x.add_scalar(-c));
binary_operator!(Mul, mul, |x, c| x.mul_scalar(c));
binary_operator!(Div, div, |x, c| x.mul_scalar(T::one() / c));

impl<'t, T: Real> Neg for Var<'t, T> {
    type Output = Result<Var<'t, T>>;
    fn neg(self) -> Self::Output {
        Var::neg(self)
    }
}

#[cfg(test)]
mod tests {
    use crate::{arr_dyn, Tape};

    #[test]
    fn operators_record_the_same_ops_as_the_methods() {
        let tape = Tape::<f64>::new();
        let a = tape.var(arr_dyn(&[1.0, 2.0]));
        let b = tape.var(arr_dyn(&[3.0, 5.0]));
        // y = −((a·b + a − b)/b · 2 − 1) / 4
        let y = (-((((((a * b).unwrap() + a).unwrap() - b).unwrap() / b).unwrap() * 2.0).unwrap()
            - 1.0)
            .unwrap())
        .unwrap();
        let y = (y / 4.0).unwrap();
        let expected: Vec<f64> = [(1.0, 3.0), (2.0, 5.0)]
            .iter()
            .map(|&(a, b)| -(((a * b + a - b) / b) * 2.0 - 1.0) / 4.0)
            .collect();
        assert_eq!(y.to_array(), arr_dyn(&expected));
        let other = Tape::<f64>::new();
        let c = other.var(arr_dyn(&[1.0, 1.0]));
        assert!((a + c).is_err());
    }
}
