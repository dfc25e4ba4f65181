//! The learner's tanh MLPs (those [`crate::train::nets`] builds) on one thread's block
//! of the batch, forward and backward, over the parameters where tch keeps them.
//!
//! **Layout.** Parameters stay in the flat buffer of their optimiser
//! ([`crate::train::optim::Adam`]), each layer a weight `[out][in]` and a bias `[out]`
//! at the offsets a [`Linear`] records, so the fused path and tch read and write the
//! same numbers (checkpoints, ONNX export and evaluation need no copy). Activations
//! are **feature-major**, `[features][rows]`: the batch is the contiguous dimension,
//! so every elementwise pass (tanh, its derivative, the bias) is a run over
//! contiguous rows of a layer, and the matrix products are `H = W X` (forward),
//! `dW = dZ X^T` and `dX = W^T dZ` (backward) with the batch as the long side.

use super::math;
use super::sgemm::{Acc, Mat, MatMut, ShapeError, gemm};

/// A linear layer inside a flat parameter buffer: weight `[out][inp]` at `w`, bias
/// `[out]` at `b`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Linear {
    /// Offset of the weight.
    pub w: usize,
    /// Offset of the bias.
    pub b: usize,
    /// Input width.
    pub inp: usize,
    /// Output width.
    pub out: usize,
}

impl Linear {
    /// The weight `[out][inp]` in `p`.
    pub fn weight<'a>(&self, p: &'a [f32]) -> Mat<'a> {
        Mat::rows(&p[self.w..self.w + self.out * self.inp], self.out, self.inp)
    }

    /// The bias `[out]` in `p`.
    pub fn bias<'a>(&self, p: &'a [f32]) -> &'a [f32] {
        &p[self.b..self.b + self.out]
    }

    /// The gradient slices of weight and bias in `g` (laid out as the parameters).
    pub fn grads<'a>(
        &self,
        g: &'a mut [f32],
    ) -> Result<(&'a mut [f32], &'a mut [f32]), ShapeError> {
        disjoint(g, (self.w, self.out * self.inp), (self.b, self.out))
    }
}

/// Two non-overlapping ranges `(offset, len)` of `g`, mutably.
pub fn disjoint(
    g: &mut [f32],
    a: (usize, usize),
    b: (usize, usize),
) -> Result<(&mut [f32], &mut [f32]), ShapeError> {
    let bad = || {
        ShapeError::new(format!(
            "ranges {a:?} and {b:?} of a buffer of {} overlap or exceed it",
            g.len()
        ))
    };
    if a.0 + a.1 > g.len() || b.0 + b.1 > g.len() {
        return Err(bad());
    }
    if a.0 + a.1 <= b.0 {
        let (x, y) = g.split_at_mut(b.0);
        Ok((&mut x[a.0..a.0 + a.1], &mut y[..b.1]))
    } else if b.0 + b.1 <= a.0 {
        let (x, y) = g.split_at_mut(a.0);
        Ok((&mut y[..a.1], &mut x[b.0..b.0 + b.1]))
    } else {
        Err(bad())
    }
}

/// What follows a layer's affine map.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Act {
    /// `tanh` (hidden layers, and D's body's last layer).
    Tanh,
    /// Nothing (output layers and heads).
    Identity,
}

/// `out = act(W x + b)`: `x` is `[inp][n]`, `out` `[out][n]` (feature-major).
pub fn layer_forward(
    w: Mat,
    b: &[f32],
    x: Mat,
    out: &mut [f32],
    act: Act,
) -> Result<(), ShapeError> {
    let n = x.cols;
    if n == 0 {
        return Ok(());
    }
    let mut c = MatMut::new(out, w.rows, n, n);
    match act {
        Act::Tanh => {
            gemm(&mut c, w, x, Acc::Overwrite, None)?;
            for (row, &bi) in out.chunks_exact_mut(n).zip(b) {
                math::tanh_bias_inplace(row, bi);
            }
        }
        Act::Identity => gemm(&mut c, w, x, Acc::Overwrite, Some(b))?,
    }
    Ok(())
}

