//! Adam whose state can be saved and restored, stepping all parameters at once.
//!
//! tch's `nn::Optimizer` keeps Adam's moments and step counts inside libtorch, out of
//! reach of a checkpoint; a resumed run with fresh moments would not continue the run it
//! resumes. [`Adam`] is the same update (libtorch's `torch::optim::Adam`, no weight
//! decay, no AMSGrad) written with tch tensor ops, so its state is plain tensors. It
//! differs from libtorch only in float rounding: libtorch fuses `a + alpha * b`, tch
//! offers no `alpha`, so the moment updates round once more.
//!
//! **One buffer.** The parameters of a store are re-pointed (`set_data`) at views of
//! one flat buffer, and the moments are flat buffers too, so a step is ~10 tensor ops
//! whatever the number of parameters (libtorch's fused/foreach Adam is not reachable
//! from tch). Per parameter that cost ~12 ops each, and at the learner's sizes each op
//! is dispatch-bound (a few microseconds), so the D/Q and PPO steps spent a large share
//! of their time in Adam (bench/learner.md). Gradient clipping takes the norm of the
//! same flat gradient.
//!
//! Gradients are reset to *undefined* as libtorch's `zero_grad` does; tch exposes that
//! reset only through an optimiser, so a learning-rate-0 SGD over the same variables
//! does just that and nothing else. A step where no parameter has a gradient is
//! skipped. Where only some have one, the others count as zero gradients (the moments
//! decay; a parameter never reached keeps zero moments and does not move), and one step
//! count serves all parameters. libtorch instead skips such parameters; the learner's
//! losses reach the same parameters at every step of a run, so the two agree there.

use std::collections::BTreeMap;
use tch::{Kind, TchError, Tensor, nn, nn::OptimizerConfig};

/// Adam over the trainable variables of one [`nn::VarStore`].
pub struct Adam {
    /// `(name, variable)` in the store's creation order; each a view of `flat`.
    params: Vec<(String, Tensor)>,
    /// Every parameter's values, back to back.
    flat: Tensor,
    /// First moments, laid out as `flat`.
    exp_avg: Tensor,
    /// Second moments, laid out as `flat`.
    exp_avg_sq: Tensor,
    /// `(offset, numel)` of each parameter in the flat buffers.
    layout: Vec<(i64, i64)>,
    /// Steps taken.
    steps: i64,
    lr: f64,
    beta1: f64,
    beta2: f64,
    eps: f64,
    /// Used only for `zero_grad` (libtorch's set-to-none).
    grads: nn::Optimizer,
}

/// An [`Adam`]'s state as slices ([`Adam::flat_mut`]).
pub struct FlatAdam<'a> {
    /// Every parameter, back to back.
    pub params: &'a mut [f32],
    /// First moments.
    pub exp_avg: &'a mut [f32],
    /// Second moments.
    pub exp_avg_sq: &'a mut [f32],
    /// Steps taken.
    pub steps: &'a mut i64,
    lr: f64,
    beta1: f64,
    beta2: f64,
    eps: f64,
}

impl FlatAdam<'_> {
    /// One Adam step with gradient `g` (laid out as `params`): the same operations, in
    /// the same order and precision, as [`Adam::step`].
    pub fn step(&mut self, g: &[f32]) {
        *self.steps += 1;
        let t = *self.steps as i32;
        let bc1 = 1.0 - self.beta1.powi(t);
        let bc2 = 1.0 - self.beta2.powi(t);
        let (b1, b2) = (self.beta1 as f32, self.beta2 as f32);
        let (c1, c2) = ((1.0 - self.beta1) as f32, (1.0 - self.beta2) as f32);
        let (sbc2, eps, step) = (bc2.sqrt() as f32, self.eps as f32, (self.lr / bc1) as f32);
        let consts = [b1, c1, b2, c2, sbc2, eps, step];
        crate::fused::math::adam(self.params, self.exp_avg, self.exp_avg_sq, g, consts);
    }
}

/// Scales `g` so that its L2 norm is at most `max` (as [`Adam::clip_and_step`]);
/// returns the norm before.
pub fn clip_norm(g: &mut [f32], max: f64) -> f64 {
    let total = g
        .iter()
        .map(|&x| f64::from(x) * f64::from(x))
        .sum::<f64>()
        .sqrt();
    let coef = max / (total + 1e-6);
    if coef < 1.0 {
        let c = coef as f32;
        g.iter_mut().for_each(|x| *x *= c);
    }
    total
}

/// The saved form of an [`Adam`]: per parameter name, `exp_avg`, `exp_avg_sq` and the
/// step count.
#[derive(Debug, Default)]
pub struct AdamState {
    /// `name -> (exp_avg, exp_avg_sq, step)`.
    pub params: BTreeMap<String, (Tensor, Tensor, i64)>,
}

