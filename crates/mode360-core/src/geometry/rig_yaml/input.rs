//! What every calibration text (rig YAML, Kalibr camchain, Basalt JSON) passes before a parser
//! sees it: a size limit checked before reading, a UTF-8 byte-order mark dropped, and a bound
//! on flow nesting (`[` and `{`), so that no input can make a parser take long.
//!
//! The YAML parser (libyaml, under serde_yaml) takes time growing with the square of the flow
//! nesting depth: 200,000 nested `[` (400 KB) did not finish in a minute. Two checks bound it:
//!
//! * the nesting depth, counting every `[`/`{` up and every `]`/`}` down (strings and comments
//!   included: a quick scan, not a parser), at most [`MAX_FLOW_DEPTH`];
//! * the number of `[` and `{` in the whole text, at most [`MAX_FLOW_COLLECTIONS`]. The depth
//!   scan can be fooled by closing brackets inside quoted strings; this count cannot, and it
//!   bounds the true depth, so parse time stays small whatever the text.

use std::io::Read;
use std::path::Path;

/// The largest calibration file read, bytes (1 MiB; real ones are a few KB).
pub const MAX_CALIBRATION_FILE_BYTES: u64 = 1 << 20;
/// The deepest flow nesting (`[` / `{`) accepted; calibrations nest 3 deep.
pub const MAX_FLOW_DEPTH: usize = 64;
/// The most `[` and `{` a YAML calibration may hold (about 15 per camera in a Kalibr chain).
pub const MAX_FLOW_COLLECTIONS: usize = 8192;

/// A file refused before parsing.
#[derive(Debug)]
pub(crate) enum ReadError {
    Io(std::io::Error),
    /// The problem, in words.
    Refused(String),
}

fn too_large(bytes: u64) -> String {
    format!(
        "file is {bytes} bytes, more than the {MAX_CALIBRATION_FILE_BYTES}-byte (1 MiB) limit for calibration files"
    )
}

