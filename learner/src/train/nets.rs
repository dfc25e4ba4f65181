//! The networks (tch): policy, value, discriminator body with its heads, and p(c).
//!
//! Shapes follow the paper's reference implementation (see DESIGN.md):
//! - policy `pi(a | s, eps, c)`: tanh MLP (64-64) on `[norm(s), eps, c]` giving the mean of
//!   a Gaussian with a state-independent `log_std`, squashed by tanh;
//! - value `V(s, eps, c)`: tanh MLP (64-64), same input;
//! - discriminator body `D_body(s, a)`: tanh MLP (100-100) shared by the heads `D` (1 logit,
//!   "expert" = 1), `Q_c` (K logits) and `Q_eps` (1), Fig. 2;
//! - p(c): softmax over K learnable logits, updated with the policy (Sec. 3.2).

use ess_actor::{Mlp as RustMlp, PolicyWeights};
use ess_proto::{MlpLayout, WeightsError};
use tch::{Kind, Tensor, nn, nn::Module};

/// A tanh MLP built from `nn::Linear` layers.
#[derive(Debug)]
pub struct Mlp {
    layers: Vec<nn::Linear>,
    sizes: Vec<usize>,
    /// Apply tanh after the last layer too (a body rather than a head).
    tanh_out: bool,
}

impl Mlp {
    /// Layers `sizes[0] -> ... -> sizes[n]` under `p`; `out_scale` multiplies the last
    /// layer's initial weights (small for policy heads).
    pub fn new(p: nn::Path, sizes: &[usize], tanh_out: bool, out_scale: f64) -> Self {
        let n = sizes.len() - 1;
        let layers = (0..n)
            .map(|l| {
                let lin = nn::linear(
                    &p / format!("l{l}"),
                    sizes[l] as i64,
                    sizes[l + 1] as i64,
                    Default::default(),
                );
                if l + 1 == n && out_scale != 1.0 {
                    tch::no_grad(|| {
                        let mut ws = lin.ws.shallow_clone();
                        let _ = ws.f_mul_scalar_(out_scale);
                        if let Some(bs) = &lin.bs {
                            let _ = bs.shallow_clone().f_zero_();
                        }
                    });
                }
                lin
            })
            .collect();
        Self {
            layers,
            sizes: sizes.to_vec(),
            tanh_out,
        }
    }

    /// Layer sizes.
    pub fn sizes(&self) -> &[usize] {
        &self.sizes
    }

    /// The layers, input first.
    pub fn layers(&self) -> &[nn::Linear] {
        &self.layers
    }

    /// Whether the last layer is activated too.
    pub fn tanh_out(&self) -> bool {
        self.tanh_out
    }

    /// Parameters flattened in the [`MlpLayout`] order (weight `[out][in]`, then bias).
    pub fn export(&self) -> Vec<f32> {
        let mut out = Vec::new();
        tch::no_grad(|| {
            for lin in &self.layers {
                out.extend(tensor_to_vec(&lin.ws));
                if let Some(b) = &lin.bs {
                    out.extend(tensor_to_vec(b));
                }
            }
        });
        out
    }
}

/// The weights that apply `(w, b)` to a layer input held in sigmoid form (`h = 2 s - 1`,
/// `W h + b = (2 W) s + (b - W 1)`) and, when `activate`, yield twice the
/// pre-activation (`tanh(z) = 2 sigmoid(2 z) - 1`). See [`Mlp::forward_folded`].
fn folded(w: &Tensor, b: Option<&Tensor>, sigmoid_form: bool, activate: bool) -> (Tensor, Tensor) {
    // New tensors throughout: `w` and `b` are the parameters themselves, which an
    // in-place op would change.
    let b = match b {
        Some(b) => b.shallow_clone(),
        None => Tensor::zeros([w.size()[0]], (w.kind(), w.device())),
    };
    let b = if sigmoid_form {
        b - w.sum_dim_intlist(1, false, Kind::Float)
    } else {
        b
    };
    let scale = match (sigmoid_form, activate) {
        (false, false) => return (w.shallow_clone(), b),
        (true, true) => 4.0,
        _ => 2.0,
    };
    let b = if activate { b * 2.0 } else { b };
    (w * scale, b)
}

