//! mode360 patch: pacing of fragmented user samples.
//!
//! RustDDS 0.15.1 sends all DATAFRAG datagrams of a large sample back to back.
//! On one host a reader whose receive buffer is Fast DDS's default (212,992
//! bytes, which holds fewer than a hundred 1.4 kB datagrams) overflows within
//! a millisecond, and NACK_FRAG repair (8 fragments a round) brings the sample
//! seconds late or never. The writers of one participant (one event-loop
//! thread) therefore share a byte budget per period for the datagrams of
//! fragmented user samples: once a period's budget is spent the writer keeps
//! its fragment cursor and resumes at the next period (a timed event), like a
//! Fast DDS flow controller. Unfragmented samples, discovery and repairs are
//! not paced.
//!
//! `MODE360_DDS_PACE_KIB_PER_MS` sets the budget in KiB per millisecond
//! (default [`DEFAULT_KIB_PER_MS`]; 0 turns pacing off).
//!
//! Writers take turns in the order they were first paced ([`Turns`]): the
//! sample at the head goes at the full rate and the others wait for it, so a
//! node's outputs arrive in the order they were published (its depth image
//! first, not interleaved with its confidence and point cloud, which would
//! make each arrive as late as the last).

use std::{
  cell::{Cell, RefCell},
  collections::VecDeque,
  time::{Duration, Instant},
};

use crate::structure::guid::GUID;

/// Length of one budget period.
pub(crate) const PERIOD: Duration = Duration::from_millis(1);
/// Default budget, KiB per period: 32 MiB/s, a 1.6 MB sample in 50 ms. Measured
/// with rclpy of Jazzy at the default buffer, mode360 at 512 wide: 16 and 32
/// delivered every output (7 of 7 per topic in 10 runs, at most 0.2 s after
/// an in-process RustDDS subscriber); unpaced, 4 of 7 confidence images
/// arrived, 2.7 to 5 s late.
pub(crate) const DEFAULT_KIB_PER_MS: usize = 32;
/// Environment variable overriding [`DEFAULT_KIB_PER_MS`].
pub(crate) const ENV_KIB_PER_MS: &str = "MODE360_DDS_PACE_KIB_PER_MS";

/// Most periods' worth of budget the bucket saves up while the writers are idle
/// or the event loop wakes late, so a late wake-up does not lower the rate:
/// the poll timeout is whole milliseconds, and a wait of 0.3 ms sleeps 1 to
/// 2 ms. Measured before the bucket (a window restarted at every wake-up):
/// `mode360 play` of four 512-wide cameras and ground truth (2.1 MB a frame at
/// 10 Hz) got about half its images through. Two periods let a best-effort
/// rclpy subscriber at 128 wide lose 2 of 11 confidence images once in CI.
pub(crate) const BURST_PERIODS: u32 = 1;
/// Shortest wait handed back, so a nearly refilled bucket does not spin.
const MIN_WAIT: Duration = Duration::from_micros(50);

/// A token bucket: `tokens` bytes may go now; it refills at `budget` bytes per
/// [`PERIOD`] up to [`BURST_PERIODS`] budgets. Shared by the writers of this
/// thread (one participant's event loop).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Bucket {
  refilled_at: Instant,
  tokens: f64,
}

impl Bucket {
  /// A full bucket at `now`.
  pub(crate) fn full(budget: usize, now: Instant) -> Self {
    Self {
      refilled_at: now,
      tokens: capacity(budget),
    }
  }

  /// Takes `bytes` at `now` from a bucket refilled at `budget` bytes per
  /// period: `None` when they may go now, `Some(wait)` when the bucket holds
  /// too little and will in `wait`. A datagram larger than the bucket goes
  /// once the bucket is full; the tokens it overdraws are paid back before the
  /// next one (the average rate holds):
  ///
  /// `tokens(now) = min(C, tokens + budget * (now - refilled_at) / PERIOD)`,
  /// `C = BURST_PERIODS * budget`.
  pub(crate) fn take_at(&mut self, bytes: usize, budget: usize, now: Instant) -> Option<Duration> {
    let rate_per_s = budget as f64 / PERIOD.as_secs_f64();
    let elapsed_s = now.saturating_duration_since(self.refilled_at).as_secs_f64();
    self.tokens = (self.tokens + rate_per_s * elapsed_s).min(capacity(budget));
    self.refilled_at = now;
    let needed = (bytes as f64).min(capacity(budget));
    if self.tokens >= needed {
      self.tokens -= bytes as f64;
      None
    } else {
      let wait_s = (needed - self.tokens) / rate_per_s;
      Some(Duration::from_secs_f64(wait_s).max(MIN_WAIT))
    }
  }
}

fn capacity(budget: usize) -> f64 {
  budget as f64 * f64::from(BURST_PERIODS)
}

