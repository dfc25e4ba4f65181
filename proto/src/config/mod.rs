//! Training configuration: one objective made of weighted terms, selected by presets.
//!
//! Layering: [`TrainConfig::default`] (the paper's values) < a preset TOML
//! (`deploy/presets/<name>.toml`) < a user file < `--set key=value` overrides. Every
//! layer is a TOML table merged key by key into the defaults; a key that the defaults
//! do not have is rejected with its dotted name, so a typo never passes silently. The
//! merged table is deserialized (`deny_unknown_fields`) and then checked once by
//! [`TrainConfig::check`] into a [`CheckedConfig`], whose values are in range.

mod check;
mod layers;
mod remote;

pub use layers::{ConfigBuilder, EnvLayer};
pub use remote::{RemoteConfig, is_tls_endpoint, valid_host_name};
use serde::{Deserialize, Serialize};
use thiserror::Error;

/// A configuration error; each names the key (or file) and the value at fault.
#[derive(Debug, Error)]
pub enum ConfigError {
    /// A key that the configuration does not have.
    #[error(
        "unknown config key `{}` (in {source_name})",
        crate::text::printable(key)
    )]
    UnknownKey {
        /// Dotted key.
        key: String,
        /// Which layer it came from (preset name, file path, `--set`).
        source_name: String,
    },
    /// A value of the wrong TOML type.
    #[error(
        "config key `{}` (in {source_name}) must be {expected}, got {got}",
        crate::text::printable(key)
    )]
    WrongType {
        /// Dotted key.
        key: String,
        /// Which layer it came from.
        source_name: String,
        /// The expected type.
        expected: String,
        /// What was given.
        got: String,
    },
    /// A value outside its allowed range.
    #[error(
        "config key `{}` = {} is out of range: {reason}",
        crate::text::printable(key),
        crate::text::printable(value)
    )]
    OutOfRange {
        /// Dotted key.
        key: String,
        /// The offending value.
        value: String,
        /// What is allowed.
        reason: String,
    },
    /// A `--set` argument not of the form `key=value`.
    #[error("bad override `{}`: expected key=value", crate::text::printable(arg))]
    BadOverride {
        /// The argument as given.
        arg: String,
    },
    /// A TOML document that does not parse.
    #[error("{source_name}: invalid TOML: {message}")]
    Parse {
        /// File or preset name.
        source_name: String,
        /// The parser's message.
        message: String,
    },
    /// Deserialization failed after merging (should name the key in `message`).
    #[error("invalid configuration: {message}")]
    Invalid {
        /// The deserializer's message.
        message: String,
    },
}

/// How the latent skill `c` is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LatentPrior {
    /// No latent skill reaches the policy (GAIL): `c` is fed as zeros.
    None,
    /// Fixed uniform categorical, one-hot `c` (InfoGAIL, ACGAIL, Ess-InfoGAIL\GS).
    Uniform,
    /// Learnable p(c) sampled with Gumbel-softmax (Eq. 7), gradient to its logits
    /// through the PPO surrogate (Elastic-InfoGAIL, Ess-InfoGAIL).
    Gumbel,
}

/// Which distribution the actors draw each episode's latent skill `c` from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RolloutCodes {
    /// From p(c) itself (Sec. 3.2, the paper's code): a code the demonstrations hold
    /// 0.5% of is rolled out in 0.5% of the episodes once p(c) has learned that.
    #[default]
    Prior,
    /// From a uniform Gumbel-softmax, so every code gets rollouts whatever p(c) is;
    /// needs `method.prior = "gumbel"`. p(c) follows Q_c's label marginal on the
    /// unlabeled demonstrations (the minimum over p(c) of L_RIM's KL term, Eq. 8-9)
    /// instead of the PPO surrogate, and is RIM's label prior; with
    /// `method.disc_code_reweight` D's generated batch is drawn at p(c)'s code
    /// proportions (importance resampling of the uniform rollouts).
    Uniform,
}

/// Where the actors run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ActorTransport {
    /// Threads of the learner process (the in-process path and test double;
    /// `ess train --actors 0`).
    Threads,
    /// `ess-actor` processes feeding the learner over iceoryx2 shared memory (the
    /// default; `ess train --actors N`).
    #[default]
    Processes,
}

