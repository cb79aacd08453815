//! Handing freed memory back to the kernel, which only the allocator can do, and the allocator
//! is the binary's business: `src/main.rs` allocates with jemalloc and registers its purge
//! here ([`set_page_release`]); the library calls [`release_freed_pages`] when memory was freed
//! for good (a live-view client gone, `live_view.rs`; resident memory well above the working
//! set after a burst of large input, [`TrimPolicy`], checked by the receive loop once a second). A process that registers nothing (a
//! test, another binary with the system allocator) releases nothing and pays nothing.

use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// Hands the allocator's free pages back to the kernel; true when it did.
pub type PageRelease = fn() -> bool;

static PAGE_RELEASE: OnceLock<PageRelease> = OnceLock::new();

/// Registers how this process releases freed pages; false when one was registered already
/// (the first stays).
pub fn set_page_release(release: PageRelease) -> bool {
    PAGE_RELEASE.set(release).is_ok()
}

/// Releases the allocator's free pages through the registered function, so the resident size
/// drops to what is in use; false when none is registered or it released nothing. The next
/// allocations fault their pages in again, so this runs when memory was freed for good, never
/// per frame.
pub fn release_freed_pages() -> bool {
    PAGE_RELEASE.get().is_some_and(|release| release())
}

/// Resident memory this far above the working set is handed back to the kernel.
pub const TRIM_MARGIN_MIB: f64 = 100.0;
/// Releases are at least this far apart: each costs the next frame its page faults, and where
/// the working set grew for good by more than the margin (measured: 955 -> 1,095 MiB at 512
/// after a burst of 4096x2048 images) the node releases at this period from then on.
pub const TRIM_MIN_INTERVAL: Duration = Duration::from_secs(30);
/// From start, and again from the first published output, the highest resident size seen for
/// this long is the working set (model loaded, tables built, the first frames run).
pub const TRIM_STARTUP: Duration = Duration::from_secs(30);
/// After a release, the highest resident size seen for this long is measured as the working set
/// again (the next frames fault their buffers back in). As long as the interval: at 512 the
/// resident size takes 20 to 30 s to grow back (measured: a 10 s window read it 100 to 300 MiB
/// low, and the node released every 30 s from then on).
pub const TRIM_SETTLE: Duration = Duration::from_secs(30);

/// When the node hands freed memory back: a burst of large input (oversized images, a backlog
/// of fragments) leaves the allocator holding pages the node no longer uses, and jemalloc as the
/// binary configures it keeps them for good. The policy releases once the resident size is more
/// than [`TRIM_MARGIN_MIB`] above the working set, at most every [`TRIM_MIN_INTERVAL`]. The
/// working set is the highest resident size of the first [`TRIM_STARTUP`], measured again over
/// as long from the first published output ([`Self::outputs_started`]: a slow start must not
/// leave the estimate below what running frames need). After each release it is measured again
/// over [`TRIM_SETTLE`] and taken if it grew by less than the margin; a window that grew by more
/// is kept as a candidate (an ongoing burst inflates one window) and taken when the next window
/// agrees with it within the margin (the working set did grow), so steady operation, whose
/// frames reuse their buffers, triggers at most two releases.
#[derive(Clone, Debug)]
pub struct TrimPolicy {
    margin_mib: f64,
    min_interval: Duration,
    settle: Duration,
    /// When the current measurement window began (start or the last release).
    since: Instant,
    /// How long the current window lasts.
    window: Duration,
    /// The highest resident size of the current window.
    window_max_mib: f64,
    /// The accepted working set; `None` until the startup window ends.
    working_set_mib: Option<f64>,
    /// A window's maximum that was more than the margin above the working set, waiting for the
    /// next window to confirm it.
    candidate_mib: Option<f64>,
    startup: Duration,
    /// Whether [`Self::outputs_started`] restarted the startup window.
    outputs_seen: bool,
    /// Releases so far.
    pub releases: u64,
}

impl TrimPolicy {
    /// The node's policy, from `now` (the node's start).
    pub fn new(now: Instant) -> Self {
        Self::with_limits(
            now,
            TRIM_MARGIN_MIB,
            TRIM_MIN_INTERVAL,
            TRIM_STARTUP,
            TRIM_SETTLE,
        )
    }

    pub fn with_limits(
        now: Instant,
        margin_mib: f64,
        min_interval: Duration,
        startup: Duration,
        settle: Duration,
    ) -> Self {
        Self {
            margin_mib,
            min_interval,
            settle,
            since: now,
            window: startup,
            window_max_mib: 0.0,
            working_set_mib: None,
            candidate_mib: None,
            startup,
            outputs_seen: false,
            releases: 0,
        }
    }

    /// The node published its first output at `now`: the working set is measured again over
    /// the startup window from here, whatever was measured before (later calls do nothing).
    pub fn outputs_started(&mut self, now: Instant) {
        if std::mem::replace(&mut self.outputs_seen, true) {
            return;
        }
        self.since = now;
        self.window = self.startup;
        self.window_max_mib = 0.0;
        self.working_set_mib = None;
        self.candidate_mib = None;
    }

    /// The accepted working set, once measured.
    pub fn working_set_mib(&self) -> Option<f64> {
        self.working_set_mib
    }

