//! One D/Q step of the fused backend: [`crate::objective::combined::disc_objective`]'s
//! loss, its gradient and the Adam step, for every preset's terms but R1's.
//!
//! The step's rows are stacked as the tch path stacks them, `[generated; expert;
//! labeled; noisy expert]`, and cut into one block per thread ([`super::team`]). Each
//! thread gathers its rows (feature-major), runs D's body and the three heads as one
//! product; the terms ([`super::terms`]) then run once over all heads' outputs (they
//! are batch means and a batch softmax, cheap next to the products); each thread
//! back-propagates its block into its own gradient buffer, and the buffers are summed
//! into one for Adam.

use super::mlp::{Act, Acts, Input, LayerGrad, Linear, Mlp, layer_backward, layer_forward};
use super::sgemm::{Acc, Mat, ShapeError};
use super::team::{Team, block};
use super::terms::{self, Cols, Heads, Scratch};
use crate::objective::combined::DiscWeights;
use crate::train::optim::FlatAdam;

/// D's layout in its optimiser's flat buffer.
#[derive(Debug, Clone)]
pub struct DiscNet {
    /// The body (tanh on every layer).
    pub body: Mlp,
    /// Heads D (1), Q_c (K), Q_eps (1).
    pub heads: [Linear; 3],
    /// Q_c's codes K.
    pub k: usize,
}

impl DiscNet {
    /// Input width (normalised observation prefix and action).
    pub fn inp(&self) -> usize {
        self.body.inp()
    }

    fn hidden(&self) -> usize {
        self.body.out()
    }

    /// The encoder psi of RIM's L2 term: the body's and Q_c's weights (not biases).
    fn encoder(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        self.body
            .layers
            .iter()
            .chain(std::iter::once(&self.heads[1]))
            .map(|l| (l.w, l.out * l.inp))
    }

    /// The three heads stacked into one layer `[K + 2][hidden]` (weights, then bias).
    pub(crate) fn stack_heads_into(&self, p: &[f32], w: &mut Vec<f32>, b: &mut Vec<f32>) {
        w.clear();
        b.clear();
        for h in &self.heads {
            w.extend_from_slice(&p[h.w..h.w + h.out * h.inp]);
            b.extend_from_slice(h.bias(p));
        }
    }
}

/// Where a step's rows come from (row-major, as the tch tensors hold them).
pub struct DiscSources<'a> {
    /// Generated inputs `[rollout][inp]`.
    pub gen_x: &'a [f32],
    /// Their codes `[rollout][K]`.
    pub gen_code: &'a [f32],
    /// Their eps.
    pub gen_eps: &'a [f32],
    /// Unlabeled expert inputs `[n][inp]`.
    pub expert_x: &'a [f32],
    /// Their true modes (the full-label term only).
    pub expert_mode: &'a [i64],
    /// Labeled expert inputs.
    pub labeled_x: &'a [f32],
    /// Their labels.
    pub labels: &'a [i64],
}

/// One step's draw: row indices into the sources and the contrastive noise.
pub struct DiscDraw<'a> {
    /// Generated rows.
    pub gen_: &'a [i64],
    /// Expert rows.
    pub expert: &'a [i64],
    /// Labeled rows (empty when the labeled term is off).
    pub labeled: &'a [i64],
    /// Noise of the contrastive copies `[n_con][inp]` (the first `n_con` expert rows).
    pub noise: &'a [f32],
    /// Instance noise `[generated + expert][inp]` added to those rows
    /// (`disc.input_noise`); empty: none.
    pub instance_noise: &'a [f32],
    /// Compute every term's value (the logged step); else only the gradients' (the
    /// BCE's value costs a logarithm per row).
    pub report: bool,
}

/// What a step reports (as [`crate::objective::combined::DiscTerms`]).
#[derive(Debug, Clone, Default)]
pub struct DiscReport {
    /// Discriminator BCE.
    pub bce: f64,
    /// Q_eps MAE.
    pub qeps: Option<f64>,
    /// Q_c CE on generated data.
    pub qc_generated: Option<f64>,
    /// Q_c CE on labeled data.
    pub qc_labeled: Option<f64>,
    /// RIM conditional entropy.
    pub rim_entropy: Option<f64>,
    /// RIM marginal KL.
    pub rim_kl: Option<f64>,
    /// NT-Xent.
    pub contrastive: Option<f64>,
    /// Share of expert rows D calls expert.
    pub d_acc_expert: f64,
    /// Share of generated rows D calls policy.
    pub d_acc_policy: f64,
    /// Q_c's mean prediction on the expert rows (`[K]`, before the step).
    pub expert_marginal: Vec<f64>,
    /// The loss's gradient with respect to `log p(c)` (RIM's KL term; `[K]`).
    pub dlog_prior: Vec<f32>,
}

