//! Bakes the libtorch (and its CUDA runtime stub) and MuJoCo library directories into
//! the `ess` binary's rpath, so it runs without `LD_LIBRARY_PATH` after `make build`.
//! `LIBTORCH` and `MUJOCO_DYNAMIC_LINK_DIR` are what `scripts/bootstrap.sh` writes into
//! `.deps/env.sh`.

fn main() {
    println!("cargo:rerun-if-env-changed=LIBTORCH");
    println!("cargo:rerun-if-env-changed=MUJOCO_DYNAMIC_LINK_DIR");
    if let Ok(dir) = std::env::var("MUJOCO_DYNAMIC_LINK_DIR") {
        println!("cargo:rustc-link-arg=-Wl,-rpath,{dir}");
    }
    if let Ok(torch) = std::env::var("LIBTORCH") {
        let torch = std::path::PathBuf::from(torch);
        let lib = torch.join("lib");
        println!("cargo:rustc-link-arg=-Wl,-rpath,{}", lib.display());
        if let Some(site) = torch.parent() {
            let cu = site.join("nvidia").join("cu13").join("lib");
            println!("cargo:rustc-link-arg=-Wl,-rpath,{}", cu.display());
        }
    }
}