/// A state that does not fit the optimiser it is loaded into.
#[derive(Debug, thiserror::Error)]
pub enum AdamStateError {
    /// A parameter has no saved state, or the state names an unknown parameter.
    #[error("optimizer state: parameter `{name}` {why}")]
    Mismatch {
        /// Parameter name.
        name: String,
        /// What is wrong.
        why: String,
    },
}

impl Adam {
    /// Adam with libtorch's defaults (betas 0.9 / 0.999, eps 1e-8) over every trainable
    /// variable of `vs` at this point, which from now on live in one flat buffer.
    pub fn new(vs: &nn::VarStore, lr: f64) -> Result<Self, TchError> {
        let named = vs.variables();
        let params: Vec<(String, Tensor)> = vs
            .trainable_variables()
            .into_iter()
            .map(|t| {
                let name = named
                    .iter()
                    .find(|(_, v)| v.data_ptr() == t.data_ptr())
                    .map(|(n, _)| n.clone())
                    .unwrap_or_default();
                (name, t)
            })
            .collect();
        let mut layout = Vec::with_capacity(params.len());
        let mut off = 0;
        for (_, p) in &params {
            let n = p.numel() as i64;
            layout.push((off, n));
            off += n;
        }
        let flat = tch::no_grad(|| {
            let parts: Vec<Tensor> = params
                .iter()
                .map(|(_, p)| p.detach().reshape([-1]))
                .collect();
            if parts.is_empty() {
                Tensor::zeros([0], (Kind::Float, tch::Device::Cpu))
            } else {
                Tensor::cat(&parts, 0)
            }
        });
        for ((_, p), &(o, n)) in params.iter().zip(&layout) {
            let view = flat.narrow(0, o, n).view(p.size().as_slice());
            p.shallow_clone().f_set_data(&view)?;
        }
        Ok(Self {
            exp_avg: flat.zeros_like(),
            exp_avg_sq: flat.zeros_like(),
            flat,
            layout,
            steps: 0,
            params,
            lr,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            grads: nn::Sgd::default().build(vs, 0.0)?,
        })
    }

    /// Resets every gradient to undefined.
    pub fn zero_grad(&mut self) {
        self.grads.zero_grad();
    }

    /// The gradients laid out as the flat buffer (zeros where undefined); `None` when
    /// no parameter has one.
    fn flat_grad(&self) -> Option<Tensor> {
        let grads: Vec<Tensor> = self.params.iter().map(|(_, p)| p.grad()).collect();
        if !grads.iter().any(Tensor::defined) {
            return None;
        }
        let parts: Vec<Tensor> = grads
            .iter()
            .zip(&self.layout)
            .map(|(g, &(_, n))| {
                if g.defined() {
                    g.reshape([-1])
                } else {
                    Tensor::zeros([n], (Kind::Float, tch::Device::Cpu))
                }
            })
            .collect();
        Some(Tensor::cat(&parts, 0))
    }

    /// One Adam step on every parameter (see the module docs on missing gradients).
    pub fn step(&mut self) {
        self.clipped_step(None);
    }

    /// Scales the gradients so that their joint L2 norm is at most `max` (as tch's
    /// `Optimizer::clip_grad_norm`), then takes one Adam step.
    pub fn clip_and_step(&mut self, max: f64) {
        self.clipped_step(Some(max));
    }

    fn clipped_step(&mut self, max_norm: Option<f64>) {
        tch::no_grad(|| {
            let Some(mut g) = self.flat_grad() else {
                return;
            };
            if let Some(max) = max_norm {
                let total = f64::try_from(g.norm()).unwrap_or(f64::NAN);
                let coef = max / (total + 1e-6);
                if coef < 1.0 {
                    g *= coef;
                }
            }
            self.steps += 1;
            let t = self.steps as i32;
            let bc1 = 1.0 - self.beta1.powi(t);
            let bc2 = 1.0 - self.beta2.powi(t);
            let m = &mut self.exp_avg;
            let _ = m.g_mul_scalar_(self.beta1);
            let _ = m.g_add_(&(&g * (1.0 - self.beta1)));
            let v = &mut self.exp_avg_sq;
            let _ = v.g_mul_scalar_(self.beta2);
            let _ = v.g_add_(&(&g * &g * (1.0 - self.beta2)));
            let denom = (v.sqrt() / bc2.sqrt()) + self.eps;
            let update = &self.exp_avg / denom * (self.lr / bc1);
            let _ = self.flat.g_sub_(&update);
        });
    }

    /// Learning rate.
    pub fn lr(&self) -> f64 {
        self.lr
    }

    /// Parameters in the flat buffer.
    pub fn len(&self) -> usize {
        self.flat.numel()
    }

