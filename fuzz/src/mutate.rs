//! The short fuzz run of `make test`, on the stable toolchain: replay a target's corpus,
//! then mutate it at random (bit flips, interesting values, inserted, deleted and
//! duplicated ranges, splices of two inputs) for a fixed number of executions, from a
//! fixed seed, so a run is reproducible. No coverage guidance: that is what the
//! libFuzzer runs of `make fuzz` add. A panicking input is returned, to be saved into
//! the corpus once fixed (every bug found stays a regression input).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};

use crate::Target;

/// Longest input a mutation makes (libFuzzer's `-max_len` in `make fuzz` is larger).
pub const MAX_LEN: usize = 1 << 17;

/// `fuzz/corpus/<target>`.
pub fn corpus_dir(target: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("corpus")
        .join(target)
}

/// Every file of a target's corpus, by name order.
pub fn corpus(target: &str) -> std::io::Result<Vec<(PathBuf, Vec<u8>)>> {
    let mut paths: Vec<PathBuf> = std::fs::read_dir(corpus_dir(target))?
        .map(|e| e.map(|e| e.path()))
        .collect::<Result<_, _>>()?;
    paths.sort();
    paths
        .into_iter()
        .map(|p| std::fs::read(&p).map(|b| (p, b)))
        .collect()
}

/// An input a target panicked on, with the panic message.
#[derive(Debug)]
pub struct Finding {
    /// The input.
    pub input: Vec<u8>,
    /// The panic message.
    pub message: String,
}

/// Runs `target` on `input`, catching a panic.
pub fn exec(target: Target, input: &[u8]) -> Result<(), Finding> {
    catch_unwind(AssertUnwindSafe(|| target(input))).map_err(|p| Finding {
        input: input.to_vec(),
        message: p
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| p.downcast_ref::<&str>().map(|s| (*s).to_string()))
            .unwrap_or_else(|| "a panic without a message".into()),
    })
}

/// Runs every seed, then `execs` mutations of randomly chosen seeds.
pub fn run(target: Target, seeds: &[Vec<u8>], execs: usize, seed: u64) -> Result<(), Finding> {
    for s in seeds {
        exec(target, s)?;
    }
    if seeds.is_empty() {
        return Ok(());
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    for _ in 0..execs {
        let mut input = seeds[rng.random_range(0..seeds.len())].clone();
        for _ in 0..rng.random_range(1..=4) {
            let other = &seeds[rng.random_range(0..seeds.len())];
            mutate(&mut rng, &mut input, other);
        }
        exec(target, &input)?;
    }
    Ok(())
}

const INTERESTING: [u64; 10] = [
    0,
    1,
    0x7f,
    0x80,
    0xff,
    0x7fff_ffff,
    0xffff_ffff,
    1 << 32,
    i64::MAX as u64,
    u64::MAX,
];

/// One random edit of `input`; `other` is a second input to splice from.
pub fn mutate(rng: &mut impl Rng, input: &mut Vec<u8>, other: &[u8]) {
    let len = input.len();
    let at = |rng: &mut dyn rand::RngCore, n: usize| {
        if n == 0 { 0 } else { rng.random_range(0..n) }
    };
    match rng.random_range(0..7) {
        0 if len > 0 => {
            let i = at(rng, len);
            input[i] ^= 1 << rng.random_range(0..8);
        }
        1 if len > 0 => {
            let i = at(rng, len);
            input[i] = rng.random();
        }
        2 if len > 0 => {
            let v = INTERESTING[rng.random_range(0..INTERESTING.len())];
            let width = [1, 2, 4, 8][rng.random_range(0..4)].min(len);
            let i = at(rng, len - width + 1);
            input[i..i + width].copy_from_slice(&v.to_le_bytes()[..width]);
        }
        3 if len > 0 => {
            let i = at(rng, len);
            let n = rng.random_range(1..=(len - i).min(64));
            input.drain(i..i + n);
        }
        4 if len > 0 => {
            let i = at(rng, len);
            let n = rng.random_range(1..=(len - i).min(64));
            let piece = input[i..i + n].to_vec();
            let j = at(rng, len + 1);
            input.splice(j..j, piece);
        }
        5 if !other.is_empty() => {
            let i = at(rng, other.len());
            let n = rng.random_range(1..=(other.len() - i).min(256));
            let j = at(rng, len + 1);
            let end = (j + n).min(len);
            input.splice(j..end, other[i..i + n].iter().copied());
        }
        _ => {
            let j = at(rng, len + 1);
            let n = rng.random_range(1..=16);
            let bytes: Vec<u8> = (0..n).map(|_| rng.random()).collect();
            input.splice(j..j, bytes);
        }
    }
    input.truncate(MAX_LEN);
}
