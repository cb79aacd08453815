//! What the offline commands (`replay`, `eval`) dropped: malformed or mismatched messages are
//! counted per file, topic and reason, like the live node counts them, and every good frame
//! is still processed.

use mode360_io::bag::BagError;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// One kind of drop and how often it happened.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct DropCount {
    pub file: String,
    /// Empty for problems of the whole file (damage).
    pub topic: String,
    pub reason: String,
    pub count: usize,
}

/// Drops counted by file, topic and reason.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct DropTally {
    counts: BTreeMap<(String, String, String), usize>,
}

impl DropTally {
    /// Counts `err` (and logs it once per kind, so a bag of bad messages does not flood the
    /// terminal).
    pub fn record(&mut self, err: &BagError) {
        self.count(err.file(), err.topic().unwrap_or_default(), &err.reason());
    }

    /// Counts one drop of `reason` on `topic` of `file`.
    pub fn count(&mut self, file: &str, topic: &str, reason: &str) {
        let key = (file.to_string(), topic.to_string(), reason.to_string());
        let count = self.counts.entry(key).or_insert(0);
        if *count == 0 {
            tracing::warn!("dropped from {file}, topic '{topic}': {reason}");
        }
        *count += 1;
    }

    /// Messages or frames dropped in all.
    pub fn total(&self) -> usize {
        self.counts.values().sum()
    }

    /// One entry per file, topic and reason.
    pub fn counts(&self) -> Vec<DropCount> {
        self.counts
            .iter()
            .map(|((file, topic, reason), &count)| DropCount {
                file: file.clone(),
                topic: topic.clone(),
                reason: reason.clone(),
                count,
            })
            .collect()
    }

    /// A summary for the terminal: one line per kind, or a line saying nothing was dropped.
    pub fn summary(&self) -> String {
        summary(&self.counts())
    }
}

/// A summary of `counts` for the terminal: one line per kind, or a line saying nothing was
/// dropped.
pub fn summary(counts: &[DropCount]) -> String {
    if counts.is_empty() {
        return "dropped: nothing".into();
    }
    let total: usize = counts.iter().map(|c| c.count).sum();
    let mut out = format!("dropped {total} (file, topic: count x reason):");
    for c in counts {
        let topic = if c.topic.is_empty() {
            "(whole file)"
        } else {
            &c.topic
        };
        out.push_str(&format!(
            "\n  {}, {}: {} x {}",
            c.file, topic, c.count, c.reason
        ));
    }
    out
}
