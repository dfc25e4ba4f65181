//! `[remote]`: actor hosts on other machines feeding this run over zenoh
//! (`ess actor-host`, `ess_learner::remote`). Empty `listen` (the default): this
//! machine's actors only, nothing listens.

use super::ConfigError;
use super::check::range;
use serde::{Deserialize, Serialize};

/// Where remote actor hosts reach the learner, which of them it waits for, and the
/// run's credentials.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RemoteConfig {
    /// zenoh endpoint the learner listens on for actor hosts, `tls/ADDR:PORT` (mutual
    /// TLS, the only kind accepted); empty: no remote hosts.
    pub listen: String,
    /// Hosts (their `ess actor-host --name`) the first rollout waits for; they take actor
    /// indices after the local actors in this order, so a run's rollouts do not depend
    /// on which host joined first. Other hosts with the run's credentials may join
    /// later.
    pub hosts: Vec<String>,
    /// Seconds the run waits for `hosts` before it starts without the missing ones.
    pub wait_s: f64,
    /// Seconds without a sign of life after which a host counts as lost (zenoh's
    /// session lease): its share of the rollout is collected again from the others.
    pub timeout_s: f64,
    /// PEM: the CA that signed the learner's and every host's certificate.
    pub tls_ca: String,
    /// PEM: the learner's certificate (its names must match the address hosts dial).
    pub tls_cert: String,
    /// PEM: the learner's private key.
    pub tls_key: String,
}

impl Default for RemoteConfig {
    fn default() -> Self {
        Self {
            listen: String::new(),
            hosts: Vec::new(),
            wait_s: 60.0,
            timeout_s: 5.0,
            tls_ca: String::new(),
            tls_cert: String::new(),
            tls_key: String::new(),
        }
    }
}

/// A host name: what `ess actor-host --name` accepts and zenoh keys can carry.
pub fn valid_host_name(name: &str) -> bool {
    (1..=64).contains(&name.len())
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_' || b == b'.')
}

/// A zenoh mutual-TLS endpoint, `tls/ADDR:PORT`: what `remote.listen` and `ess
/// actor-host --learner` accept (the only transport a remote host may use).
pub fn is_tls_endpoint(endpoint: &str) -> bool {
    endpoint
        .strip_prefix("tls/")
        .and_then(|a| a.rsplit_once(':'))
        .is_some_and(|(addr, port)| !addr.is_empty() && port.parse::<u16>().is_ok())
}

impl RemoteConfig {
    /// Whether remote hosts are part of the run.
    pub fn enabled(&self) -> bool {
        !self.listen.is_empty()
    }

    pub(super) fn check(&self) -> Result<(), ConfigError> {
        range(
            self.timeout_s.is_finite() && (0.5..=3600.0).contains(&self.timeout_s),
            "remote.timeout_s",
            self.timeout_s,
            "must be in 0.5..=3600",
        )?;
        range(
            self.wait_s.is_finite() && (0.0..=86400.0).contains(&self.wait_s),
            "remote.wait_s",
            self.wait_s,
            "must be in 0..=86400",
        )?;
        for (i, h) in self.hosts.iter().enumerate() {
            range(
                valid_host_name(h),
                "remote.hosts",
                crate::text::printable(h),
                "a host name is 1-64 of A-Z a-z 0-9 - _ .",
            )?;
            range(
                !self.hosts[..i].contains(h),
                "remote.hosts",
                h,
                "named twice",
            )?;
        }
        if !self.enabled() {
            return range(
                self.hosts.is_empty(),
                "remote.hosts",
                format!("{:?}", self.hosts),
                "needs remote.listen",
            );
        }
        range(
            is_tls_endpoint(&self.listen),
            "remote.listen",
            crate::text::printable(&self.listen),
            "must be a zenoh TLS endpoint, tls/ADDR:PORT",
        )?;
        for (key, v) in [
            ("remote.tls_ca", &self.tls_ca),
            ("remote.tls_cert", &self.tls_cert),
            ("remote.tls_key", &self.tls_key),
        ] {
            range(
                !v.is_empty(),
                key,
                "\"\"",
                "remote hosts need mutual TLS files",
            )?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn on() -> RemoteConfig {
        RemoteConfig {
            listen: "tls/0.0.0.0:7447".into(),
            hosts: vec!["a".into(), "b-2".into()],
            tls_ca: "ca.pem".into(),
            tls_cert: "l.pem".into(),
            tls_key: "l.key".into(),
            ..Default::default()
        }
    }

    fn refused(r: RemoteConfig) -> String {
        r.check().unwrap_err().to_string()
    }

    #[test]
    fn off_by_default_and_a_full_section_passes() {
        assert!(!RemoteConfig::default().enabled());
        RemoteConfig::default().check().unwrap();
        on().check().unwrap();
    }

    #[test]
    fn tls_endpoints_need_an_address_and_a_port() {
        for ok in ["tls/0.0.0.0:7447", "tls/[::1]:7447", "tls/learner.lab:1"] {
            assert!(is_tls_endpoint(ok), "{ok}");
        }
        for bad in [
            "tcp/0.0.0.0:7447",
            "tls/0.0.0.0",
            "tls/:7447",
            "tls/a:port",
            "tls/a:70000",
            "",
        ] {
            assert!(!is_tls_endpoint(bad), "{bad}");
        }
    }

    #[test]
    fn each_bad_value_is_named() {
        let e = refused(RemoteConfig {
            listen: "tcp/0.0.0.0:7447".into(),
            ..on()
        });
        assert!(
            e.contains("remote.listen") && e.contains("tls/ADDR:PORT"),
            "{e}"
        );
        let e = refused(RemoteConfig {
            tls_key: String::new(),
            ..on()
        });
        assert!(e.contains("remote.tls_key"), "{e}");
        let e = refused(RemoteConfig {
            hosts: vec!["a".into(), "a".into()],
            ..on()
        });
        assert!(e.contains("named twice"), "{e}");
        let e = refused(RemoteConfig {
            hosts: vec!["a/b".into()],
            ..on()
        });
        assert!(e.contains("remote.hosts"), "{e}");
        let e = refused(RemoteConfig {
            hosts: vec!["a".into()],
            ..RemoteConfig::default()
        });
        assert!(e.contains("needs remote.listen"), "{e}");
        let e = refused(RemoteConfig {
            timeout_s: f64::NAN,
            ..on()
        });
        assert!(e.contains("remote.timeout_s"), "{e}");
    }
}
