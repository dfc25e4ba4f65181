//! Single-precision matrix products for the fused backend: `C = A B (+ bias) (+ C)`.
//!
//! Every product of the fused learner has one long side, the batch (1000-5000 rows),
//! and short others (the layer widths, 1-400). Activations are kept feature-major
//! (`[features, batch]`, see [`super::mlp`]), so in the forward product `H = W X` and in
//! `dX = W^T dZ` the batch is the column dimension of `C`, stored contiguously, and in
//! the weight gradient `dW = dZ X^T` it is the reduction dimension.
//!
//! The products run in the `gemm` crate (pure Rust; with its `x86-v4` feature it picks
//! AVX-512 kernels at run time where the CPU has them, else AVX2/FMA). It was the
//! fastest of the single-precision products measured for these shapes on our AMD EPYC
//! (bench/learner.md, "sgemm"): libtorch's MKL runs only AVX2 kernels on AMD, and our
//! own AVX-512 kernel, written and measured first, was slower on the narrow shapes.
//! This file adds the strided views, the shape and bounds checks that make the calls
//! safe, and a bias.

/// A read-only strided matrix: element `(i, j)` at `data[i * rs + j * cs]`.
#[derive(Clone, Copy, Debug)]
pub struct Mat<'a> {
    /// Backing storage.
    pub data: &'a [f32],
    /// Rows.
    pub rows: usize,
    /// Columns.
    pub cols: usize,
    /// Row stride.
    pub rs: usize,
    /// Column stride.
    pub cs: usize,
}

impl<'a> Mat<'a> {
    /// A row-major `rows x cols` matrix (leading dimension `cols`).
    pub fn rows(data: &'a [f32], rows: usize, cols: usize) -> Self {
        Self::strided(data, rows, cols, cols)
    }

    /// A row-major matrix with leading dimension `ld`.
    pub fn strided(data: &'a [f32], rows: usize, cols: usize, ld: usize) -> Self {
        Self {
            data,
            rows,
            cols,
            rs: ld,
            cs: 1,
        }
    }

    /// The transpose (a view: strides swapped).
    pub fn t(self) -> Self {
        Self {
            data: self.data,
            rows: self.cols,
            cols: self.rows,
            rs: self.cs,
            cs: self.rs,
        }
    }

    /// Columns `j0..j1` (a view).
    pub fn cols_range(self, j0: usize, j1: usize) -> Self {
        let off = if j1 > j0 { j0 * self.cs } else { 0 };
        Self {
            data: &self.data[off.min(self.data.len())..],
            cols: j1 - j0,
            ..self
        }
    }

    /// Rows `i0..i1` (a view).
    pub fn rows_range(self, i0: usize, i1: usize) -> Self {
        self.t().cols_range(i0, i1).t()
    }

    /// True when every element lies inside `data`.
    fn in_bounds(&self) -> bool {
        if self.rows == 0 || self.cols == 0 {
            return true;
        }
        let last = (self.rows - 1) * self.rs + (self.cols - 1) * self.cs;
        last < self.data.len()
    }

    #[inline(always)]
    fn at(&self, i: usize, j: usize) -> f32 {
        self.data[i * self.rs + j * self.cs]
    }
}

/// A row-major output matrix with leading dimension `ld`.
#[derive(Debug)]
pub struct MatMut<'a> {
    /// Backing storage.
    pub data: &'a mut [f32],
    /// Rows.
    pub rows: usize,
    /// Columns.
    pub cols: usize,
    /// Leading dimension.
    pub ld: usize,
}

impl<'a> MatMut<'a> {
    /// A row-major `rows x cols` matrix with leading dimension `ld`.
    pub fn new(data: &'a mut [f32], rows: usize, cols: usize, ld: usize) -> Self {
        Self {
            data,
            rows,
            cols,
            ld,
        }
    }

    fn in_bounds(&self) -> bool {
        self.rows == 0 || self.cols == 0 || (self.rows - 1) * self.ld + self.cols <= self.data.len()
    }
}

/// What happens to `C`'s previous values.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Acc {
    /// `C = A B (+ bias)`.
    Overwrite,
    /// `C += A B (+ bias)`.
    Add,
}