/// The file's text: at most [`MAX_CALIBRATION_FILE_BYTES`] (checked before reading, and while
/// reading for files whose size is not known up front), UTF-8, without a byte-order mark.
pub(crate) fn read_calibration(path: &Path) -> Result<String, ReadError> {
    let f = std::fs::File::open(path).map_err(ReadError::Io)?;
    let len = f.metadata().map_err(ReadError::Io)?.len();
    if len > MAX_CALIBRATION_FILE_BYTES {
        return Err(ReadError::Refused(too_large(len)));
    }
    let mut bytes = Vec::with_capacity(len as usize);
    f.take(MAX_CALIBRATION_FILE_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(ReadError::Io)?;
    if bytes.len() as u64 > MAX_CALIBRATION_FILE_BYTES {
        return Err(ReadError::Refused(format!(
            "file is more than the {MAX_CALIBRATION_FILE_BYTES}-byte (1 MiB) limit for calibration files"
        )));
    }
    let text = String::from_utf8(bytes).map_err(|e| {
        ReadError::Refused(format!(
            "file is not UTF-8 text (invalid byte at offset {})",
            e.utf8_error().valid_up_to()
        ))
    })?;
    Ok(strip_bom(&text).to_string())
}

/// `text` without a leading UTF-8 byte-order mark.
pub(crate) fn strip_bom(text: &str) -> &str {
    text.strip_prefix('\u{feff}').unwrap_or(text)
}

/// `Err` (the problem) when `text` is over the size limit.
pub(crate) fn check_size(text: &str) -> Result<(), String> {
    if text.len() as u64 > MAX_CALIBRATION_FILE_BYTES {
        return Err(too_large(text.len() as u64));
    }
    Ok(())
}

/// `Err` (the problem, with the line and column) when the flow nesting goes deeper than
/// [`MAX_FLOW_DEPTH`]; with `max_collections`, also when there are more `[` and `{` than that.
pub(crate) fn check_nesting(text: &str, max_collections: Option<usize>) -> Result<(), String> {
    let (mut depth, mut opened, mut line, mut col) = (0usize, 0usize, 1usize, 0usize);
    for c in text.chars() {
        col += 1;
        match c {
            '\n' => (line, col) = (line + 1, 0),
            '[' | '{' => {
                depth += 1;
                opened += 1;
                if depth > MAX_FLOW_DEPTH {
                    return Err(format!(
                        "nesting deeper than {MAX_FLOW_DEPTH} '[' or '{{' at line {line} column {col}: refused before parsing (no calibration nests that deep)"
                    ));
                }
                if max_collections.is_some_and(|m| opened > m) {
                    return Err(format!(
                        "more than {} '[' or '{{' (at line {line} column {col}): refused before parsing (a calibration has a few per camera)",
                        max_collections.unwrap_or_default()
                    ));
                }
            }
            ']' | '}' => depth = depth.saturating_sub(1),
            _ => {}
        }
    }
    Ok(())
}

/// The checks for YAML text: size, then nesting with [`MAX_FLOW_COLLECTIONS`].
pub(crate) fn check_yaml(text: &str) -> Result<(), String> {
    check_size(text)?;
    check_nesting(text, Some(MAX_FLOW_COLLECTIONS))
}

/// serde_yaml's message for `e` on `text`, always with a line and column: the scanner's
/// errors that give only a byte position (`control characters are not allowed at position
/// 87`) get the line and column of that byte instead.
pub(crate) fn yaml_error(text: &str, e: &serde_yaml::Error) -> String {
    let message = e.to_string();
    let Some((head, offset)) = message
        .rsplit_once(" at position ")
        .and_then(|(head, n)| Some((head, n.trim().parse::<usize>().ok()?)))
    else {
        return message;
    };
    let before = text.get(..offset.min(text.len())).unwrap_or(text);
    let line = before.matches('\n').count() + 1;
    let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    format!("{head} at line {line} column {column}")
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Instant;

    #[test]
    fn nesting_is_bounded_before_parsing() {
        assert!(check_yaml("a: [1, [2, {b: [3]}]]\nc: '[[['\n").is_ok());
        let deep = format!("cam0: {}", "[".repeat(200_000));
        let e = check_yaml(&deep).unwrap_err();
        assert!(
            e.contains("deeper than 64") && e.contains("line 1 column 71"),
            "{e}"
        );
        // Closing brackets in quoted strings fool the depth count, not the total count.
        let sneaky = format!("a: {}", "[ \"]\", ".repeat(20_000));
        assert!(check_nesting(&sneaky, None).is_ok());
        let e = check_yaml(&sneaky).unwrap_err();
        assert!(e.contains("more than 8192"), "{e}");
        // Neither text reaches the parser, so neither takes long there.
        let t0 = Instant::now();
        assert!(check_yaml(&"[".repeat(1 << 20)).is_err());
        assert!(t0.elapsed().as_secs_f64() < 1.0);
    }

    #[test]
    fn a_byte_position_becomes_a_line_and_column() {
        let text = "a: 1\nb: x\u{0}y\n";
        let e = serde_yaml::from_str::<serde_yaml::Value>(text).unwrap_err();
        assert!(e.to_string().ends_with("at position 9"), "{e}");
        assert_eq!(
            yaml_error(text, &e),
            "control characters are not allowed at line 2 column 5"
        );
        let text = "a: [1\n";
        let e = serde_yaml::from_str::<serde_yaml::Value>(text).unwrap_err();
        assert_eq!(yaml_error(text, &e), e.to_string());
        assert!(yaml_error(text, &e).contains("line 2 column 1"), "{e}");
    }

    #[test]
    fn size_and_bom() {
        assert_eq!(strip_bom("\u{feff}a: 1"), "a: 1");
        assert_eq!(strip_bom("a: 1"), "a: 1");
        let big = "#".repeat(MAX_CALIBRATION_FILE_BYTES as usize + 1);
        assert!(check_size(&big).unwrap_err().contains("1048576-byte"));
    }
}