/// How an iteration's rollout and the learner's update interleave.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Pipeline {
    /// Collect, then update (Algorithm 1 as written).
    #[default]
    Sync,
    /// The actors collect iteration k+1 under the weights of version k while the
    /// learner updates on iteration k's rollout; PPO's ratio uses the behaviour
    /// log-probabilities the actors recorded (one version stale, as in APPO and
    /// Cleanba). Deterministic: the rollouts depend on the weights, not the timing.
    Overlap,
}

/// Which implementation runs the learner's update ([`LearnerConfig::backend`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Backend {
    /// The fused CPU passes of `ess-learner`'s `fused` module (the default): the same
    /// objective as `tch`, several times faster at the learner's sizes. A
    /// configuration it does not cover (R1's gradient penalty) runs on `tch`, and the
    /// run's log says so.
    #[default]
    Fused,
    /// libtorch's operations and autograd (the reference implementation).
    Tch,
}

/// The learner's implementation.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LearnerConfig {
    /// `fused` (default) or `tch`; both read and write the same networks, so a
    /// checkpoint of one resumes on the other.
    pub backend: Backend,
}

/// Form of the discriminator's term in the policy reward.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DiscReward {
    /// `-log(1 - D(s, a))` (GAIL's usual form; saturates at 0 where D is sure "policy").
    NegLogOneMinusD,
    /// `log D - log(1 - D)`, the logit (AIRL form): an estimate of
    /// `log p_E(s, a) / p_pi(s, a)` that keeps a gradient where D is sure.
    Logit,
}

/// The environment and its behaviour modes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EnvConfig {
    /// Environment name: `traj2d`.
    pub name: String,
    /// Number of behaviour modes K (Traj2D: 4; Reacher: 2..12, paper 6).
    pub n_modes: usize,
}

impl Default for EnvConfig {
    fn default() -> Self {
        Self {
            name: "traj2d".into(),
            n_modes: 4,
        }
    }
}

/// Demonstrations: imbalanced unlabeled part plus a small balanced labeled part.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DemosConfig {
    /// A dataset file written by `ess demos generate`; empty: generate in memory.
    pub path: String,
    /// Labeled steps as a fraction of the unlabeled steps, in (0, 1] (paper, 2D: 1%).
    pub label_ratio: f64,
    /// Largest over smallest mode frequency in the unlabeled part, >= 1 (paper: 100).
    pub imbalance_ratio: f64,
    /// Unlabeled episodes of each majority mode.
    pub majority_episodes: usize,
    /// Seed of the dataset (independent of the training seed, as in the paper).
    pub seed: u64,
}

impl Default for DemosConfig {
    fn default() -> Self {
        Self {
            path: String::new(),
            label_ratio: 0.01,
            imbalance_ratio: 100.0,
            majority_episodes: 200,
            seed: 0,
        }
    }
}

