//! TLS for the control plane, through tonic's rustls support (`ring` provider).
//!
//! - Server (`ess serve --tls-cert F --tls-key F [--tls-client-ca F]`): the server's
//!   certificate chain and key as PEM; with a client CA, every client must present a
//!   certificate that CA signed (mutual TLS), refused at the handshake otherwise.
//! - Client (`ess job --server https://HOST:PORT [--tls-ca F] [--tls-cert F --tls-key F]`):
//!   trusts the given CA, else the system's roots; presents its own certificate when
//!   given one. The server's name is checked against the URL's host (DNS name or IP).
//!
//! Files are read and their PEM parsed here, so a wrong or unreadable file is one error
//! naming it (rustls would otherwise fail later, at the first handshake, without the
//! path).

use rustls_pki_types::pem::PemObject;
use rustls_pki_types::{CertificateDer, PrivateKeyDer};
use std::path::{Path, PathBuf};
use std::time::Duration;
use tonic::transport::{Certificate, ClientTlsConfig, Identity, ServerTlsConfig};

/// How long a peer may take to finish the TLS handshake.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

/// A TLS file that cannot serve.
#[derive(Debug, thiserror::Error)]
pub enum TlsError {
    /// Unreadable.
    #[error("{flag} {}: cannot read it: {source}", path.display())]
    Read {
        /// The option that named it.
        flag: &'static str,
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// Not the PEM it must hold.
    #[error("{flag} {}: {what}", path.display())]
    Pem {
        /// The option that named it.
        flag: &'static str,
        /// The file.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
    /// A certificate without its key, or the reverse.
    #[error("{given} needs {missing} too")]
    Pair {
        /// The option given.
        given: &'static str,
        /// The one missing.
        missing: &'static str,
    },
}

/// The PEM text of a file holding at least one certificate.
fn certificates(flag: &'static str, path: &Path) -> Result<Vec<u8>, TlsError> {
    let pem = read(flag, path)?;
    let certs: Result<Vec<CertificateDer>, _> = CertificateDer::pem_slice_iter(&pem).collect();
    match certs {
        Ok(c) if !c.is_empty() => Ok(pem),
        Ok(_) => Err(pem_err(
            flag,
            path,
            "holds no PEM certificate (BEGIN CERTIFICATE)",
        )),
        Err(e) => Err(pem_err(flag, path, &format!("not a PEM certificate: {e}"))),
    }
}

/// The PEM text of a file holding a private key (PKCS#8, PKCS#1 or SEC1).
fn private_key(flag: &'static str, path: &Path) -> Result<Vec<u8>, TlsError> {
    let pem = read(flag, path)?;
    PrivateKeyDer::from_pem_slice(&pem)
        .map_err(|e| pem_err(flag, path, &format!("holds no PEM private key: {e}")))?;
    Ok(pem)
}

fn read(flag: &'static str, path: &Path) -> Result<Vec<u8>, TlsError> {
    std::fs::read(path).map_err(|source| TlsError::Read {
        flag,
        path: path.to_path_buf(),
        source,
    })
}

fn pem_err(flag: &'static str, path: &Path, what: &str) -> TlsError {
    TlsError::Pem {
        flag,
        path: path.to_path_buf(),
        what: what.to_string(),
    }
}

/// A PEM file's path and contents.
type Pem<'a> = (&'a Path, Vec<u8>);

/// A certificate chain and its key as PEM, both given or neither.
fn pem_pair<'a>(
    cert: Option<&'a Path>,
    key: Option<&'a Path>,
    names: (&'static str, &'static str),
) -> Result<Option<(Pem<'a>, Pem<'a>)>, TlsError> {
    match (cert, key) {
        (Some(c), Some(k)) => Ok(Some((
            (c, certificates(names.0, c)?),
            (k, private_key(names.1, k)?),
        ))),
        (None, None) => Ok(None),
        (Some(_), None) => Err(TlsError::Pair {
            given: names.0,
            missing: names.1,
        }),
        (None, Some(_)) => Err(TlsError::Pair {
            given: names.1,
            missing: names.0,
        }),
    }
}

/// The server's TLS files, read and checked once: the gRPC side's configuration
/// ([`ServerTls::grpc`]) and, from the same bytes, the dashboard's ([`ServerTls::https`]).
#[derive(Debug, Clone)]
pub struct ServerTls {
    /// tonic's configuration for the gRPC listener.
    pub grpc: ServerTlsConfig,
    cert: (PathBuf, Vec<u8>),
    key: (PathBuf, Vec<u8>),
    client_ca: Option<(PathBuf, Vec<u8>)>,
}

