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

use std::{
  cell::Cell,
  time::{Duration, Instant},
};

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

/// The budget of the current period, shared by the writers of this thread
/// (one participant's event loop).
struct Window {
  start: Instant,
  spent: usize,
}

thread_local! {
  static WINDOW: Cell<Option<(Instant, usize)>> = const { Cell::new(None) };
  static BUDGET: Cell<Option<usize>> = const { Cell::new(None) };
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

/// Takes `bytes` from this period's budget: `None` when they may go now,
/// `Some(wait)` when the budget is spent and the next period starts in `wait`.
/// A datagram larger than a whole budget goes out at the start of a period.
pub(crate) fn take(bytes: usize) -> Option<Duration> {
  let budget = budget_bytes()?;
  let now = Instant::now();
  WINDOW.with(|w| {
    let mut window = match w.get() {
      Some((start, spent)) if now.duration_since(start) < PERIOD => Window { start, spent },
      _ => Window {
        start: now,
        spent: 0,
      },
    };
    let result = if window.spent > 0 && window.spent + bytes > budget {
      Some(PERIOD.saturating_sub(now.duration_since(window.start)).max(Duration::from_micros(50)))
    } else {
      window.spent += bytes;
      None
    };
    w.set(Some((window.start, window.spent)));
    result
  })
}