/// One thread's rows (contiguous) and buffers. (Cutting them further into L2-sized
/// tiles of 256 rows was measured slower: 5% on Reacher, 50% on Humanoid, the
/// products' operand packing repeated per tile; bench/learner.md.)
#[derive(Debug, Default)]
struct Block {
    rows: (usize, usize),
    x: Input,
    acts: Acts,
    out: Vec<f32>,
    dout: Vec<f32>,
    dh: Vec<f32>,
    g: Vec<f32>,
    gh: Vec<f32>,
    gbh: Vec<f32>,
}

/// The D/Q step's buffers, kept between steps (nothing is allocated once they have
/// grown to a step's size).
#[derive(Debug, Default)]
pub struct DiscStep {
    blocks: Vec<Block>,
    wh: Vec<f32>,
    bh: Vec<f32>,
    out: Vec<f32>,
    dout: Vec<f32>,
    g: Vec<f32>,
    labels: Vec<i64>,
    scratch: Scratch,
}

/// The stacked rows: counts of each source.
#[derive(Debug, Clone, Copy)]
struct Layout {
    gen_: usize,
    expert: usize,
    labeled: usize,
    noisy: usize,
}

impl Layout {
    fn n(&self) -> usize {
        self.gen_ + self.expert + self.labeled + self.noisy
    }

    fn cols(&self) -> [Cols; 4] {
        let g = Cols {
            start: 0,
            len: self.gen_,
        };
        let e = Cols {
            start: self.gen_,
            len: self.expert,
        };
        let l = Cols {
            start: e.start + e.len,
            len: self.labeled,
        };
        let c = Cols {
            start: l.start + l.len,
            len: self.noisy,
        };
        [g, e, l, c]
    }
}

/// The stacked rows of one step: where each comes from.
struct Stack<'s, 'a> {
    src: &'s DiscSources<'a>,
    draw: &'s DiscDraw<'a>,
    lay: Layout,
    inp: usize,
}

impl Stack<'_, '_> {
    /// Rows `start..end` of the stacked batch into `x`.
    fn gather(&self, (start, end): (usize, usize), x: &mut Input) -> Result<(), ShapeError> {
        let inp = self.inp;
        x.reset(inp, end - start);
        let [_, e, l, _] = self.lay.cols();
        let (src, draw) = (self.src, self.draw);
        let instance = |j: usize| draw.instance_noise.get(j * inp..(j + 1) * inp);
        for (col, j) in (start..end).enumerate() {
            let (data, idx, noise) = if j < e.start {
                (src.gen_x, draw.gen_[j], instance(j))
            } else if j < l.start {
                (src.expert_x, draw.expert[j - e.start], instance(j))
            } else if j < l.start + l.len {
                (src.labeled_x, draw.labeled[j - l.start], None)
            } else {
                let c = j - l.start - l.len;
                let noise = &draw.noise[c * inp..(c + 1) * inp];
                (src.expert_x, draw.expert[c], Some(noise))
            };
            let row = usize::try_from(idx)
                .ok()
                .and_then(|i| data.get(i * inp..(i + 1) * inp))
                .ok_or_else(|| {
                    ShapeError::new(format!(
                        "row {idx} past a source of {} rows",
                        data.len() / inp.max(1)
                    ))
                })?;
            match noise {
                None => x.set(col, 0, row),
                Some(noise) => {
                    for (f, (&v, &e)) in row.iter().zip(noise).enumerate() {
                        x.set(col, f, &[v + e]);
                    }
                }
            }
        }
        Ok(())
    }
}

impl DiscStep {
    /// The last step's gradient, laid out as the parameters.
    pub fn grad(&self) -> &[f32] {
        &self.g
    }

    /// One step: loss, gradient, and Adam on `opt` (D's optimiser, whose parameters
    /// `net` describes). `log_prior` is `log p(c)`.
    #[allow(clippy::too_many_arguments)]
    pub fn step(
        &mut self,
        team: &Team,
        net: &DiscNet,
        opt: &mut FlatAdam,
        src: &DiscSources,
        draw: &DiscDraw,
        w: &DiscWeights,
        log_prior: &[f32],
    ) -> Result<DiscReport, ShapeError> {
        let noisy = if w.contrastive > 0.0 {
            w.contrastive_batch.min(draw.expert.len())
        } else {
            0
        };
        let labeled = if w.qc_labeled > 0.0 {
            draw.labeled.len()
        } else {
            0
        };
        let lay = Layout {
            gen_: draw.gen_.len(),
            expert: draw.expert.len(),
            labeled,
            noisy,
        };
        if draw.noise.len() < noisy * net.inp() {
            return Err(ShapeError::new(
                "contrastive noise shorter than its rows".into(),
            ));
        }
        let stacked = (lay.gen_ + lay.expert) * net.inp();
        if !draw.instance_noise.is_empty() && draw.instance_noise.len() != stacked {
            return Err(ShapeError::new(format!(
                "instance noise of {} values for {stacked}",
                draw.instance_noise.len()
            )));
        }
        self.forward(team, net, opt.params, src, draw, lay)?;
        let report = self.terms(net, src, draw, w, lay, log_prior)?;
        self.backward(team, net, opt.params)?;
        self.reduce(net, opt.params, w);
        opt.step(&self.g);
        Ok(report)
    }