/// The server's TLS: its identity, and the CA its clients' certificates must chain to
/// (mutual TLS) when `client_ca` is given. `None` when neither file is given.
pub fn server_config(
    cert: Option<&Path>,
    key: Option<&Path>,
    client_ca: Option<&Path>,
) -> Result<Option<ServerTls>, TlsError> {
    let Some(((cert, cert_pem), (key, key_pem))) =
        pem_pair(cert, key, ("--tls-cert", "--tls-key"))?
    else {
        return match client_ca {
            Some(_) => Err(TlsError::Pair {
                given: "--tls-client-ca",
                missing: "--tls-cert and --tls-key",
            }),
            None => Ok(None),
        };
    };
    let mut grpc = ServerTlsConfig::new()
        .identity(Identity::from_pem(&cert_pem, &key_pem))
        .timeout(HANDSHAKE_TIMEOUT);
    let ca = match client_ca {
        Some(ca) => {
            let pem = certificates("--tls-client-ca", ca)?;
            grpc = grpc.client_ca_root(Certificate::from_pem(&pem));
            Some((ca.to_path_buf(), pem))
        }
        None => None,
    };
    Ok(Some(ServerTls {
        grpc,
        cert: (cert.to_path_buf(), cert_pem),
        key: (key.to_path_buf(), key_pem),
        client_ca: ca,
    }))
}

impl ServerTls {
    /// The same identity (and client CA) as rustls' configuration, for the dashboard's
    /// HTTPS listener. Errors name the file, as [`server_config`]'s do.
    pub fn https(&self) -> Result<std::sync::Arc<tokio_rustls::rustls::ServerConfig>, TlsError> {
        use tokio_rustls::rustls;
        let ((cert, cert_pem), (key, key_pem)) = (&self.cert, &self.key);
        let chain: Vec<CertificateDer<'static>> = CertificateDer::pem_slice_iter(cert_pem)
            .collect::<Result<_, _>>()
            .map_err(|e| pem_err("--tls-cert", cert, &e.to_string()))?;
        let der = PrivateKeyDer::from_pem_slice(key_pem)
            .map_err(|e| pem_err("--tls-key", key, &e.to_string()))?;
        let provider = std::sync::Arc::new(rustls::crypto::ring::default_provider());
        let builder = rustls::ServerConfig::builder_with_provider(provider.clone())
            .with_safe_default_protocol_versions()
            .map_err(|e| pem_err("--tls-cert", cert, &e.to_string()))?;
        let builder = match &self.client_ca {
            Some((ca, pem)) => {
                let mut roots = rustls::RootCertStore::empty();
                for c in CertificateDer::pem_slice_iter(pem) {
                    let c = c.map_err(|e| pem_err("--tls-client-ca", ca, &e.to_string()))?;
                    roots
                        .add(c)
                        .map_err(|e| pem_err("--tls-client-ca", ca, &e.to_string()))?;
                }
                let verifier = rustls::server::WebPkiClientVerifier::builder_with_provider(
                    roots.into(),
                    provider,
                )
                .build()
                .map_err(|e| pem_err("--tls-client-ca", ca, &e.to_string()))?;
                builder.with_client_cert_verifier(verifier)
            }
            None => builder.with_no_client_auth(),
        };
        let mut cfg = builder
            .with_single_cert(chain, der)
            .map_err(|e| pem_err("--tls-key", key, &format!("does not serve --tls-cert: {e}")))?;
        cfg.alpn_protocols = vec![b"h2".to_vec(), b"http/1.1".to_vec()];
        Ok(std::sync::Arc::new(cfg))
    }
}

/// The client's TLS: the CA that signed the server's certificate (else the system's
/// roots) and the client's own certificate for mutual TLS.
pub fn client_config(
    ca: Option<&Path>,
    cert: Option<&Path>,
    key: Option<&Path>,
) -> Result<ClientTlsConfig, TlsError> {
    let mut cfg = ClientTlsConfig::new().timeout(HANDSHAKE_TIMEOUT);
    cfg = match ca {
        Some(ca) => cfg.ca_certificate(Certificate::from_pem(certificates("--tls-ca", ca)?)),
        None => cfg.with_native_roots(),
    };
    if let Some(((_, c), (_, k))) = pem_pair(cert, key, ("--tls-cert", "--tls-key"))? {
        cfg = cfg.identity(Identity::from_pem(c, k));
    }
    Ok(cfg)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unreadable_and_non_pem_files_are_named_with_their_flag() {
        let dir = tempfile::tempdir().unwrap();
        let junk = dir.path().join("junk.pem");
        std::fs::write(&junk, "not pem at all\n").unwrap();
        let missing = dir.path().join("missing.pem");
        let e = server_config(Some(&junk), Some(&junk), None).unwrap_err();
        assert!(e.to_string().starts_with("--tls-cert "), "{e}");
        assert!(e.to_string().contains("junk.pem"), "{e}");
        let e = client_config(Some(&missing), None, None).unwrap_err();
        assert!(e.to_string().contains("--tls-ca") && e.to_string().contains("missing.pem"));
        let e = server_config(Some(&junk), None, None).unwrap_err();
        assert_eq!(e.to_string(), "--tls-cert needs --tls-key too");
        let e = server_config(None, None, Some(&junk)).unwrap_err();
        assert!(e.to_string().starts_with("--tls-client-ca needs"), "{e}");
        assert!(server_config(None, None, None).unwrap().is_none());
    }
}
