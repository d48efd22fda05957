//! Why a configuration could not be used ([`ConfigError`]), and where in the text a TOML parse
//! error is: the parser gives a byte span and a message, `locate` turns them into the key path
//! and line an operator can find.

use std::path::PathBuf;

use crate::problem::Problem;

/// Why a configuration could not be used.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read rig config {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// Not valid TOML, an unknown key, a missing key or a value of the wrong type.
    #[error("{}", parse_message(.origin, .key, .line, .message))]
    Parse {
        /// File path or `<embedded ...>` / `<string>`.
        origin: String,
        /// Best-effort key path of the problem, when it could be located.
        key: Option<String>,
        /// 1-based line of the problem, when known.
        line: Option<usize>,
        /// The parser's own description.
        message: String,
    },
    /// Parsed, but one or more values are unusable.
    #[error("{}", invalid_message(.origin, .problems))]
    Invalid {
        origin: String,
        problems: Vec<Problem>,
    },
}

impl ConfigError {
    /// The key paths this error names (empty for I/O errors).
    pub fn keys(&self) -> Vec<String> {
        match self {
            ConfigError::Io { .. } => Vec::new(),
            ConfigError::Parse { key, .. } => key.iter().cloned().collect(),
            ConfigError::Invalid { problems, .. } => {
                problems.iter().map(|p| p.key.clone()).collect()
            }
        }
    }
}

fn parse_message(
    origin: &str,
    key: &Option<String>,
    line: &Option<usize>,
    message: &str,
) -> String {
    let message = message.trim();
    let at = match line {
        Some(l) => format!("{origin}, line {l}"),
        None => origin.to_owned(),
    };
    match key {
        Some(k) => format!("rig config {at}: {k}: {message}"),
        None => format!("rig config {at}: {message}"),
    }
}

fn invalid_message(origin: &str, problems: &[Problem]) -> String {
    match problems {
        [one] => format!("rig config {origin}: {one}"),
        many => {
            let mut s = format!("rig config {origin}: {} problems:", many.len());
            for p in many {
                s.push_str("\n  ");
                s.push_str(&p.to_string());
            }
            s
        }
    }
}

/// Best-effort key path and line of a parse error spanning `span` of `text`.
///
/// The TOML parser reports a byte span and a message but not the key path; this walks the text
/// up to the span: the last `[table]` header gives the table, an inline table on the error line
/// (`down = { ... }`) adds its key, and either the field named in the message (unknown or missing
/// field) or the key of the line holding the span gives the last part.
pub(super) fn locate(
    text: &str,
    span: std::ops::Range<usize>,
    message: &str,
) -> (Option<String>, Option<usize>) {
    let offset = span.start.min(text.len());
    if !text.is_char_boundary(offset) {
        return (field_in_message(message), None);
    }
    let before = &text[..offset];
    let line_no = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let line_end = text[offset..].find('\n').map_or(text.len(), |i| offset + i);
    let error_line = &text[line_start..line_end];
    let error_is_header = strip_comment(error_line).trim().starts_with('[');

    let mut table = String::new();
    let mut last_key: Option<String> = None;
    for line in text[..line_start]
        .lines()
        .chain(std::iter::once(error_line))
    {
        let t = strip_comment(line).trim();
        if let Some(h) = t.strip_prefix('[') {
            let h = h.trim_start_matches('[');
            if let Some(end) = h.find(']') {
                table = h[..end].trim().to_owned();
                last_key = None;
                continue;
            }
        }
        if let Some(eq) = t.find('=') {
            let k = t[..eq].trim();
            if !k.is_empty() && !k.starts_with('"') && !k.starts_with('[') {
                last_key = Some(k.to_owned());
            }
        }
    }
    // An inline table opened on the error line before the span: `down = { ... }`.
    let prefix = &text[line_start..offset];
    let inline_key = prefix.find('=').and_then(|eq| {
        let rest = text[line_start + eq + 1..].trim_start();
        let key = prefix[..eq].trim();
        (rest.starts_with('{') && !key.is_empty() && !error_is_header).then(|| key.to_owned())
    });

    let join = |a: &str, b: &str| {
        if a.is_empty() {
            b.to_owned()
        } else {
            format!("{a}.{b}")
        }
    };
    let key = if message.contains("unknown field") || message.contains("missing field") {
        let field = field_in_message(message);
        let missing = message.contains("missing field");
        let owner = if missing && span.start == 0 && (span.end == 0 || span.end >= text.len()) {
            // A missing top-level table is reported at the document itself.
            String::new()
        } else if !missing && error_is_header {
            // An unknown table is reported at its own header: its owner is the header's parent.
            table
                .rsplit_once('.')
                .map_or(String::new(), |(parent, _)| parent.to_owned())
        } else {
            match &inline_key {
                Some(k) => join(&table, k),
                None => table.clone(),
            }
        };
        field.map(|f| join(&owner, &f))
    } else {
        last_key
            .map(|k| join(&table, &k))
            .or((!table.is_empty()).then_some(table))
    };
    (key, Some(line_no))
}

fn strip_comment(line: &str) -> &str {
    // Good enough for locating keys: a '#' inside a string value only shortens the value part.
    line.find('#').map_or(line, |i| &line[..i])
}

/// The first `` `name` `` in a serde message ("unknown field `foo`, expected ...").
pub(super) fn field_in_message(message: &str) -> Option<String> {
    let start = message.find('`')? + 1;
    let len = message[start..].find('`')?;
    Some(message[start..start + len].to_owned())
}