impl Mlp {
    /// The network's output, in sigmoid form (`(s, true)`: the output is `2 s - 1`)
    /// when the last layer is activated, so a following linear layer can fold the
    /// `2 s - 1` into its weights ([`folded`]).
    ///
    /// `tanh(W h + b)` is computed as `2 sigmoid(2 (W h + b)) - 1`, with the factor 2
    /// folded into this layer's weights and the `2 s - 1` into the next layer's, so
    /// each hidden activation costs one sigmoid and the extra work is on the small
    /// weight matrices. The reason is speed: libtorch's float `tanh` calls MKL's
    /// `vsTanh`, which on AMD CPUs runs a generic code path ~6x slower than
    /// libtorch's own vectorised sigmoid (`bench/learner.md`: 766 us against 123 us
    /// on `[3000, 100]`). The network, its parameters and its gradients are the same
    /// up to float rounding (a test holds it to `tanh` within 1e-6).
    pub fn forward_folded(&self, x: &Tensor) -> (Tensor, bool) {
        let n = self.layers.len();
        let mut h = x.shallow_clone();
        let mut sigmoid_form = false;
        for (l, lin) in self.layers.iter().enumerate() {
            let activate = l + 1 < n || self.tanh_out;
            let (w, b) = folded(&lin.ws, lin.bs.as_ref(), sigmoid_form, activate);
            h = h.linear(&w, Some(&b));
            if activate {
                h = h.sigmoid();
            }
            sigmoid_form = activate;
        }
        (h, sigmoid_form)
    }
}

impl Module for Mlp {
    fn forward(&self, x: &Tensor) -> Tensor {
        match self.forward_folded(x) {
            (s, true) => s * 2.0 - 1.0,
            (h, false) => h,
        }
    }
}

/// Copies a float tensor's values out (any shape, row-major).
pub fn tensor_to_vec(t: &Tensor) -> Vec<f32> {
    let flat = t.detach().to_kind(Kind::Float).contiguous().view([-1]);
    Vec::<f32>::try_from(&flat).unwrap_or_default()
}

/// A `[rows, cols]` float tensor from a row-major slice.
pub fn tensor_2d(data: &[f32], cols: usize) -> Tensor {
    let rows = data.len().checked_div(cols).unwrap_or(0);
    Tensor::from_slice(data).view([rows as i64, cols as i64])
}

/// Policy: mean MLP plus state-independent log standard deviation.
#[derive(Debug)]
pub struct Policy {
    /// Mean network.
    pub mean: Mlp,
    /// Log standard deviation, `[act_dim]`.
    pub log_std: Tensor,
}

impl Policy {
    /// New policy for `input` features and `act_dim` actions.
    pub fn new(p: nn::Path, input: usize, hidden: &[usize], act_dim: usize, log_std0: f64) -> Self {
        let mut sizes = vec![input];
        sizes.extend_from_slice(hidden);
        sizes.push(act_dim);
        let mean = Mlp::new(&p / "mean", &sizes, false, 0.01);
        let log_std = p.var("log_std", &[act_dim as i64], nn::Init::Const(log_std0));
        Self { mean, log_std }
    }

    /// Gaussian log-density of pre-tanh samples `u` `[n, act]` given inputs `[n, in]`.
    pub fn log_prob(&self, input: &Tensor, u: &Tensor) -> Tensor {
        let mean = self.mean.forward(input);
        let z = (u - mean) * (-&self.log_std).exp();
        let ln_sqrt_2pi = 0.5 * (2.0 * std::f64::consts::PI).ln();
        (z.square() * -0.5 - &self.log_std - ln_sqrt_2pi).sum_dim_intlist(-1, false, Kind::Float)
    }

    /// Entropy of the Gaussian (before squashing), summed over action dims.
    pub fn entropy(&self) -> Tensor {
        let c = 0.5 * (2.0 * std::f64::consts::PI * std::f64::consts::E).ln();
        (&self.log_std + c).sum(Kind::Float)
    }
}

/// How many leading observation entries a net reads under an `obs_prefix` setting
/// (`sac.obs_prefix`, `disc.obs_prefix`): 0 means all `obs_dim`; `None` when the
/// prefix is longer than the observation.
pub fn obs_columns(prefix: usize, obs_dim: usize) -> Option<usize> {
    match prefix {
        0 => Some(obs_dim),
        p if p <= obs_dim => Some(p),
        _ => None,
    }
}

/// Discriminator body and its three heads.
#[derive(Debug)]
pub struct Discriminator {
    /// Shared body on `[norm(s), a]`.
    pub body: Mlp,
    /// Expert-vs-policy logit head (1).
    pub d: nn::Linear,
    /// Latent skill posterior head Q_c (K logits).
    pub qc: nn::Linear,
    /// Latent shift regression head Q_eps (1).
    pub qeps: nn::Linear,
}

