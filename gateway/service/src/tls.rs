//! HTTPS (errors are messages naming the file and the key of BOX.toml): the service's certificate and key, from the files BOX.toml names or a
//! self-signed pair made at first start, as a rustls server configuration (ring as the
//! crypto provider, TLS 1.2 and 1.3, HTTP/1.1 only, as the plain server).
//!
//! The self-signed pair is kept in `<data_dir>/tls/` (`cert.pem`, and `key.pem` with
//! mode 0600 in a folder of mode 0700), so the fingerprint the operator checked once
//! stays the box's. Its SHA-256 fingerprint (of the certificate's DER, as browsers show
//! it: `Certificate Viewer > SHA-256 Fingerprint`) is logged at every start, with the
//! base64 SHA-256 of its public key (what `chromium
//! --ignore-certificate-errors-spki-list=` and HPKP-style pins take).

use crate::config::TlsSource;
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};
use sha2::{Digest, Sha256};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The largest PEM file read (a chain of a few certificates is a few kB).
const MAX_PEM_BYTES: u64 = 1024 * 1024;

/// What the operator checks of the certificate the service presents.
#[derive(Debug, Clone)]
pub struct TlsIdentity {
    /// The certificate file.
    pub cert_file: PathBuf,
    /// SHA-256 of the (first) certificate's DER, upper-case hex pairs joined by `:`.
    pub cert_sha256: String,
    /// base64 of the SHA-256 of the certificate's SubjectPublicKeyInfo.
    pub spki_sha256_base64: String,
    /// The pair was made by this start (self-signed, first start).
    pub made_now: bool,
}

/// The rustls configuration and what to tell the operator.
pub(crate) struct Tls {
    pub config: Arc<rustls::ServerConfig>,
    pub identity: TlsIdentity,
}

/// The server's certificate and key: from `source`'s files, or the self-signed pair in
/// `<data_dir>/tls/` (made now if neither file exists; `names` and the listening
/// address go into its subject alternative names).
pub(crate) fn load(
    source: &TlsSource,
    data_dir: &Path,
    names: &[String],
    listen: SocketAddr,
) -> Result<Tls, String> {
    let (cert_file, key_file, cert_key, key_key, made_now) = match source {
        TlsSource::Off => unreachable!("no TLS to load"),
        TlsSource::Files { cert, key } => (
            cert.clone(),
            key.clone(),
            "service.tls_cert_file",
            "service.tls_key_file",
            false,
        ),
        TlsSource::SelfSigned => {
            let dir = data_dir.join("tls");
            let (cert, key) = (dir.join("cert.pem"), dir.join("key.pem"));
            let made = make_self_signed_if_absent(&dir, &cert, &key, names, listen)?;
            (
                cert,
                key,
                "service.tls (self-signed)",
                "service.tls (self-signed)",
                made,
            )
        }
    };
    let cert_pem = read_pem(&cert_file, cert_key)?;
    let key_pem = read_pem(&key_file, key_key)?;
    let certs: Vec<CertificateDer<'static>> = CertificateDer::pem_slice_iter(&cert_pem)
        .collect::<Result<_, _>>()
        .map_err(|e| {
            format!(
                "{cert_key} {}: not a PEM certificate file ({e})",
                cert_file.display()
            )
        })?;
    if certs.is_empty() {
        return Err(format!(
            "{cert_key} {}: no certificate in it (a PEM '-----BEGIN CERTIFICATE-----' block expected)",
            cert_file.display()
        ));
    }
    let key = PrivateKeyDer::from_pem_slice(&key_pem).map_err(|e| {
        format!(
            "{key_key} {}: no private key in it (a PEM PKCS#8, PKCS#1 or SEC1 key expected: {e})",
            key_file.display()
        )
    })?;
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let signing = provider
        .key_provider
        .load_private_key(key.clone_key())
        .map_err(|e| {
            format!(
                "{key_key} {}: a key rustls cannot use ({e}; RSA, ECDSA P-256/P-384 or Ed25519)",
                key_file.display()
            )
        })?;
    let spki = signing.public_key().ok_or_else(|| {
        format!(
            "{key_key} {}: the key's public half cannot be read",
            key_file.display()
        )
    })?;
    let cert_sha256 = hex_pairs(&Sha256::digest(certs[0].as_ref()));
    let mut config = rustls::ServerConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .map_err(|e| format!("TLS versions: {e}"))?
        .with_no_client_auth()
        .with_single_cert(certs, key)
        .map_err(|e| {
            format!(
                "{cert_key} {} with {key_key} {}: {e} (is the key the certificate's?)",
                cert_file.display(),
                key_file.display()
            )
        })?;
    // The server speaks HTTP/1.1 only (serve.rs).
    config.alpn_protocols = vec![b"http/1.1".to_vec()];
    use base64::Engine;
    let spki_sha256_base64 =
        base64::engine::general_purpose::STANDARD.encode(Sha256::digest(spki.as_ref()));
    Ok(Tls {
        config: Arc::new(config),
        identity: TlsIdentity {
            cert_file,
            cert_sha256,
            spki_sha256_base64,
            made_now,
        },
    })
}

