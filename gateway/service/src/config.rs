//! BOX.toml: the service's own settings, the machines it drives, and the optional MQTT
//! northbound. Relative paths are relative to the BOX.toml file's folder.

use serde::Deserialize;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// A BOX.toml that could not be used; the message names the file and the key.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("{path}: {source}")]
    Read {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: key `{key}`: {message}")]
    Parse {
        path: String,
        key: String,
        message: String,
    },
    #[error("{path}: {key}: {message}")]
    Invalid {
        path: String,
        key: String,
        message: String,
    },
}

/// `job = "builtin:demo"` names the embedded demo job instead of a file.
pub const BUILTIN_DEMO_JOB: &str = "builtin:demo";

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawBox {
    service: RawService,
    #[serde(default, rename = "machine")]
    machines: Vec<RawMachine>,
    #[serde(default)]
    mqtt: Option<toml::Table>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawService {
    #[serde(default = "default_listen")]
    listen: SocketAddr,
    data_dir: PathBuf,
    #[serde(default)]
    token_file: Option<PathBuf>,
    #[serde(default)]
    cors_origins: Vec<String>,
    #[serde(default = "default_max_body")]
    max_body_bytes: usize,
    #[serde(default = "default_max_job_body")]
    max_job_body_bytes: usize,
    #[serde(default = "default_bad_token_delay_cap_ms")]
    bad_token_delay_cap_ms: u64,
    #[serde(default = "default_header_timeout_s")]
    header_timeout_s: f64,
    #[serde(default = "default_idle_timeout_s")]
    idle_timeout_s: f64,
    #[serde(default = "default_max_connections")]
    max_connections: usize,
    #[serde(default)]
    tls: TlsMode,
    #[serde(default)]
    tls_cert_file: Option<PathBuf>,
    #[serde(default)]
    tls_key_file: Option<PathBuf>,
    #[serde(default)]
    tls_names: Vec<String>,
    #[serde(default)]
    plain_http_beyond_loopback: bool,
}

/// `tls` in `[service]`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Deserialize)]
#[serde(rename_all = "kebab-case")]
enum TlsMode {
    /// A pair made at first start in `<data_dir>/tls/`.
    #[default]
    SelfSigned,
    /// `tls_cert_file` and `tls_key_file`.
    Files,
    /// Plain HTTP.
    Off,
}

/// Where the HTTPS certificate and key come from (`tls` in `[service]`).
#[derive(Debug, Clone, PartialEq)]
pub enum TlsSource {
    /// `tls = "self-signed"` (the default): made at first start in `<data_dir>/tls/`
    /// (`cert.pem`, `key.pem`), kept after; its fingerprint logged at every start.
    SelfSigned,
    /// `tls = "files"`: PEM files, `tls_cert_file` (the certificate, then its chain) and
    /// `tls_key_file` (PKCS#8, PKCS#1 or SEC1).
    Files { cert: PathBuf, key: PathBuf },
    /// `tls = "off"`: plain HTTP; refused off loopback unless
    /// `plain_http_beyond_loopback = true` (a TLS proxy in front).
    Off,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMachine {
    id: String,
    #[serde(default)]
    description: String,
    job: String,
    #[serde(default)]
    map_profile: Option<String>,
    #[serde(default)]
    rotary: Option<String>,
}

fn default_listen() -> SocketAddr {
    SocketAddr::from(([127, 0, 0, 1], 8780))
}
fn default_max_body() -> usize {
    64 * 1024
}
/// A job's body carries a layout file for `layout` jobs: an apparel nest in DXF is a
/// few megabytes.
fn default_max_job_body() -> usize {
    16 * 1024 * 1024
}
fn default_bad_token_delay_cap_ms() -> u64 {
    2000
}
fn default_header_timeout_s() -> f64 {
    10.0
}
fn default_idle_timeout_s() -> f64 {
    60.0
}
/// Well below `LimitNOFILE=8192` of `config/systemd/gateway.service`, which leaves room
/// for the machines' device handles, the store and the MQTT link.
fn default_max_connections() -> usize {
    1024
}

/// The largest `max_connections` accepted.
pub const MAX_CONNECTIONS_LIMIT: usize = 65536;

/// The longest `header_timeout_s` / `idle_timeout_s` accepted (one day).
const MAX_TIMEOUT_S: f64 = 86_400.0;

/// A timeout in seconds from BOX.toml: finite, > 0, at most a day.
fn timeout(value: f64) -> Result<Duration, String> {
    if value.is_finite() && value > 0.0 && value <= MAX_TIMEOUT_S {
        Ok(Duration::from_secs_f64(value))
    } else {
        Err(format!(
            "{value} is not a timeout (seconds, more than 0 and at most {MAX_TIMEOUT_S})"
        ))
    }
}

/// Where a machine's job file comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum JobSource {
    /// The embedded demo job (every device simulated in-process).
    BuiltinDemo,
    File(PathBuf),
}

impl JobSource {
    pub fn load(&self) -> Result<job::Job, String> {
        match self {
            JobSource::BuiltinDemo => Ok(job::Job::demo()),
            JobSource::File(path) => job::Job::load(path).map_err(|e| e.to_string()),
        }
    }
}

/// Where a machine's rotary measurement job (source B) comes from: `rotary =
/// "builtin:demo"` is the paper's A/C table simulated in-process, a path a rotary job
/// file (JSON, as `gateway rotary measure --config`: its `link` says which controller).
#[derive(Debug, Clone, PartialEq)]
pub enum RotarySource {
    BuiltinDemo,
    File(PathBuf),
}

impl RotarySource {
    pub fn load(&self) -> Result<job::rotary::RotaryJob, String> {
        match self {
            RotarySource::BuiltinDemo => Ok(job::rotary::RotaryJob::default()),
            RotarySource::File(path) => {
                let text =
                    protocol::config::read_kind(path, protocol::config::DataKind::RotaryJson)
                        .map_err(|e| e.to_string())?;
                job::rotary::RotaryJob::from_json(&text)
                    .map_err(|e| format!("{}: {e}", path.display()))
            }
        }
    }
}

/// One machine of the box.
#[derive(Debug, Clone)]
pub struct MachineConfig {
    /// Short name used in URLs: letters, digits, `-` and `_`.
    pub id: String,
    pub description: String,
    pub job: JobSource,
    /// Name of the error-map profile verify jobs use (default "error_map").
    pub map_profile: String,
    /// The rotary table's measurement job, if the machine has an A/C table (`rotary` jobs
    /// are refused otherwise).
    pub rotary: Option<RotarySource>,
}

/// The service's settings (`[service]`).
#[derive(Debug, Clone)]
pub struct ServiceConfig {
    /// Loopback by default: the API is reachable from elsewhere only when asked.
    pub listen: SocketAddr,
    pub data_dir: PathBuf,
    /// Holds the bearer token (hex of 256 random bits), created at first start, mode 0600.
    pub token_file: PathBuf,
    /// Origins allowed by CORS; empty = CORS off.
    pub cors_origins: Vec<String>,
    /// Larger request bodies get 413 (every route but a job's submission and a
    /// profile's upload).
    pub max_body_bytes: usize,
    /// Larger job submissions (`POST /api/v1/machines/{machine}/jobs`) get 413.
    pub max_job_body_bytes: usize,
    /// Cap of the growing delay before answering a wrong token (ms).
    pub bad_token_delay_cap_ms: u64,
    /// `header_timeout_s` (default 10): a connection must deliver a whole request head
    /// within this time, counted from its accept for the first request and from the
    /// first byte of the next one on a keep-alive connection; else it is closed.
    pub header_timeout: Duration,
    /// `idle_timeout_s` (default 60): a keep-alive connection with no request for this
    /// long after its last response is closed. WebSockets are never idle-closed.
    pub idle_timeout: Duration,
    /// `max_connections` (default 1024, 1 to 65536): open connections (WebSockets
    /// included). At the cap a new connection closes the one waiting longest for a
    /// request; see `serve.rs` for the policy. Keep it well below the process's open-file
    /// limit (`LimitNOFILE` in the systemd unit).
    pub max_connections: usize,
    /// HTTPS or plain HTTP (`tls`, `tls_cert_file`, `tls_key_file`).
    pub tls: TlsSource,
    /// `tls_names`: host names and addresses put in a self-signed certificate besides
    /// localhost, 127.0.0.1, ::1 and the listening address.
    pub tls_names: Vec<String>,
    /// `plain_http_beyond_loopback` (default false): `tls = "off"` on an address other
    /// than loopback, for a box behind a TLS reverse proxy.
    pub plain_http_beyond_loopback: bool,
}

impl ServiceConfig {
    /// Plain HTTP is served on loopback only, unless BOX.toml says otherwise: the bearer
    /// token would cross the plant's network in clear.
    pub fn check_plain_http(&self) -> Result<(), String> {
        if self.tls == TlsSource::Off
            && !self.listen.ip().is_loopback()
            && !self.plain_http_beyond_loopback
        {
            return Err(format!(
                "\"off\" would serve plain HTTP on {} (not loopback): the token \
                 would cross the network in clear. Use tls = \"self-signed\" (the default) or \
                 \"files\", listen on 127.0.0.1, or set service.plain_http_beyond_loopback = \
                 true when a TLS proxy is in front",
                self.listen
            ));
        }
        Ok(())
    }

    /// `https` or `http`.
    pub fn scheme(&self) -> &'static str {
        match self.tls {
            TlsSource::Off => "http",
            _ => "https",
        }
    }
}