/// A product whose operands do not fit their declared shapes (a bug in the caller).
#[derive(Debug, thiserror::Error)]
#[error("fused learner: {0}")]
pub struct ShapeError(String);

impl ShapeError {
    /// An error saying `what`.
    pub fn new(what: String) -> Self {
        Self(what)
    }
}

/// `C = A B` or `C += A B`, plus `row_bias[i]` on every element of row `i` when given,
/// on the calling thread.
pub fn gemm(
    c: &mut MatMut,
    a: Mat,
    b: Mat,
    acc: Acc,
    row_bias: Option<&[f32]>,
) -> Result<(), ShapeError> {
    check(c, &a, &b, row_bias)?;
    if c.rows == 0 || c.cols == 0 {
        return Ok(());
    }
    let mut read_dst = acc == Acc::Add;
    if let Some(bias) = row_bias {
        for (i, &b) in bias.iter().enumerate().take(c.rows) {
            let row = &mut c.data[i * c.ld..i * c.ld + c.cols];
            if read_dst {
                row.iter_mut().for_each(|x| *x += b);
            } else {
                row.fill(b);
            }
        }
        read_dst = true;
    }
    #[cfg(target_arch = "x86_64")]
    if narrow_long(c, &a, &b) && super::avx512::available() {
        // SAFETY: AVX-512F is there; `check` proved the rows of `A` and the columns of
        // `B` (both contiguous: `narrow_long`) and the rows of `C` inside their slices.
        unsafe {
            super::avx512::dot_gemm(
                c.rows, c.cols, a.cols, a.data, a.rs, b.data, b.cs, c.data, c.ld, read_dst,
            );
        }
        return Ok(());
    }
    if a.cols == 0 {
        if !read_dst {
            for i in 0..c.rows {
                c.data[i * c.ld..i * c.ld + c.cols].fill(0.0);
            }
        }
        return Ok(());
    }
    // SAFETY: `check` proved every index of the three operands inside its slice, and
    // `C` does not alias `A` or `B` (it is borrowed mutably); strides of a Rust slice
    // fit in isize.
    unsafe {
        gemm::gemm(
            c.rows,
            c.cols,
            a.cols,
            c.data.as_mut_ptr(),
            1,
            c.ld as isize,
            read_dst,
            a.data.as_ptr(),
            a.cs as isize,
            a.rs as isize,
            b.data.as_ptr(),
            b.cs as isize,
            b.rs as isize,
            1.0f32,
            1.0f32,
            false,
            false,
            false,
            gemm::Parallelism::None,
        );
    }
    Ok(())
}

fn check(c: &MatMut, a: &Mat, b: &Mat, bias: Option<&[f32]>) -> Result<(), ShapeError> {
    let shapes = || {
        format!(
            "C {}x{}, A {}x{}, B {}x{}",
            c.rows, c.cols, a.rows, a.cols, b.rows, b.cols
        )
    };
    if a.rows != c.rows || b.cols != c.cols || a.cols != b.rows {
        return Err(ShapeError(format!("shapes do not chain: {}", shapes())));
    }
    if !a.in_bounds() || !b.in_bounds() || !c.in_bounds() || c.cols > c.ld {
        return Err(ShapeError(format!(
            "an operand exceeds its slice: {}",
            shapes()
        )));
    }
    if bias.is_some_and(|v| v.len() < c.rows) {
        return Err(ShapeError(format!("bias shorter than {} rows", c.rows)));
    }
    Ok(())
}

/// A weight gradient of a narrow layer: the reduction (the batch) long, one side of
/// `C` at most 16, `A`'s rows and `B`'s columns contiguous. The `gemm` crate runs these
/// at a third of its rate (its tiles are mostly empty); dot products run them at
/// about its full rate (bench/learner.md, "sgemm").
fn narrow_long(c: &MatMut, a: &Mat, b: &Mat) -> bool {
    a.cols >= 256 && c.rows.min(c.cols) <= 16 && a.cs == 1 && b.rs == 1
}

