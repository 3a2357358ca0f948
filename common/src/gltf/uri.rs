//! URI handling for buffers and images: `data:` URIs are decoded in place, everything else must
//! be a relative reference that stays inside the scene's folder or bundle; it is percent-decoded
//! and normalised into a `/`-separated path before any [`Resolver`](super::Resolver) sees it.

use base64::engine::{DecodePaddingMode, GeneralPurpose, GeneralPurposeConfig};
use base64::Engine as _;

/// Where the bytes of a buffer or an image come from.
#[derive(Debug, PartialEq)]
pub(crate) enum Source {
    /// The decoded payload of a `data:` URI.
    Data(Vec<u8>),
    /// A normalised relative path: `/`-separated, percent-decoded, no `.`, `..` or empty parts.
    File(String),
}

/// Classifies a URI. The error says what is wrong with it (without naming the object; the caller
/// prefixes that).
pub(crate) fn classify(uri: &str) -> Result<Source, String> {
    if let Some(rest) = strip_prefix_ignore_case(uri, "data:") {
        return decode_data_uri(rest).map(Source::Data);
    }
    if let Some(scheme) = scheme_of(uri) {
        return Err(format!(
            "URI '{}' has scheme '{scheme}:'; only data: URIs and paths relative to the scene are allowed",
            shorten(uri)
        ));
    }
    // A relative reference: drop the query and the fragment, then percent-decode the path.
    let path = uri.split(['?', '#']).next().unwrap_or("");
    let decoded =
        percent_decode(path.as_bytes()).map_err(|e| format!("URI '{}': {e}", shorten(uri)))?;
    let decoded = String::from_utf8(decoded)
        .map_err(|_| format!("URI '{}' is not valid UTF-8 once percent-decoded", shorten(uri)))?;
    normalize_relative(&decoded).map(Source::File)
}

/// Normalises a relative path: rejects absolute paths, drive letters, NUL bytes and any `..`
/// that would leave the folder; removes `.` and empty parts. Backslashes count as separators.
pub(crate) fn normalize_relative(path: &str) -> Result<String, String> {
    if path.is_empty() {
        return Err("empty URI".into());
    }
    if path.starts_with('/') || path.starts_with('\\') {
        return Err(format!(
            "URI '{}' is an absolute path; only relative paths are allowed",
            shorten(path)
        ));
    }
    if path.contains('\0') {
        return Err(format!("URI '{}' contains a NUL byte", shorten(path)));
    }
    let mut parts: Vec<&str> = Vec::new();
    for part in path.split(['/', '\\']) {
        match part {
            "" | "." => {}
            ".." => {
                if parts.pop().is_none() {
                    return Err(format!("URI '{}' escapes the scene folder", shorten(path)));
                }
            }
            p if p.contains(':') => {
                return Err(format!(
                    "URI '{}' contains ':' in a path segment (drive letter or stream name)",
                    shorten(path)
                ));
            }
            p => parts.push(p),
        }
    }
    if parts.is_empty() {
        return Err(format!("URI '{}' names no file", shorten(path)));
    }
    Ok(parts.join("/"))
}

/// The URI scheme (RFC 3986: ALPHA *( ALPHA / DIGIT / "+" / "-" / "." ) ":"), if any.
fn scheme_of(uri: &str) -> Option<&str> {
    let colon = uri.find(':')?;
    let scheme = &uri[..colon];
    // A ':' after the first '/', '?' or '#' is part of the path, not a scheme.
    if scheme.contains(['/', '?', '#']) {
        return None;
    }
    let mut chars = scheme.chars();
    let first = chars.next()?;
    // Anything else with a ':' in its first segment is rejected by `normalize_relative`.
    (first.is_ascii_alphabetic() && chars.all(|c| c.is_ascii_alphanumeric() || "+-.".contains(c)))
        .then_some(scheme)
}