/// How long the writer at the head of [`Turns`] may go without sending before
/// the next one gets the turn: a writer whose sample was dropped or that was
/// deleted mid-sample never says it is done. Far above a period and a late
/// wake-up of the event loop, far below a frame period.
pub(crate) const STALE_TURN: Duration = Duration::from_millis(20);

/// One waiting writer and when it last sent (or reached the head).
#[derive(Clone, Copy, Debug)]
struct Turn<K> {
  writer: K,
  since: Instant,
}

/// The writers of one event loop in the order they were first paced. The
/// head's sample goes; the others wait until it is done, so samples go one
/// after another at the full rate instead of interleaved at a fraction of it.
#[derive(Debug)]
pub(crate) struct Turns<K> {
  queue: VecDeque<Turn<K>>,
}

impl<K: Copy + Eq> Turns<K> {
  pub(crate) const fn new() -> Self {
    Self {
      queue: VecDeque::new(),
    }
  }

  /// Whether `writer` may send now: the queue is empty or `writer` is its
  /// head. Otherwise `writer` joins the end of the queue (once). A head that
  /// has not sent for [`STALE_TURN`] is dropped first.
  pub(crate) fn may_send(&mut self, writer: K, now: Instant) -> bool {
    while let Some(head) = self.queue.front() {
      if head.writer == writer || now.saturating_duration_since(head.since) < STALE_TURN {
        break;
      }
      self.queue.pop_front();
      self.restart_head(now);
    }
    match self.queue.front() {
      Some(head) if head.writer != writer => {
        if !self.queue.iter().any(|t| t.writer == writer) {
          self.queue.push_back(Turn { writer, since: now });
        }
        false
      }
      _ => true,
    }
  }

  /// `writer`, which [`Self::may_send`] let go, sent at `now`.
  pub(crate) fn sent(&mut self, writer: K, now: Instant) {
    if let Some(head) = self.queue.front_mut() {
      if head.writer == writer {
        head.since = now;
      }
    }
  }

  /// `writer`, which [`Self::may_send`] let go, must wait for the bucket: it
  /// keeps the turn (it takes it when nobody holds it).
  pub(crate) fn paced(&mut self, writer: K, now: Instant) {
    if self.queue.is_empty() {
      self.queue.push_back(Turn { writer, since: now });
    }
  }

  /// `writer`'s sample is sent (or given up): the next writer's turn. Returns
  /// the writer whose turn it now is, to be woken at once (waiting, it would
  /// look again only a period later, and the budget of that gap is lost).
  pub(crate) fn done(&mut self, writer: K, now: Instant) -> Option<K> {
    let was_head = self.queue.front().is_some_and(|t| t.writer == writer);
    self.queue.retain(|t| t.writer != writer);
    if was_head {
      self.restart_head(now);
      self.queue.front().map(|t| t.writer)
    } else {
      None
    }
  }

  fn restart_head(&mut self, now: Instant) {
    if let Some(head) = self.queue.front_mut() {
      head.since = now;
    }
  }
}

thread_local! {
  static BUCKET: Cell<Option<Bucket>> = const { Cell::new(None) };
  static BUDGET: Cell<Option<usize>> = const { Cell::new(None) };
  static TURNS: RefCell<Turns<GUID>> = const { RefCell::new(Turns::new()) };
}

/// Bytes a period may carry (`None`: pacing off).
fn budget_bytes() -> Option<usize> {
  BUDGET.with(|b| {
    let bytes = b.get().unwrap_or_else(|| {
      let kib = std::env::var(ENV_KIB_PER_MS)
        .ok()
        .and_then(|v| v.trim().parse::<usize>().ok())
        .unwrap_or(DEFAULT_KIB_PER_MS);
      let bytes = kib.saturating_mul(1024);
      b.set(Some(bytes));
      bytes
    });
    (bytes > 0).then_some(bytes)
  })
}

/// Takes `bytes` for `writer` from this thread's bucket, in its turn
/// ([`Turns`]): `None` when they may go now, `Some(wait)` when the writer
/// should resume in `wait`. A writer waiting for its turn is woken when it
/// comes ([`done`]); it looks again after [`STALE_TURN`] in case the head
/// never finishes (polling each period, six waiting writers cost the event loop
/// so much that a loaded player at 512 fell behind).
pub(crate) fn take(writer: GUID, bytes: usize) -> Option<Duration> {
  let budget = budget_bytes()?;
  let now = Instant::now();
  TURNS.with(|turns| {
    let mut turns = turns.borrow_mut();
    if !turns.may_send(writer, now) {
      return Some(STALE_TURN);
    }
    let result = BUCKET.with(|cell| {
      let mut bucket = cell.get().unwrap_or_else(|| Bucket::full(budget, now));
      let result = bucket.take_at(bytes, budget, now);
      cell.set(Some(bucket));
      result
    });
    match result {
      None => turns.sent(writer, now),
      Some(_) => turns.paced(writer, now),
    }
    result
  })
}

