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

/// A job request body as the API receives it (`service::api::JobRequest`, then
/// `procedure::Request::parse`, the one check of every procedure's request): an accepted
/// one is stored normalized (every default written out), parses back to the same
/// request, and is queued and read back unchanged; a refusal names a field or the kind.
pub fn api_job_body(data: &[u8]) {
    let Ok(request) = serde_json::from_slice::<service::api::JobRequest>(data) else {
        return;
    };
    match procedure::Request::parse(&request.kind, &request.params) {
        Ok(parsed) => {
            let params = parsed.params();
            let again = procedure::Request::parse(&request.kind, &params)
                .expect("a normalized request parses again");
            assert_eq!(again, parsed);
            let mut store = store::Store::open_in_memory().expect("in-memory store");
            let queued = store
                .enqueue("m", &request.kind, &params)
                .expect("an accepted job is queued");
            let back = store.job(queued.id).expect("read").expect("present");
            assert_eq!(back.kind, request.kind);
            assert_eq!(back.params, params);
        }
        Err(e) => assert!(!e.field.is_empty() && !e.message.is_empty(), "{e}"),
    }
}
