//! Approximate-time synchronization of N camera streams (pure logic, no DDS).
//!
//! Grouping policy: every stream keeps a bounded queue of messages ordered by header stamp.
//! While every *active* stream has a message, look at the earliest message of each:
//!
//! * if their stamps span at most `tolerance_ns`, they form a group (all are removed);
//! * otherwise the earliest of them can never join a group (every other stream's messages are
//!   later than its head, which is already too late) and is dropped.
//!
//! A queue longer than `queue_size` drops its oldest message. Inactive streams (e.g. a camera
//! that fell silent) are not waited for; their messages still join a group when they match.
//!
//! Time policy: each stream has a *clock*, `last_ns`, the stamp of its newest accepted
//! message. A message stamped `t` on a stream is judged before it is queued:
//!
//! * **Small reorder**, `last_ns - reset_jump_ns <= t < last_ns`: rejected as
//!   [`SyncError::OutOfOrder`] (counted in [`SyncStats::out_of_order`]).
//! * **Jump back**, `t < last_ns - reset_jump_ns`: the clock was reset (a simulator or clock
//!   reset, a restarted driver, `ros2 bag play --loop`, a bag played twice). Every queue and
//!   every stream's clock is cleared, the message is accepted as the first of the new epoch,
//!   [`SyncStats::resets`] counts it and [`Pushed::reset`] reports it once to the caller. The
//!   queued messages it discards count as [`SyncStats::unmatched`]. Because every clock is
//!   cleared, when all cameras jump back together (a looped bag) the first camera's jump resets
//!   and the others' older stamps are then plain first messages: groups resume at once; an
//!   image of the old epoch delivered after the reset is far ahead (below) and dropped. A loop
//!   shorter than `reset_jump_ns` cannot be told from a reorder: its stamps stay out of order.
//! * **Far ahead**: with `margin = max(max_ahead_ns, tolerance_ns)`, `t` is far ahead when
//!   `t > receipt_ns + margin` (the receive time, when the caller passes one) or
//!   `t > max(last_ns of the other streams) + margin` (when any other stream has a clock, and
//!   either the caller passes no receive time or the stream has no clock yet: its first message
//!   at start or after a reset). Such a message is rejected as [`SyncError::Ahead`] (counted in
//!   [`SyncStats::ahead`]) and does not move the stream's clock, so one image stamped an hour
//!   (or until 2038) ahead costs that image only. Where a receive time is known the other
//!   streams bound only a first message: stamps of a bag from the past lie far behind the
//!   receive time, and when every camera steps forward together (a gap in the bag) the first
//!   camera to step must not be taken for a runaway; a single camera's stray stamp there costs
//!   one reset (its next stamp jumps back) instead of one image.
//!   Two exceptions keep a stream that really lives ahead from being starved:
//!   - `t <= last_ns + margin`: the stream continues its own accepted clock (e.g. the only
//!     camera still sending while the others' clocks are stale);
//!   - the [`AHEAD_STAMPS_TO_FOLLOW`]-th consecutive far-ahead message of a stream, each
//!     stamped no earlier than the one before, is accepted: time really moved forward (a
//!     forward clock step, a gap in a bag played faster than real time, a camera clock that
//!     runs ahead of the receiver's). A stray far-ahead stamp is followed by a normal one,
//!     which breaks the run.
//!
//! Messages a stream has queued are not revisited when time is judged; only the clocks are.

use std::collections::VecDeque;

/// Default of [`SyncConfig::max_ahead_ns`]: one second.
pub const DEFAULT_MAX_AHEAD_NS: u64 = 1_000_000_000;
/// Default of [`SyncConfig::reset_jump_ns`]: one second.
pub const DEFAULT_RESET_JUMP_NS: u64 = 1_000_000_000;
/// Default of [`SyncConfig::tolerance_ns`]: 10 ms.
pub const DEFAULT_TOLERANCE_NS: u64 = 10_000_000;
/// Default of [`SyncConfig::queue_size`].
pub const DEFAULT_QUEUE_SIZE: usize = 5;
/// Consecutive far-ahead messages of one stream (stamps non-decreasing) after which the last
/// of them is accepted and the stream's clock follows (see the module's time policy).
pub const AHEAD_STAMPS_TO_FOLLOW: u32 = 3;

/// Synchronizer settings. The time limits have serde defaults, so settings written before
/// they existed still load.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SyncConfig {
    /// Largest spread of stamps inside one group, nanoseconds.
    pub tolerance_ns: u64,
    /// Messages kept per stream while waiting for partners.
    pub queue_size: usize,
    /// A stamp later than the receive time or the other streams' newest stamps by more than
    /// this (or than `tolerance_ns`, whichever is larger) is dropped as far ahead, nanoseconds.
    #[serde(default = "default_max_ahead_ns")]
    pub max_ahead_ns: u64,
    /// A stamp earlier than its stream's newest by more than this resets the synchronizer
    /// (a smaller step back is an out-of-order drop), nanoseconds.
    #[serde(default = "default_reset_jump_ns")]
    pub reset_jump_ns: u64,
}

