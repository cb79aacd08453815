//! Approximate-time synchronization of N camera streams (pure logic, no DDS).
//!
//! Policy: every stream keeps a bounded queue of messages ordered by header stamp. While every
//! *active* stream has a message, look at the earliest message of each:
//!
//! * if their stamps span at most `tolerance_ns`, they form a group (all are removed);
//! * otherwise the earliest of them can never join a group (every other stream's messages are
//!   later than its head, which is already too late) and is dropped.
//!
//! A stream whose newest stamp goes backwards rejects that message (out of order). A queue
//! longer than `queue_size` drops its oldest message. Inactive streams (e.g. a camera that fell
//! silent) are not waited for; their messages still join a group when they match.

use std::collections::VecDeque;

/// Synchronizer settings.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SyncConfig {
    /// Largest spread of stamps inside one group, nanoseconds.
    pub tolerance_ns: u64,
    /// Messages kept per stream while waiting for partners.
    pub queue_size: usize,
}

impl Default for SyncConfig {
    fn default() -> Self {
        Self {
            tolerance_ns: 10_000_000,
            queue_size: 5,
        }
    }
}

/// A message the synchronizer refused.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SyncError {
    #[error(
        "stream {stream}: stamp {stamp_ns} ns is older than the previous message ({last_ns} ns)"
    )]
    OutOfOrder {
        stream: usize,
        stamp_ns: u64,
        last_ns: u64,
    },
    #[error("stream {stream} does not exist ({count} streams)")]
    NoSuchStream { stream: usize, count: usize },
}

/// A synchronized group: one slot per stream, `None` for streams that were inactive.
#[derive(Clone, Debug, PartialEq)]
pub struct SyncGroup<T> {
    /// The group's stamp: the earliest stamp in it, nanoseconds.
    pub stamp_ns: u64,
    pub messages: Vec<Option<(u64, T)>>,
}

/// Counters for diagnostics.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SyncStats {
    pub groups: u64,
    /// Messages dropped because no partner matched them.
    pub unmatched: u64,
    /// Messages dropped because a queue overflowed.
    pub overflow: u64,
    pub out_of_order: u64,
}

/// Approximate-time synchronizer over a fixed number of streams.
#[derive(Clone, Debug)]
pub struct ApproxTimeSync<T> {
    config: SyncConfig,
    queues: Vec<VecDeque<(u64, T)>>,
    last_stamp_ns: Vec<Option<u64>>,
    active: Vec<bool>,
    stats: SyncStats,
}

impl<T> ApproxTimeSync<T> {
    pub fn new(streams: usize, config: SyncConfig) -> Self {
        Self {
            config,
            queues: (0..streams).map(|_| VecDeque::new()).collect(),
            last_stamp_ns: vec![None; streams],
            active: vec![true; streams],
            stats: SyncStats::default(),
        }
    }

    pub fn stats(&self) -> SyncStats {
        self.stats
    }

    /// Marks a stream as waited for (`true`) or not. Returns groups that became complete.
    pub fn set_active(&mut self, stream: usize, active: bool) -> Vec<SyncGroup<T>> {
        if let Some(a) = self.active.get_mut(stream) {
            *a = active;
        }
        self.drain()
    }

    pub fn is_active(&self, stream: usize) -> bool {
        self.active.get(stream).copied().unwrap_or(false)
    }

    /// Adds a message; returns the groups it completed (usually zero or one).
    pub fn push(
        &mut self,
        stream: usize,
        stamp_ns: u64,
        msg: T,
    ) -> Result<Vec<SyncGroup<T>>, SyncError> {
        let count = self.queues.len();
        let last = self
            .last_stamp_ns
            .get_mut(stream)
            .ok_or(SyncError::NoSuchStream { stream, count })?;
        if let Some(last_ns) = *last {
            if stamp_ns < last_ns {
                self.stats.out_of_order += 1;
                return Err(SyncError::OutOfOrder {
                    stream,
                    stamp_ns,
                    last_ns,
                });
            }
        }
        *last = Some(stamp_ns);
        let q = &mut self.queues[stream];
        q.push_back((stamp_ns, msg));
        while q.len() > self.config.queue_size.max(1) {
            q.pop_front();
            self.stats.overflow += 1;
        }
        Ok(self.drain())
    }