/// The method: which latent prior and which weighted objective terms.
///
/// Every term's weight 0 switches it off. Equation numbers refer to the paper.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MethodConfig {
    /// Display name of the method (set by the preset).
    pub name: String,
    /// Prior of the latent skill `c`.
    pub prior: LatentPrior,
    /// Gumbel-softmax temperature tau (Eq. 7; reference code: 0.1).
    pub gumbel_tau: f64,
    /// Feed the latent shifting variable eps ~ U(-1, 1) to the policy.
    pub use_eps: bool,
    /// Discriminator binary cross-entropy (Eq. 1).
    pub w_disc: f64,
    /// R1 gradient penalty on expert inputs of D (stabiliser, not in the paper).
    pub w_grad_penalty: f64,
    /// Q_eps regression with mean absolute error on generated data (Eq. 2 for eps).
    pub w_qeps: f64,
    /// Q_c cross-entropy on labeled expert data (Eq. 4).
    pub w_qc_labeled: f64,
    /// Q_c cross-entropy on generated data against the sampled `c` (Eq. 2 / 5, InfoGAIL).
    pub w_qc_generated: f64,
    /// Q_c cross-entropy on all expert data with its true mode (ACGAIL, full labels).
    pub w_qc_full_labels: f64,
    /// Contrastive (NT-Xent) loss on Q_c features, noise-augmented pairs (Elastic-InfoGAIL).
    pub w_contrastive: f64,
    /// Std of the Gaussian augmentation noise of the contrastive loss.
    pub contrastive_noise: f64,
    /// Temperature of the contrastive loss.
    pub contrastive_temperature: f64,
    /// Expert transitions per D/Q step that enter the contrastive loss (its cost grows
    /// with the square of this).
    pub contrastive_batch: usize,
    /// RIM weight lambda_3 (Eq. 8) on unlabeled expert data.
    pub w_rim: f64,
    /// RIM: weight of the mean conditional entropy (cluster assumption).
    pub rim_cond_entropy: f64,
    /// RIM: weight of KL(empirical Q_c marginal || p(c)).
    pub rim_marginal_kl: f64,
    /// RIM: L2 regularisation of the encoder parameters R(psi).
    pub rim_l2: f64,
    /// Let RIM's KL term also move the p(c) logits (Eq. 9 minimises L_RIM over p(c)),
    /// so p(c) follows Q_c's label marginal on the unlabeled expert data. Off by
    /// default: p(c) then learns the imbalance (0.49/0.49/0.005/0.005 on Traj2D) and
    /// the minority codes are sampled too rarely to be learned (bench/README.md).
    pub rim_prior_grad: bool,
    /// RIM weight ramps linearly from 0 to `w_rim` over this many iterations.
    pub rim_warmup_iters: usize,
    /// Iterations over which the policy's information rewards (`reward_qc`,
    /// `reward_qeps`) ramp linearly from 0 to their full weight (0 = full from the
    /// start). On Reacher the log Q_c reward of a still-random policy swamps the
    /// imitation reward; the reference code likewise starts its information terms
    /// after a warm-up ("begin_weight").
    pub info_reward_warmup_iters: usize,
    /// Policy reward weight of log Q_c(c | s, a) (lambda_2 in Eq. 9 / Eq. 5 for pi).
    /// 4 (not 1): on Traj2D with imbalance 100, weaker weights let the discriminator
    /// pull the minority codes onto the majority modes (bench/README.md, tuning notes).
    pub reward_qc: f64,
    /// Add the entropy `H(c)` of the current p(c) to the log Q_c reward, so that each
    /// step's term is Eq. 2's mutual-information bound `log Q_c(c | s, a) + H(c)` rather
    /// than `log Q_c` alone. The constant is >= 0 wherever Q_c beats chance; it matters
    /// where episodes terminate (Walker2d, Humanoid): an always-negative reward teaches
    /// the policy to fall early to stop collecting it.
    pub qc_reward_entropy: bool,
    /// Clip each step's `log Q_c + H(c)` at 0 from below: a step Q_c does not credit
    /// to its code earns nothing instead of a penalty. Where episodes end on a fall,
    /// a code Q_c does not yet recognise otherwise learns that falling at once is
    /// best (Walker2d: the forward code fell within ~6 steps, bench/experiments.md).
    pub qc_reward_floor: bool,
    /// The value `method.qc_reward_floor` clips at (<= 0; 0: a misattributed step
    /// earns nothing). Below 0, a step Q_c credits to another code costs at most
    /// this much: on Humanoid the forward code drifted to the easier backward gait,
    /// which the discriminator pays and a 0 floor does not charge (bench/humanoid.md).
    pub qc_reward_floor_at: f64,
    /// Multiply each step's discriminator reward by `Q_c(c | s, a)`, the probability
    /// Q_c gives the step's own code: D, which judges the mixture of all modes, then
    /// pays a code only for looking like its own mode. On Humanoid D paid the forward
    /// code for the easier backward gait (bench/humanoid.md). Off: Eq. 9's reward.
    pub disc_reward_qc_gate: bool,
    /// Policy reward weight of -|Q_eps(s, a) - eps| (lambda_1 in Eq. 3).
    pub reward_qeps: f64,
    /// Policy reward weight of the discriminator term.
    pub reward_disc: f64,
    /// Form of the discriminator term.
    pub disc_reward: DiscReward,
    /// Temperature T of the discriminator term: the form reads `logit / T` instead of
    /// D's logit, i.e. `-log(1 - sigmoid(logit / T))` (1: the paper's). D is trained as
    /// Eq. 1 says; only the policy's reading of it changes. Where D is sure of every
    /// generated step (Humanoid: accuracy 1.00 from iteration ~10), `-log(1 - D)` is
    /// ~`exp(logit)` and spans orders of magnitude across steps; `T > 1` keeps it
    /// positive and monotone in the logit but of comparable size on every step.
    pub disc_reward_temperature: f64,
    /// Policy reward weight of the env's mode-agnostic shared reward (moving and staying
    /// upright on Walker2d and Humanoid; `Env::shared_reward` in `ess-envs`). The
    /// paper's code adds it to every method's reward with `reward_t_coef` 0.005; 0
    /// leaves the reward pure imitation. It never tells the modes apart.
    pub reward_shared: f64,
    /// Weight of a score-function (REINFORCE) gradient for the p(c) logits: each
    /// episode's code `k = argmax c` (Gumbel-max: `k ~ p(c)`) is reinforced by the
    /// discriminator reward its steps got, so p(c) moves toward the code frequencies
    /// that make the generated data look like the (imbalanced) expert data (the
    /// min over p(c) of Eq. 9). 0: p(c) learns only through the PPO surrogate.
    pub prior_score_coef: f64,
    /// Draw D's generated batch so that each code appears with the mode frequency Q_c
    /// estimates on the unlabeled demos (a running mean of its predicted marginal)
    /// instead of the rollout's code frequency. The rollouts keep sampling every code,
    /// so minority codes still get trained, while D compares the expert data with a
    /// generated mixture of the same mode proportions (the alignment the learnable p(c)
    /// of Sec. 3 is for) and stops calling rare-but-expert states "policy".
    pub disc_code_reweight: bool,
    /// Which distribution rollouts draw codes from ([`RolloutCodes`]).
    pub rollout_codes: RolloutCodes,
}

