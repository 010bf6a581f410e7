//! HTTPS through the real service (demo machine, port 0, `tls = "self-signed"`): the
//! page, the API and the event WebSocket (wss) answer over TLS to a client that pins the
//! certificate's SHA-256 fingerprint the service logs; a client pinning another
//! fingerprint gets no connection, plain HTTP on the TLS port gets no answer, and plain
//! HTTP off loopback is refused at start naming the key.

use futures_util::StreamExt;
use rustls::client::danger::{HandshakeSignatureValid, ServerCertVerified, ServerCertVerifier};
use rustls::pki_types::{CertificateDer, ServerName, UnixTime};
use rustls::{DigitallySignedStruct, SignatureScheme};
use sha2::{Digest, Sha256};
use std::net::SocketAddr;
use std::sync::Arc;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::Message;

/// Trusts exactly one certificate, by the SHA-256 of its DER (what an operator compares
/// in the browser); signatures are still checked with the provider's algorithms.
#[derive(Debug)]
struct Pinned {
    sha256: String,
    provider: Arc<rustls::crypto::CryptoProvider>,
}

impl ServerCertVerifier for Pinned {
    fn verify_server_cert(
        &self,
        end_entity: &CertificateDer<'_>,
        _intermediates: &[CertificateDer<'_>],
        _server_name: &ServerName<'_>,
        _ocsp: &[u8],
        _now: UnixTime,
    ) -> Result<ServerCertVerified, rustls::Error> {
        let seen: Vec<String> = Sha256::digest(end_entity.as_ref())
            .iter()
            .map(|b| format!("{b:02X}"))
            .collect();
        if seen.join(":") == self.sha256 {
            Ok(ServerCertVerified::assertion())
        } else {
            Err(rustls::Error::General("not the pinned certificate".into()))
        }
    }

    fn verify_tls12_signature(
        &self,
        message: &[u8],
        cert: &CertificateDer<'_>,
        dss: &DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, rustls::Error> {
        rustls::crypto::verify_tls12_signature(
            message,
            cert,
            dss,
            &self.provider.signature_verification_algorithms,
        )
    }

    fn verify_tls13_signature(
        &self,
        message: &[u8],
        cert: &CertificateDer<'_>,
        dss: &DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, rustls::Error> {
        rustls::crypto::verify_tls13_signature(
            message,
            cert,
            dss,
            &self.provider.signature_verification_algorithms,
        )
    }

    fn supported_verify_schemes(&self) -> Vec<SignatureScheme> {
        self.provider
            .signature_verification_algorithms
            .supported_schemes()
    }
}

async fn tls_connect(
    addr: SocketAddr,
    sha256: &str,
) -> std::io::Result<tokio_rustls::client::TlsStream<TcpStream>> {
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let config = rustls::ClientConfig::builder_with_provider(provider.clone())
        .with_safe_default_protocol_versions()
        .unwrap()
        .dangerous()
        .with_custom_certificate_verifier(Arc::new(Pinned {
            sha256: sha256.to_string(),
            provider,
        }))
        .with_no_client_auth();
    let connector = tokio_rustls::TlsConnector::from(Arc::new(config));
    let tcp = TcpStream::connect(addr).await?;
    connector
        .connect(ServerName::try_from("localhost").unwrap(), tcp)
        .await
}

/// One HTTP/1.1 request over a fresh TLS connection: the status and the body.
async fn https_get(
    addr: SocketAddr,
    sha256: &str,
    path: &str,
    token: Option<&str>,
) -> (u16, String) {
    let mut tls = tls_connect(addr, sha256).await.expect("TLS handshake");
    let auth = token
        .map(|t| format!("authorization: Bearer {t}\r\n"))
        .unwrap_or_default();
    tls.write_all(
        format!("GET {path} HTTP/1.1\r\nhost: localhost\r\n{auth}connection: close\r\n\r\n")
            .as_bytes(),
    )
    .await
    .unwrap();
    let mut answer = Vec::new();
    tls.read_to_end(&mut answer).await.unwrap();
    let answer = String::from_utf8_lossy(&answer).into_owned();
    let status = answer
        .split(' ')
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("not an HTTP answer: {answer}"));
    let body = answer
        .split_once("\r\n\r\n")
        .map(|(_, b)| b.to_string())
        .unwrap_or_default();
    (status, body)
}

fn https_box(dir: &std::path::Path) -> service::BoxConfig {
    let mut config = service::BoxConfig::demo(dir);
    config.service.tls = service::TlsSource::SelfSigned;
    config
}

#[tokio::test]
async fn page_api_and_events_over_https_with_the_logged_fingerprint() {
    let dir = tempfile::tempdir().unwrap();
    let running = service::start(https_box(dir.path()))
        .await
        .expect("starts with HTTPS");
    let addr = running.local_addr();
    let id = running.tls().expect("serving HTTPS").clone();
    assert!(id.made_now);
    assert_eq!(running.url(), format!("https://{addr}/"));
    let pin = id.cert_sha256.as_str();

    let (status, page) = https_get(addr, pin, "/", None).await;
    assert_eq!(status, 200);
    assert!(page.contains("<html"), "{page}");
    let (status, _) = https_get(addr, pin, "/api/v1/machines", None).await;
    assert_eq!(status, 401, "the token is still asked for");
    let (status, machines) = https_get(addr, pin, "/api/v1/machines", Some(running.token())).await;
    assert_eq!(status, 200);
    assert!(machines.contains("\"demo\""), "{machines}");

    // The event WebSocket over the same TLS (wss): the machines' states come first.
    let tls = tls_connect(addr, pin).await.unwrap();
    let mut request = format!("wss://localhost:{}/api/v1/events", addr.port())
        .into_client_request()
        .unwrap();
    request.headers_mut().insert(
        "Sec-WebSocket-Protocol",
        format!("gateway.v1, bearer.{}", running.token())
            .parse()
            .unwrap(),
    );
    let (mut ws, _) = tokio_tungstenite::client_async(request, tls)
        .await
        .expect("wss handshake");
    let first = loop {
        match ws.next().await.expect("an event").expect("a message") {
            Message::Text(t) => break serde_json::from_str::<serde_json::Value>(&t).unwrap(),
            _ => continue,
        }
    };
    assert!(first["type"].is_string(), "{first}");

    // Another certificate's fingerprint: no connection.
    let other = "00:".repeat(31) + "00";
    assert!(tls_connect(addr, &other).await.is_err());
    // Plain HTTP to the TLS port: no HTTP answer (the handshake fails, the socket closes).
    let mut plain = TcpStream::connect(addr).await.unwrap();
    plain
        .write_all(b"GET / HTTP/1.1\r\nhost: x\r\nconnection: close\r\n\r\n")
        .await
        .unwrap();
    let mut answer = Vec::new();
    let _ = plain.read_to_end(&mut answer).await;
    assert!(
        !answer.starts_with(b"HTTP/1.1 200"),
        "{:?}",
        String::from_utf8_lossy(&answer)
    );
    drop(ws);
    running.shutdown().await;

    // The next start serves the same certificate.
    let again = service::start(https_box(dir.path()))
        .await
        .expect("starts again");
    let id2 = again.tls().unwrap();
    assert!(!id2.made_now);
    assert_eq!(id2.cert_sha256, id.cert_sha256);
    again.shutdown().await;
}

#[tokio::test]
async fn plain_http_off_loopback_is_refused_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = service::BoxConfig::demo(dir.path());
    config.service.listen = "0.0.0.0:0".parse().unwrap();
    let e = service::start(config)
        .await
        .err()
        .expect("refused")
        .to_string();
    assert!(
        e.starts_with("service.tls:") && e.contains("plain_http_beyond_loopback"),
        "{e}"
    );
    // Said otherwise in BOX.toml (a TLS proxy in front): it starts.
    let mut config = service::BoxConfig::demo(dir.path());
    config.service.listen = "0.0.0.0:0".parse().unwrap();
    config.service.plain_http_beyond_loopback = true;
    let running = service::start(config).await.expect("starts");
    assert!(running.tls().is_none());
    running.shutdown().await;
}
