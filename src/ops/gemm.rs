//! A bounds-checked call of `matrixmultiply::sgemm` and the deterministic reduction the backward
//! passes build on (SPEC.md §7.8).
//!
//! `matrixmultiply::sgemm` runs on the calling thread and sums every output value over `k` in an
//! order that depends only on `(m, k, n)` and the strides, so a call's result does not depend on
//! which rayon thread runs it.

use rayon::prelude::*;

/// A strided matrix view: `rows x cols`, element `(i, j)` at `data[i * rs + j * cs]`.
#[derive(Clone, Copy)]
pub(crate) struct MatRef<'a> {
    pub data: &'a [f32],
    pub rows: usize,
    pub cols: usize,
    pub rs: usize,
    pub cs: usize,
}

impl<'a> MatRef<'a> {
    /// A row-major `rows x cols` matrix.
    pub fn row_major(data: &'a [f32], rows: usize, cols: usize) -> Self {
        MatRef { data, rows, cols, rs: cols, cs: 1 }
    }
    /// The transpose (no copy).
    pub fn t(self) -> Self {
        MatRef { data: self.data, rows: self.cols, cols: self.rows, rs: self.cs, cs: self.rs }
    }
    /// Whether every element lies inside `data`.
    fn in_bounds(&self) -> bool {
        self.rows == 0
            || self.cols == 0
            || (self.rows - 1) * self.rs + (self.cols - 1) * self.cs < self.data.len()
    }
}

/// `c = beta · c + a · b` with `c` row-major `a.rows x b.cols`.
///
/// # Panics
/// If the shapes disagree or a view reaches past its slice (a bug in the caller).
pub(crate) fn sgemm(a: MatRef, b: MatRef, beta: f32, c: &mut [f32]) {
    let (m, k, n) = (a.rows, a.cols, b.cols);
    assert_eq!(b.rows, k, "sgemm inner dimensions");
    assert!(a.in_bounds() && b.in_bounds(), "sgemm operand past its slice");
    assert_eq!(c.len(), m * n, "sgemm output length");
    if m == 0 || n == 0 {
        return;
    }
    if k == 0 {
        // β = 0 overwrites (as matrixmultiply does below): `c` need not be initialised.
        for v in c.iter_mut() {
            *v = if beta == 0.0 { 0.0 } else { *v * beta };
        }
        return;
    }
    // SAFETY: every element of `a` and `b` read by sgemm is `(i, j)` with i < rows, j < cols,
    // which in_bounds checked lies inside its slice; `c` is exactly m·n floats written row-major
    // (row stride n, column stride 1) and, being a `&mut`, aliases neither input. The strides are
    // lengths or products bounded by slice lengths, so they fit in isize.
    unsafe {
        matrixmultiply::sgemm(
            m,
            k,
            n,
            1.0,
            a.data.as_ptr(),
            a.rs as isize,
            a.cs as isize,
            b.data.as_ptr(),
            b.rs as isize,
            b.cs as isize,
            beta,
            c.as_mut_ptr(),
            n as isize,
            1,
        );
    }
}

/// The sum over `chunks` of `len`-float partial results `part(i)` computed in parallel, added in
/// chunk order (`((p_0 + p_1) + p_2) + ...`): the chunks are fixed by the caller's geometry, so the
/// result does not depend on the thread count.
pub(crate) fn sum_of_chunks<F>(chunks: usize, len: usize, part: F) -> Vec<f32>
where
    F: Fn(usize) -> Vec<f32> + Sync + Send,
{
    let parts: Vec<Vec<f32>> = (0..chunks).into_par_iter().map(part).collect();
    let mut total = vec![0.0f32; len];
    for (i, p) in parts.iter().enumerate() {
        assert_eq!(p.len(), len, "partial result length");
        if i == 0 {
            total.copy_from_slice(p);
        } else {
            for (t, &v) in total.iter_mut().zip(p) {
                *t += v;
            }
        }
    }
    total
}

/// Rows per chunk of a map `width` pixels wide so that a chunk holds about `target` pixels (at
/// least one row, at most `height`): a function of the geometry only.
pub(crate) fn rows_per_chunk(width: usize, height: usize, target: usize) -> usize {
    (target / width.max(1)).clamp(1, height.max(1))
}