fn default_max_ahead_ns() -> u64 {
    DEFAULT_MAX_AHEAD_NS
}

fn default_reset_jump_ns() -> u64 {
    DEFAULT_RESET_JUMP_NS
}

impl Default for SyncConfig {
    fn default() -> Self {
        Self {
            tolerance_ns: DEFAULT_TOLERANCE_NS,
            queue_size: DEFAULT_QUEUE_SIZE,
            max_ahead_ns: DEFAULT_MAX_AHEAD_NS,
            reset_jump_ns: DEFAULT_RESET_JUMP_NS,
        }
    }
}

/// What a far-ahead stamp was compared with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TimeReference {
    /// The receive time the caller passed.
    Receipt,
    /// The newest accepted stamp of the other streams.
    OtherStreams,
}

impl std::fmt::Display for TimeReference {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Receipt => "the receive time",
            Self::OtherStreams => "the other cameras' newest stamp",
        })
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
    #[error(
        "stream {stream}: stamp {stamp_ns} ns is {:.3} s ahead of {reference} ({reference_ns} ns)",
        seconds(stamp_ns.saturating_sub(*reference_ns))
    )]
    Ahead {
        stream: usize,
        stamp_ns: u64,
        reference: TimeReference,
        reference_ns: u64,
    },
    #[error("stream {stream} does not exist ({count} streams)")]
    NoSuchStream { stream: usize, count: usize },
}

fn seconds(ns: u64) -> f64 {
    ns as f64 / 1e9
}

/// A reset of the synchronizer: a stream's stamp jumped back by more than `reset_jump_ns`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ClockReset {
    /// The stream whose stamp jumped back.
    pub stream: usize,
    /// Its newest stamp before the jump, nanoseconds.
    pub last_ns: u64,
    /// The stamp that jumped back (accepted as the first of the new epoch), nanoseconds.
    pub stamp_ns: u64,
    /// Queued messages of all streams discarded by the reset.
    pub discarded: usize,
}

impl ClockReset {
    /// How far back the stamp jumped, nanoseconds.
    pub fn jump_ns(&self) -> u64 {
        self.last_ns - self.stamp_ns
    }
}

/// What an accepted message did.
#[derive(Clone, Debug, PartialEq)]
pub struct Pushed<T> {
    /// Groups it completed (usually zero or one).
    pub groups: Vec<SyncGroup<T>>,
    /// `Some` when it reset the synchronizer (reported only on the message that reset it).
    pub reset: Option<ClockReset>,
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
    /// Messages dropped because no partner matched them (also those a reset discarded).
    pub unmatched: u64,
    /// Messages dropped because a queue overflowed.
    pub overflow: u64,
    /// Messages dropped because their stamp was slightly older than their stream's newest.
    pub out_of_order: u64,
    /// Messages dropped because their stamp was far ahead (of the receive time or of the
    /// other streams).
    pub ahead: u64,
    /// Resets: a stream's stamp jumped back by more than `reset_jump_ns`.
    pub resets: u64,
}

/// A stream's run of consecutive far-ahead messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct AheadRun {
    /// The newest far-ahead stamp of the run.
    stamp_ns: u64,
    /// Messages in the run.
    count: u32,
}

/// How many bytes a queued message holds.
pub type BytesOf<T> = fn(&T) -> usize;

/// Approximate-time synchronizer over a fixed number of streams.
#[derive(Clone, Debug)]
pub struct ApproxTimeSync<T> {
    config: SyncConfig,
    queues: Vec<VecDeque<(u64, T)>>,
    /// Bytes a message holds, and the most bytes a queue may hold (see [`Self::with_bytes_cap`]).
    bytes_cap: Option<(BytesOf<T>, usize)>,
    last_stamp_ns: Vec<Option<u64>>,
    ahead_runs: Vec<Option<AheadRun>>,
    active: Vec<bool>,
    stats: SyncStats,
}

impl<T> ApproxTimeSync<T> {
    pub fn new(streams: usize, config: SyncConfig) -> Self {
        Self {
            config,
            queues: (0..streams).map(|_| VecDeque::new()).collect(),
            bytes_cap: None,
            last_stamp_ns: vec![None; streams],
            ahead_runs: vec![None; streams],
            active: vec![true; streams],
            stats: SyncStats::default(),
        }
    }

    /// Also bounds each stream's queue in bytes: `bytes_of` weighs a message, and while a
    /// queue holds more than `max_bytes` (and more than one message) its oldest message is
    /// dropped as an overflow, as for `queue_size`.
    pub fn with_bytes_cap(mut self, bytes_of: BytesOf<T>, max_bytes: usize) -> Self {
        self.bytes_cap = Some((bytes_of, max_bytes));
        self
    }