fn strip_prefix_ignore_case<'s>(s: &'s str, prefix: &str) -> Option<&'s str> {
    let head = s.get(..prefix.len())?;
    head.eq_ignore_ascii_case(prefix).then(|| &s[prefix.len()..])
}

/// Decodes what follows `data:`: `[<mediatype>][;base64],<data>`.
fn decode_data_uri(rest: &str) -> Result<Vec<u8>, String> {
    let comma = rest.find(',').ok_or("data URI has no ',' before its payload")?;
    let (header, payload) = (&rest[..comma], &rest[comma + 1..]);
    let is_base64 = header.split(';').any(|p| p.trim().eq_ignore_ascii_case("base64"));
    if is_base64 {
        let cleaned: Vec<u8> = if payload.contains('%') {
            percent_decode(payload.as_bytes())?
        } else {
            payload.as_bytes().to_vec()
        };
        let cleaned: Vec<u8> = cleaned.into_iter().filter(|b| !b.is_ascii_whitespace()).collect();
        let engine = GeneralPurpose::new(
            &base64::alphabet::STANDARD,
            GeneralPurposeConfig::new()
                .with_decode_padding_mode(DecodePaddingMode::Indifferent)
                .with_decode_allow_trailing_bits(true),
        );
        engine.decode(&cleaned).map_err(|e| format!("bad base64 in data URI: {e}"))
    } else {
        percent_decode(payload.as_bytes())
    }
}

/// Percent-decodes bytes; a '%' not followed by two hex digits is an error.
pub(crate) fn percent_decode(s: &[u8]) -> Result<Vec<u8>, String> {
    let mut out = Vec::with_capacity(s.len());
    let mut i = 0;
    while i < s.len() {
        if s[i] == b'%' {
            let hex = |b: u8| (b as char).to_digit(16);
            match (s.get(i + 1).copied().and_then(hex), s.get(i + 2).copied().and_then(hex)) {
                (Some(h), Some(l)) => out.push((h * 16 + l) as u8),
                _ => return Err(format!("bad percent-encoding at byte {i}")),
            }
            i += 3;
        } else {
            out.push(s[i]);
            i += 1;
        }
    }
    Ok(out)
}

/// A URI cut short for messages (data URIs can be megabytes).
pub(crate) fn shorten(uri: &str) -> String {
    const MAX: usize = 80;
    if uri.len() <= MAX {
        return uri.to_string();
    }
    let mut end = MAX;
    while !uri.is_char_boundary(end) {
        end -= 1;
    }
    format!("{}...", &uri[..end])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_paths_are_normalised() {
        assert_eq!(classify("a.bin"), Ok(Source::File("a.bin".into())));
        assert_eq!(classify("./sub/../b%20c.bin"), Ok(Source::File("b c.bin".into())));
        assert_eq!(classify("sub/x.png?v=2#frag"), Ok(Source::File("sub/x.png".into())));
        assert_eq!(classify("sub\\x.png"), Ok(Source::File("sub/x.png".into())));
    }

    #[test]
    fn escapes_and_schemes_are_rejected() {
        for bad in [
            "../x.bin",
            "a/../../x.bin",
            "%2e%2e/x.bin",
            "/etc/passwd",
            "\\x.bin",
            "C:/x.bin",
            "c:x.bin",
            "file:///etc/passwd",
            "http://example.com/x.bin",
            "a/%00.bin",
            "",
            ".",
            "a%2",
        ] {
            assert!(classify(bad).is_err(), "{bad:?} was accepted");
        }
    }

    #[test]
    fn data_uris_decode() {
        assert_eq!(
            classify("data:application/octet-stream;base64,AAEC"),
            Ok(Source::Data(vec![0, 1, 2]))
        );
        assert_eq!(classify("DATA:;base64,AAE"), Ok(Source::Data(vec![0, 1])));
        assert_eq!(classify("data:,a%20b"), Ok(Source::Data(b"a b".to_vec())));
        assert!(classify("data:application/octet-stream;base64,A*=").is_err());
        assert!(classify("data:application/octet-stream;base64").is_err());
    }
}