/// BOX.toml, resolved.
#[derive(Debug, Clone)]
pub struct BoxConfig {
    pub service: ServiceConfig,
    pub machines: Vec<MachineConfig>,
    /// `[mqtt]`: the Sparkplug B northbound; absent = none.
    pub mqtt: Option<northbound::MqttConfig>,
}

impl BoxConfig {
    pub fn load(path: &Path) -> Result<BoxConfig, ConfigError> {
        // The bounded reader: regular files only (a FIFO never blocks the start).
        let text = protocol::config::read_data_file(path).map_err(|source| ConfigError::Read {
            path: path.display().to_string(),
            source,
        })?;
        let base = path.parent().unwrap_or(Path::new("."));
        BoxConfig::parse(&text, &path.display().to_string(), base)
    }

    /// Parse BOX.toml text; `name` is used in errors, `base` resolves relative paths.
    pub fn parse(text: &str, name: &str, base: &Path) -> Result<BoxConfig, ConfigError> {
        let de = toml::Deserializer::new(text);
        let raw: RawBox = serde_path_to_error::deserialize(de).map_err(|e| ConfigError::Parse {
            path: name.to_string(),
            key: e.path().to_string(),
            message: e.inner().message().to_string(),
        })?;
        let invalid = |key: String, message: String| ConfigError::Invalid {
            path: name.to_string(),
            key,
            message,
        };
        let resolve = |p: &Path| {
            if p.is_absolute() {
                p.to_path_buf()
            } else {
                base.join(p)
            }
        };
        if raw.service.max_body_bytes == 0 {
            return Err(invalid(
                "service.max_body_bytes".into(),
                "must be at least 1".into(),
            ));
        }
        // Past the largest layout a request may carry, a body would only be refused later.
        let most = procedure::request::MAX_LAYOUT_BYTES + 1024 * 1024;
        if !(1..=most).contains(&raw.service.max_job_body_bytes) {
            return Err(invalid(
                "service.max_job_body_bytes".into(),
                format!(
                    "must be from 1 to {most}, got {}",
                    raw.service.max_job_body_bytes
                ),
            ));
        }
        let header_timeout = timeout(raw.service.header_timeout_s)
            .map_err(|m| invalid("service.header_timeout_s".into(), m))?;
        let idle_timeout = timeout(raw.service.idle_timeout_s)
            .map_err(|m| invalid("service.idle_timeout_s".into(), m))?;
        if !(1..=MAX_CONNECTIONS_LIMIT).contains(&raw.service.max_connections) {
            return Err(invalid(
                "service.max_connections".into(),
                format!(
                    "{} is not between 1 and {MAX_CONNECTIONS_LIMIT}",
                    raw.service.max_connections
                ),
            ));
        }
        let data_dir = resolve(&raw.service.data_dir);
        let tls = match (
            raw.service.tls,
            &raw.service.tls_cert_file,
            &raw.service.tls_key_file,
        ) {
            (TlsMode::Files, Some(cert), Some(key)) => TlsSource::Files {
                cert: resolve(cert),
                key: resolve(key),
            },
            (TlsMode::Files, cert, _) => {
                let missing = if cert.is_none() {
                    "service.tls_cert_file"
                } else {
                    "service.tls_key_file"
                };
                return Err(invalid(
                    missing.into(),
                    "tls = \"files\" needs tls_cert_file and tls_key_file (PEM)".into(),
                ));
            }
            (mode, cert, key) => {
                if let Some(key_name) = [(cert, "tls_cert_file"), (key, "tls_key_file")]
                    .iter()
                    .find_map(|(v, k)| v.is_some().then_some(*k))
                {
                    return Err(invalid(
                        format!("service.{key_name}"),
                        "is used with tls = \"files\" only".into(),
                    ));
                }
                if mode == TlsMode::Off {
                    TlsSource::Off
                } else {
                    TlsSource::SelfSigned
                }
            }
        };
        let token_file = match &raw.service.token_file {
            Some(p) => resolve(p),
            None => data_dir.join("token"),
        };
        let mut machines: Vec<MachineConfig> = Vec::new();
        for (i, m) in raw.machines.iter().enumerate() {
            let key = |field: &str| format!("machine[{i}].{field}");
            if !valid_id(&m.id) {
                return Err(invalid(
                    key("id"),
                    format!(
                        "{:?} is not a machine id (1 to 64 letters, digits, '-' or '_')",
                        m.id
                    ),
                ));
            }
            if machines.iter().any(|other| other.id == m.id) {
                return Err(invalid(key("id"), format!("{:?} is used twice", m.id)));
            }
            let job = if m.job == BUILTIN_DEMO_JOB {
                JobSource::BuiltinDemo
            } else {
                JobSource::File(resolve(Path::new(&m.job)))
            };
            machines.push(MachineConfig {
                id: m.id.clone(),
                description: m.description.clone(),
                job,
                map_profile: m.map_profile.clone().unwrap_or_else(|| "error_map".into()),
                rotary: m.rotary.as_deref().map(|r| {
                    if r == BUILTIN_DEMO_JOB {
                        RotarySource::BuiltinDemo
                    } else {
                        RotarySource::File(resolve(Path::new(r)))
                    }
                }),
            });
        }
        let config = BoxConfig {
            service: ServiceConfig {
                listen: raw.service.listen,
                data_dir,
                token_file,
                cors_origins: raw.service.cors_origins,
                max_body_bytes: raw.service.max_body_bytes,
                max_job_body_bytes: raw.service.max_job_body_bytes,
                bad_token_delay_cap_ms: raw.service.bad_token_delay_cap_ms,
                header_timeout,
                idle_timeout,
                max_connections: raw.service.max_connections,
                tls,
                tls_names: raw.service.tls_names,
                plain_http_beyond_loopback: raw.service.plain_http_beyond_loopback,
            },
            machines,
            mqtt: match raw.mqtt {
                None => None,
                Some(table) => {
                    let mqtt: northbound::MqttConfig = toml::Value::Table(table)
                        .try_into()
                        .map_err(|e: toml::de::Error| {
                            invalid("mqtt".into(), e.message().to_string())
                        })?;
                    mqtt.check().map_err(|e| invalid("mqtt".into(), e))?;
                    Some(mqtt)
                }
            },
        };
        config
            .service
            .check_plain_http()
            .map_err(|m| ConfigError::Invalid {
                path: name.to_string(),
                key: "service.tls".into(),
                message: m,
            })?;
        Ok(config)
    }

