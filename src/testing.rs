//! Comparisons for the test suites: a fast kernel against its reference within an error budget
//! (SPEC.md §7.5). Library code so that every backend's tests share one definition.

use ndarray::{ArrayView, Dimension};
use std::fmt;

/// How many mismatches a [`BudgetError`] lists in full.
const REPORTED: usize = 5;

/// One value outside its budget.
#[derive(Clone, Debug)]
pub struct Mismatch {
    /// Multi-index of the value.
    pub index: Vec<usize>,
    /// Value under test.
    pub got: f32,
    /// Reference value.
    pub want: f32,
    /// Allowed absolute difference.
    pub budget: f32,
}

/// Why [`within_budget`] failed: the shapes differ, or some values are outside their budget.
#[derive(Clone, Debug)]
pub struct BudgetError {
    /// Shapes of `got` and `want` when they differ.
    pub shapes: Option<(Vec<usize>, Vec<usize>)>,
    /// The first mismatches, in row-major order (at most five).
    pub first: Vec<Mismatch>,
    /// Total number of mismatches.
    pub count: usize,
    /// Number of values compared.
    pub total: usize,
}

impl fmt::Display for BudgetError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if let Some((g, w)) = &self.shapes {
            return write!(f, "shape mismatch: got {g:?}, want {w:?}");
        }
        writeln!(f, "{} of {} values outside the budget:", self.count, self.total)?;
        for m in &self.first {
            let abs = (m.got - m.want).abs();
            let rel = abs / m.want.abs();
            writeln!(
                f,
                "  at {:?}: got {:e}, want {:e}, |diff| {:e} (rel {:e}), budget {:e}",
                m.index, m.got, m.want, abs, rel, m.budget
            )?;
        }
        if self.count > self.first.len() {
            writeln!(f, "  ... and {} more", self.count - self.first.len())?;
        }
        Ok(())
    }
}

impl std::error::Error for BudgetError {}

/// Checks `|got - want| <= rel · magnitude` elementwise, where `magnitude` bounds the size of the
/// terms summed into each value (for a dot product plus bias, `Σ|x||w| + |b|`, obtained by running
/// the reference on `|x|`, `|w|`, `|b|`). NaN anywhere in `got` or `want` is a mismatch.
///
/// # Errors
/// A [`BudgetError`] listing the shapes, or the first five mismatches with index, got, want,
/// difference and budget, and how many more there are.
pub fn within_budget<D: Dimension>(
    got: ArrayView<f32, D>,
    want: ArrayView<f32, D>,
    magnitude: ArrayView<f32, D>,
    rel: f32,
) -> Result<(), BudgetError> {
    if got.shape() != want.shape() || magnitude.shape() != want.shape() {
        return Err(BudgetError {
            shapes: Some((got.shape().to_vec(), want.shape().to_vec())),
            first: Vec::new(),
            count: 0,
            total: 0,
        });
    }
    let mut err = BudgetError { shapes: None, first: Vec::new(), count: 0, total: want.len() };
    for ((index, &g), (&w, &m)) in got.into_dyn().indexed_iter().zip(want.iter().zip(magnitude.iter())) {
        let budget = rel * m;
        let ok = (g - w).abs() <= budget; // false when anything is NaN
        if !ok {
            err.count += 1;
            if err.first.len() < REPORTED {
                let index = index.slice().to_vec();
                err.first.push(Mismatch { index, got: g, want: w, budget });
            }
        }
    }
    if err.count == 0 {
        Ok(())
    } else {
        Err(err)
    }
}
