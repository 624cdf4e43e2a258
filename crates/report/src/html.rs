//! Escaping for the three languages data reaches in the report: HTML text and attributes, URL
//! paths in `src` attributes, and JSON inside JavaScript; and the page's Content-Security-Policy.
//!
//! Everything that comes from data (file names, warnings, paths, the workspace's own path in the
//! title) goes through one of these, so that a photo named `<img src=x onerror=…>.jpg` is text.

use base64::Engine;
use sha2::{Digest, Sha256};

/// `s` as HTML text or as a quoted attribute value: the five characters that can end either.
pub fn esc(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// A relative path (with `/` between its parts) as a URL path for `src`, percent-encoded, then
/// escaped for an attribute: a file named `a#b?.png` or `%41.png` still names itself, and no
/// name becomes a scheme (`javascript:…` is a relative path `javascript%3A…`).
pub fn url_path(rel: &str) -> String {
    let mut out = String::with_capacity(rel.len());
    for b in rel.bytes() {
        if b.is_ascii_alphanumeric() || b"/-_.~".contains(&b) {
            out.push(b as char);
        } else {
            out.push_str(&format!("%{b:02X}"));
        }
    }
    esc(&out)
}

/// JSON for a JavaScript file or a `<script>` element: `serde_json` leaves `<`, `>`, `&` and
/// the line separators U+2028/U+2029 as they are; here they are `\u` escapes, so that no string
/// can end a script element (`</script>`), open a comment (`<!--`) or, in an older engine, a
/// line. These characters occur in JSON only inside strings, where the escape means the same.
pub fn js_json(v: &serde_json::Value) -> String {
    let s = v.to_string();
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '<' => out.push_str("\\u003c"),
            '>' => out.push_str("\\u003e"),
            '&' => out.push_str("\\u0026"),
            '\u{2028}' => out.push_str("\\u2028"),
            '\u{2029}' => out.push_str("\\u2029"),
            c => out.push(c),
        }
    }
    out
}

/// The CSP hash source of an inline `<style>` or `<script>` whose text is `body`.
pub fn sha256_source(body: &str) -> String {
    let digest = Sha256::digest(body.as_bytes());
    format!(
        "'sha256-{}'",
        base64::engine::general_purpose::STANDARD.encode(digest)
    )
}

/// The page's Content-Security-Policy: nothing from the network, no plugins, no forms, no
/// `<base>`; scripts from the page's own files (`report/scene.js`) and the inline viewer by its
/// hash; the inline stylesheet by its hash; images from the page's files and `data:` (the
/// mesh atlas); videos from the page's files. Opened from `file://`, `'self'` is the local files
/// (Chromium); no inline event handler or `javascript:` URL runs.
pub fn content_security_policy(style: &str, script: &str) -> String {
    format!(
        "default-src 'none'; script-src 'self' {js}; style-src {css}; img-src 'self' data:; \
         media-src 'self'; connect-src 'none'; object-src 'none'; base-uri 'none'; form-action 'none'",
        js = sha256_source(script),
        css = sha256_source(style),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escapes_what_ends_text_attributes_urls_and_scripts() {
        assert_eq!(
            esc(r#"<img src=x onerror="a('&')">"#),
            "&lt;img src=x onerror=&quot;a(&#39;&amp;&#39;)&quot;&gt;"
        );
        assert_eq!(
            url_path("dense/preview/a b#c?d%\"é.png"),
            "dense/preview/a%20b%23c%3Fd%25%22%C3%A9.png"
        );
        assert_eq!(url_path("javascript:x"), "javascript%3Ax");
        let v = serde_json::json!({"n": "</script><!--\u{2028}\u{2029}&\"'"});
        let s = js_json(&v);
        assert!(!s.contains('<') && !s.contains('\u{2028}') && !s.contains('\u{2029}'));
        assert_eq!(serde_json::from_str::<serde_json::Value>(&s).unwrap(), v);
    }

    #[test]
    fn hash_sources_are_base64_sha256() {
        // echo -n 'alert(1)' | openssl dgst -sha256 -binary | base64
        assert_eq!(
            sha256_source("alert(1)"),
            "'sha256-bhHHL3z2vDgxUt0W3dWQOrprscmda2Y5pLsLg4GF+pI='"
        );
    }
}
