//! Bakes MuJoCo's library directory into the rpath of this crate's test and example
//! binaries, so they run without `LD_LIBRARY_PATH` (`mujoco-rs` sets no rpath).
//! `MUJOCO_DYNAMIC_LINK_DIR` is what `scripts/bootstrap.sh` writes into `.deps/env.sh`.

fn main() {
    println!("cargo:rerun-if-env-changed=MUJOCO_DYNAMIC_LINK_DIR");
    if let Ok(dir) = std::env::var("MUJOCO_DYNAMIC_LINK_DIR") {
        println!("cargo:rustc-link-arg=-Wl,-rpath,{dir}");
    }
}