    /// Every thread: gather its rows, body, heads.
    fn forward(
        &mut self,
        team: &Team,
        net: &DiscNet,
        p: &[f32],
        src: &DiscSources,
        draw: &DiscDraw,
        lay: Layout,
    ) -> Result<(), ShapeError> {
        let (n, inp, kh) = (lay.n(), net.inp(), net.k + 2);
        net.stack_heads_into(p, &mut self.wh, &mut self.bh);
        self.blocks.resize_with(team.threads(), Block::default);
        let threads = self.blocks.len();
        let (wh, bh) = (&self.wh, &self.bh);
        let stack = Stack {
            src,
            draw,
            lay,
            inp,
        };
        let (hid, wm) = (net.hidden(), Mat::rows(wh, kh, net.hidden()));
        team.each(&mut self.blocks, |t, b| {
            b.rows = block(n, threads, t);
            let width = b.rows.1 - b.rows.0;
            stack.gather(b.rows, &mut b.x)?;
            net.body.forward(p, b.x.mat(), &mut b.acts)?;
            let h = b.acts.h.last().map(|h| &h[..]).unwrap_or_default();
            b.out.resize(kh * width, 0.0);
            layer_forward(wm, bh, Mat::rows(h, hid, width), &mut b.out, Act::Identity)
        })?;
        // The heads' outputs of all blocks side by side: `[K + 2][n]`.
        self.out.resize(kh * n, 0.0);
        for b in &self.blocks {
            let (s0, s1) = b.rows;
            for r in 0..kh {
                let w = s1 - s0;
                self.out[r * n + s0..r * n + s1].copy_from_slice(&b.out[r * w..(r + 1) * w]);
            }
        }
        Ok(())
    }

    /// Eq. 9's D/Q terms on the heads' outputs: the report, and `dout`.
    fn terms(
        &mut self,
        net: &DiscNet,
        src: &DiscSources,
        draw: &DiscDraw,
        w: &DiscWeights,
        lay: Layout,
        log_prior: &[f32],
    ) -> Result<DiscReport, ShapeError> {
        let (n, k) = (lay.n(), net.k);
        let [g, e, l, c] = lay.cols();
        self.dout.clear();
        self.dout.resize((k + 2) * n, 0.0);
        let h = Heads::new(&self.out[..], n, k);
        let mut d = Heads::new(&mut self.dout[..], n, k);
        let s = &mut self.scratch;
        let mut r = DiscReport {
            expert_marginal: vec![0.0; k],
            dlog_prior: vec![0.0; k],
            ..Default::default()
        };
        let f = |x: f64| x as f32;
        s.reset();
        r.bce = terms::disc_bce(
            &h,
            &mut d,
            (e, g),
            (f(w.disc), f(w.label_smoothing), f(w.policy_target)),
            draw.report,
            s,
        );
        let gen_rows = |data: &[f32], width: usize, out: &mut Vec<f32>| -> Result<(), ShapeError> {
            out.clear();
            for &i in draw.gen_ {
                let i =
                    usize::try_from(i).map_err(|_| ShapeError::new(format!("row index {i}")))?;
                let row = data
                    .get(i * width..(i + 1) * width)
                    .ok_or_else(|| ShapeError::new(format!("generated row {i}")))?;
                out.extend_from_slice(row);
            }
            Ok(())
        };
        let mut tmp = std::mem::take(&mut self.g);
        if w.qeps > 0.0 {
            gen_rows(src.gen_eps, 1, &mut tmp)?;
            r.qeps = Some(terms::qeps_mae(&h, &mut d, g, &tmp, f(w.qeps)));
        }
        if w.qc_generated > 0.0 {
            gen_rows(src.gen_code, k, &mut tmp)?;
            r.qc_generated = Some(terms::soft_ce(&h, &mut d, g, &tmp, f(w.qc_generated), s));
        }
        self.g = tmp;
        let labels = &mut self.labels;
        if w.qc_full_labels > 0.0 {
            pick(src.expert_mode, draw.expert, labels)?;
            terms::hard_ce(&h, &mut d, e, labels, f(w.qc_full_labels), s)?;
        }
        if lay.labeled > 0 {
            pick(src.labels, draw.labeled, labels)?;
            r.qc_labeled = Some(terms::hard_ce(&h, &mut d, l, labels, f(w.qc_labeled), s)?);
        }
        terms::mean_prediction(&h, e, &mut r.expert_marginal, s);
        if w.rim > 0.0 {
            let (wh, wkl) = (f(w.rim * w.rim_cond_entropy), f(w.rim * w.rim_marginal_kl));
            let (ent, kl) = terms::rim(&h, &mut d, e, log_prior, wh, wkl, &mut r.dlog_prior, s);
            r.rim_entropy = Some(ent);
            r.rim_kl = Some(kl);
        }
        if lay.noisy > 0 {
            let z1 = Cols {
                start: e.start,
                len: lay.noisy,
            };
            let t = f(w.contrastive_temperature);
            r.contrastive = Some(terms::nt_xent(&h, &mut d, z1, c, t, f(w.contrastive), s)?);
        }
        let share = |c: Cols, hit: fn(f32) -> bool| {
            h.d(c).iter().filter(|&&x| hit(x)).count() as f64 / c.len.max(1) as f64
        };
        r.d_acc_expert = share(e, |x| x > 0.0);
        r.d_acc_policy = share(g, |x| x <= 0.0);
        Ok(r)
    }