fn read_pem(path: &Path, key: &str) -> Result<Vec<u8>, String> {
    protocol::config::read_bytes_bounded(path, MAX_PEM_BYTES, "a PEM file")
        .map_err(|e| format!("{key} {}: {e}", path.display()))
}

fn hex_pairs(bytes: &[u8]) -> String {
    bytes
        .iter()
        .map(|b| format!("{b:02X}"))
        .collect::<Vec<_>>()
        .join(":")
}

/// Makes the self-signed pair unless both files exist (true: made). One file without
/// the other is refused, never replaced: the operator may have checked its fingerprint.
fn make_self_signed_if_absent(
    dir: &Path,
    cert: &Path,
    key: &Path,
    names: &[String],
    listen: SocketAddr,
) -> Result<bool, String> {
    match (cert.exists(), key.exists()) {
        (true, true) => return Ok(false),
        (false, false) => {}
        (has_cert, _) => {
            let (present, missing) = if has_cert { (cert, key) } else { (key, cert) };
            return Err(format!(
                "service.tls (self-signed): {} is there but {} is not; remove the other one \
                 to have a new pair made (its fingerprint changes), or restore it",
                present.display(),
                missing.display()
            ));
        }
    }
    let mut alt_names: Vec<String> = vec!["localhost".into(), "127.0.0.1".into(), "::1".into()];
    if !listen.ip().is_unspecified() {
        alt_names.push(listen.ip().to_string());
    }
    for n in names {
        if !alt_names.contains(n) {
            alt_names.push(n.clone());
        }
    }
    let mut params = rcgen::CertificateParams::new(alt_names)
        .map_err(|e| format!("service.tls_names: a name the certificate cannot hold ({e})"))?;
    params
        .distinguished_name
        .push(rcgen::DnType::CommonName, "gateway box (self-signed)");
    let now = std::time::SystemTime::now();
    params.not_before = (now - std::time::Duration::from_secs(86_400)).into();
    // Ten years: a box's life; the operator checks the fingerprint, not a chain.
    params.not_after = (now + std::time::Duration::from_secs(10 * 365 * 86_400)).into();
    let pair = rcgen::KeyPair::generate()
        .map_err(|e| format!("a key for the self-signed certificate: {e}"))?;
    let certificate = params
        .self_signed(&pair)
        .map_err(|e| format!("the self-signed certificate: {e}"))?;
    make_private_dir(dir)?;
    // The key first: a certificate without its key is never left behind.
    let write = |path: &Path, text: String| {
        protocol::config::write_output(path, text.as_bytes(), &[])
            .map_err(|e| format!("{}: writing the TLS pair: {e}", path.display()))
    };
    write(key, pair.serialize_pem())?;
    owner_only(key)?;
    write(cert, certificate.pem())?;
    Ok(true)
}