impl Default for MethodConfig {
    fn default() -> Self {
        Self {
            name: "ess-infogail".into(),
            prior: LatentPrior::Gumbel,
            gumbel_tau: 0.1,
            use_eps: true,
            w_disc: 1.0,
            w_grad_penalty: 0.0,
            w_qeps: 1.0,
            w_qc_labeled: 1.0,
            w_qc_generated: 0.0,
            w_qc_full_labels: 0.0,
            w_contrastive: 0.0,
            contrastive_noise: 0.05,
            contrastive_temperature: 0.5,
            contrastive_batch: 256,
            w_rim: 1.0,
            rim_cond_entropy: 1.0,
            rim_marginal_kl: 1.0,
            rim_l2: 1e-4,
            rim_prior_grad: false,
            rim_warmup_iters: 20,
            info_reward_warmup_iters: 0,
            reward_qc: 4.0,
            qc_reward_entropy: false,
            qc_reward_floor: false,
            qc_reward_floor_at: 0.0,
            disc_reward_qc_gate: false,
            reward_qeps: 0.5,
            reward_disc: 1.0,
            disc_reward: DiscReward::Logit,
            disc_reward_temperature: 1.0,
            reward_shared: 0.0,
            prior_score_coef: 0.0,
            disc_code_reweight: false,
            rollout_codes: RolloutCodes::Prior,
        }
    }
}

/// PPO with GAE (policy and value updates).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PpoConfig {
    /// Hidden widths of the policy and value MLPs (tanh; paper code: 64-64).
    pub hidden: Vec<usize>,
    /// Adam learning rate of policy and value.
    pub lr: f64,
    /// Adam learning rate of the p(c) logits.
    pub prior_lr: f64,
    /// Epochs over each rollout (paper code: 20).
    pub epochs: usize,
    /// Minibatch size.
    pub minibatch: usize,
    /// Clip range of the probability ratio (0.2).
    pub clip: f64,
    /// Discount gamma (0.99).
    pub gamma: f64,
    /// GAE lambda (0.95).
    pub gae_lambda: f64,
    /// Entropy bonus coefficient.
    pub entropy_coef: f64,
    /// Value loss coefficient.
    pub value_coef: f64,
    /// Global gradient-norm clip.
    pub max_grad_norm: f64,
    /// Initial state-independent log standard deviation of the Gaussian.
    pub log_std_init: f64,
    /// Divide rewards by the running standard deviation of the discounted return
    /// before GAE (as common PPO implementations do), so the value targets stay near
    /// unit scale whatever the reward's scale (e.g. D logits of -20 on Reacher). Off by
    /// default (Traj2D's measured results); the MuJoCo env defaults turn it on.
    pub normalize_rewards: bool,
    /// Behaviour-cloning warm start: minibatch steps (`minibatch` rows each) fitting
    /// the policy's mean to the labeled demonstrations, each under its own code,
    /// before the first iteration of a fresh run (0: off, the paper's setting).
    pub bc_steps: usize,
    /// Behaviour-cloning steps after every PPO update (the warm start's loss and
    /// rows), which keep each code near its labeled mode while the imitation rewards
    /// train it (0: off, the paper's setting). Not in the paper: an auxiliary
    /// behaviour-cloning loss as in DAPG (Rajeswaran et al. 2018), on the labeled few.
    pub bc_steps_per_iter: usize,
    /// Behaviour-cloning steps after every PPO update on the *unlabeled*
    /// demonstrations, each row under the code Q_c reads for it (rows Q_c is at least
    /// 90% sure of), beside `bc_steps_per_iter`'s (0: off, the paper's setting). Needs
    /// a method whose Q_c learns from the labeled few (`method.w_qc_labeled > 0`).
    pub bc_unlabeled_steps_per_iter: usize,
    /// Draw those rows equally from each code Q_c reads (every unlabeled row read once
    /// per update), not in the demonstrations' proportions of the modes (false).
    pub bc_unlabeled_balanced: bool,
}