    /// Takes the resident size at `now`; true when freed memory should be released now
    /// (then call [`Self::released`]).
    pub fn observe(&mut self, resident_mib: f64, now: Instant) -> bool {
        let age = now.saturating_duration_since(self.since);
        if age <= self.window {
            self.window_max_mib = self.window_max_mib.max(resident_mib);
            return false;
        }
        if self.window_max_mib > 0.0 {
            let measured = self.window_max_mib;
            let margin = self.margin_mib;
            let candidate = self.candidate_mib.take();
            self.working_set_mib = match self.working_set_mib {
                Some(old) if measured > old + margin => match candidate {
                    // Two windows in a row agree: the working set grew.
                    Some(c) if (measured - c).abs() <= margin => Some(measured.max(c)),
                    _ => {
                        self.candidate_mib = Some(measured);
                        Some(old)
                    }
                },
                _ => Some(measured),
            };
            self.window_max_mib = 0.0;
        }
        let Some(working_set) = self.working_set_mib else {
            return false;
        };
        age >= self.min_interval && resident_mib > working_set + self.margin_mib
    }

    /// A release was done at `now`: the working set is measured again from here.
    pub fn released(&mut self, now: Instant) {
        self.since = now;
        self.window = self.settle;
        self.window_max_mib = 0.0;
        self.releases += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SEC: Duration = Duration::from_secs(1);

    fn policy(t0: Instant) -> TrimPolicy {
        TrimPolicy::with_limits(t0, 100.0, 10 * SEC, 30 * SEC, 10 * SEC)
    }

    #[test]
    fn steady_frames_trigger_nothing_and_a_burst_is_released() {
        let t0 = Instant::now();
        let mut p = policy(t0);
        // Start: loading, then frames between 400 and 600 MiB.
        for s in 0..=30 {
            let rss = if s < 5 {
                200.0
            } else if s % 2 == 0 {
                400.0
            } else {
                600.0
            };
            assert!(!p.observe(rss, t0 + s * SEC), "startup at {s} s");
        }
        for s in 31..60 {
            assert!(!p.observe(650.0, t0 + s * SEC), "steady at {s} s");
        }
        assert_eq!(p.working_set_mib(), Some(600.0));
        // A burst leaves 1.5 GiB held: released at once.
        assert!(p.observe(1500.0, t0 + 60 * SEC));
        p.released(t0 + 60 * SEC);
        // The burst goes on while the working set is measured again: that window is refused,
        // and the memory goes back once the interval has passed.
        for s in 61..=70 {
            assert!(!p.observe(1200.0, t0 + s * SEC));
        }
        assert!(p.observe(1250.0, t0 + 71 * SEC));
        p.released(t0 + 71 * SEC);
        assert_eq!(p.working_set_mib(), Some(600.0));
        // Calm again: the working set measured anew, nothing released.
        for s in 72..120 {
            assert!(!p.observe(if s % 2 == 0 { 420.0 } else { 640.0 }, t0 + s * SEC));
        }
        assert_eq!(p.working_set_mib(), Some(640.0));
        assert_eq!(p.releases, 2);
    }

    #[test]
    fn a_working_set_that_grew_is_taken_after_two_agreeing_windows() {
        let t0 = Instant::now();
        let mut p = policy(t0);
        // A slow start: 300 MiB until the first output at 40 s, then frames at 900 to 950.
        for s in 0..=40 {
            assert!(!p.observe(300.0, t0 + s * SEC), "startup at {s} s");
        }
        assert_eq!(p.working_set_mib(), Some(300.0));
        p.outputs_started(t0 + 40 * SEC);
        assert_eq!(p.working_set_mib(), None);
        let frames = |s: u32| if s.is_multiple_of(2) { 900.0 } else { 950.0 };
        for s in 41..=70 {
            assert!(!p.observe(frames(s), t0 + s * SEC), "frames at {s} s");
        }
        // Measured again from the first output: nothing to release in steady operation.
        for s in 71..200 {
            assert!(!p.observe(frames(s), t0 + s * SEC), "steady at {s} s");
        }
        assert_eq!(p.working_set_mib(), Some(950.0));
        assert_eq!(p.releases, 0);
        // Later calls do not restart the measurement.
        p.outputs_started(t0 + 200 * SEC);
        assert_eq!(p.working_set_mib(), Some(950.0));

        // Without the restart (the old behaviour's case), a working set that grew for good
        // costs two releases, not one every interval.
        let mut q = policy(t0);
        for s in 0..=30 {
            assert!(!q.observe(300.0, t0 + s * SEC));
        }
        let mut releases_at = Vec::new();
        for s in 31..400 {
            let now = t0 + s * SEC;
            if q.observe(frames(s), now) {
                q.released(now);
                releases_at.push(s);
            }
        }
        assert_eq!(releases_at.len(), 2, "{releases_at:?}");
        assert_eq!(q.working_set_mib(), Some(950.0));
    }

    #[test]
    fn nothing_is_released_before_the_working_set_is_known_or_the_interval_passed() {
        let t0 = Instant::now();
        let mut p = TrimPolicy::with_limits(t0, 100.0, 40 * SEC, 30 * SEC, 5 * SEC);
        assert!(!p.observe(300.0, t0 + SEC));
        assert!(!p.observe(3000.0, t0 + 20 * SEC));
        // The startup window's maximum is the working set, whatever it was.
        assert!(!p.observe(3000.0, t0 + 35 * SEC));
        assert_eq!(p.working_set_mib(), Some(3000.0));
        assert!(p.observe(3200.0, t0 + 41 * SEC));
    }
}
