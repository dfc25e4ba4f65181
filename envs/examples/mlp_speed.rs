//! Cost of one policy forward pass ([`ess_proto::Mlp::forward`]) against the scalar
//! row-major loop with libm `tanhf` it replaced, for the 64-64 policies of each task
//! (`bench/mujoco.md`). Best of 5 rounds of 200K calls each; the two are timed in
//! alternating rounds.
//!
//! ```text
//! source .deps/env.sh && cargo run --release -p ess-envs --example mlp_speed
//! ```

use std::hint::black_box;
use std::time::Instant;

use ess_envs::{
    Env, Humanoid, HumanoidConfig, Pusher, PusherConfig, Reacher, ReacherConfig, Walker2d,
    Walker2dConfig,
};
use ess_proto::{Mlp, MlpLayout};

const CALLS: usize = 200_000;
const ROUNDS: usize = 5;

/// The previous forward: one dot product per output over `[out][in]` rows, libm tanh.
fn scalar_forward(mlp: &Mlp, input: &[f32], out: &mut [f32], scratch: &mut [f32]) {
    let sizes = &mlp.layout().sizes;
    let w = mlp.layout().max_width();
    let (a, b) = scratch.split_at_mut(w);
    a[..input.len()].copy_from_slice(input);
    let (mut cur, mut nxt) = (a, b);
    let n = sizes.len() - 1;
    for l in 0..n {
        let (n_in, n_out) = (sizes[l], sizes[l + 1]);
        let (wo, bo) = mlp.layout().offsets(l);
        let weights = &mlp.params()[wo..bo];
        let bias = &mlp.params()[bo..bo + n_out];
        let x = &cur[..n_in];
        for (o, (row, bias_o)) in weights.chunks_exact(n_in).zip(bias).enumerate() {
            let mut acc = *bias_o;
            for (wi, xi) in row.iter().zip(x) {
                acc += wi * xi;
            }
            nxt[o] = if l + 1 < n { acc.tanh() } else { acc };
        }
        std::mem::swap(&mut cur, &mut nxt);
    }
    out.copy_from_slice(&cur[..sizes[n]]);
}

/// Nanoseconds per call of `f`, best of the rounds it is given.
fn time(input: &mut [f32], out: &mut [f32], f: &mut dyn FnMut(&[f32], &mut [f32])) -> f64 {
    let start = Instant::now();
    for i in 0..CALLS {
        // Feed the output back so calls cannot be hoisted or overlapped wholesale.
        input[0] = (i % 97) as f32 * 0.01 + out[0] * 1e-3;
        f(black_box(input), out);
    }
    start.elapsed().as_secs_f64() * 1e9 / CALLS as f64
}

fn main() -> Result<(), ess_envs::EnvError> {
    println!("| task | layout | scalar + libm tanh ns | packed ns | speed-up |");
    println!("|---|---|---|---|---|");
    // [obs, eps, c] -> 64 -> 64 -> act, as the actor and `mujoco_speed` build it.
    let envs: [(&str, Box<dyn Env>); 4] = [
        ("reacher", Box::new(Reacher::new(ReacherConfig::default())?)),
        ("pusher", Box::new(Pusher::new(PusherConfig::default())?)),
        (
            "walker2d",
            Box::new(Walker2d::new(Walker2dConfig::default())?),
        ),
        (
            "humanoid",
            Box::new(Humanoid::new(HumanoidConfig::default())?),
        ),
    ];
    for (name, env) in envs {
        let spec = env.spec();
        let sizes = [spec.obs_dim + 1 + spec.n_modes, 64, 64, spec.act_dim];
        let layout = MlpLayout {
            sizes: sizes.to_vec(),
        };
        let params = (0..layout.n_params())
            .map(|i| ((i * 7919 % 1000) as f32 / 1000.0 - 0.5) * 0.2)
            .collect();
        let mlp = Mlp::new(layout.clone(), params).expect("layout fits");
        let mut input = vec![0.1f32; layout.input()];
        let mut out = vec![0.0f32; layout.output()];
        let mut scratch = vec![0.0f32; mlp.scratch_len().max(2 * layout.max_width())];
        let (mut old, mut new) = (f64::MAX, f64::MAX);
        for _ in 0..ROUNDS {
            old = old.min(time(&mut input, &mut out, &mut |x, o| {
                scalar_forward(&mlp, x, o, &mut scratch)
            }));
            new = new.min(time(&mut input, &mut out, &mut |x, o| {
                mlp.forward(x, o, &mut scratch)
            }));
        }
        println!(
            "| {name} | {:?} | {old:.0} | {new:.0} | {:.1}x |",
            layout.sizes,
            old / new
        );
    }
    Ok(())
}