/// Outputs of the discriminator on a batch.
pub struct DiscOut {
    /// D logits `[n]`.
    pub d_logit: Tensor,
    /// Q_c logits `[n, K]`.
    pub qc_logits: Tensor,
    /// Q_eps prediction `[n]`.
    pub qeps: Tensor,
}

impl Discriminator {
    /// New body `input -> hidden` with heads for `n_codes` codes.
    pub fn new(p: nn::Path, input: usize, hidden: &[usize], n_codes: usize) -> Self {
        let mut sizes = vec![input];
        sizes.extend_from_slice(hidden);
        let body = Mlp::new(&p / "body", &sizes, true, 1.0);
        let h = *hidden.last().unwrap_or(&input) as i64;
        Self {
            body,
            d: nn::linear(&p / "d", h, 1, Default::default()),
            qc: nn::linear(&p / "qc", h, n_codes as i64, Default::default()),
            qeps: nn::linear(&p / "qeps", h, 1, Default::default()),
        }
    }

    /// All heads on inputs `[n, in]`, as one linear layer over the body's features
    /// (the three heads' weights stacked: one matrix product instead of three).
    pub fn forward(&self, x: &Tensor) -> DiscOut {
        let (s, sigmoid_form) = self.body.forward_folded(x);
        let heads = [&self.d, &self.qc, &self.qeps];
        let w = Tensor::cat(&heads.map(|h| &h.ws), 0);
        let b = heads.map(|h| h.bs.as_ref());
        let b = match b {
            [Some(d), Some(qc), Some(qeps)] => Some(Tensor::cat(&[d, qc, qeps], 0)),
            _ => None,
        };
        let (w, b) = folded(&w, b.as_ref(), sigmoid_form, false);
        let out = s.linear(&w, Some(&b));
        let k = self.qc.ws.size()[0];
        DiscOut {
            d_logit: out.select(1, 0),
            qc_logits: out.narrow(1, 1, k),
            qeps: out.select(1, 1 + k),
        }
    }

    /// Encoder parameters psi of Q_c (body and Q_c head), for the RIM L2 term.
    pub fn encoder_params(&self) -> Vec<Tensor> {
        let mut v = Vec::new();
        for lin in self.body.layers.iter().chain(std::iter::once(&self.qc)) {
            v.push(lin.ws.shallow_clone());
        }
        v
    }
}