/// The folder of the key: mode 0700, so the key is never readable by others, even for
/// the moment between its atomic write and its mode 0600.
fn make_private_dir(dir: &Path) -> Result<(), String> {
    let io = |e| format!("{}: the TLS folder: {e}", dir.display());
    std::fs::create_dir_all(dir).map_err(io)?;
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o700)).map_err(io)?;
    }
    Ok(())
}

fn owner_only(path: &Path) -> Result<(), String> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o600))
            .map_err(|e| format!("{}: restricting it to its owner: {e}", path.display()))?;
    }
    #[cfg(not(unix))]
    let _ = path;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn listen() -> SocketAddr {
        "0.0.0.0:8780".parse().unwrap()
    }

    /// The first start makes the pair (key 0600 in a 0700 folder); the next start reads
    /// the same pair, so the fingerprint stays.
    #[test]
    fn self_signed_pair_is_made_once_and_kept() {
        let dir = tempfile::tempdir().unwrap();
        let first = load(&TlsSource::SelfSigned, dir.path(), &[], listen()).unwrap();
        assert!(first.identity.made_now);
        let fp = &first.identity.cert_sha256;
        assert_eq!(fp.len(), 32 * 3 - 1, "{fp}");
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = |p: &Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
            assert_eq!(mode(&dir.path().join("tls/key.pem")), 0o600);
            assert_eq!(mode(&dir.path().join("tls")), 0o700);
        }
        let again = load(&TlsSource::SelfSigned, dir.path(), &[], listen()).unwrap();
        assert!(!again.identity.made_now);
        assert_eq!(&again.identity.cert_sha256, fp);
        assert_eq!(
            again.identity.spki_sha256_base64,
            first.identity.spki_sha256_base64
        );
        // The fingerprint is the certificate file's DER digest.
        let pem = std::fs::read(dir.path().join("tls/cert.pem")).unwrap();
        let der = CertificateDer::pem_slice_iter(&pem)
            .next()
            .unwrap()
            .unwrap();
        assert_eq!(hex_pairs(&Sha256::digest(der.as_ref())), *fp);
    }

    /// A key left without its certificate is not replaced.
    #[test]
    fn half_a_pair_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        load(&TlsSource::SelfSigned, dir.path(), &[], listen()).unwrap();
        std::fs::remove_file(dir.path().join("tls/cert.pem")).unwrap();
        let e = load(&TlsSource::SelfSigned, dir.path(), &[], listen())
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains("key.pem is there but") && e.contains("cert.pem"),
            "{e}"
        );
    }

    /// Files named in BOX.toml: a missing file, a file without a certificate and a key
    /// of another certificate are each refused naming the key of BOX.toml.
    #[test]
    fn given_files_are_checked() {
        let dir = tempfile::tempdir().unwrap();
        let a = dir.path().join("a");
        let b = dir.path().join("b");
        load(&TlsSource::SelfSigned, &a, &[], listen()).unwrap();
        load(&TlsSource::SelfSigned, &b, &[], listen()).unwrap();
        let files = |cert: &Path, key: &Path| TlsSource::Files {
            cert: cert.to_path_buf(),
            key: key.to_path_buf(),
        };
        let (ca, ka) = (a.join("tls/cert.pem"), a.join("tls/key.pem"));
        let kb = b.join("tls/key.pem");
        let ok = load(&files(&ca, &ka), dir.path(), &[], listen()).unwrap();
        assert!(!ok.identity.made_now);
        let err = |source: TlsSource| {
            load(&source, dir.path(), &[], listen())
                .err()
                .unwrap()
                .to_string()
        };
        let e = err(files(&dir.path().join("none.pem"), &ka));
        assert!(e.starts_with("service.tls_cert_file"), "{e}");
        let e = err(files(&ka, &ka));
        assert!(
            e.starts_with("service.tls_cert_file") && e.contains("no certificate"),
            "{e}"
        );
        let e = err(files(&ca, &ca));
        assert!(
            e.starts_with("service.tls_key_file") && e.contains("no private key"),
            "{e}"
        );
        let e = err(files(&ca, &kb));
        assert!(e.contains("is the key the certificate's?"), "{e}");
    }
}