    pub fn stats(&self) -> SyncStats {
        self.stats
    }

    pub fn config(&self) -> SyncConfig {
        self.config
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

    /// Adds a message without a receive time (only the other streams bound how far ahead its
    /// stamp may be); returns the groups it completed. A reset is counted in the stats but
    /// not reported: callers that log resets use [`Self::push_at`].
    pub fn push(
        &mut self,
        stream: usize,
        stamp_ns: u64,
        msg: T,
    ) -> Result<Vec<SyncGroup<T>>, SyncError> {
        self.push_at(stream, stamp_ns, None, msg).map(|p| p.groups)
    }

    /// Adds a message received at `receipt_ns` (same clock and epoch as the stamps; `None`
    /// when no such clock is known: then the other streams bound every stamp, not only a
    /// stream's first). The module's time policy decides whether it is queued, dropped or
    /// resets the synchronizer.
    pub fn push_at(
        &mut self,
        stream: usize,
        stamp_ns: u64,
        receipt_ns: Option<u64>,
        msg: T,
    ) -> Result<Pushed<T>, SyncError> {
        let count = self.queues.len();
        let last = *self
            .last_stamp_ns
            .get(stream)
            .ok_or(SyncError::NoSuchStream { stream, count })?;
        let mut reset = None;
        match last {
            Some(last_ns) if stamp_ns < last_ns - last_ns.min(self.config.reset_jump_ns) => {
                reset = Some(self.reset(stream, last_ns, stamp_ns));
            }
            Some(last_ns) if stamp_ns < last_ns => {
                self.stats.out_of_order += 1;
                return Err(SyncError::OutOfOrder {
                    stream,
                    stamp_ns,
                    last_ns,
                });
            }
            _ => self.check_ahead(stream, stamp_ns, receipt_ns)?,
        }
        self.last_stamp_ns[stream] = Some(stamp_ns);
        self.ahead_runs[stream] = None;
        let q = &mut self.queues[stream];
        q.push_back((stamp_ns, msg));
        let over_bytes = |q: &VecDeque<(u64, T)>| match self.bytes_cap {
            Some((bytes_of, max_bytes)) => {
                q.len() > 1 && q.iter().map(|(_, m)| bytes_of(m)).sum::<usize>() > max_bytes
            }
            None => false,
        };
        while q.len() > self.config.queue_size.max(1) || over_bytes(q) {
            q.pop_front();
            self.stats.overflow += 1;
        }
        Ok(Pushed {
            groups: self.drain(),
            reset,
        })
    }

    /// `Err(Ahead)` (counted, the run recorded) when `stamp_ns` is far ahead and no exception
    /// of the time policy applies.
    fn check_ahead(
        &mut self,
        stream: usize,
        stamp_ns: u64,
        receipt_ns: Option<u64>,
    ) -> Result<(), SyncError> {
        let margin = self.config.max_ahead_ns.max(self.config.tolerance_ns);
        let beyond = |reference_ns: u64| stamp_ns > reference_ns.saturating_add(margin);
        let last = self.last_stamp_ns[stream];
        if last.is_some_and(|last| !beyond(last)) {
            return Ok(());
        }
        let others_ns = if receipt_ns.is_none() || last.is_none() {
            (0..self.last_stamp_ns.len())
                .filter(|&i| i != stream)
                .filter_map(|i| self.last_stamp_ns[i])
                .max()
        } else {
            None
        };
        let (reference, reference_ns) = match (receipt_ns, others_ns) {
            (Some(r), _) if beyond(r) => (TimeReference::Receipt, r),
            (_, Some(o)) if beyond(o) => (TimeReference::OtherStreams, o),
            _ => return Ok(()),
        };
        let run = match self.ahead_runs[stream] {
            Some(run) if run.stamp_ns <= stamp_ns => AheadRun {
                stamp_ns,
                count: run.count + 1,
            },
            _ => AheadRun { stamp_ns, count: 1 },
        };
        if run.count >= AHEAD_STAMPS_TO_FOLLOW {
            return Ok(());
        }
        self.ahead_runs[stream] = Some(run);
        self.stats.ahead += 1;
        Err(SyncError::Ahead {
            stream,
            stamp_ns,
            reference,
            reference_ns,
        })
    }

    /// Clears every queue, clock and far-ahead run; counts the reset.
    fn reset(&mut self, stream: usize, last_ns: u64, stamp_ns: u64) -> ClockReset {
        let discarded: usize = self.queues.iter().map(VecDeque::len).sum();
        self.queues.iter_mut().for_each(VecDeque::clear);
        self.last_stamp_ns.iter_mut().for_each(|l| *l = None);
        self.ahead_runs.iter_mut().for_each(|r| *r = None);
        self.stats.unmatched += discarded as u64;
        self.stats.resets += 1;
        ClockReset {
            stream,
            last_ns,
            stamp_ns,
            discarded,
        }
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
mod tests;
