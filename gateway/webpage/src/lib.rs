//! The service's web page, embedded in the binary (being built; see issue 15).

/// The page's HTML shell (holds no data; everything is fetched with the bearer token).
pub const INDEX_HTML: &str = "<!doctype html><title>gateway</title>";
/// The page's script.
pub const APP_JS: &str = "";
/// The page's style sheet.
pub const STYLE_CSS: &str = "";