/// `writer`'s paced sample is sent, or given up: the next writer's turn.
/// Returns that writer, to be woken now.
pub(crate) fn done(writer: GUID) -> Option<GUID> {
  TURNS.with(|turns| turns.borrow_mut().done(writer, Instant::now()))
}

#[cfg(test)]
mod tests {
  use super::*;

  const BUDGET: usize = 32 * 1024;
  const DATAGRAM: usize = 1_400;

  /// Sends `total` bytes in datagrams, sleeping each wait plus `late` (how
  /// late the event loop wakes); returns the time it took.
  fn send_all(total: usize, late: Duration) -> Duration {
    let t0 = Instant::now();
    let mut now = t0;
    let mut bucket = Bucket::full(BUDGET, t0);
    let mut sent = 0;
    while sent < total {
      match bucket.take_at(DATAGRAM, BUDGET, now) {
        None => {
          sent += DATAGRAM;
          now += Duration::from_micros(2);
        }
        Some(wait) => now += wait + late,
      }
    }
    now - t0
  }

  #[test]
  fn the_rate_holds_when_the_loop_wakes_late() {
    let total = 2_100_000;
    let ideal_s = total as f64 / (BUDGET as f64 / PERIOD.as_secs_f64());
    for late_us in [0, 300, 900] {
      let took = send_all(total, Duration::from_micros(late_us)).as_secs_f64();
      assert!(
        took < ideal_s * 1.1 && took > ideal_s * 0.9,
        "late {late_us} us: {took} s against {ideal_s} s"
      );
    }
  }

  #[test]
  fn writers_take_turns_in_the_order_they_were_paced() {
    let t0 = Instant::now();
    let mut turns = Turns::new();
    // Writer 1 sends, is paced and holds the turn; 2 and 3 queue behind it.
    assert!(turns.may_send(1, t0));
    turns.sent(1, t0);
    turns.paced(1, t0);
    assert!(!turns.may_send(2, t0));
    assert!(!turns.may_send(3, t0));
    assert!(!turns.may_send(2, t0), "asking again does not queue twice");
    assert!(turns.may_send(1, t0 + PERIOD));
    assert_eq!(turns.done(1, t0 + PERIOD), Some(2), "2 is woken");
    assert!(!turns.may_send(3, t0 + PERIOD), "2 was paced before 3");
    assert!(turns.may_send(2, t0 + PERIOD));
    assert_eq!(turns.done(3, t0 + PERIOD), None, "3 gives up; not the head");
    assert_eq!(turns.done(2, t0 + 2 * PERIOD), None, "nobody is waiting");
    assert!(turns.queue.is_empty());
  }

  #[test]
  fn a_head_that_stops_sending_loses_the_turn() {
    let t0 = Instant::now();
    let mut turns = Turns::new();
    turns.paced(1, t0);
    assert!(!turns.may_send(2, t0 + PERIOD));
    // Writer 1 never comes back (its sample was dropped).
    assert!(!turns.may_send(2, t0 + STALE_TURN - PERIOD));
    assert!(turns.may_send(2, t0 + STALE_TURN));
    // Writer 2 is now the head, counted from when it got the turn.
    assert!(!turns.may_send(3, t0 + STALE_TURN + PERIOD));
  }

  #[test]
  fn a_burst_is_at_most_the_bucket() {
    let t0 = Instant::now();
    let mut bucket = Bucket::full(BUDGET, t0);
    // Idle for a second: the bucket saves up no more than its capacity.
    let now = t0 + Duration::from_secs(1);
    let mut burst = 0;
    while bucket.take_at(DATAGRAM, BUDGET, now).is_none() {
      burst += DATAGRAM;
    }
    let cap = BURST_PERIODS as usize * BUDGET;
    assert!(burst <= cap + DATAGRAM && burst + DATAGRAM >= cap, "{burst} against {cap}");
  }

  #[test]
  fn a_datagram_larger_than_the_bucket_goes_when_it_is_full() {
    let t0 = Instant::now();
    let mut bucket = Bucket::full(BUDGET, t0);
    let big = 4 * BUDGET;
    assert_eq!(bucket.take_at(big, BUDGET, t0), None);
    // Paid back: the next small datagram waits about (big - capacity) / rate.
    let wait = bucket.take_at(DATAGRAM, BUDGET, t0).expect("must wait");
    let expected = Duration::from_secs_f64(
      (big as f64 - capacity(BUDGET) + DATAGRAM as f64) / (BUDGET as f64 / PERIOD.as_secs_f64()),
    );
    assert!((wait.as_secs_f64() - expected.as_secs_f64()).abs() < 1e-5, "{wait:?} against {expected:?}");
  }
}