    fn drain(&mut self) -> Vec<SyncGroup<T>> {
        let mut out = Vec::new();
        loop {
            let active: Vec<usize> = (0..self.queues.len()).filter(|&i| self.active[i]).collect();
            if active.is_empty() || active.iter().any(|&i| self.queues[i].is_empty()) {
                return out;
            }
            let heads = active.iter().map(|&i| (self.queues[i][0].0, i));
            let (min_ns, min_i) = heads.clone().min().unwrap_or((0, 0));
            let max_ns = heads.map(|(s, _)| s).max().unwrap_or(0);
            if max_ns - min_ns > self.config.tolerance_ns {
                self.queues[min_i].pop_front();
                self.stats.unmatched += 1;
                continue;
            }
            // Inactive streams join with their best-matching message, if one is in tolerance.
            let messages = (0..self.queues.len())
                .map(|i| {
                    if self.active[i] {
                        return self.queues[i].pop_front();
                    }
                    let q = &mut self.queues[i];
                    let pos = q.iter().position(|(s, _)| {
                        s.abs_diff(min_ns) <= self.config.tolerance_ns
                            && s.abs_diff(max_ns) <= self.config.tolerance_ns
                    })?;
                    q.drain(..pos).for_each(drop);
                    q.pop_front()
                })
                .collect();
            self.stats.groups += 1;
            out.push(SyncGroup {
                stamp_ns: min_ns,
                messages,
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn sync(n: usize) -> ApproxTimeSync<&'static str> {
        ApproxTimeSync::new(
            n,
            SyncConfig {
                tolerance_ns: 5 * MS,
                queue_size: 3,
            },
        )
    }

    #[test]
    fn groups_messages_within_tolerance() {
        let mut s = sync(3);
        assert!(s.push(0, 100 * MS, "a0").unwrap().is_empty());
        assert!(s.push(1, 102 * MS, "b0").unwrap().is_empty());
        let g = s.push(2, 104 * MS, "c0").unwrap();
        assert_eq!(g.len(), 1);
        assert_eq!(g[0].stamp_ns, 100 * MS);
        let names: Vec<_> = g[0].messages.iter().map(|m| m.unwrap().1).collect();
        assert_eq!(names, ["a0", "b0", "c0"]);
        assert_eq!(s.stats().groups, 1);
    }

    #[test]
    fn drops_messages_that_can_never_match() {
        let mut s = sync(2);
        s.push(0, 0, "a0").unwrap();
        s.push(0, 100 * MS, "a1").unwrap();
        let g = s.push(1, 98 * MS, "b0").unwrap();
        assert_eq!(g.len(), 1);
        assert_eq!(g[0].messages[0].unwrap().1, "a1");
        assert_eq!(s.stats().unmatched, 1);
    }

    #[test]
    fn out_of_order_is_rejected_and_queue_is_bounded() {
        let mut s = sync(2);
        s.push(0, 50 * MS, "a").unwrap();
        assert_eq!(
            s.push(0, 40 * MS, "late"),
            Err(SyncError::OutOfOrder {
                stream: 0,
                stamp_ns: 40 * MS,
                last_ns: 50 * MS
            })
        );
        for k in 0..10 {
            s.push(0, (60 + k) * MS, "x").unwrap();
        }
        assert_eq!(s.stats().overflow, 8);
        assert!(matches!(
            s.push(5, 0, "?"),
            Err(SyncError::NoSuchStream { .. })
        ));
    }

    #[test]
    fn inactive_stream_is_not_waited_for_and_returns() {
        let mut s = sync(3);
        s.set_active(2, false);
        s.push(0, 10 * MS, "a").unwrap();
        let g = s.push(1, 11 * MS, "b").unwrap();
        assert_eq!(g.len(), 1);
        assert!(g[0].messages[2].is_none());
        // Back again: it joins when it matches.
        s.set_active(2, true);
        s.push(0, 20 * MS, "a").unwrap();
        s.push(1, 21 * MS, "b").unwrap();
        let g = s.push(2, 22 * MS, "c").unwrap();
        assert_eq!(g[0].messages.iter().filter(|m| m.is_some()).count(), 3);
    }
}