    /// One machine "demo" on the embedded demo job, listening on 127.0.0.1:0, no MQTT.
    pub fn demo(data_dir: &Path) -> BoxConfig {
        BoxConfig {
            service: ServiceConfig {
                listen: SocketAddr::from(([127, 0, 0, 1], 0)),
                data_dir: data_dir.to_path_buf(),
                token_file: data_dir.join("token"),
                cors_origins: Vec::new(),
                max_body_bytes: default_max_body(),
                max_job_body_bytes: default_max_job_body(),
                bad_token_delay_cap_ms: default_bad_token_delay_cap_ms(),
                header_timeout: Duration::from_secs_f64(default_header_timeout_s()),
                idle_timeout: Duration::from_secs_f64(default_idle_timeout_s()),
                max_connections: default_max_connections(),
                // Loopback: plain HTTP is allowed (the tests' clients and the page test
                // set `tls` when they mean HTTPS).
                tls: TlsSource::Off,
                tls_names: Vec::new(),
                plain_http_beyond_loopback: false,
            },
            machines: vec![MachineConfig {
                id: "demo".into(),
                description:
                    "Simulated stage and camera (the embedded demo job), simulated A/C table".into(),
                job: JobSource::BuiltinDemo,
                map_profile: "error_map".into(),
                rotary: Some(RotarySource::BuiltinDemo),
            }],
            mqtt: None,
        }
    }
}

