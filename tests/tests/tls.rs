//! TLS on the control plane, against certificates made by the `openssl` command (as a
//! user makes them) and checked from outside by `openssl s_client`: a verified client
//! gets answers, a client without a certificate, with one from another CA, or speaking
//! plain HTTP/2 is refused; a listener reachable from other machines needs TLS and a way
//! to authenticate; bad certificate files are one line naming them, exit 2.

use ess_tests::pki::Pki;
use ess_tests::{ess_bin, start_serve};
use std::ffi::OsStr;
use std::path::Path;
use std::process::{Command, Output, Stdio};

fn out(o: &Output) -> String {
    format!(
        "status {:?}\nstdout: {}\nstderr: {}",
        o.status.code(),
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// `ess job --server URL ARGS list --json`.
fn job_list(url: &str, args: &[&OsStr]) -> Output {
    Command::new(ess_bin())
        .args(["job", "--server", url])
        .args(args)
        .args(["list", "--json"])
        .env("RUST_LOG", "warn")
        .env_remove("ESS_TOKEN_FILE")
        .env_remove("ESS_TLS_CA")
        .env_remove("ESS_TLS_CERT")
        .env_remove("ESS_TLS_KEY")
        .output()
        .unwrap()
}

#[test]
fn mutual_tls_admits_only_clients_with_a_certificate_of_the_clients_ca() {
    let pki = Pki::new();
    let p = |f: &str| pki.path(f).into_os_string();
    let data = pki.path("data");
    let (ca, cert, key, client_ca) = (p("ca.pem"), p("server.pem"), p("server.key"), p("ca.pem"));
    let args: Vec<&OsStr> = vec![
        "--data-dir".as_ref(),
        data.as_os_str(),
        "--tls-cert".as_ref(),
        &cert,
        "--tls-key".as_ref(),
        &key,
        "--tls-client-ca".as_ref(),
        &client_ca,
    ];
    let (mut server, addr) = start_serve(&args, &pki.path("serve.stderr"));
    let https = format!("https://{addr}");
    let (client, client_key) = (p("client.pem"), p("client.key"));
    let (stranger, stranger_key) = (p("stranger.pem"), p("stranger.key"));
    let tls_ca: [&OsStr; 2] = ["--tls-ca".as_ref(), &ca];

    // The verified client: answers.
    let mut ok = tls_ca.to_vec();
    ok.extend([
        "--tls-cert".as_ref(),
        client.as_os_str(),
        "--tls-key".as_ref(),
        &client_key,
    ]);
    let o = job_list(&https, &ok);
    assert!(o.status.success(), "{}", out(&o));
    assert_eq!(String::from_utf8_lossy(&o.stdout).trim(), "[]");

    // No client certificate, or one from another CA: refused at the handshake.
    let mut stranger_args = tls_ca.to_vec();
    stranger_args.extend([
        "--tls-cert".as_ref(),
        stranger.as_os_str(),
        "--tls-key".as_ref(),
        &stranger_key,
    ]);
    for (what, args) in [
        ("no certificate", tls_ca.to_vec()),
        ("another CA's", stranger_args),
    ] {
        let o = job_list(&https, &args);
        assert!(!o.status.success(), "{what}: {}", out(&o));
        assert!(o.stdout.is_empty(), "{what}: {}", out(&o));
    }
    // Plain HTTP/2 to the TLS port: no answer either.
    let o = job_list(&format!("http://{addr}"), &[]);
    assert!(!o.status.success(), "plain text: {}", out(&o));
    // A client that does not trust the server's CA refuses the server.
    let o = job_list(
        &https,
        &[
            "--tls-ca".as_ref(),
            &p("other.pem"),
            "--tls-cert".as_ref(),
            &client,
            "--tls-key".as_ref(),
            &client_key,
        ],
    );
    assert!(!o.status.success(), "untrusted server: {}", out(&o));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("UnknownIssuer"),
        "{}",
        out(&o)
    );

    // OpenSSL's own client verifies the chain and negotiates HTTP/2 (ALPN h2).
    let o = Command::new("openssl")
        .args([
            "s_client",
            "-connect",
            &addr,
            "-alpn",
            "h2",
            "-verify_return_error",
        ])
        .arg("-CAfile")
        .arg(&ca)
        .arg("-cert")
        .arg(&client)
        .arg("-key")
        .arg(&client_key)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("Verify return code: 0 (ok)"), "{}", out(&o));
    assert!(text.contains("ALPN protocol: h2"), "{}", out(&o));

    let _ = server.kill();
    let _ = server.wait();
}

#[test]
fn a_remote_listener_needs_tls_and_client_authentication() {
    let pki = Pki::new();
    let serve = |args: &[&OsStr]| {
        Command::new(ess_bin())
            .args(["serve", "--data-dir"])
            .arg(pki.path("data"))
            .args(args)
            .output()
            .unwrap()
    };
    let (cert, key) = (pki.path("server.pem"), pki.path("server.key"));
    let tls: Vec<&OsStr> = vec![
        "--tls-cert".as_ref(),
        cert.as_os_str(),
        "--tls-key".as_ref(),
        key.as_os_str(),
    ];
    let remote: [&OsStr; 2] = ["--listen".as_ref(), "0.0.0.0:0".as_ref()];
    // Plain text off loopback, token or not.
    let tok = pki.path("token");
    std::fs::write(&tok, "s3cret\n").unwrap();
    let o = serve(&[
        remote[0],
        remote[1],
        "--token-file".as_ref(),
        tok.as_os_str(),
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", out(&o));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("--tls-cert"),
        "{}",
        out(&o)
    );
    // TLS but nobody authenticated.
    let mut args = remote.to_vec();
    args.extend(&tls);
    let o = serve(&args);
    assert_eq!(o.status.code(), Some(2), "{}", out(&o));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("--token-file") && err.contains("--tls-client-ca"),
        "{err}"
    );
    assert_eq!(err.trim().lines().count(), 1, "{err}");
}

#[test]
fn bad_certificate_files_are_one_line_naming_them() {
    let pki = Pki::new();
    let junk = pki.path("junk.pem");
    std::fs::write(
        &junk,
        "-----BEGIN NOTHING-----\nAAAA\n-----END NOTHING-----\n",
    )
    .unwrap();
    let (cert, key) = (pki.path("server.pem"), pki.path("server.key"));
    let client_key = pki.path("client.key");
    let cases: [(&str, [&Path; 2], &str); 3] = [
        ("junk certificate", [&junk, &key], "junk.pem"),
        ("junk key", [&cert, &junk], "junk.pem"),
        (
            "key of another certificate",
            [&cert, &client_key],
            "client.key",
        ),
    ];
    for (what, [c, k], named) in cases {
        let o = Command::new(ess_bin())
            .args(["serve", "--listen", "127.0.0.1:0", "--data-dir"])
            .arg(pki.path("data"))
            .arg("--tls-cert")
            .arg(c)
            .arg("--tls-key")
            .arg(k)
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(2), "{what}: {}", out(&o));
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(named), "{what}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{what}: {err}");
    }
}
