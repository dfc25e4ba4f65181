//! Adam whose state can be saved and restored.
//!
//! tch's `nn::Optimizer` keeps Adam's moments and step counts inside libtorch, out of
//! reach of a checkpoint; a resumed run with fresh moments would not continue the run it
//! resumes. [`Adam`] is the same update (libtorch's `torch::optim::Adam`, no weight
//! decay, no AMSGrad) written with tch tensor ops, so its state is three plain tensors
//! per parameter. It differs from libtorch only in float rounding: libtorch fuses
//! `a + alpha * b`, tch offers no `alpha`, so the moment updates round once more.
//!
//! Gradients are reset to *undefined* as libtorch's `zero_grad` does (a parameter that
//! no backward pass reached is skipped by `step`, its moments untouched); tch exposes
//! that reset only through an optimiser, so a learning-rate-0 SGD over the same
//! variables does just that and nothing else.

use std::collections::BTreeMap;
use tch::{Kind, TchError, Tensor, nn, nn::OptimizerConfig};

/// Adam over the trainable variables of one [`nn::VarStore`].
pub struct Adam {
    /// `(name, variable)` in the store's creation order.
    params: Vec<(String, Tensor)>,
    exp_avg: Vec<Tensor>,
    exp_avg_sq: Vec<Tensor>,
    /// Steps taken per parameter (a parameter without a gradient is not stepped).
    steps: Vec<i64>,
    lr: f64,
    beta1: f64,
    beta2: f64,
    eps: f64,
    /// Used only for `zero_grad` (libtorch's set-to-none).
    grads: nn::Optimizer,
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
    /// variable of `vs` at this point.
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
        let zeros = |t: &Tensor| t.zeros_like().detach();
        Ok(Self {
            exp_avg: params.iter().map(|(_, t)| zeros(t)).collect(),
            exp_avg_sq: params.iter().map(|(_, t)| zeros(t)).collect(),
            steps: vec![0; params.len()],
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

    /// Scales all gradients so that their joint L2 norm is at most `max` (as tch's
    /// `Optimizer::clip_grad_norm`).
    pub fn clip_grad_norm(&self, max: f64) {
        tch::no_grad(|| {
            let norms: Vec<Tensor> = self
                .params
                .iter()
                .map(|(_, p)| p.grad())
                .filter(|g| g.defined())
                .map(|g| g.norm())
                .collect();
            if norms.is_empty() {
                return;
            }
            let total = f64::try_from(Tensor::stack(&norms, 0).norm()).unwrap_or(f64::NAN);
            let coef = max / (total + 1e-6);
            if coef < 1.0 {
                for (_, p) in &self.params {
                    let mut g = p.grad();
                    if g.defined() {
                        let _ = g.g_mul_scalar_(coef);
                    }
                }
            }
        });
    }

    /// One Adam step on every parameter that has a gradient.
    pub fn step(&mut self) {
        tch::no_grad(|| {
            for (i, (_, p)) in self.params.iter_mut().enumerate() {
                let g = p.grad();
                if !g.defined() {
                    continue;
                }
                self.steps[i] += 1;
                let t = self.steps[i] as i32;
                let bc1 = 1.0 - self.beta1.powi(t);
                let bc2 = 1.0 - self.beta2.powi(t);
                let m = &mut self.exp_avg[i];
                let _ = m.g_mul_scalar_(self.beta1);
                let _ = m.g_add_(&(&g * (1.0 - self.beta1)));
                let v = &mut self.exp_avg_sq[i];
                let _ = v.g_mul_scalar_(self.beta2);
                let _ = v.g_add_(&(&g * &g * (1.0 - self.beta2)));
                let denom = (v.sqrt() / bc2.sqrt()) + self.eps;
                let update = &self.exp_avg[i] / denom * (self.lr / bc1);
                let _ = p.g_sub_(&update);
            }
        });
    }

    /// Learning rate.
    pub fn lr(&self) -> f64 {
        self.lr
    }

    /// A deep copy of the moments and step counts.
    pub fn state(&self) -> AdamState {
        AdamState {
            params: self
                .params
                .iter()
                .enumerate()
                .map(|(i, (name, _))| {
                    (
                        name.clone(),
                        (
                            self.exp_avg[i].copy(),
                            self.exp_avg_sq[i].copy(),
                            self.steps[i],
                        ),
                    )
                })
                .collect(),
        }
    }

    /// Replaces the moments and step counts with `state` (every parameter, same shapes).
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
            self.exp_avg[i] = m.copy();
            self.exp_avg_sq[i] = v.copy();
            self.steps[i] = *s;
        }
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
            .map(|(n, t)| (n, crate::nets::tensor_to_vec(&t.flatten(0, -1))))
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
                opt.clip_grad_norm(0.5);
                opt.step();
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
