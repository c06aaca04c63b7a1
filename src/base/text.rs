//! Pieces of user input in error messages: a 40 MB key or header is cut, not copied, into the
//! message. Every layer's errors quote through these.

/// Longest piece of user input (a key, a header, a line) echoed in an error message, in
/// characters: a 40 MB header or key must not be copied into the message.
pub(crate) const EXCERPT_CHARS: usize = 60;

/// The first `max_chars` characters of `text`, or `None` when it is no longer than that.
pub(crate) fn head(text: &str, max_chars: usize) -> Option<&str> {
    text.char_indices()
        .nth(max_chars)
        .map(|(end, _)| &text[..end])
}

/// `text` for an error message: whole up to `max_chars` characters, else its start, `…` and its
/// length (`abc… (40000000 bytes)`).
pub(crate) fn excerpt(text: &str, max_chars: usize) -> String {
    match head(text, max_chars) {
        None => text.to_string(),
        Some(start) => format!("{start}… ({} bytes)", text.len()),
    }
}

/// `text` in `quote`s for an error message: whole up to `max_chars` characters, else its start
/// and `…` inside the quotes and its length after them (`"abc…" (40000000 bytes)`).
pub(crate) fn quoted(text: &str, quote: char, max_chars: usize) -> String {
    match head(text, max_chars) {
        None => format!("{quote}{text}{quote}"),
        Some(start) => format!("{quote}{start}…{quote} ({} bytes)", text.len()),
    }
}

/// A message written by another crate (serde_json's `unknown field `…``, `invalid type: string
/// "…"`) with every quoted piece longer than `max_chars` characters cut as [`quoted`] cuts it,
/// and the whole cut to a few such pieces' length if it is still long.
pub(crate) fn shorten_quoted(message: &str, max_chars: usize) -> String {
    let mut out = String::with_capacity(message.len().min(16 * max_chars));
    let mut rest = message;
    while let Some(open) = rest.find(['`', '"']) {
        let quote = if rest.as_bytes()[open] == b'`' {
            '`'
        } else {
            '"'
        };
        out.push_str(&rest[..open]);
        let inner = &rest[open + 1..];
        // The closing quote; a double-quoted piece (Rust's Debug form) escapes quotes with '\'.
        let mut escaped = false;
        let close = inner.char_indices().find_map(|(i, c)| {
            let found = c == quote && !escaped;
            escaped = quote == '"' && c == '\\' && !escaped;
            found.then_some(i)
        });
        let Some(close) = close else {
            out.push(quote);
            out.push_str(&excerpt(inner, max_chars));
            rest = "";
            break;
        };
        out.push_str(&quoted(&inner[..close], quote, max_chars));
        rest = &inner[close + 1..];
    }
    out.push_str(rest);
    match head(&out, 16 * max_chars) {
        Some(start) => format!("{start}… ({} bytes)", out.len()),
        None => out,
    }
}
