//! Percent-decoding (RFC 3986, section 2.1: `%` and two hex digits stand for one octet), through
//! the `percent-encoding` crate; the decoded octets must be UTF-8 (section 2.5) to name a file.

use percent_encoding::percent_decode_str;
use std::borrow::Cow;

/// `s` with its `%XX` escapes decoded, or `None` when the result is not UTF-8. A `%` not followed
/// by two hex digits stays a literal `%`, as browsers send and read it.
pub fn decode(s: &str) -> Option<Cow<'_, str>> {
    percent_decode_str(s).decode_utf8().ok()
}

/// [`decode`], but `None` also for a `%` not followed by two hex digits: section 2.1 allows no
/// other use of `%`, so a file that writes one is malformed rather than naming a literal `%`.
pub fn decode_strict(s: &str) -> Option<Cow<'_, str>> {
    let b = s.as_bytes();
    let well_formed = b
        .iter()
        .enumerate()
        .filter(|(_, &c)| c == b'%')
        .all(|(i, _)| {
            b.get(i + 1..i + 3)
                .is_some_and(|h| h.iter().all(u8::is_ascii_hexdigit))
        });
    well_formed.then(|| decode(s)).flatten()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escapes_decode() {
        assert_eq!(decode("a%20b.png").unwrap(), "a b.png");
        assert_eq!(decode("%2e%2E").unwrap(), "..");
        assert_eq!(decode("%C3%A9").unwrap(), "é");
        assert_eq!(decode("plain").unwrap(), "plain");
        // Decoded once only: a double encoding stays an escape.
        assert_eq!(decode("%252e").unwrap(), "%2e");
        assert_eq!(decode_strict("a%20b.png").unwrap(), "a b.png");
        assert_eq!(decode_strict("%252e").unwrap(), "%2e");
    }

    #[test]
    fn malformed_escapes_are_literal_unless_strict() {
        assert_eq!(decode("%zz.bin").unwrap(), "%zz.bin");
        assert_eq!(decode("100%").unwrap(), "100%");
        assert!(decode_strict("%zz.bin").is_none());
        assert!(decode_strict("100%").is_none());
        assert!(decode_strict("%2").is_none());
        assert!(decode_strict("%+f").is_none());
    }

    #[test]
    fn not_utf8_is_refused() {
        assert!(decode("%ff%fe").is_none());
        assert!(decode_strict("%ff%fe").is_none());
    }
}
