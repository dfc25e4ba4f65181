//! The single-precision matrix products of the fused learner's steps, timed in every
//! sgemm this machine offers, on one thread: the table in bench/learner.md ("sgemm"),
//! and the ceiling a D/Q step's rate is compared against (the sum over its products of
//! the fastest implementation's time for each).
//!
//! Implementations: the `gemm` crate (what the fused backend calls), `matrixmultiply`,
//! libtorch's `mm` (MKL, what the tch backend runs), and, when the system has them,
//! OpenBLAS (`libopenblas.so.0`) and BLIS (`libblis.so.4`) through their CBLAS entry
//! point, loaded at run time (Debian: `apt-get install libopenblas0-serial
//! libblis4-serial`; nothing in Ess links them).
//!
//! `cargo run --release -p ess-learner --example sgemm_table -- [--reps 30]`

use ess_learner::fused::sgemm::{Acc, Mat, MatMut, gemm};
use std::time::Instant;
use tch::{Device, Kind, Tensor};

/// One product `C[m][n] = A[m][k] B[k][n]` of a step, A or B read transposed.
struct Product {
    what: &'static str,
    m: usize,
    n: usize,
    k: usize,
    a_t: bool,
    b_t: bool,
}

/// The products of one fused step (feature-major: the batch `rows` is `n`, or `k` for
/// the weight gradients) of an MLP `sizes` on `rows` rows; `dx_first`: the first
/// layer's input gradient too.
fn step(sizes: &[usize], rows: usize) -> Vec<Product> {
    let mut v = Vec::new();
    for w in sizes.windows(2) {
        let (i, o) = (w[0], w[1]);
        v.push(Product {
            what: "forward W X",
            m: o,
            n: rows,
            k: i,
            a_t: false,
            b_t: false,
        });
        v.push(Product {
            what: "weight gradient dZ X^T",
            m: o,
            n: i,
            k: rows,
            a_t: false,
            b_t: true,
        });
    }
    for w in sizes.windows(2).skip(1) {
        let (i, o) = (w[0], w[1]);
        v.push(Product {
            what: "input gradient W^T dZ",
            m: i,
            n: rows,
            k: o,
            a_t: true,
            b_t: false,
        });
    }
    v
}

type Cblas = unsafe extern "C" fn(
    i32,
    i32,
    i32,
    i32,
    i32,
    i32,
    f32,
    *const f32,
    i32,
    *const f32,
    i32,
    f32,
    *mut f32,
    i32,
);

/// A CBLAS library loaded at run time.
struct Blas {
    name: &'static str,
    _lib: libloading::Library,
    sgemm: Cblas,
}

fn load(name: &'static str, file: &str, threads_fn: &[u8]) -> Option<Blas> {
    // SAFETY: loading a system BLAS runs its initialisers, which only set up the library.
    let lib = unsafe { libloading::Library::new(file) }.ok()?;
    // SAFETY: `cblas_sgemm` has this C signature in every CBLAS.
    let sgemm: Cblas = unsafe { *lib.get::<Cblas>(b"cblas_sgemm\0").ok()? };
    // SAFETY: `openblas_set_num_threads` / `bli_thread_set_num_threads` take an int.
    if let Ok(set) = unsafe { lib.get::<unsafe extern "C" fn(i32)>(threads_fn) } {
        unsafe { set(1) };
    }
    Some(Blas {
        name,
        _lib: lib,
        sgemm,
    })
}

fn time(reps: usize, mut f: impl FnMut()) -> f64 {
    for _ in 0..3 {
        f();
    }
    let mut best = f64::MAX;
    for _ in 0..5 {
        let t = Instant::now();
        for _ in 0..reps {
            f();
        }
        best = best.min(t.elapsed().as_secs_f64() / reps as f64);
    }
    best
}

fn data(n: usize, seed: f32) -> Vec<f32> {
    (0..n).map(|i| ((i as f32) * 0.37 + seed).sin()).collect()
}

