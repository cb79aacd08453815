//! How far the node looks for peers, from the environment variables ROS 2 uses:
//! `ROS_AUTOMATIC_DISCOVERY_RANGE` (Iron and later: `SUBNET`, the default, `LOCALHOST`, `OFF`,
//! `SYSTEM_DEFAULT`), `ROS_LOCALHOST_ONLY=1` (Humble's form, deprecated since Iron; it still
//! means `LOCALHOST` and wins, as in rcl) and `ROS_STATIC_PEERS` (addresses to reach beyond the
//! range).
//!
//! RustDDS binds discovery and data to the interfaces it is given, so `LOCALHOST` sends and
//! listens on loopback only. It has no list of unicast peers and cannot switch discovery off:
//! `OFF` is served as `LOCALHOST` (the narrowest it can do; other hosts see nothing) and
//! `ROS_STATIC_PEERS` is reported and not used (within `SUBNET` multicast discovery finds peers
//! on the same subnet anyway). Each of these is said once at start, naming the variable.

use super::NodeError;

/// `ROS_AUTOMATIC_DISCOVERY_RANGE`.
pub const DISCOVERY_RANGE_ENV: &str = "ROS_AUTOMATIC_DISCOVERY_RANGE";
/// `ROS_LOCALHOST_ONLY`.
pub const LOCALHOST_ONLY_ENV: &str = "ROS_LOCALHOST_ONLY";
/// `ROS_STATIC_PEERS`.
pub const STATIC_PEERS_ENV: &str = "ROS_STATIC_PEERS";

/// The automatic discovery range of REP 2013 / rmw's `rmw_automatic_discovery_range_t`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum DiscoveryRange {
    /// Every interface, multicast discovery on the subnet (ROS 2's default).
    #[default]
    Subnet,
    /// This host only.
    Localhost,
    /// No automatic discovery (static peers only).
    Off,
    /// The middleware's own default (RustDDS: every interface, as `Subnet`).
    SystemDefault,
}

impl DiscoveryRange {
    /// Whether the node binds to loopback only: `Localhost`, and `Off` (RustDDS cannot switch
    /// discovery off; loopback is the narrowest it can do).
    pub fn loopback_only(self) -> bool {
        matches!(self, Self::Localhost | Self::Off)
    }
}

/// What the environment asked for, and what the node has to say about it.
#[derive(Clone, Debug, PartialEq, Eq, Default)]
pub struct DiscoverySettings {
    pub range: DiscoveryRange,
    /// `ROS_STATIC_PEERS`, split at `;` (not used: RustDDS has no unicast peer list).
    pub static_peers: Vec<String>,
    /// Notes to log once at start (deprecated or unsupported settings), each naming its variable.
    pub notes: Vec<String>,
}

impl DiscoverySettings {
    /// Reads the variables through `var` (`std::env::var` in the node; a map in tests). An
    /// unknown range value is an error naming the variable and the values it takes; an unset
    /// or empty variable is the default.
    pub fn from_vars(var: impl Fn(&str) -> Option<String>) -> Result<Self, NodeError> {
        let set = |name: &str| {
            var(name)
                .map(|v| v.trim().to_string())
                .filter(|v| !v.is_empty())
        };
        let mut notes = Vec::new();
        let asked = match set(DISCOVERY_RANGE_ENV) {
            None => None,
            Some(value) => Some(match value.to_ascii_uppercase().as_str() {
                "SUBNET" => DiscoveryRange::Subnet,
                "LOCALHOST" => DiscoveryRange::Localhost,
                "OFF" => DiscoveryRange::Off,
                "SYSTEM_DEFAULT" => DiscoveryRange::SystemDefault,
                _ => {
                    return Err(NodeError::Environment {
                        variable: DISCOVERY_RANGE_ENV.into(),
                        value,
                        expected: "SUBNET, LOCALHOST, OFF or SYSTEM_DEFAULT".into(),
                    })
                }
            }),
        };
        let localhost_only = match set(LOCALHOST_ONLY_ENV).as_deref() {
            None | Some("0") => false,
            Some("1") => true,
            Some(other) => {
                return Err(NodeError::Environment {
                    variable: LOCALHOST_ONLY_ENV.into(),
                    value: other.to_string(),
                    expected: "0 or 1".into(),
                })
            }
        };
        let range = if localhost_only {
            notes.push(format!(
                "{LOCALHOST_ONLY_ENV}=1 is deprecated since Iron; it means \
                 {DISCOVERY_RANGE_ENV}=LOCALHOST (loopback only){}",
                match asked {
                    Some(r) if r != DiscoveryRange::Localhost => {
                        format!(" and wins over {DISCOVERY_RANGE_ENV}={r:?}")
                    }
                    _ => String::new(),
                }
            ));
            DiscoveryRange::Localhost
        } else {
            asked.unwrap_or_default()
        };
        if range == DiscoveryRange::Off {
            notes.push(format!(
                "{DISCOVERY_RANGE_ENV}=OFF: RustDDS cannot switch discovery off; the node \
                 binds to loopback only (as LOCALHOST), so no other host sees it"
            ));
        }
        let static_peers: Vec<String> = set(STATIC_PEERS_ENV)
            .map(|v| {
                v.split(';')
                    .map(str::trim)
                    .filter(|p| !p.is_empty())
                    .map(String::from)
                    .collect()
            })
            .unwrap_or_default();
        if !static_peers.is_empty() {
            notes.push(format!(
                "{STATIC_PEERS_ENV} ({}) is not used: RustDDS has no unicast peer list{}",
                static_peers.join(", "),
                if range.loopback_only() {
                    ", and the range is loopback only"
                } else {
                    "; multicast discovery still finds peers on the subnet"
                }
            ));
        }
        Ok(Self {
            range,
            static_peers,
            notes,
        })
    }

