//! Echoing outside input in error messages.
//!
//! Ess reports bad input in one line. A name, key or id that a user or a gRPC client
//! sent may hold a newline or a terminal escape, so an error that quotes it shows its
//! control characters escaped (`\n`, `\u{1b}`); everything else, quotes included, is
//! shown as it was given.

use std::borrow::Cow;

/// `s` with each control character written as its Rust escape.
pub fn printable(s: &str) -> Cow<'_, str> {
    if !s.chars().any(char::is_control) {
        return Cow::Borrowed(s);
    }
    let mut out = String::with_capacity(s.len() + 8);
    for c in s.chars() {
        if c.is_control() {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    Cow::Owned(out)
}

#[cfg(test)]
mod tests {
    use super::printable;

    #[test]
    fn control_characters_are_escaped_and_the_rest_kept() {
        assert_eq!(printable("run.iterations"), "run.iterations");
        assert_eq!(printable("\"fast\" ünï"), "\"fast\" ünï");
        assert_eq!(printable("gai\n"), "gai\\n");
        assert_eq!(printable("a\r\tb\u{1b}[31m"), "a\\r\\tb\\u{1b}[31m");
    }
}
