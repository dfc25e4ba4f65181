//! Bakes the libtorch (and its CUDA runtime stub) library directories into the `ess`
//! binary's rpath, so it runs without `LD_LIBRARY_PATH` after `make build`.
//! `LIBTORCH` is what `scripts/bootstrap.sh` writes into `.deps/env.sh`.

fn main() {
    println!("cargo:rerun-if-env-changed=LIBTORCH");
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
