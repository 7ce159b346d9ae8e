//! TCP only with TLS and a token: a client with the daemon's CA gets in; plaintext, a wrong
//! CA or a missing token do not; plaintext TCP only when spelled out. The certificates are
//! made here, with rcgen.

use crate::common;

use common::*;
use machlink::daemon::{Daemon, StartOptions, TcpSecurity};
use machlink::faces::client::{Client, ClientError, Endpoint};
use machlink::services::access::new_token;
use std::path::{Path, PathBuf};

const MACHINE: &str = "[[machine]]\nname = \"bench\"\nlink = \"sim-grbl\"\ntime_scale = 100.0\n";

/// A CA and a certificate it signed for localhost and 127.0.0.1, as PEM files in `dir`:
/// (CA certificate, server certificate, server key).
pub(crate) fn certificates(dir: &Path, prefix: &str) -> (PathBuf, PathBuf, PathBuf) {
    let ca_key = rcgen::KeyPair::generate().unwrap();
    let mut ca_params = rcgen::CertificateParams::new(Vec::<String>::new()).unwrap();
    ca_params.is_ca = rcgen::IsCa::Ca(rcgen::BasicConstraints::Unconstrained);
    ca_params
        .distinguished_name
        .push(rcgen::DnType::CommonName, format!("{prefix} test CA"));
    let ca = rcgen::CertifiedIssuer::self_signed(ca_params, ca_key).unwrap();
    let key = rcgen::KeyPair::generate().unwrap();
    let params =
        rcgen::CertificateParams::new(vec!["localhost".to_string(), "127.0.0.1".to_string()])
            .unwrap();
    let cert = params.signed_by(&key, &ca).unwrap();
    let (ca_path, cert_path, key_path) = (
        dir.join(format!("{prefix}-ca.pem")),
        dir.join(format!("{prefix}-cert.pem")),
        dir.join(format!("{prefix}-key.pem")),
    );
    std::fs::write(&ca_path, ca.pem()).unwrap();
    std::fs::write(&cert_path, cert.pem()).unwrap();
    std::fs::write(&key_path, key.serialize_pem()).unwrap();
    (ca_path, cert_path, key_path)
}

async fn start_tcp(dir: &Path, security: TcpSecurity, token: &str) -> Result<Daemon, String> {
    let cfg = machlink::config::Config::parse(
        &format!(
            "[daemon]\nstore = \"{}\"\nsocket = \"{}\"\n\n{MACHINE}",
            dir.join("jobs.db").display(),
            dir.join("ml.sock").display()
        ),
        &dir.join("machlink.toml"),
    )
    .unwrap();
    Daemon::start(
        cfg,
        StartOptions {
            listen: Some("127.0.0.1:0".into()),
            token: Some(token.to_string()),
            tcp_security: security,
            ..Default::default()
        },
    )
    .await
    .map_err(|e| e.to_string())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_with_the_daemons_ca_and_token_gets_in_and_no_other() {
    let dir = tempfile::tempdir().unwrap();
    let (ca, cert, key) = certificates(dir.path(), "daemon");
    let (other_ca, _, _) = certificates(dir.path(), "other");
    let token = new_token().unwrap();
    let d = start_tcp(dir.path(), TcpSecurity::Tls { cert, key }, &token)
        .await
        .expect("the daemon starts with TLS");
    let addr = d.tcp.unwrap().to_string();
    let tls = |ca: &Path, token: Option<&str>, name: Option<&str>| {
        Client::new(Endpoint::Tls {
            addr: addr.clone(),
            token: token.map(String::from),
            ca: ca.to_path_buf(),
            server_name: name.map(String::from),
        })
    };
    // the daemon's CA and the token: in, by address and by name
    assert_eq!(
        tls(&ca, Some(&token), None).machines().await.unwrap()[0].name,
        "bench"
    );
    assert_eq!(
        tls(&ca, Some(&token), Some("localhost"))
            .machines()
            .await
            .unwrap()[0]
            .name,
        "bench"
    );
    let who = tls(&ca, Some(&token), None).whoami().await.unwrap();
    assert_eq!(
        (who["name"].as_str(), who["role"].as_str()),
        (Some("command-line"), Some("admin"))
    );
    assert!(
        who["from"].as_str().unwrap().starts_with("tcp 127.0.0.1:"),
        "{who}"
    );
    // a CA that did not sign the daemon's certificate: no connection
    let e = tls(&other_ca, Some(&token), None)
        .machines()
        .await
        .unwrap_err();
    assert!(matches!(e, ClientError::Tls { .. }), "{e}");
    // a name the certificate does not carry: no connection
    let e = tls(&ca, Some(&token), Some("machlink.example"))
        .machines()
        .await
        .unwrap_err();
    assert!(matches!(e, ClientError::Tls { .. }), "{e}");
    // no token, or a wrong one: refused
    let e = tls(&ca, None, None)
        .machines()
        .await
        .unwrap_err()
        .to_string();
    assert!(e.contains("Authorization: Bearer"), "{e}");
    let e = tls(&ca, Some(&new_token().unwrap()), None)
        .machines()
        .await
        .unwrap_err()
        .to_string();
    assert!(e.contains("no such token"), "{e}");
    // plaintext to a TLS daemon: no answer that makes sense
    let e = Client::new(Endpoint::Tcp {
        addr: addr.clone(),
        token: Some(token.clone()),
    })
    .machines()
    .await
    .unwrap_err();
    assert!(matches!(e, ClientError::Protocol(_)), "{e}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn plaintext_tcp_only_when_spelled_out_and_never_with_a_weak_token() {
    let dir = tempfile::tempdir().unwrap();
    let token = new_token().unwrap();
    let e = start_tcp(dir.path(), TcpSecurity::Unset, &token)
        .await
        .err()
        .expect("TCP without TLS is refused");
    assert!(
        e.contains("--insecure-plaintext") && e.contains("--tls-cert"),
        "{e}"
    );
    for weak in ["", "s3cret", "0123456789012345678901234567890"] {
        let e = start_tcp(dir.path(), TcpSecurity::InsecurePlaintext, weak)
            .await
            .err()
            .expect("a short token is refused");
        assert!(e.contains("at least 32"), "{weak:?}: {e}");
    }
    let d = start_tcp(dir.path(), TcpSecurity::InsecurePlaintext, &token)
        .await
        .expect("plaintext when asked");
    let c = Client::new(Endpoint::Tcp {
        addr: d.tcp.unwrap().to_string(),
        token: Some(token.clone()),
    });
    assert_eq!(c.machines().await.unwrap()[0].name, "bench");
    let log = machlink::services::audit::read(d.access.audit.path()).unwrap();
    assert!(
        log.iter()
            .any(|r| r.action.starts_with("listen plaintext") && r.outcome.contains("insecure")),
        "{log:#?}"
    );
    // the socket is still there, for the daemon's own user
    assert_eq!(client(&d).machines().await.unwrap()[0].name, "bench");
}