/// Machine ids appear in URLs and MQTT topics: keep them plain.
pub fn valid_id(id: &str) -> bool {
    !id.is_empty()
        && id.len() <= 64
        && id
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_the_demo_box() {
        let text = include_str!("../../../config/box/demo.toml");
        let c = BoxConfig::parse(text, "demo.toml", Path::new("/etc/gw")).unwrap();
        assert_eq!(c.service.listen, "127.0.0.1:8780".parse().unwrap());
        assert_eq!(c.service.data_dir, Path::new("/var/lib/gateway"));
        assert_eq!(c.service.token_file, Path::new("/var/lib/gateway/token"));
        assert!(c.service.cors_origins.is_empty());
        assert_eq!(c.machines.len(), 1);
        assert_eq!(
            c.machines[0].job,
            JobSource::File(PathBuf::from("/etc/gw/../gateway/demo.toml"))
        );
        assert_eq!(
            c.machines[0].rotary,
            Some(RotarySource::File(PathBuf::from(
                "/etc/gw/../rotary/sim-table.json"
            )))
        );
        assert!(c.mqtt.is_none());
        assert_eq!(c.service.tls, TlsSource::SelfSigned);
        assert_eq!(c.service.header_timeout, Duration::from_secs(10));
        assert_eq!(c.service.idle_timeout, Duration::from_secs(60));
        assert_eq!(c.service.max_connections, 1024);
        assert_eq!(c.service.max_job_body_bytes, 16 << 20);
    }

    #[test]
    fn connection_limits_are_read_and_checked() {
        let base = "[service]\ndata_dir = \"d\"\n";
        let c = BoxConfig::parse(
            &format!("{base}header_timeout_s = 2.5\nidle_timeout_s = 30\nmax_connections = 8\n"),
            "b.toml",
            Path::new("."),
        )
        .unwrap();
        assert_eq!(c.service.header_timeout, Duration::from_millis(2500));
        assert_eq!(c.service.idle_timeout, Duration::from_secs(30));
        assert_eq!(c.service.max_connections, 8);
        let c = BoxConfig::parse(base, "b.toml", Path::new(".")).unwrap();
        assert_eq!(
            (c.service.header_timeout, c.service.idle_timeout),
            (Duration::from_secs(10), Duration::from_secs(60))
        );
        for (line, key) in [
            ("header_timeout_s = 0", "service.header_timeout_s"),
            ("header_timeout_s = -1.0", "service.header_timeout_s"),
            ("header_timeout_s = nan", "service.header_timeout_s"),
            ("header_timeout_s = inf", "service.header_timeout_s"),
            ("idle_timeout_s = 0.0", "service.idle_timeout_s"),
            ("idle_timeout_s = 1e300", "service.idle_timeout_s"),
            ("max_connections = 0", "service.max_connections"),
            ("max_connections = 65537", "service.max_connections"),
            ("max_connections = -3", "service.max_connections"),
            ("max_connections = \"many\"", "service.max_connections"),
            ("max_job_body_bytes = 0", "service.max_job_body_bytes"),
            (
                "max_job_body_bytes = 1000000000",
                "service.max_job_body_bytes",
            ),
        ] {
            let e =
                BoxConfig::parse(&format!("{base}{line}\n"), "b.toml", Path::new(".")).unwrap_err();
            assert!(e.to_string().contains(key), "{line}: {e}");
        }
    }

    /// HTTPS by default, files when named, plain HTTP on loopback only unless allowed;
    /// every refusal names its key.
    #[test]
    fn tls_keys() {
        let base = "[service]\ndata_dir = \"d\"\n";
        let parse = |extra: &str| {
            BoxConfig::parse(&format!("{base}{extra}"), "b.toml", Path::new("/etc/gw"))
        };
        let c = parse("").unwrap();
        assert_eq!(c.service.tls, TlsSource::SelfSigned);
        assert_eq!(c.service.scheme(), "https");
        let c = parse("tls = \"files\"\ntls_cert_file = \"c.pem\"\ntls_key_file = \"/k.pem\"\n")
            .unwrap();
        assert_eq!(
            c.service.tls,
            TlsSource::Files {
                cert: PathBuf::from("/etc/gw/c.pem"),
                key: PathBuf::from("/k.pem")
            }
        );
        assert_eq!(parse("tls = \"off\"\n").unwrap().service.scheme(), "http");
        for (extra, key) in [
            (
                "tls = \"files\"\ntls_key_file = \"k\"\n",
                "service.tls_cert_file",
            ),
            (
                "tls = \"files\"\ntls_cert_file = \"c\"\n",
                "service.tls_key_file",
            ),
            ("tls_key_file = \"k\"\n", "service.tls_key_file"),
            ("tls = \"on\"\n", "service.tls"),
            ("listen = \"0.0.0.0:8780\"\ntls = \"off\"\n", "service.tls"),
        ] {
            let e = parse(extra).unwrap_err().to_string();
            assert!(e.contains(key), "{extra}: {e}");
        }
        let c =
            parse("listen = \"0.0.0.0:8780\"\ntls = \"off\"\nplain_http_beyond_loopback = true\n")
                .unwrap();
        assert_eq!(c.service.tls, TlsSource::Off);
    }

    #[test]
    fn errors_name_the_key() {
        let text = "[service]\ndata_dir = \"d\"\nlisten = \"nowhere\"\n";
        let e = BoxConfig::parse(text, "b.toml", Path::new(".")).unwrap_err();
        assert!(e.to_string().contains("service.listen"), "{e}");
        let text = "[service]\ndata_dir = \"d\"\n[[machine]]\nid = \"a b\"\njob = \"j\"\n";
        let e = BoxConfig::parse(text, "b.toml", Path::new(".")).unwrap_err();
        assert!(e.to_string().contains("machine[0].id"), "{e}");
        let text = "[service]\ndata_dir = \"d\"\nport = 3\n";
        let e = BoxConfig::parse(text, "b.toml", Path::new(".")).unwrap_err();
        assert!(e.to_string().contains("port"), "{e}");
        let text = "[service]\ndata_dir = \"d\"\n[[machine]]\nid = \"a\"\njob = \"j\"\n[[machine]]\nid = \"a\"\njob = \"k\"\n";
        let e = BoxConfig::parse(text, "b.toml", Path::new(".")).unwrap_err();
        assert!(e.to_string().contains("machine[1].id"), "{e}");
    }

    #[test]
    fn mqtt_is_read_and_checked() {
        let base = "[service]\ndata_dir = \"d\"\n[mqtt]\nhost = \"broker\"\ngroup_id = \"plant\"\n";
        let c = BoxConfig::parse(
            &format!("{base}edge_node_id = \"box-1\"\n"),
            "b.toml",
            Path::new("."),
        )
        .unwrap();
        let m = c.mqtt.unwrap();
        assert_eq!(
            (m.host.as_str(), m.port, m.keep_alive_s),
            ("broker", 1883, 30)
        );
        // Sparkplug ids may not hold + # /.
        let e = BoxConfig::parse(
            &format!("{base}edge_node_id = \"box/1\"\n"),
            "b.toml",
            Path::new("."),
        )
        .unwrap_err();
        assert!(
            e.to_string().contains("mqtt") && e.to_string().contains("edge_node_id"),
            "{e}"
        );
        let e = BoxConfig::parse(
            &format!("{base}edge_node_id = \"b\"\nqos = 2\n"),
            "b.toml",
            Path::new("."),
        )
        .unwrap_err();
        assert!(e.to_string().contains("qos"), "{e}");
        let e = BoxConfig::parse(&format!("{base}\n"), "b.toml", Path::new(".")).unwrap_err();
        assert!(e.to_string().contains("edge_node_id"), "{e}");
    }
}