impl Default for PpoConfig {
    fn default() -> Self {
        Self {
            hidden: vec![64, 64],
            lr: 3e-4,
            prior_lr: 1e-3,
            epochs: 20,
            minibatch: 1000,
            clip: 0.2,
            gamma: 0.99,
            gae_lambda: 0.95,
            entropy_coef: 0.0,
            value_coef: 0.5,
            max_grad_norm: 0.5,
            log_std_init: -0.5,
            normalize_rewards: false,
            bc_steps: 0,
            bc_steps_per_iter: 0,
            bc_unlabeled_steps_per_iter: 0,
            bc_unlabeled_balanced: false,
        }
    }
}

/// Soft actor-critic for expert training (`ess experts train --algo sac`): Haarnoja
/// et al. 2018 ("Soft Actor-Critic Algorithms and Applications"), clipped double Q,
/// Polyak-averaged target critics and an automatically tuned temperature.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SacConfig {
    /// Hidden widths of the actor (tanh, exported as the expert's mean MLP) and of each
    /// critic (ReLU).
    pub hidden: Vec<usize>,
    /// Adam learning rate of actor, critics and temperature.
    pub lr: f64,
    /// Minibatch size of every gradient step.
    pub batch: usize,
    /// Replay buffer capacity in transitions.
    pub buffer: usize,
    /// Discount gamma.
    pub gamma: f64,
    /// Polyak rate of the target critics.
    pub tau: f64,
    /// Uniformly random env steps before the first update (a fresh run only).
    pub learning_starts: usize,
    /// Gradient steps per env step.
    pub updates_per_step: usize,
    /// Initial temperature alpha.
    pub init_alpha: f64,
    /// Target policy entropy per action dimension (the total target is this times
    /// `act_dim`; SAC's default is -1).
    pub target_entropy_per_dim: f64,
    /// Observe only the first this many observation entries (0: all). E.g. 45 on
    /// Humanoid keeps `qpos[2..]` and `qvel` and drops the com-based blocks; the exported
    /// expert still reads the whole observation, with zero weights on the rest.
    pub obs_prefix: usize,
    /// Env steps per CSV row and progress report.
    pub log_every: usize,
    /// When the run stops (finished or Ctrl-C), write the replay buffer beside the
    /// expert (`<out>.replay.safetensors`, the observed prefix only: ~440 MB for a full
    /// 1M buffer on Humanoid with `obs_prefix = 45`) so that `--resume` continues with
    /// it instead of refilling from the current policy.
    pub save_replay: bool,
}

impl Default for SacConfig {
    fn default() -> Self {
        Self {
            hidden: vec![256, 256],
            lr: 3e-4,
            batch: 256,
            buffer: 1_000_000,
            gamma: 0.99,
            tau: 0.005,
            learning_starts: 5000,
            updates_per_step: 1,
            init_alpha: 1.0,
            target_entropy_per_dim: -1.0,
            obs_prefix: 0,
            log_every: 5000,
            save_replay: true,
        }
    }
}