    /// True when the optimiser holds no parameter.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Where `t` (one of this optimiser's parameters, or a view of one) starts in the
    /// flat buffer; `None` for a tensor outside it.
    pub fn offset_of(&self, t: &Tensor) -> Option<usize> {
        let base = self.flat.data_ptr() as usize;
        let at = t.data_ptr() as usize;
        let len = self.len() * std::mem::size_of::<f32>();
        (at >= base && at < base + len.max(1) && (at - base).is_multiple_of(4))
            .then(|| (at - base) / 4)
    }

    /// The parameters, moments and step count as plain slices, for the fused backend
    /// ([`crate::fused`]), which updates them in place: the tch variables see every
    /// change (they are views of the same buffer), so both backends share one state.
    pub fn flat_mut(&mut self) -> FlatAdam<'_> {
        let n = self.len();
        let slice = |t: &Tensor| -> &mut [f32] {
            if n == 0 {
                return &mut [];
            }
            // SAFETY: `flat`, `exp_avg` and `exp_avg_sq` are three distinct contiguous
            // CPU float tensors of `n` elements that this optimiser created and owns;
            // the slices live no longer than the `&mut self` borrow, during which no
            // tch operation runs on them (the VarStore's variables are views of
            // `flat`, used only on this thread and not while the borrow lasts).
            unsafe { std::slice::from_raw_parts_mut(t.data_ptr() as *mut f32, n) }
        };
        let (params, exp_avg, exp_avg_sq) = (
            slice(&self.flat),
            slice(&self.exp_avg),
            slice(&self.exp_avg_sq),
        );
        FlatAdam {
            params,
            exp_avg,
            exp_avg_sq,
            steps: &mut self.steps,
            lr: self.lr,
            beta1: self.beta1,
            beta2: self.beta2,
            eps: self.eps,
        }
    }

    /// A deep copy of the moments and step counts.
    pub fn state(&self) -> AdamState {
        let part = |t: &Tensor, i: usize| {
            let (o, n) = self.layout[i];
            t.narrow(0, o, n)
                .view(self.params[i].1.size().as_slice())
                .copy()
        };
        AdamState {
            params: self
                .params
                .iter()
                .enumerate()
                .map(|(i, (name, _))| {
                    let moments = (part(&self.exp_avg, i), part(&self.exp_avg_sq, i));
                    (name.clone(), (moments.0, moments.1, self.steps))
                })
                .collect(),
        }
    }

    /// Replaces the moments and step count with `state` (every parameter, same
    /// shapes). One count serves all parameters: the largest saved one (a parameter
    /// saved with fewer steps was never reached, so its moments are zero).
    pub fn set_state(&mut self, state: &AdamState) -> Result<(), AdamStateError> {
        let mismatch = |name: &str, why: String| AdamStateError::Mismatch {
            name: name.to_string(),
            why,
        };
        for name in state.params.keys() {
            if !self.params.iter().any(|(n, _)| n == name) {
                return Err(mismatch(name, "is not a parameter of this model".into()));
            }
        }
        let mut steps = 0;
        for (i, (name, p)) in self.params.iter().enumerate() {
            let (m, v, s) = state
                .params
                .get(name)
                .ok_or_else(|| mismatch(name, "has no saved state".into()))?;
            for (what, t) in [("exp_avg", m), ("exp_avg_sq", v)] {
                if t.size() != p.size() || t.kind() != Kind::Float {
                    return Err(mismatch(
                        name,
                        format!(
                            "{what} is {:?} {:?}, the parameter is {:?} Float",
                            t.kind(),
                            t.size(),
                            p.size()
                        ),
                    ));
                }
            }
            if *s < 0 {
                return Err(mismatch(name, format!("step count {s} is negative")));
            }
            let (o, n) = self.layout[i];
            tch::no_grad(|| {
                self.exp_avg.narrow(0, o, n).copy_(&m.reshape([-1]));
                self.exp_avg_sq.narrow(0, o, n).copy_(&v.reshape([-1]));
            });
            steps = steps.max(*s);
        }
        self.steps = steps;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::nn::Module;

    fn model(vs: &nn::VarStore) -> nn::Sequential {
        nn::seq()
            .add(nn::linear(vs.root() / "a", 3, 4, Default::default()))
            .add_fn(|x| x.tanh())
            .add(nn::linear(vs.root() / "b", 4, 2, Default::default()))
    }

    fn batch(i: i64) -> Tensor {
        Tensor::arange(12, (Kind::Float, tch::Device::Cpu)).view([4, 3]) * (0.1 * (i + 1) as f64)
    }

    fn weights(vs: &nn::VarStore) -> Vec<(String, Vec<f32>)> {
        let mut v: Vec<_> = vs
            .variables()
            .into_iter()
            .map(|(n, t)| (n, crate::train::nets::tensor_to_vec(&t.flatten(0, -1))))
            .collect();
        v.sort_by(|a, b| a.0.cmp(&b.0));
        v
    }

    #[test]
    fn adam_follows_libtorch_adam_up_to_float_rounding() {
        tch::manual_seed(1);
        let vs1 = nn::VarStore::new(tch::Device::Cpu);
        let m1 = model(&vs1);
        let mut vs2 = nn::VarStore::new(tch::Device::Cpu);
        let m2 = model(&vs2);
        vs2.copy(&vs1).expect("copy");
        let mut ours = Adam::new(&vs1, 0.01).expect("adam");
        let mut theirs = nn::Adam::default().build(&vs2, 0.01).expect("adam");
        for i in 0..20 {
            ours.zero_grad();
            m1.forward(&batch(i)).square().mean(Kind::Float).backward();
            ours.step();
            theirs.zero_grad();
            m2.forward(&batch(i)).square().mean(Kind::Float).backward();
            theirs.step();
        }
        let (a, b) = (weights(&vs1), weights(&vs2));
        let mut moved = 0.0f32;
        for ((na, wa), (_, wb)) in a.iter().zip(&b) {
            for (x, y) in wa.iter().zip(wb) {
                assert!((x - y).abs() < 1e-5, "{na}: {x} vs {y}");
                moved = moved.max(x.abs());
            }
        }
        assert!(moved > 0.0);
    }

    #[test]
    fn a_restored_adam_continues_exactly_like_the_original() {
        tch::manual_seed(2);
        let vs1 = nn::VarStore::new(tch::Device::Cpu);
        let m1 = model(&vs1);
        let mut opt1 = Adam::new(&vs1, 0.01).expect("adam");
        let train = |m: &nn::Sequential, opt: &mut Adam, range: std::ops::Range<i64>| {
            for i in range {
                opt.zero_grad();
                m.forward(&batch(i)).square().mean(Kind::Float).backward();
                opt.clip_and_step(0.5);
            }
        };
        train(&m1, &mut opt1, 0..5);
        let saved = opt1.state();
        let mut vs2 = nn::VarStore::new(tch::Device::Cpu);
        let m2 = model(&vs2);
        vs2.copy(&vs1).expect("copy");
        let mut opt2 = Adam::new(&vs2, 0.01).expect("adam");
        opt2.set_state(&saved).expect("restore");
        train(&m1, &mut opt1, 5..12);
        train(&m2, &mut opt2, 5..12);
        assert_eq!(weights(&vs1), weights(&vs2));
    }

    #[test]
    fn a_parameter_no_loss_reaches_keeps_its_values_and_zero_moments() {
        tch::manual_seed(3);
        let vs = nn::VarStore::new(tch::Device::Cpu);
        let used = nn::linear(vs.root() / "used", 3, 2, Default::default());
        let _unused = nn::linear(vs.root() / "unused", 3, 2, Default::default());
        let before = weights(&vs);
        let mut opt = Adam::new(&vs, 0.01).expect("adam");
        for i in 0..5 {
            opt.zero_grad();
            used.forward(&batch(i))
                .square()
                .mean(Kind::Float)
                .backward();
            opt.step();
        }
        let after = weights(&vs);
        for ((name, b), (_, a)) in before.iter().zip(&after) {
            assert_eq!(name.starts_with("unused"), a == b, "{name}");
        }
        let st = opt.state();
        for (name, (m, v, steps)) in &st.params {
            assert_eq!(*steps, 5, "{name}");
            let zero = f64::try_from(m.abs().sum(Kind::Float) + v.abs().sum(Kind::Float))
                .expect("sum")
                == 0.0;
            assert_eq!(name.starts_with("unused"), zero, "{name}");
        }
    }

    #[test]
    fn a_state_with_uneven_step_counts_resumes_at_the_largest() {
        let vs = nn::VarStore::new(tch::Device::Cpu);
        let _m = model(&vs);
        let mut opt = Adam::new(&vs, 0.01).expect("adam");
        let mut st = opt.state();
        for (i, (_, (_, _, s))) in st.params.iter_mut().enumerate() {
            *s = if i == 0 { 7 } else { 0 };
        }
        opt.set_state(&st).expect("restore");
        assert!(opt.state().params.values().all(|(_, _, s)| *s == 7));
    }

    #[test]
    fn a_state_for_another_model_is_refused_by_name() {
        let vs = nn::VarStore::new(tch::Device::Cpu);
        let _m = model(&vs);
        let mut opt = Adam::new(&vs, 0.01).expect("adam");
        let mut st = opt.state();
        let (k, v) = st.params.pop_first().expect("one param");
        st.params.insert(format!("{k}x"), v);
        let e = opt.set_state(&st).expect_err("mismatch").to_string();
        assert!(e.contains(&format!("{k}x")), "{e}");
    }
}
