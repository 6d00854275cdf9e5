//! Small dense factorisations of the solver: partial-pivoting LU (the
//! dense statics tangent and the 6x6 joint blocks of the structured one)
//! and Cholesky (the mass matrix). No solver types: every other file of
//! the solver may use it.

use nalgebra::storage::{Storage, StorageMut};
use nalgebra::{DMatrix, Dim, Matrix, Matrix6, Vector6};

/// Simple dense LU with partial pivoting on a preallocated matrix.
#[derive(Debug, Clone)]
pub(crate) struct DenseLu {
    pub(crate) a: DMatrix<f64>,
    pub(crate) piv: Vec<usize>,
    pub(crate) ok: bool,
}

impl DenseLu {
    pub(crate) fn new(n: usize) -> Self {
        DenseLu {
            a: DMatrix::zeros(n, n),
            piv: vec![0; n],
            ok: false,
        }
    }
    /// Factorise `self.a` in place. Returns false when singular.
    pub(crate) fn factor(&mut self) -> bool {
        let n = self.a.nrows();
        let scale = self.a.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let tiny = scale * 1e-15 * (n.max(1) as f64);
        self.ok = lu_factor(&mut self.a, &mut self.piv, n, tiny);
        self.ok
    }
    /// Solve A x = b in place (after a successful `factor`).
    pub(crate) fn solve_in_place(&self, b: &mut [f64]) {
        lu_solve(&self.a, &self.piv, self.a.nrows(), b);
    }
}

/// Partial-pivoting LU of the leading `n x n` block of `a`, in place (unit
/// lower factor below the diagonal, upper factor on and above it; row
/// swaps in `piv`). False when a pivot is not finite or at most `tiny`.
/// Shared by the dense tangent ([`DenseLu`]) and the 6x6 joint blocks of
/// the structured factorisation.
pub(crate) fn lu_factor<R: Dim, C: Dim, S: StorageMut<f64, R, C>>(
    a: &mut Matrix<f64, R, C, S>,
    piv: &mut [usize],
    n: usize,
    tiny: f64,
) -> bool {
    for k in 0..n {
        let mut p = k;
        let mut best = a[(k, k)].abs();
        for i in k + 1..n {
            let v = a[(i, k)].abs();
            if v > best {
                best = v;
                p = i;
            }
        }
        piv[k] = p;
        if !best.is_finite() || best <= tiny {
            return false;
        }
        if p != k {
            a.swap_rows(p, k);
        }
        let d = a[(k, k)];
        for i in k + 1..n {
            a[(i, k)] /= d;
        }
        for j in k + 1..n {
            let akj = a[(k, j)];
            if akj != 0.0 {
                for i in k + 1..n {
                    let l = a[(i, k)];
                    a[(i, j)] -= l * akj;
                }
            }
        }
    }
    true
}

/// Solve `A x = b` for the leading `n` entries of `b` in place, with the
/// factors of [`lu_factor`] (entries past `n` are left as given).
pub(crate) fn lu_solve<R: Dim, C: Dim, S: Storage<f64, R, C>>(
    a: &Matrix<f64, R, C, S>,
    piv: &[usize],
    n: usize,
    b: &mut [f64],
) {
    for k in 0..n {
        let p = piv[k];
        if p != k {
            b.swap(p, k);
        }
    }
    for j in 0..n {
        let bj = b[j];
        if bj != 0.0 {
            for i in j + 1..n {
                b[i] -= a[(i, j)] * bj;
            }
        }
    }
    for j in (0..n).rev() {
        b[j] /= a[(j, j)];
        let bj = b[j];
        for i in 0..j {
            b[i] -= a[(i, j)] * bj;
        }
    }
}

/// Partial-pivoting LU of a joint block (n <= 6, padded to 6 x 6 with the
/// identity).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Lu6 {
    a: Matrix6<f64>,
    piv: [usize; 6],
    n: usize,
}

impl Lu6 {
    pub(crate) fn identity() -> Self {
        Lu6 {
            a: Matrix6::identity(),
            piv: [0, 1, 2, 3, 4, 5],
            n: 0,
        }
    }

    /// Factorise the leading `n x n` block of `a`. None when a pivot is
    /// negligible against the block's scale (or not finite).
    pub(crate) fn factor(mut a: Matrix6<f64>, n: usize) -> Option<Lu6> {
        let n = n.min(6);
        let mut scale = 0.0f64;
        for j in 0..n {
            for i in 0..n {
                scale = scale.max(a[(i, j)].abs());
            }
        }
        let mut piv = [0, 1, 2, 3, 4, 5];
        lu_factor(&mut a, &mut piv, n, scale * 1e-13).then_some(Lu6 { a, piv, n })
    }

    /// Solve `D x = b` for the leading `n` entries (the rest stay as given:
    /// zero in, zero out).
    #[inline]
    pub(crate) fn solve(&self, b: &mut Vector6<f64>) {
        lu_solve(&self.a, &self.piv, self.n, b.as_mut_slice());
    }
}

/// In-place Cholesky (lower triangle); false when not positive definite.
pub(crate) fn cholesky_in_place(a: &mut nalgebra::DMatrix<f64>) -> bool {
    let n = a.nrows();
    for j in 0..n {
        let mut d = a[(j, j)];
        for k in 0..j {
            d -= a[(j, k)] * a[(j, k)];
        }
        if !d.is_finite() || d <= 0.0 {
            return false;
        }
        let d = d.sqrt();
        a[(j, j)] = d;
        for i in j + 1..n {
            let mut s = a[(i, j)];
            for k in 0..j {
                s -= a[(i, k)] * a[(j, k)];
            }
            a[(i, j)] = s / d;
        }
    }
    true
}

/// Solve with the factor from [`cholesky_in_place`].
pub(crate) fn cholesky_solve(l: &nalgebra::DMatrix<f64>, b: &mut [f64]) {
    let n = l.nrows();
    for i in 0..n {
        let mut s = b[i];
        for k in 0..i {
            s -= l[(i, k)] * b[k];
        }
        b[i] = s / l[(i, i)];
    }
    for i in (0..n).rev() {
        let mut s = b[i];
        for k in i + 1..n {
            s -= l[(k, i)] * b[k];
        }
        b[i] = s / l[(i, i)];
    }
}
