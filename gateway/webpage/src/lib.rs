//! The service's web page, embedded in the binary: plain HTML, JavaScript and CSS under
//! `web/`, no build step and no outside scripts, so the box serves it without files on
//! disk and without internet. The page holds no data: everything is fetched from the
//! API v1 with the bearer token (taken from the `#token=` fragment or a form).

/// The page's HTML shell (`GET /`).
pub const INDEX_HTML: &str = include_str!("../web/index.html");
/// The page's script (`GET /app.js`).
pub const APP_JS: &str = include_str!("../web/app.js");
/// The page's style sheet (`GET /style.css`).
pub const STYLE_CSS: &str = include_str!("../web/style.css");

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_page_loads_only_its_own_files() {
        assert!(INDEX_HTML.contains(r#"<script src="/app.js" defer></script>"#));
        assert!(INDEX_HTML.contains(r#"<link rel="stylesheet" href="/style.css">"#));
        for text in [INDEX_HTML, APP_JS, STYLE_CSS] {
            assert!(
                !text.contains("http://") && !text.contains("https://"),
                "no CDN"
            );
        }
    }

    #[test]
    fn the_ids_the_script_uses_exist_in_the_page() {
        // Every $('id') in the script must name an element of the page.
        let mut rest = APP_JS;
        let mut count = 0;
        while let Some(at) = rest.find("$('") {
            rest = &rest[at + 3..];
            let id = &rest[..rest.find('\'').unwrap()];
            assert!(
                INDEX_HTML.contains(&format!("id=\"{id}\"")),
                "#{id} is not in index.html"
            );
            count += 1;
        }
        assert!(count > 20, "found only {count} ids");
    }

    #[test]
    fn the_token_goes_in_the_websocket_subprotocols_not_the_url() {
        assert!(APP_JS.contains("['gateway.v1', 'bearer.' + view.token]"));
        assert!(!APP_JS.contains("?token="));
        assert!(APP_JS.contains("history.replaceState"));
    }
}
