//! Certificates made by the `openssl` command, as a user makes them: CA `ca` with
//! `server` (serverAuth) and `client` (clientAuth) under it, and CA `other` with
//! `stranger` (clientAuth) under it.

use std::path::{Path, PathBuf};
use std::process::Command;

/// Runs `openssl ARGS` in `dir`; panics with its stderr if it fails.
pub fn openssl(args: &[&str], dir: &Path) {
    let o = Command::new("openssl")
        .args(args)
        .current_dir(dir)
        .output()
        .expect("running openssl");
    assert!(
        o.status.success(),
        "openssl {args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// `NAME.pem` and `NAME.key` signed by `ca` (a P-256 key), for `usage` (serverAuth or
/// clientAuth), with 127.0.0.1, localhost and `ips` as its names.
pub fn signed(dir: &Path, ca: &str, name: &str, usage: &str, ips: &[&str]) {
    let ext = format!("{name}.ext");
    std::fs::write(
        dir.join(&ext),
        format!(
            "subjectAltName=IP:127.0.0.1,DNS:localhost{}\nextendedKeyUsage={usage}\nbasicConstraints=CA:FALSE\n",
            ips.iter().map(|ip| format!(",IP:{ip}")).collect::<String>()
        ),
    )
    .unwrap();
    let (key, csr, pem) = (
        format!("{name}.key"),
        format!("{name}.csr"),
        format!("{name}.pem"),
    );
    let subj = format!("/CN={name}");
    openssl(
        &[
            "req",
            "-newkey",
            "ec",
            "-pkeyopt",
            "ec_paramgen_curve:P-256",
            "-nodes",
            "-keyout",
            &key,
            "-out",
            &csr,
            "-subj",
            &subj,
        ],
        dir,
    );
    let (ca_pem, ca_key) = (format!("{ca}.pem"), format!("{ca}.key"));
    openssl(
        &[
            "x509",
            "-req",
            "-in",
            &csr,
            "-CA",
            &ca_pem,
            "-CAkey",
            &ca_key,
            "-CAcreateserial",
            "-out",
            &pem,
            "-days",
            "2",
            "-extfile",
            &ext,
        ],
        dir,
    );
}

/// Certificates for the tests: CA `ca` with `server` and `client` under it, and CA
/// `other` with `stranger` under it.
pub struct Pki {
    dir: tempfile::TempDir,
}

impl Default for Pki {
    fn default() -> Self {
        Pki::new()
    }
}

impl Pki {
    /// The four certificates, the server's valid for 127.0.0.1 and localhost.
    pub fn new() -> Pki {
        Pki::for_server_ips(&[])
    }

    /// The four certificates, the server's also valid for `ips`.
    pub fn for_server_ips(ips: &[&str]) -> Pki {
        let dir = tempfile::tempdir().unwrap();
        for ca in ["ca", "other"] {
            openssl(
                &[
                    "req",
                    "-x509",
                    "-newkey",
                    "ec",
                    "-pkeyopt",
                    "ec_paramgen_curve:P-256",
                    "-nodes",
                    "-keyout",
                    &format!("{ca}.key"),
                    "-out",
                    &format!("{ca}.pem"),
                    "-subj",
                    &format!("/CN=ess test {ca}"),
                    "-days",
                    "2",
                ],
                dir.path(),
            );
        }
        signed(dir.path(), "ca", "server", "serverAuth", ips);
        signed(dir.path(), "ca", "client", "clientAuth", &[]);
        signed(dir.path(), "other", "stranger", "clientAuth", &[]);
        Pki { dir }
    }

    /// A file of the set (`ca.pem`, `server.key`, ...).
    pub fn path(&self, file: &str) -> PathBuf {
        self.dir.path().join(file)
    }
}
