//! The ROS 2 names a rig carries, checked by [`super::Rig::new`] so that every path to a rig
//! (rig YAML, calibration import, training rigs) gets the same rules.
//!
//! **Topics** follow ROS 2's topic name rules (design.ros2.org, "Topic and Service name
//! mapping to DDS"; rmw's `rmw_validate_full_topic_name`):
//!
//! * not empty, and at most [`MAX_TOPIC_NAME_LEN`] characters (rmw's
//!   `RMW_TOPIC_MAX_NAME_LENGTH`: RTPS's 255 less 8 reserved for the DDS prefix);
//! * only ASCII letters, digits, `_` and `/`;
//! * no `//`, no `/` at the end (so not `/` alone), no `__`;
//! * no token (a part between slashes) starts with a digit.
//!
//! Relative names (`cam1/image_raw`) are allowed: the node resolves them in its namespace. The
//! rules' `~` (private namespace) and `{}` (substitutions) are refused: the node's ROS 2
//! client expands neither, so such a topic would never meet its publisher.
//!
//! **Frame ids** (tf2 has no grammar for them, only a few refusals; these are ours): not empty,
//! at most [`MAX_FRAME_ID_LEN`] characters, no whitespace, no control characters, no quotes
//! (`"`, `'`, `` ` ``), and no `/` at the start (tf2 refuses such ids in lookups: "frame_ids
//! cannot start with a '/'").

/// The longest topic name accepted (rmw's `RMW_TOPIC_MAX_NAME_LENGTH`, 255 - 8).
pub const MAX_TOPIC_NAME_LEN: usize = 247;
/// The longest frame id accepted (tf2 sets none; longer is surely not a frame name).
pub const MAX_FRAME_ID_LEN: usize = 255;
/// How much of an offending name an error message quotes.
const QUOTED_PREFIX_CHARS: usize = 64;

/// `value` for an error message: escaped (newlines, quotes and control characters visible)
/// and cut to its first 64 characters.
pub fn quoted(value: &str) -> String {
    let n = value.chars().count();
    if n <= QUOTED_PREFIX_CHARS {
        format!("{value:?}")
    } else {
        let head: String = value.chars().take(QUOTED_PREFIX_CHARS).collect();
        format!("{head:?}... ({n} characters)")
    }
}

/// `Ok` when `topic` is a ROS 2 topic name the node can subscribe to (the rules in the
/// module docs); otherwise what is wrong, quoting the name.
pub fn validate_topic_name(topic: &str) -> Result<(), String> {
    let bad = |why: String| {
        Err(format!(
            "{} is not a valid ROS 2 topic name: {why}",
            quoted(topic)
        ))
    };
    if topic.is_empty() {
        return Err("empty (a ROS 2 topic name such as /cam1/image_raw)".into());
    }
    let len = topic.chars().count();
    if len > MAX_TOPIC_NAME_LEN {
        return bad(format!(
            "{len} characters, more than ROS 2's {MAX_TOPIC_NAME_LEN}"
        ));
    }
    if let Some((i, c)) = topic
        .chars()
        .enumerate()
        .find(|(_, c)| !(c.is_ascii_alphanumeric() || *c == '_' || *c == '/'))
    {
        let why = match c {
            '~' | '{' | '}' => format!(
                "'{c}' at character {}: private names (~) and substitutions ({{}}) are not expanded by the node; give the full name",
                i + 1
            ),
            _ => format!(
                "character {c:?} at {} (only letters, digits, '_' and '/' are allowed)",
                i + 1
            ),
        };
        return bad(why);
    }
    if topic.contains("//") {
        return bad("it contains '//' (an empty token)".into());
    }
    if topic.ends_with('/') {
        return bad("it ends with '/'".into());
    }
    if topic.contains("__") {
        return bad("it contains '__' (repeated underscores are reserved)".into());
    }
    if let Some(tok) = topic
        .split('/')
        .find(|t| t.starts_with(|c: char| c.is_ascii_digit()))
    {
        return bad(format!("its token '{tok}' starts with a digit"));
    }
    Ok(())
}

/// `Ok` when `frame_id` is a usable tf2 frame id (the rules in the module docs); otherwise
/// what is wrong, quoting the id.
pub fn validate_frame_id(frame_id: &str) -> Result<(), String> {
    let bad = |why: String| {
        Err(format!(
            "{} is not a valid frame id: {why}",
            quoted(frame_id)
        ))
    };
    if frame_id.is_empty() {
        return Err("empty (a tf2 frame id such as cam1_link)".into());
    }
    let len = frame_id.chars().count();
    if len > MAX_FRAME_ID_LEN {
        return bad(format!("{len} characters, more than {MAX_FRAME_ID_LEN}"));
    }
    if let Some((i, c)) = frame_id
        .chars()
        .enumerate()
        .find(|(_, c)| c.is_whitespace() || c.is_control() || matches!(c, '"' | '\'' | '`'))
    {
        return bad(format!(
            "character {c:?} at {} (no whitespace, control characters or quotes)",
            i + 1
        ));
    }
    if frame_id.starts_with('/') {
        return bad("it starts with '/' (tf2 refuses frame ids that do)".into());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topic_names_follow_ros2_rules() {
        for ok in [
            "/cam1/image_raw",
            "cam1/image_raw",
            "/front_left/image_raw",
            "/_hidden/x",
            "/a/b/c9",
            "image",
        ] {
            assert_eq!(validate_topic_name(ok), Ok(()), "{ok}");
        }
        for (bad, why) in [
            ("", "empty"),
            ("/cam 1/image", "' '"),
            ("/cam1/image\n", "'\\n'"),
            ("/cam1/\"image\"", "'\"'"),
            ("/cam1//image", "'//'"),
            ("/cam1/image/", "ends with '/'"),
            ("/", "ends with '/'"),
            ("/1cam/image", "'1cam' starts with a digit"),
            ("2cam", "starts with a digit"),
            ("/cam__1/image", "'__'"),
            ("~/image", "'~'"),
            ("/{node}/image", "'{'"),
            ("/kamera/bild-roh", "'-'"),
            ("/kamera/bild\u{e4}", "'\u{e4}'"),
        ] {
            let e = validate_topic_name(bad).expect_err(bad);
            assert!(e.contains(why), "{bad:?}: '{e}' should say {why}");
        }
        let long = format!("/{}", "a".repeat(MAX_TOPIC_NAME_LEN));
        let e = validate_topic_name(&long).unwrap_err();
        assert!(e.contains("248 characters") && e.contains("247"), "{e}");
        // The quoted name is cut to a prefix.
        assert!(e.len() < 250, "{e}");
    }

    #[test]
    fn frame_ids_have_no_blanks_quotes_or_leading_slash() {
        for ok in [
            "cam1_link",
            "base_link",
            "rack_center",
            "cam0_optical_frame",
            "a/b",
            "x-y.z",
        ] {
            assert_eq!(validate_frame_id(ok), Ok(()), "{ok}");
        }
        for (bad, why) in [
            ("", "empty"),
            ("cam 1", "' '"),
            ("cam1\tlink", "'\\t'"),
            ("cam1\n", "'\\n'"),
            ("\"cam1\"", "'\"'"),
            ("it's", "'\\''"),
            ("/cam1_link", "starts with '/'"),
            ("cam\u{7}", "'\\u{7}'"),
        ] {
            let e = validate_frame_id(bad).expect_err(bad);
            assert!(e.contains(why), "{bad:?}: '{e}' should say {why}");
        }
    }
}