/// Exports the acting policy as [`PolicyWeights`] for the actors.
pub fn export_policy(
    policy: &Policy,
    prior_logits: &Tensor,
    obs_mean: &[f32],
    obs_std: &[f32],
    version: u64,
) -> Result<PolicyWeights, WeightsError> {
    let s = policy.mean.sizes();
    let layout = MlpLayout { sizes: s.to_vec() };
    Ok(PolicyWeights {
        version,
        mean: RustMlp::new(layout, policy.mean.export())?,
        log_std: tensor_to_vec(&policy.log_std),
        prior_logits: tensor_to_vec(prior_logits),
        obs_mean: obs_mean.to_vec(),
        obs_std: obs_std.to_vec(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn obs_columns_reads_0_as_all_and_refuses_a_prefix_past_the_end() {
        assert_eq!(obs_columns(0, 45), Some(45));
        assert_eq!(obs_columns(2, 45), Some(2));
        assert_eq!(obs_columns(45, 45), Some(45));
        assert_eq!(obs_columns(46, 45), None);
    }

    /// The plain `tanh(W h + b)` chain [`Mlp::forward`] reformulates.
    fn tanh_chain(m: &Mlp, x: &Tensor) -> Tensor {
        let n = m.layers.len();
        let mut h = x.shallow_clone();
        for (l, lin) in m.layers.iter().enumerate() {
            h = lin.forward(&h);
            if l + 1 < n || m.tanh_out {
                h = h.tanh();
            }
        }
        h
    }

    #[test]
    fn the_sigmoid_form_equals_tanh_layers_in_values_and_gradients() {
        tch::manual_seed(5);
        for tanh_out in [false, true] {
            let vs = nn::VarStore::new(tch::Device::Cpu);
            let m = Mlp::new(vs.root() / "m", &[7, 16, 16, 3], tanh_out, 1.0);
            // Pre-activations from about -6 to 6, where tanh saturates.
            let x = Tensor::randn([64, 7], (Kind::Float, tch::Device::Cpu)) * 3.0;
            let grads = |out: Tensor| {
                vs.trainable_variables()
                    .iter_mut()
                    .for_each(|v| v.zero_grad());
                (&out * &out).sum(Kind::Float).backward();
                let g: Vec<Vec<f32>> = vs
                    .trainable_variables()
                    .iter()
                    .map(|v| tensor_to_vec(&v.grad()))
                    .collect();
                (tensor_to_vec(&out), g)
            };
            let (fast, gf) = grads(m.forward(&x));
            let (plain, gp) = grads(tanh_chain(&m, &x));
            let max_diff = |a: &[f32], b: &[f32]| {
                a.iter()
                    .zip(b)
                    .map(|(a, b)| (a - b).abs() / b.abs().max(1.0))
                    .fold(0.0f32, f32::max)
            };
            assert!(
                max_diff(&fast, &plain) < 1e-6,
                "values, tanh_out {tanh_out}"
            );
            for (a, b) in gf.iter().zip(&gp) {
                assert!(max_diff(a, b) < 1e-5, "gradients, tanh_out {tanh_out}");
            }
        }
    }

    #[test]
    fn the_stacked_heads_equal_each_head_on_the_tanh_features() {
        tch::manual_seed(6);
        let vs = nn::VarStore::new(tch::Device::Cpu);
        let d = Discriminator::new(vs.root() / "d", 5, &[12, 12], 4);
        let x = Tensor::randn([9, 5], (Kind::Float, tch::Device::Cpu)) * 2.0;
        let o = d.forward(&x);
        let f = tanh_chain(&d.body, &x);
        let close = |a: &Tensor, b: &Tensor| {
            let diff = f64::try_from((a - b).abs().max()).expect("max");
            assert!(diff < 1e-5, "{diff}");
        };
        close(&o.d_logit, &d.d.forward(&f).squeeze_dim(-1));
        close(&o.qc_logits, &d.qc.forward(&f));
        close(&o.qeps, &d.qeps.forward(&f).squeeze_dim(-1));
    }

    #[test]
    fn rust_forward_equals_tch_forward_within_1e_5() {
        tch::manual_seed(3);
        let vs = nn::VarStore::new(tch::Device::Cpu);
        let obs_dim = 10;
        let k = 4;
        let policy = Policy::new(vs.root() / "pi", obs_dim + 1 + k, &[64, 64], 2, -0.5);
        // Make the output layer non-trivial so the comparison means something.
        tch::no_grad(|| {
            for lin in &policy.mean.layers {
                let _ = lin.ws.shallow_clone().f_normal_(0.0, 0.5);
            }
        });
        let logits = Tensor::zeros([k as i64], (Kind::Float, tch::Device::Cpu));
        let w = export_policy(&policy, &logits, &[0.0; 10], &[1.0; 10], 1).unwrap();
        let x = Tensor::randn(
            [32, (obs_dim + 1 + k) as i64],
            (Kind::Float, tch::Device::Cpu),
        );
        let want = tensor_to_vec(&policy.mean.forward(&x));
        let xs = tensor_to_vec(&x);
        let mut out = [0.0f32; 2];
        let mut scratch = vec![0.0; w.mean.scratch_len()];
        for (i, row) in xs.chunks(obs_dim + 1 + k).enumerate() {
            w.mean.forward(row, &mut out, &mut scratch);
            for j in 0..2 {
                let d = (out[j] - want[i * 2 + j]).abs();
                assert!(
                    d < 1e-5,
                    "row {i} dim {j}: {} vs {}",
                    out[j],
                    want[i * 2 + j]
                );
            }
        }
    }

    #[test]
    fn policy_log_prob_matches_the_gaussian_formula() {
        let vs = nn::VarStore::new(tch::Device::Cpu);
        let policy = Policy::new(vs.root(), 3, &[8], 2, -0.5);
        let x = Tensor::zeros([1, 3], (Kind::Float, tch::Device::Cpu));
        let mean = tensor_to_vec(&policy.mean.forward(&x));
        let u = Tensor::from_slice(&[0.3f32, -0.2]).view([1, 2]);
        let lp = f64::try_from(policy.log_prob(&x, &u).sum(Kind::Float)).unwrap();
        let std = (-0.5f64).exp();
        let want: f64 = [0.3, -0.2]
            .iter()
            .zip(&mean)
            .map(|(u, m)| {
                let z = (u - *m as f64) / std;
                -0.5 * z * z - std.ln() - 0.5 * (2.0 * std::f64::consts::PI).ln()
            })
            .sum();
        assert!((lp - want).abs() < 1e-5, "{lp} vs {want}");
    }
}