/// Seconds per product, per implementation (`None`: not available here).
fn times(p: &Product, reps: usize, blas: &[Blas]) -> Vec<Option<f64>> {
    let (av, bv) = (data(p.m * p.k, 0.1), data(p.k * p.n, 0.7));
    let mut cv = vec![0.0f32; p.m * p.n];
    let a = if p.a_t {
        Mat::rows(&av, p.k, p.m).t()
    } else {
        Mat::rows(&av, p.m, p.k)
    };
    let b = if p.b_t {
        Mat::rows(&bv, p.n, p.k).t()
    } else {
        Mat::rows(&bv, p.k, p.n)
    };
    let mut out = Vec::new();
    out.push(Some(time(reps, || {
        let mut c = MatMut::new(&mut cv, p.m, p.n, p.n);
        gemm(&mut c, a, b, Acc::Overwrite, None).expect("shapes");
    })));
    out.push(Some(time(reps, || unsafe {
        // SAFETY: the strides describe `av`, `bv` and `cv` exactly.
        matrixmultiply::sgemm(
            p.m,
            p.k,
            p.n,
            1.0,
            av.as_ptr(),
            a.rs as isize,
            a.cs as isize,
            bv.as_ptr(),
            b.rs as isize,
            b.cs as isize,
            0.0,
            cv.as_mut_ptr(),
            p.n as isize,
            1,
        );
    })));
    let ta = Tensor::from_slice(&av).view(if p.a_t {
        [p.k as i64, p.m as i64]
    } else {
        [p.m as i64, p.k as i64]
    });
    let tb = Tensor::from_slice(&bv).view(if p.b_t {
        [p.n as i64, p.k as i64]
    } else {
        [p.k as i64, p.n as i64]
    });
    let (ta, tb) = (
        if p.a_t { ta.tr() } else { ta },
        if p.b_t { tb.tr() } else { tb },
    );
    let tc = Tensor::zeros([p.m as i64, p.n as i64], (Kind::Float, Device::Cpu));
    out.push(Some(time(reps, || {
        let _ = ta.mm_out(&tc, &tb);
    })));
    const ROW: i32 = 101;
    const NO: i32 = 111;
    const TRANS: i32 = 112;
    for l in blas {
        let (ta_, lda) = if p.a_t { (TRANS, p.m) } else { (NO, p.k) };
        let (tb_, ldb) = if p.b_t { (TRANS, p.k) } else { (NO, p.n) };
        out.push(Some(time(reps, || unsafe {
            // SAFETY: row-major operands of the declared shapes and leading dimensions.
            (l.sgemm)(
                ROW,
                ta_,
                tb_,
                p.m as i32,
                p.n as i32,
                p.k as i32,
                1.0,
                av.as_ptr(),
                lda as i32,
                bv.as_ptr(),
                ldb as i32,
                0.0,
                cv.as_mut_ptr(),
                p.n as i32,
            );
        })));
    }
    out
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let reps: usize = args
        .iter()
        .position(|a| a == "--reps")
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(30);
    tch::set_num_threads(1);
    let blas: Vec<Blas> = [
        load(
            "OpenBLAS",
            "libopenblas.so.0",
            b"openblas_set_num_threads\0",
        ),
        load("BLIS", "libblis.so.4", b"bli_thread_set_num_threads\0"),
    ]
    .into_iter()
    .flatten()
    .collect();
    let mut names = vec!["gemm (ess)", "matrixmultiply", "libtorch mm (MKL)"];
    names.extend(blas.iter().map(|b| b.name));
    println!(
        "sgemm, one thread, GFLOP/s (best of 5 x {reps} calls); CPU: {}",
        cpu()
    );
    let steps = [
        ("Reacher D/Q step", vec![10, 100, 100, 8], 3000),
        ("Reacher PPO step (policy)", vec![15, 64, 64, 2], 1000),
        ("Reacher PPO step (value)", vec![15, 64, 64, 1], 1000),
        ("Humanoid D/Q step", vec![365, 100, 100, 5], 3000),
        ("Humanoid PPO step (policy)", vec![352, 64, 64, 17], 1000),
    ];
    for (title, sizes, rows) in steps {
        println!("\n{title}: MLP {sizes:?} on {rows} rows\n");
        println!("| product | m x n x k | {} |", names.join(" | "));
        println!("|---|---|{}", "---|".repeat(names.len()));
        let mut totals = vec![0.0f64; names.len()];
        let (mut best_total, mut flop) = (0.0f64, 0.0f64);
        for p in step(&sizes, rows) {
            let t = times(&p, reps, &blas);
            let f = 2.0 * (p.m * p.n * p.k) as f64;
            flop += f;
            let cells: Vec<String> = t
                .iter()
                .map(|t| t.map_or("-".into(), |t| format!("{:.0}", f / t / 1e9)))
                .collect();
            println!(
                "| {} | {} x {} x {} | {} |",
                p.what,
                p.m,
                p.n,
                p.k,
                cells.join(" | ")
            );
            for (tot, t) in totals.iter_mut().zip(&t) {
                *tot += t.unwrap_or(f64::NAN);
            }
            best_total += t.iter().flatten().fold(f64::MAX, |a, &b| a.min(b));
        }
        let cells: Vec<String> = totals
            .iter()
            .map(|t| format!("**{:.0}**", flop / t / 1e9))
            .collect();
        println!(
            "| the step's products | {:.0} MFLOP | {} |",
            flop / 1e6,
            cells.join(" | ")
        );
        println!(
            "\nceiling (fastest implementation per product): {:.0} GFLOP/s, {:.3} ms for the step's products",
            flop / best_total / 1e9,
            best_total * 1e3
        );
    }
}

fn cpu() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_else(|| "unknown".into())
}
