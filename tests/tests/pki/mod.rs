//! A throwaway PKI for the TLS tests, made at run time with rcgen (no key is committed).
#![allow(dead_code, unreachable_pub, reason = "each test file uses a subset")]

use std::path::{Path, PathBuf};

use rcgen::{BasicConstraints, CertificateParams, ExtendedKeyUsagePurpose, IsCa, Issuer, KeyPair};

/// Files of one throwaway PKI: a CA and a server certificate it signed.
pub struct Pki {
    /// PEM of the CA certificate.
    pub ca: PathBuf,
    /// PEM of the server certificate.
    pub server_cert: PathBuf,
    /// PEM of the server's private key.
    pub server_key: PathBuf,
    issuer: Issuer<'static, KeyPair>,
}

/// A new CA and a server certificate for `server_names`, written to `dir` as
/// `<name>-ca.pem`, `<name>-server.pem` and `<name>-server.key`.
pub fn write_pki(dir: &Path, name: &str, server_names: &[&str]) -> Pki {
    let ca_key = KeyPair::generate().unwrap();
    let mut ca_params = CertificateParams::new(Vec::<String>::new()).unwrap();
    ca_params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
    let ca_cert = ca_params.self_signed(&ca_key).unwrap();
    let issuer = Issuer::new(ca_params, ca_key);
    let server_key = KeyPair::generate().unwrap();
    let server_cert = CertificateParams::new(
        server_names
            .iter()
            .map(|n| n.to_string())
            .collect::<Vec<_>>(),
    )
    .unwrap()
    .signed_by(&server_key, &issuer)
    .unwrap();
    let pki = Pki {
        ca: dir.join(format!("{name}-ca.pem")),
        server_cert: dir.join(format!("{name}-server.pem")),
        server_key: dir.join(format!("{name}-server.key")),
        issuer,
    };
    std::fs::write(&pki.ca, ca_cert.pem()).unwrap();
    std::fs::write(&pki.server_cert, server_cert.pem()).unwrap();
    std::fs::write(&pki.server_key, server_key.serialize_pem()).unwrap();
    pki
}

/// A client certificate the PKI's CA signed, as (certificate, key) files.
pub fn write_client_cert(pki: &Pki, dir: &Path) -> (PathBuf, PathBuf) {
    let key = KeyPair::generate().unwrap();
    let mut params = CertificateParams::new(Vec::<String>::new()).unwrap();
    params.extended_key_usages = vec![ExtendedKeyUsagePurpose::ClientAuth];
    let cert = params.signed_by(&key, &pki.issuer).unwrap();
    let paths = (dir.join("client.pem"), dir.join("client.key"));
    std::fs::write(&paths.0, cert.pem()).unwrap();
    std::fs::write(&paths.1, key.serialize_pem()).unwrap();
    paths
}