/// Where a layer's backward pass puts its gradients, and whether it adds to them.
pub struct LayerGrad<'a> {
    /// The weight's gradient `[out][inp]`.
    pub w: &'a mut [f32],
    /// The bias's gradient `[out]`.
    pub b: &'a mut [f32],
    /// Overwrite, or add (the second and later blocks of a batch).
    pub acc: Acc,
}

/// Backward through one layer. On entry `dz` holds `dL/d out` (`[out][n]`); on exit
/// `dL/d (W x + b)`. Writes (or adds) `dw = dz x^T`, `db = sum over rows of dz`, and,
/// when asked, writes `dx = W^T dz` (`[inp][n]`). `h` is the layer's forward output.
pub fn layer_backward(
    w: Mat,
    x: Mat,
    h: &[f32],
    act: Act,
    dz: &mut [f32],
    grad: LayerGrad,
    dx: Option<&mut [f32]>,
) -> Result<(), ShapeError> {
    let n = x.cols;
    let LayerGrad { w: dw, b: db, acc } = grad;
    if n == 0 {
        if acc == Acc::Overwrite {
            dw.fill(0.0);
            db.fill(0.0);
        }
        return Ok(());
    }
    let add = |db: &mut f32, v: f32| match acc {
        Acc::Overwrite => *db = v,
        Acc::Add => *db += v,
    };
    match act {
        Act::Tanh => {
            for ((d, hr), db) in dz
                .chunks_exact_mut(n)
                .zip(h.chunks_exact(n))
                .zip(db.iter_mut())
            {
                add(db, math::tanh_backward(d, hr));
            }
        }
        Act::Identity => {
            for (d, db) in dz.chunks_exact(n).zip(db.iter_mut()) {
                add(db, math::sum(d));
            }
        }
    }
    let dzm = Mat::rows(dz, w.rows, n);
    gemm(
        &mut MatMut::new(dw, w.rows, w.cols, w.cols),
        dzm,
        x.t(),
        acc,
        None,
    )?;
    if let Some(dx) = dx {
        gemm(
            &mut MatMut::new(dx, w.cols, n, n),
            w.t(),
            dzm,
            Acc::Overwrite,
            None,
        )?;
    }
    Ok(())
}

/// Inputs wider than this are kept row-major ([`Input`]).
const NARROW: usize = 32;

/// One block of input rows as the first layer reads them, `[inp][n]` logically:
/// feature-major when narrow (the transposing copy is cheap, and the weight gradient's
/// operands stay contiguous), row-major when wide (each row is one contiguous copy; a
/// transposing copy of Humanoid's 365 features wrote a page per feature per row and
/// took a fifth of a D/Q step: bench/learner.md). The products read either through
/// strides.
#[derive(Debug, Default)]
pub struct Input {
    data: Vec<f32>,
    inp: usize,
    n: usize,
    row_major: bool,
}

impl Input {
    /// Room for `n` rows of `inp` features (contents unspecified until written).
    pub fn reset(&mut self, inp: usize, n: usize) {
        self.data.resize(inp * n, 0.0);
        (self.inp, self.n, self.row_major) = (inp, n, inp > NARROW);
    }

    /// Features `from..from + values.len()` of row `row`.
    #[inline]
    pub fn set(&mut self, row: usize, from: usize, values: &[f32]) {
        if self.row_major {
            self.data[row * self.inp + from..][..values.len()].copy_from_slice(values);
        } else {
            for (f, &v) in values.iter().enumerate() {
                self.data[(from + f) * self.n + row] = v;
            }
        }
    }

    /// Feature `f` of row `row`.
    #[inline]
    pub fn get(&self, f: usize, row: usize) -> f32 {
        if self.row_major {
            self.data[row * self.inp + f]
        } else {
            self.data[f * self.n + row]
        }
    }

    /// The block as the first layer's input `[inp][n]`.
    pub fn mat(&self) -> Mat<'_> {
        if self.row_major {
            Mat::rows(&self.data, self.n, self.inp).t()
        } else {
            Mat::rows(&self.data, self.inp, self.n)
        }
    }
}

