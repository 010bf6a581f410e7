//! docs/service.md's API table is the OpenAPI document's routes: every path and method
//! the document has is a row of the table and every row is in the document, with the
//! same answers (status codes). A route added without its row, or a row left after its
//! route went, fails here naming it.

use std::collections::BTreeMap;
use utoipa::OpenApi;

/// (method, path) -> the status codes it answers, from the OpenAPI document.
fn from_openapi() -> BTreeMap<(String, String), String> {
    let doc = serde_json::to_value(service::api::ApiDoc::openapi()).expect("the document");
    let mut routes = BTreeMap::new();
    for (path, item) in doc["paths"].as_object().expect("paths") {
        for (method, operation) in item.as_object().expect("a path item") {
            let mut codes: Vec<&str> = operation["responses"]
                .as_object()
                .map(|r| r.keys().map(String::as_str).collect())
                .unwrap_or_default();
            codes.sort_unstable();
            routes.insert((method.to_uppercase(), path.clone()), codes.join(", "));
        }
    }
    routes
}

/// The rows of the table under `### API` in docs/service.md:
/// `| GET | `/api/v1/jobs` | 200, 400 | what it does |`.
fn from_docs() -> BTreeMap<(String, String), String> {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../docs/service.md");
    let text = std::fs::read_to_string(path).expect("docs/service.md");
    let table = text
        .split("\n### API\n")
        .nth(1)
        .expect("docs/service.md has a `### API` section with the route table");
    let mut rows = BTreeMap::new();
    for line in table.lines().skip_while(|l| !l.starts_with('|')) {
        if !line.starts_with('|') {
            break;
        }
        let cells: Vec<&str> = line.trim_matches('|').split('|').map(str::trim).collect();
        let method = cells[0];
        if method == "method" || method.starts_with("---") {
            continue;
        }
        let route = cells.get(1).expect("a path cell").trim_matches('`');
        let answers = cells.get(2).expect("an answers cell").to_string();
        let previous = rows.insert((method.to_string(), route.to_string()), answers);
        assert!(previous.is_none(), "{method} {route} is in the table twice");
    }
    rows
}

#[test]
fn the_docs_api_table_lists_exactly_the_openapi_routes_and_their_answers() {
    let api = from_openapi();
    let docs = from_docs();
    let missing: Vec<String> = api
        .iter()
        .filter(|(k, _)| !docs.contains_key(*k))
        .map(|((m, p), codes)| format!("| {m} | `{p}` | {codes} | |"))
        .collect();
    let stale: Vec<String> = docs
        .keys()
        .filter(|k| !api.contains_key(*k))
        .map(|(m, p)| format!("{m} {p}"))
        .collect();
    let wrong: Vec<String> = api
        .iter()
        .filter_map(|(k, codes)| {
            let listed = docs.get(k)?;
            (listed != codes)
                .then(|| format!("{} {}: the table says {listed}, OpenAPI {codes}", k.0, k.1))
        })
        .collect();
    assert!(
        missing.is_empty() && stale.is_empty() && wrong.is_empty(),
        "docs/service.md's API table differs from the OpenAPI document\n\
         rows missing:\n{}\nrows without a route: {stale:?}\nanswers differ: {wrong:#?}",
        missing.join("\n")
    );
    assert!(api.len() >= 20, "{api:?}");
}

/// Every `$ref` of the OpenAPI document names a schema it has, and each job kind's params
/// and result are among them (`job.<kind>`, `job.<kind>.result`).
#[test]
fn every_schema_reference_resolves_and_every_kind_has_its_params_and_result() {
    let doc = serde_json::to_value(service::api::ApiDoc::openapi()).expect("the document");
    let schemas = doc["components"]["schemas"].as_object().expect("schemas");
    fn refs<'a>(v: &'a serde_json::Value, out: &mut Vec<&'a str>) {
        match v {
            serde_json::Value::Object(o) => {
                if let Some(r) = o.get("$ref").and_then(|r| r.as_str()) {
                    out.push(r);
                }
                o.values().for_each(|v| refs(v, out));
            }
            serde_json::Value::Array(a) => a.iter().for_each(|v| refs(v, out)),
            _ => {}
        }
    }
    let mut found = Vec::new();
    refs(&doc, &mut found);
    let unresolved: Vec<&str> = found
        .into_iter()
        .filter(|r| {
            r.strip_prefix("#/components/schemas/")
                .is_none_or(|name| !schemas.contains_key(name))
        })
        .collect();
    assert!(unresolved.is_empty(), "unresolved: {unresolved:?}");
    for kind in procedure::KINDS {
        for name in [
            format!("job.{}", kind.name),
            format!("job.{}.result", kind.name),
        ] {
            assert!(schemas.contains_key(&name), "no schema {name}");
        }
    }
}