/// Discriminator body with heads D, Q_c and Q_eps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DiscConfig {
    /// Hidden widths of the shared body (tanh; paper code: 100-100).
    pub hidden: Vec<usize>,
    /// Adam learning rate.
    pub lr: f64,
    /// D/Q update steps per iteration (paper code: 50).
    pub steps: usize,
    /// Batch size of each update, per data source (paper code: 1000).
    pub batch: usize,
    /// D, Q_c and Q_eps read only the first this many observation entries, plus the
    /// action unless `actions` is false (0: the whole observation, as in the paper). E.g. 45 on Humanoid keeps
    /// `qpos[2..]` and `qvel` and drops the com-inertia, com-velocity, actuator-force and
    /// contact-force blocks, by which D can tell policy from expert without the pose.
    pub obs_prefix: usize,
    /// Whether D, Q_c and Q_eps read the action beside the state (true: the paper's
    /// `D(s, a)`). False makes them functions of the state alone, as in imitation from
    /// observation (Torabi et al. 2019): D then cannot tell policy from expert by the
    /// action noise (a Gaussian policy against tanh-squashed experts of another std)
    /// and rewards only where the policy goes.
    pub actions: bool,
    /// One-sided label smoothing (Salimans et al. 2016): D's target on expert rows is
    /// `1 - label_smoothing` instead of 1 in Eq. 1's cross-entropy (0: off, the
    /// paper's setting). A D that may not be sure keeps finite logits on expert-like
    /// generated steps.
    pub label_smoothing: f64,
    /// The other side of label smoothing: D's target on generated rows is this instead
    /// of 0 (0: off, the paper's setting). D's optimum on a step only the policy makes
    /// is then `D = label_smoothing_policy`, not 0, so its logit stays finite there and
    /// the policy's `-log(1 - D)` keeps a floor of `-log(1 - label_smoothing_policy)`
    /// per step instead of vanishing where D is sure (Humanoid, bench/humanoid.md).
    pub label_smoothing_policy: f64,
    /// Instance noise (Sønderby et al. 2017): std of Gaussian noise added to the
    /// normalised generated and unlabeled expert rows of every D/Q step (0: off, the
    /// paper's setting), so the two sets overlap and D cannot separate them perfectly.
    /// The policy's reward reads D without noise.
    pub input_noise: f64,
}

impl Default for DiscConfig {
    fn default() -> Self {
        Self {
            hidden: vec![100, 100],
            lr: 3e-4,
            steps: 50,
            batch: 1000,
            obs_prefix: 0,
            actions: true,
            label_smoothing: 0.0,
            label_smoothing_policy: 0.0,
            input_noise: 0.0,
        }
    }
}

/// Default `run.actors`: one per core (`std::thread::available_parallelism`), at
/// most 256 (the configured maximum), at least 1.
pub fn default_actors() -> usize {
    std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1)
        .clamp(1, 256)
}

/// The run: budget, seed, evaluation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RunConfig {
    /// Training seed.
    pub seed: u64,
    /// Training iterations (rollout + D/Q + PPO each).
    pub iterations: usize,
    /// Environment steps per iteration (paper code: 5000).
    pub rollout_steps: usize,
    /// Actors, each stepping one environment (threads or processes, see `transport`);
    /// default: one per core of this machine ([`default_actors`]), so a run's numbers
    /// depend on the machine unless `actors` is given. Actor `i` seeds its random
    /// stream the same way on both transports. 0 is the single-process path: checking
    /// turns it into one actor on `threads` (what `ess train --actors 0` asks for).
    pub actors: usize,
    /// Where the actors run: `processes` (default: `ess-actor` over iceoryx2 shared
    /// memory) or `threads` of the learner (the single-process path; `ess train
    /// --actors 0`).
    pub transport: ActorTransport,
    /// `sync` (default): collect, then update; `overlap`: collect the next
    /// iteration's rollout while the learner updates ([`Pipeline`]).
    pub pipeline: Pipeline,
    /// Seconds without a heartbeat after which an actor process counts as hung and is
    /// restarted (actors beat every 0.2 s, also while collecting).
    pub actor_timeout_s: f64,
    /// The learner's threads: libtorch's intra-op threads, and the fused backend's
    /// (0: one per core; the actors wait while the learner updates, so they do not
    /// compete for them).
    pub torch_threads: usize,
    /// Evaluate every this many iterations (0: only at the end).
    pub eval_every: usize,
    /// Deterministic evaluation episodes per latent code at the end of training.
    pub eval_episodes: usize,
    /// Evaluation episodes per code for the periodic evaluations.
    pub eval_episodes_periodic: usize,
    /// Expert episodes per mode behind the evaluation reference (behaviour classifier
    /// training data and expert returns).
    pub reference_episodes: usize,
    /// Write a checkpoint every this many iterations (0: only at the end).
    pub checkpoint_every: usize,
    /// Log a sample of the rollout chunks into the run log (`run.mcap`, topic
    /// `/train/chunk`) every this many iterations (0: none).
    pub log_chunks_every: usize,
    /// Steps logged from each actor's chunk on such an iteration (the chunk's first
    /// ones); 1..=100000.
    pub log_chunk_steps: usize,
    /// Log the periodic evaluations' episodes (per step) into the run log too; the
    /// final evaluation's episodes are always logged.
    pub log_periodic_evals: bool,
}