/// A tanh MLP as layers of a flat parameter buffer: tanh after every layer but the
/// last, and after the last too when `tanh_last` (a body rather than a head).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Mlp {
    /// The layers, input first.
    pub layers: Vec<Linear>,
    /// Activate the last layer too.
    pub tanh_last: bool,
}

/// One thread's activations of one [`Mlp`]: layer `l`'s output `[out_l][n]`.
#[derive(Debug, Default)]
pub struct Acts {
    /// Per layer, feature-major.
    pub h: Vec<Vec<f32>>,
    /// Two buffers for the backward pass's `dL/dz`.
    dz: [Vec<f32>; 2],
}

impl Mlp {
    fn act(&self, l: usize) -> Act {
        if l + 1 < self.layers.len() || self.tanh_last {
            Act::Tanh
        } else {
            Act::Identity
        }
    }

    /// Input width.
    pub fn inp(&self) -> usize {
        self.layers.first().map_or(0, |l| l.inp)
    }

    /// Output width.
    pub fn out(&self) -> usize {
        self.layers.last().map_or(0, |l| l.out)
    }

    /// Every parameter offset range `(offset, len)`, weights then bias per layer.
    pub fn ranges(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        self.layers
            .iter()
            .flat_map(|l| [(l.w, l.out * l.inp), (l.b, l.out)])
    }

    /// The forward pass on `x` (`[inp][n]`) with parameters `p`; the output is
    /// `acts.h.last()`.
    pub fn forward(&self, p: &[f32], x: Mat, acts: &mut Acts) -> Result<(), ShapeError> {
        let n = x.cols;
        acts.h.resize_with(self.layers.len(), Vec::new);
        for (l, lin) in self.layers.iter().enumerate() {
            let (done, rest) = acts.h.split_at_mut(l);
            let input = match done.last() {
                Some(prev) => Mat::rows(prev, lin.inp, n),
                None => x,
            };
            let out = &mut rest[0];
            out.resize(lin.out * n, 0.0);
            layer_forward(lin.weight(p), lin.bias(p), input, out, self.act(l))?;
        }
        Ok(())
    }

    /// The backward pass from `dout` (`dL/d output`, `[out][n]`) after
    /// [`Mlp::forward`] on the same `x`: every layer's gradients into `g` (laid out as
    /// `p`; overwritten or added to, `acc`), and `dL/dx` rows `dx.0` into `dx.1` when
    /// given (`[dx.0.len()][n]`).
    pub fn backward(
        &self,
        p: &[f32],
        x: Mat,
        acts: &mut Acts,
        dout: &[f32],
        (g, acc): (&mut [f32], Acc),
        mut dx: Option<(std::ops::Range<usize>, &mut [f32])>,
    ) -> Result<(), ShapeError> {
        let n = x.cols;
        let [cur, next] = &mut acts.dz;
        cur.clear();
        cur.extend_from_slice(dout);
        for l in (0..self.layers.len()).rev() {
            let lin = self.layers[l];
            let input = if l == 0 {
                x
            } else {
                Mat::rows(&acts.h[l - 1], lin.inp, n)
            };
            let (dw, db) = lin.grads(g)?;
            let grad = LayerGrad { w: dw, b: db, acc };
            let w = lin.weight(p);
            if l > 0 {
                next.resize(lin.inp * n, 0.0);
                layer_backward(w, input, &acts.h[l], self.act(l), cur, grad, Some(next))?;
                std::mem::swap(cur, next);
                continue;
            }
            layer_backward(w, input, &acts.h[0], self.act(0), cur, grad, None)?;
            if let Some((rows, out)) = dx.take() {
                // dx rows = W[:, rows]^T dz: only the input columns asked for.
                let wc = w.cols_range(rows.start, rows.end);
                let dzm = Mat::rows(cur, lin.out, n);
                let mut c = MatMut::new(out, rows.len(), n, n);
                gemm(&mut c, wc.t(), dzm, Acc::Overwrite, None)?;
            }
        }
        Ok(())
    }
}