    /// Every thread: back through the heads and the body into its gradient buffer.
    fn backward(&mut self, team: &Team, net: &DiscNet, p: &[f32]) -> Result<(), ShapeError> {
        let (n, kh, hid, len) = (
            self.out.len() / (net.k + 2),
            net.k + 2,
            net.hidden(),
            p.len(),
        );
        let (wh, dout) = (&self.wh, &self.dout);
        let whm = Mat::rows(wh, kh, hid);
        team.each(&mut self.blocks, |_, b| {
            let (s0, s1) = b.rows;
            let width = s1 - s0;
            b.dout.resize(kh * width, 0.0);
            for r in 0..kh {
                b.dout[r * width..(r + 1) * width].copy_from_slice(&dout[r * n + s0..r * n + s1]);
            }
            let x = b.x.mat();
            let hidden = b.acts.h.last().map(|h| &h[..]).unwrap_or_default();
            b.gh.resize(kh * hid, 0.0);
            b.gbh.resize(kh, 0.0);
            b.dh.resize(hid * width, 0.0);
            let grad = LayerGrad {
                w: &mut b.gh,
                b: &mut b.gbh,
                acc: Acc::Overwrite,
            };
            let hm = Mat::rows(hidden, hid, width);
            layer_backward(
                whm,
                hm,
                &b.out,
                Act::Identity,
                &mut b.dout,
                grad,
                Some(&mut b.dh),
            )?;
            b.g.resize(len, 0.0);
            net.body
                .backward(p, x, &mut b.acts, &b.dh, (&mut b.g, Acc::Overwrite), None)?;
            let mut row = 0;
            for head in &net.heads {
                let (gw, gb) = head.grads(&mut b.g)?;
                gw.copy_from_slice(&b.gh[row * hid..(row + head.out) * hid]);
                gb.copy_from_slice(&b.gbh[row..row + head.out]);
                row += head.out;
            }
            Ok(())
        })
    }

    /// The blocks' gradients summed, plus RIM's L2 term on the encoder.
    fn reduce(&mut self, net: &DiscNet, p: &[f32], w: &DiscWeights) {
        self.g.clear();
        self.g.resize(p.len(), 0.0);
        for b in &self.blocks {
            for (g, &x) in self.g.iter_mut().zip(&b.g) {
                *g += x;
            }
        }
        let l2 = (w.rim * w.rim_l2) as f32;
        if w.rim > 0.0 && l2 != 0.0 {
            for (o, len) in net.encoder() {
                for (g, &x) in self.g[o..o + len].iter_mut().zip(&p[o..o + len]) {
                    *g += 2.0 * l2 * x;
                }
            }
        }
    }
}

/// `values[idx[i]]` for every index, into `out`.
fn pick(values: &[i64], idx: &[i64], out: &mut Vec<i64>) -> Result<(), ShapeError> {
    out.clear();
    for &i in idx {
        let v = usize::try_from(i).ok().and_then(|i| values.get(i).copied());
        out.push(
            v.ok_or_else(|| ShapeError::new(format!("row {i} past {} labels", values.len())))?,
        );
    }
    Ok(())
}
