//! The log output of every command: lines cut to [`MAX_LOG_LINE_BYTES`] (log messages may
//! quote untrusted text, such as a WebSocket client's message) and repeated warnings and errors
//! from one place in the code limited to [`MAX_EVENTS_PER_WINDOW`] per [`RATE_WINDOW`] (a client that
//! reconnects in a loop would otherwise write a line per attempt), with a count of what was
//! left out once the window ends.

use std::collections::HashMap;
use std::io::Write;
use std::sync::Mutex;
use std::time::{Duration, Instant};
use tracing::callsite::Identifier;
use tracing_subscriber::fmt::MakeWriter;

/// Longest log line written, bytes; longer lines end in `… (N bytes cut)`.
pub const MAX_LOG_LINE_BYTES: usize = 512;
/// Events of one callsite written per window at most.
pub const MAX_EVENTS_PER_WINDOW: u32 = 5;
/// The rate-limit window.
pub const RATE_WINDOW: Duration = Duration::from_secs(10);

/// `line` cut to [`MAX_LOG_LINE_BYTES`] (at a character boundary), newline kept.
pub fn cut_line(line: &str) -> String {
    let body = line.strip_suffix('\n').unwrap_or(line);
    if body.len() <= MAX_LOG_LINE_BYTES {
        return line.to_string();
    }
    let keep = (0..=MAX_LOG_LINE_BYTES)
        .rev()
        .find(|&k| body.is_char_boundary(k))
        .unwrap_or(0);
    let newline = if line.ends_with('\n') { "\n" } else { "" };
    format!(
        "{}… ({} bytes cut){newline}",
        &body[..keep],
        body.len() - keep
    )
}

/// Writes each log line to stderr cut by [`cut_line`].
#[derive(Clone, Copy, Debug, Default)]
pub struct CutLines;

/// One formatted event, cut when written.
pub struct CutLineWriter(Vec<u8>);

impl Write for CutLineWriter {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Drop for CutLineWriter {
    fn drop(&mut self) {
        let text = String::from_utf8_lossy(&self.0);
        let _ = std::io::stderr().write_all(cut_line(&text).as_bytes());
    }
}

impl<'a> MakeWriter<'a> for CutLines {
    type Writer = CutLineWriter;
    fn make_writer(&'a self) -> Self::Writer {
        CutLineWriter(Vec::new())
    }
}

/// Per key (a callsite): the window's start, events seen in it.
pub struct RateLimit<K> {
    windows: Mutex<HashMap<K, (Instant, u32)>>,
}

impl<K> Default for RateLimit<K> {
    fn default() -> Self {
        Self {
            windows: Mutex::new(HashMap::new()),
        }
    }
}

/// The rate limit of log events, by callsite.
pub type CallsiteRateLimit = RateLimit<Identifier>;

impl<K: std::hash::Hash + Eq> RateLimit<K> {
    /// Whether an event of `callsite` at `now` is written; at a new window, how many of the
    /// last one were left out is reported once.
    pub fn allow(&self, callsite: K, now: Instant) -> bool {
        let mut windows = self.windows.lock().unwrap_or_else(|e| e.into_inner());
        let entry = windows.entry(callsite).or_insert((now, 0));
        if now.duration_since(entry.0) >= RATE_WINDOW {
            if entry.1 > MAX_EVENTS_PER_WINDOW {
                eprintln!(
                    "(log: {} repeats of a message were left out in {} s)",
                    entry.1 - MAX_EVENTS_PER_WINDOW,
                    RATE_WINDOW.as_secs()
                );
            }
            *entry = (now, 0);
        }
        entry.1 += 1;
        entry.1 <= MAX_EVENTS_PER_WINDOW
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_lines_are_cut_with_the_count() {
        let long = format!("ERROR unknown op {}\n", "x".repeat(1_000_000));
        let cut = cut_line(&long);
        assert!(cut.len() < MAX_LOG_LINE_BYTES + 40, "{}", cut.len());
        assert!(cut.ends_with("bytes cut)\n"), "{}", &cut[cut.len() - 30..]);
        assert_eq!(cut_line("short\n"), "short\n");
        let accents = "é".repeat(MAX_LOG_LINE_BYTES);
        assert!(cut_line(&accents).starts_with('é'));
    }

    #[test]
    fn a_repeated_event_is_written_five_times_a_window() {
        let limit = RateLimit::<&str>::default();
        let t0 = Instant::now();
        let written = (0..1000).filter(|_| limit.allow("here", t0)).count();
        assert_eq!(written, MAX_EVENTS_PER_WINDOW as usize);
        assert!(
            limit.allow("elsewhere", t0),
            "another callsite has its own count"
        );
        assert!(
            limit.allow("here", t0 + RATE_WINDOW),
            "a new window writes again"
        );
    }
}
