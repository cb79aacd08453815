//! The node's notion of "now": system time, or simulated time from `/clock` when the
//! `use_sim_time` parameter is true (ROS 2 semantics: before the first `/clock` message the
//! time is unknown, and simulated time may jump backwards when a bag starts over).
//!
//! Camera ages, camera timeouts and `/diagnostics` stamps are measured with this clock. It is
//! plain data: the DDS loop feeds it `/clock` messages and asks it for the time.

/// Where "now" comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ClockSource {
    /// Wall-clock time of this machine.
    System,
    /// The newest `/clock` message.
    Sim,
}

/// The node's clock.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct NodeClock {
    source: ClockSource,
    /// Newest `/clock` value, nanoseconds since the epoch.
    sim_ns: Option<u64>,
}

impl NodeClock {
    /// Simulated time when `use_sim_time`, else system time.
    pub fn new(use_sim_time: bool) -> Self {
        Self {
            source: if use_sim_time {
                ClockSource::Sim
            } else {
                ClockSource::System
            },
            sim_ns: None,
        }
    }

    pub fn source(&self) -> ClockSource {
        self.source
    }

    /// True when the node needs a `/clock` subscription.
    pub fn uses_sim_time(&self) -> bool {
        self.source == ClockSource::Sim
    }

    /// Takes a `/clock` message (nanoseconds since the epoch). The newest message wins, also
    /// when it is earlier (a replayed bag that starts over). Ignored with the system clock.
    pub fn on_clock(&mut self, clock_ns: u64) {
        if self.source == ClockSource::Sim {
            self.sim_ns = Some(clock_ns);
        }
    }

    /// Now, in nanoseconds since the epoch; `None` with simulated time before the first
    /// `/clock` message.
    pub fn now_ns(&self) -> Option<u64> {
        self.now_ns_given(system_now_ns())
    }

    /// [`Self::now_ns`] given the system time (pure).
    pub fn now_ns_given(&self, system_ns: u64) -> Option<u64> {
        match self.source {
            ClockSource::System => Some(system_ns),
            ClockSource::Sim => self.sim_ns,
        }
    }
}

/// Seconds from `earlier_ns` to `now_ns`, 0 when `now_ns` is earlier (a clock that jumped back).
pub fn seconds_between(earlier_ns: u64, now_ns: u64) -> f64 {
    now_ns.saturating_sub(earlier_ns) as f64 / 1e9
}

/// Wall-clock time in nanoseconds since the epoch (0 if the system clock is before it).
pub fn system_now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    const T0: u64 = 1_700_000_000_000_000_000;

    #[test]
    fn system_clock_ignores_clock_messages() {
        let mut c = NodeClock::new(false);
        assert_eq!(c.source(), ClockSource::System);
        assert!(!c.uses_sim_time());
        assert_eq!(c.now_ns_given(T0), Some(T0));
        c.on_clock(5);
        assert_eq!(c.now_ns_given(T0 + 7), Some(T0 + 7));
        let before = system_now_ns();
        let now = c.now_ns().unwrap();
        let after = system_now_ns();
        assert!(before <= now && now <= after, "{before} {now} {after}");
        // Sanity: after 2020-01-01.
        assert!(now > 1_577_836_800_000_000_000);
    }

    #[test]
    fn sim_clock_is_unknown_until_the_first_message_then_follows_it() {
        let mut c = NodeClock::new(true);
        assert_eq!(c.source(), ClockSource::Sim);
        assert!(c.uses_sim_time());
        assert_eq!(c.now_ns_given(T0), None);
        assert_eq!(c.now_ns(), None);
        c.on_clock(1_000);
        assert_eq!(c.now_ns_given(T0), Some(1_000));
        c.on_clock(2_500_000_000);
        assert_eq!(c.now_ns(), Some(2_500_000_000));
        // A bag that starts over: time jumps back.
        c.on_clock(1_500_000_000);
        assert_eq!(c.now_ns(), Some(1_500_000_000));
    }

    #[test]
    fn ages_saturate_at_zero() {
        assert_eq!(seconds_between(1_000_000_000, 3_500_000_000), 2.5);
        assert_eq!(seconds_between(3_500_000_000, 1_000_000_000), 0.0);
        assert_eq!(seconds_between(T0, T0), 0.0);
    }
}
