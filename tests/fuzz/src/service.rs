//! BOX.toml, the service's configuration (`service::BoxConfig::parse`).

/// A BOX.toml: refused with an error naming the key, or accepted with machine ids fit
/// for URLs and a positive body limit.
pub fn box_toml(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    match service::BoxConfig::parse(text, "box.toml", std::path::Path::new("/etc/gateway")) {
        Ok(config) => {
            assert!(config.service.max_body_bytes >= 1);
            for (i, m) in config.machines.iter().enumerate() {
                assert!(service::config::valid_id(&m.id), "{:?}", m.id);
                assert!(config.machines[..i].iter().all(|o| o.id != m.id));
            }
        }
        Err(e) => assert!(e.to_string().starts_with("box.toml"), "{e}"),
    }
}
