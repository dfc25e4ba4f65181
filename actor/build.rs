//! Bakes MuJoCo's library directory into the `ess-actor` binary's rpath, as
//! `learner/build.rs` does for `ess`: the learner starts its actors with its own
//! environment, so without it an `ess` run from a shell that never sourced
//! `.deps/env.sh` had actors that could not load `libmujoco.so` (exit 127).
//! `MUJOCO_DYNAMIC_LINK_DIR` is what `scripts/bootstrap.sh` writes into `.deps/env.sh`.

fn main() {
    println!("cargo:rerun-if-env-changed=MUJOCO_DYNAMIC_LINK_DIR");
    if let Ok(dir) = std::env::var("MUJOCO_DYNAMIC_LINK_DIR") {
        println!("cargo:rustc-link-arg=-Wl,-rpath,{dir}");
    }
}