impl Default for RunConfig {
    fn default() -> Self {
        Self {
            seed: 0,
            iterations: 300,
            rollout_steps: 5000,
            actors: default_actors(),
            transport: ActorTransport::Processes,
            pipeline: Pipeline::Sync,
            actor_timeout_s: 3.0,
            torch_threads: 0,
            eval_every: 25,
            eval_episodes: 50,
            eval_episodes_periodic: 10,
            reference_episodes: 20,
            checkpoint_every: 100,
            log_chunks_every: 25,
            log_chunk_steps: 200,
            log_periodic_evals: false,
        }
    }
}

/// The whole training configuration.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainConfig {
    /// Environment.
    pub env: EnvConfig,
    /// Demonstrations.
    pub demos: DemosConfig,
    /// Method (objective terms).
    pub method: MethodConfig,
    /// PPO.
    pub ppo: PpoConfig,
    /// SAC (expert training only).
    pub sac: SacConfig,
    /// Discriminator and encoders.
    pub disc: DiscConfig,
    /// Run budget and evaluation.
    pub run: RunConfig,
    /// The learner's implementation.
    pub learner: LearnerConfig,
    /// Actor hosts on other machines (none by default).
    pub remote: RemoteConfig,
}

/// A configuration whose values have been checked to be in range.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckedConfig(TrainConfig);

impl std::ops::Deref for CheckedConfig {
    type Target = TrainConfig;
    fn deref(&self) -> &TrainConfig {
        &self.0
    }
}

impl CheckedConfig {
    /// The same configuration run on `backend` (the backend has no range to check).
    pub fn with_backend(mut self, backend: Backend) -> Self {
        self.0.learner.backend = backend;
        self
    }

    /// The checked configuration as TOML (what goes into the run directory).
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(&self.0).unwrap_or_else(|e| format!("# unserializable: {e}\n"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_pass_their_own_check() {
        let c = ConfigBuilder::new().build().unwrap();
        assert_eq!(*c, TrainConfig::default());
    }

    #[test]
    fn layers_apply_in_order_preset_then_file_then_set() {
        let mut b = ConfigBuilder::new();
        b.merge_toml("preset", "[method]\nw_rim = 0.0\n[run]\nseed = 3\n")
            .unwrap();
        b.merge_toml("file", "[run]\nseed = 4\n").unwrap();
        b.set("run.seed=5").unwrap();
        b.set("method.name=foo").unwrap();
        let c = b.build().unwrap();
        assert_eq!(c.method.w_rim, 0.0);
        assert_eq!(c.run.seed, 5);
        assert_eq!(c.method.name, "foo");
    }

    #[test]
    fn integer_is_accepted_where_a_float_is_expected() {
        let c = ConfigBuilder::new()
            .set("ppo.lr=1")
            .unwrap()
            .build()
            .unwrap();
        assert_eq!(c.ppo.lr, 1.0);
    }

    #[test]
    fn unknown_key_is_named() {
        let e = ConfigBuilder::new()
            .set("ppo.lrr=1")
            .unwrap_err()
            .to_string();
        assert!(e.contains("`ppo.lrr`"), "{e}");
        let e = ConfigBuilder::new()
            .merge_toml("my.toml", "[nope]\nx = 1\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("`nope`") && e.contains("my.toml"), "{e}");
    }

    #[test]
    fn wrong_type_is_named_with_expected_type() {
        let e = ConfigBuilder::new()
            .set("run.iterations=\"many\"")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("`run.iterations`") && e.contains("an integer"),
            "{e}"
        );
    }

    #[test]
    fn out_of_range_values_are_rejected_with_key_and_value() {
        for (arg, key) in [
            ("demos.label_ratio=1.5", "demos.label_ratio"),
            ("demos.label_ratio=0", "demos.label_ratio"),
            ("demos.imbalance_ratio=0.5", "demos.imbalance_ratio"),
            ("env.n_modes=1", "env.n_modes"),
            ("ppo.clip=0", "ppo.clip"),
            ("sac.gamma=1", "sac.gamma"),
            ("sac.buffer=10", "sac.buffer"),
            ("sac.hidden=[256, 0]", "sac.hidden"),
            ("sac.init_alpha=0", "sac.init_alpha"),
            ("run.log_chunk_steps=0", "run.log_chunk_steps"),
        ] {
            let e = ConfigBuilder::new()
                .set(arg)
                .unwrap()
                .build()
                .unwrap_err()
                .to_string();
            assert!(e.contains(key), "{arg}: {e}");
        }
    }

    #[test]
    fn uniform_rollout_codes_need_a_learned_prior() {
        let e = ConfigBuilder::new()
            .set("method.prior=\"uniform\"")
            .unwrap()
            .set("method.rollout_codes=\"uniform\"")
            .unwrap()
            .build()
            .unwrap_err()
            .to_string();
        assert!(e.contains("method.rollout_codes"), "{e}");
        let ok = ConfigBuilder::new()
            .set("method.rollout_codes=\"uniform\"")
            .unwrap()
            .build();
        assert!(ok.is_ok(), "{ok:?}");
    }

    #[test]
    fn the_q_c_reward_floor_needs_the_entropy_offset() {
        let e = ConfigBuilder::new()
            .set("method.qc_reward_floor=true")
            .unwrap()
            .build()
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("method.qc_reward_floor") && e.contains("qc_reward_entropy"),
            "{e}"
        );
        let ok = ConfigBuilder::new()
            .set("method.qc_reward_floor=true")
            .unwrap()
            .set("method.qc_reward_entropy=true")
            .unwrap()
            .build();
        assert!(ok.is_ok(), "{ok:?}");
    }

    #[test]
    fn the_q_c_reward_floor_value_is_at_most_zero_and_needs_the_floor() {
        let e = ConfigBuilder::new()
            .set("method.qc_reward_floor_at=0.5")
            .unwrap()
            .build()
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("method.qc_reward_floor_at") && e.contains("0.5"),
            "{e}"
        );
        let with_floor = |on: bool| {
            ConfigBuilder::new()
                .set("method.qc_reward_floor_at=-0.5")
                .unwrap()
                .set(&format!("method.qc_reward_floor={on}"))
                .unwrap()
                .set("method.qc_reward_entropy=true")
                .unwrap()
                .build()
        };
        let e = with_floor(false).unwrap_err().to_string();
        assert!(
            e.contains("method.qc_reward_floor_at") && e.contains("method.qc_reward_floor ="),
            "{e}"
        );
        assert!(with_floor(true).is_ok());
    }