    /// [`Self::from_vars`] over the process's environment.
    pub fn from_env() -> Result<Self, NodeError> {
        Self::from_vars(|name| std::env::var(name).ok())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    fn settings(vars: &[(&str, &str)]) -> Result<DiscoverySettings, NodeError> {
        let map: HashMap<String, String> = vars
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect();
        DiscoverySettings::from_vars(|name| map.get(name).cloned())
    }

    #[test]
    fn defaults_to_subnet_on_every_interface() {
        let s = settings(&[]).unwrap();
        assert_eq!(s, DiscoverySettings::default());
        assert!(!s.range.loopback_only());
        let empty = settings(&[(DISCOVERY_RANGE_ENV, " "), (LOCALHOST_ONLY_ENV, "0")]).unwrap();
        assert_eq!(empty.range, DiscoveryRange::Subnet);
        assert!(empty.notes.is_empty());
    }

    #[test]
    fn localhost_range_and_localhost_only_bind_to_loopback() {
        let s = settings(&[(DISCOVERY_RANGE_ENV, "localhost")]).unwrap();
        assert_eq!(s.range, DiscoveryRange::Localhost);
        assert!(s.range.loopback_only() && s.notes.is_empty());
        // Humble's variable wins, with a note naming both.
        let s = settings(&[(LOCALHOST_ONLY_ENV, "1"), (DISCOVERY_RANGE_ENV, "SUBNET")]).unwrap();
        assert_eq!(s.range, DiscoveryRange::Localhost);
        assert_eq!(s.notes.len(), 1);
        assert!(
            s.notes[0].contains("ROS_LOCALHOST_ONLY=1 is deprecated"),
            "{:?}",
            s.notes
        );
        assert!(s.notes[0].contains("wins over ROS_AUTOMATIC_DISCOVERY_RANGE=Subnet"));
    }

    #[test]
    fn off_is_served_as_loopback_and_static_peers_are_reported() {
        let s = settings(&[
            (DISCOVERY_RANGE_ENV, "OFF"),
            (STATIC_PEERS_ENV, "192.168.0.7; robot.local;"),
        ])
        .unwrap();
        assert_eq!(s.range, DiscoveryRange::Off);
        assert!(s.range.loopback_only());
        assert_eq!(s.static_peers, ["192.168.0.7", "robot.local"]);
        assert_eq!(s.notes.len(), 2, "{:?}", s.notes);
        assert!(s.notes[1].contains("192.168.0.7, robot.local"));
        let system = settings(&[(DISCOVERY_RANGE_ENV, "SYSTEM_DEFAULT")]).unwrap();
        assert!(!system.range.loopback_only());
    }

    #[test]
    fn a_bad_value_names_the_variable_and_the_choices() {
        let e = settings(&[(DISCOVERY_RANGE_ENV, "LAN")])
            .unwrap_err()
            .to_string();
        assert!(e.contains("ROS_AUTOMATIC_DISCOVERY_RANGE='LAN'"), "{e}");
        assert!(
            e.contains("SUBNET, LOCALHOST, OFF or SYSTEM_DEFAULT"),
            "{e}"
        );
        let e = settings(&[(LOCALHOST_ONLY_ENV, "yes")])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("ROS_LOCALHOST_ONLY='yes'") && e.contains("0 or 1"),
            "{e}"
        );
    }
}
