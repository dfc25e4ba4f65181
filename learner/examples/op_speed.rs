//! Times libtorch's CPU kernels at the learner's shapes (D/Q step: 3000 x 24 -> 100 ->
//! 100; PPO: 1000 x 18 -> 64 -> 64): matmul GFLOP/s, tanh and its alternatives.
//! `cargo run --release -p ess-learner --example op_speed [threads]`.

use std::time::Instant;
use tch::{Kind, Tensor};

fn time(name: &str, flop: f64, reps: usize, f: impl Fn() -> Tensor) {
    for _ in 0..5 {
        let _ = f();
    }
    let t = Instant::now();
    for _ in 0..reps {
        let _ = f();
    }
    let s = t.elapsed().as_secs_f64() / reps as f64;
    if flop > 0.0 {
        println!(
            "{name:<40} {:>9.1} us  {:>7.1} GFLOP/s",
            s * 1e6,
            flop / s / 1e9
        );
    } else {
        println!("{name:<40} {:>9.1} us", s * 1e6);
    }
}

fn main() {
    ess_learner::malloc::keep_freed_memory();
    let threads: i32 = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(1);
    tch::set_num_threads(threads);
    tch::manual_seed(0);
    let opts = (Kind::Float, tch::Device::Cpu);
    for (n, i, h) in [(3000i64, 24i64, 100i64), (1000, 18, 64)] {
        let x = Tensor::randn([n, i], opts);
        let w1 = Tensor::randn([h, i], opts);
        let w2 = Tensor::randn([h, h], opts);
        let b = Tensor::randn([h], opts);
        let hid = Tensor::randn([n, h], opts);
        let f1 = 2.0 * (n * i * h) as f64;
        let f2 = 2.0 * (n * h * h) as f64;
        println!("-- n={n} in={i} hidden={h}, {threads} thread(s)");
        time("linear in->h", f1, 200, || x.linear(&w1, Some(&b)));
        time("linear h->h", f2, 200, || hid.linear(&w2, Some(&b)));
        time("matmul h->h (no bias)", f2, 200, || hid.matmul(&w2.tr()));
        let hb = hid.to_kind(Kind::BFloat16);
        let w2b = w2.to_kind(Kind::BFloat16);
        let bb = b.to_kind(Kind::BFloat16);
        time("linear h->h bf16", f2, 200, || hb.linear(&w2b, Some(&bb)));
        time("tanh", 0.0, 200, || hid.tanh());
        time("2 sigmoid(2x) - 1", 0.0, 200, || {
            (&hid * 2.0).sigmoid() * 2.0 - 1.0
        });
        time("sigmoid", 0.0, 200, || hid.sigmoid());
        let w2h = Tensor::randn([h, h], opts);
        time("tanh layer: linear + tanh", 0.0, 200, || {
            hid.linear(&w2, Some(&b)).tanh().linear(&w2h, Some(&b))
        });
        time("tanh layer as sigmoid, folded", 0.0, 200, || {
            let s = hid.linear(&(&w2 * 2.0), Some(&(&b * 2.0))).sigmoid();
            s.linear(
                &(&w2h * 2.0),
                Some(&(&b - w2h.sum_dim_intlist(1, false, Kind::Float))),
            )
        });
        time("tanh_backward", 0.0, 200, || {
            Tensor::tanh_backward(&hid, &hid)
        });
        time("add (elementwise)", 0.0, 200, || &hid + &hid);
        let idx = Tensor::randint(n, [n], (Kind::Int64, tch::Device::Cpu));
        time("index_select rows", 0.0, 200, || hid.index_select(0, &idx));
    }
    let s = Tensor::from(1.0f32);
    time("dispatch: scalar add", 0.0, 20000, || &s + 1.0);
}