    #[test]
    fn the_d_reward_gate_needs_codes() {
        let with = |gate: bool| {
            ConfigBuilder::new()
                .set("method.prior=\"none\"")
                .unwrap()
                .set("method.reward_qc=0")
                .unwrap()
                .set(&format!("method.disc_reward_qc_gate={gate}"))
                .unwrap()
                .build()
        };
        assert!(with(false).is_ok(), "{:?}", with(false));
        let e = with(true).unwrap_err().to_string();
        assert!(e.contains("method.disc_reward_qc_gate"), "{e}");
    }

    #[test]
    fn cloning_under_q_c_s_codes_needs_a_q_c_trained_on_labels() {
        let with = |w_qc_labeled: f64| {
            ConfigBuilder::new()
                .set("ppo.bc_unlabeled_steps_per_iter=5")
                .unwrap()
                .set(&format!("method.w_qc_labeled={w_qc_labeled}"))
                .unwrap()
                .build()
        };
        assert!(with(1.0).is_ok(), "{:?}", with(1.0));
        let e = with(0.0).unwrap_err().to_string();
        assert!(
            e.contains("ppo.bc_unlabeled_steps_per_iter") && e.contains("w_qc_labeled"),
            "{e}"
        );
    }

    #[test]
    fn negative_integer_for_unsigned_key_is_rejected_with_key() {
        let e = ConfigBuilder::new()
            .set("run.iterations=-3")
            .unwrap_err()
            .to_string();
        assert!(e.contains("iterations"), "{e}");
    }

    #[test]
    fn override_without_equals_is_rejected() {
        assert!(matches!(
            ConfigBuilder::new().set("run.seed").unwrap_err(),
            ConfigError::BadOverride { .. }
        ));
    }

    #[test]
    fn checked_config_round_trips_through_toml() {
        let c = ConfigBuilder::new().build().unwrap();
        let mut b = ConfigBuilder::new();
        b.merge_toml("resolved", &c.to_toml()).unwrap();
        assert_eq!(b.build().unwrap(), c);
    }
}