/// The reference product, one element at a time in f64 (tests only).
pub fn reference(c: &mut MatMut, a: Mat, b: Mat, acc: Acc, bias: Option<&[f32]>) {
    for i in 0..c.rows {
        for j in 0..c.cols {
            let mut s = 0.0f64;
            for k in 0..a.cols {
                s += f64::from(a.at(i, k)) * f64::from(b.at(k, j));
            }
            if let Some(b) = bias {
                s += f64::from(b[i]);
            }
            let x = &mut c.data[i * c.ld + j];
            *x = if acc == Acc::Add {
                *x + s as f32
            } else {
                s as f32
            };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn data(n: usize, seed: u32) -> Vec<f32> {
        (0..n)
            .map(|i| (i as f32 * 0.7311 + seed as f32 * 1.37).sin() * 1.5)
            .collect()
    }

    /// Every layout the fused learner uses (A or B transposed or not), odd sizes,
    /// bias and accumulation: the product equals the f64 reference within 1e-5
    /// relative to the largest entry.
    #[test]
    fn every_layout_and_edge_size_matches_the_reference() {
        let sizes = [
            (1, 1, 1),
            (5, 7, 3),
            (13, 33, 257),
            (100, 70, 100),
            (8, 1000, 12),
            (8, 100, 3000),
            (100, 10, 1000),
            (3, 5, 260),
            (3, 4, 0),
        ];
        for &(m, n, k) in &sizes {
            for (ta, tb) in [(false, false), (true, false), (false, true), (true, true)] {
                let (av, bv) = (data(m * k, 1), data(k * n, 2));
                let a = if ta {
                    Mat::rows(&av, k, m).t()
                } else {
                    Mat::rows(&av, m, k)
                };
                let b = if tb {
                    Mat::rows(&bv, n, k).t()
                } else {
                    Mat::rows(&bv, k, n)
                };
                let bias = data(m, 3);
                for (acc, bias) in [
                    (Acc::Overwrite, None),
                    (Acc::Add, None),
                    (Acc::Overwrite, Some(&bias[..])),
                    (Acc::Add, Some(&bias[..])),
                ] {
                    let c0 = data(m * (n + 3), 4);
                    let mut want = c0.clone();
                    reference(&mut MatMut::new(&mut want, m, n, n + 3), a, b, acc, bias);
                    let scale = want.iter().fold(1e-6f32, |s, x| s.max(x.abs()));
                    let mut got = c0.clone();
                    gemm(&mut MatMut::new(&mut got, m, n, n + 3), a, b, acc, bias).unwrap();
                    let err = got
                        .iter()
                        .zip(&want)
                        .fold(0.0f32, |e, (g, w)| e.max((g - w).abs()));
                    assert!(
                        err <= 1e-5 * scale,
                        "m{m} n{n} k{k} ta{ta} tb{tb} {acc:?} bias {}: error {err} scale {scale}",
                        bias.is_some()
                    );
                }
            }
        }
    }

    #[test]
    fn padding_columns_past_n_are_left_untouched() {
        let (m, n, k, ld) = (3, 5, 4, 9);
        let (av, bv) = (data(m * k, 1), data(k * n, 2));
        let mut c = vec![7.0f32; m * ld];
        let mut cm = MatMut::new(&mut c, m, n, ld);
        gemm(
            &mut cm,
            Mat::rows(&av, m, k),
            Mat::rows(&bv, k, n),
            Acc::Overwrite,
            None,
        )
        .unwrap();
        for i in 0..m {
            assert!(
                c[i * ld + n..(i + 1) * ld].iter().all(|&x| x == 7.0),
                "row {i}: {c:?}"
            );
        }
    }

    #[test]
    fn operands_that_do_not_chain_or_fit_are_refused() {
        let v = vec![0.0f32; 12];
        let mut out = vec![0.0f32; 12];
        let mut c = MatMut::new(&mut out, 3, 4, 4);
        let e = gemm(
            &mut c,
            Mat::rows(&v, 3, 2),
            Mat::rows(&v, 3, 4),
            Acc::Overwrite,
            None,
        );
        assert!(e.unwrap_err().to_string().contains("chain"));
        let e = gemm(
            &mut c,
            Mat::rows(&v, 3, 5),
            Mat::rows(&v, 5, 4),
            Acc::Overwrite,
            None,
        );
        assert!(e.unwrap_err().to_string().contains("exceeds"));
    }
}
