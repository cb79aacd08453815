//! QoS overrides in ROS 2's own parameter form (as rclcpp reads them):
//! `qos_overrides./<topic>.<publisher|subscription>.<policy>` with policies
//! `reliability` (`reliable`, `best_effort`), `durability` (`volatile`, `transient_local`),
//! `history` (`keep_last`, `keep_all`) and `depth` (a positive integer). In a params file they
//! nest: `qos_overrides: {/cam1/image_raw: {subscription: {reliability: reliable}}}`.
//!
//! The topic is the fully resolved name the node uses (after namespace and remapping).

use ros2_client::qos::{Durability, History, Reliability, WhenFull};
use ros2_client::QosProfile;
use std::collections::BTreeMap;

/// Parameter prefix of QoS overrides.
pub const QOS_OVERRIDES_PREFIX: &str = "qos_overrides.";

/// Which end of a topic an override is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum QosEntity {
    Publisher,
    Subscription,
}

impl QosEntity {
    fn parse(s: &str) -> Option<Self> {
        match s {
            "publisher" => Some(Self::Publisher),
            "subscription" => Some(Self::Subscription),
            _ => None,
        }
    }
}

/// The policies overridden for one topic end (unset ones keep the node's default).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct QosOverride {
    pub reliability: Option<Reliability>,
    pub durability: Option<Durability>,
    /// `Some(true)`: keep all; `Some(false)`: keep last (`depth`, or the default's).
    pub keep_all: Option<bool>,
    pub depth: Option<usize>,
}

impl QosOverride {
    /// `base` with these policies applied.
    pub fn apply(&self, base: QosProfile) -> QosProfile {
        let base_depth = match base.history {
            History::KeepLast { depth } => depth,
            History::KeepAll => 1,
        };
        let mut q = base;
        if let Some(r) = self.reliability {
            q = q.reliability(r);
        }
        if let Some(d) = self.durability {
            q = q.durability(d);
        }
        match (self.keep_all, self.depth) {
            (Some(true), _) => q = q.history(History::KeepAll),
            (Some(false), depth) | (None, depth @ Some(_)) => {
                q = q.history(History::KeepLast {
                    depth: depth.unwrap_or(base_depth),
                })
            }
            (None, None) => {}
        }
        q
    }
}

/// Every override the parameters set, by topic and end.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct QosOverrides {
    by_topic: BTreeMap<(String, QosEntity), QosOverride>,
}

impl QosOverrides {
    /// Sets `name` (without [`QOS_OVERRIDES_PREFIX`]: `/<topic>.<end>.<policy>`) to `value`;
    /// the error says what is allowed.
    pub fn set(&mut self, name: &str, value: &str) -> Result<(), String> {
        let (rest, policy) = name
            .rsplit_once('.')
            .ok_or("expected qos_overrides./<topic>.<publisher|subscription>.<policy>")?;
        let (topic, end) = rest
            .rsplit_once('.')
            .ok_or("expected qos_overrides./<topic>.<publisher|subscription>.<policy>")?;
        if !topic.starts_with('/') {
            return Err(format!(
                "topic '{topic}' must be a fully resolved name (start with /)"
            ));
        }
        let end = QosEntity::parse(end)
            .ok_or_else(|| format!("'{end}' is not publisher or subscription"))?;
        let entry = self.by_topic.entry((topic.to_string(), end)).or_default();
        match policy {
            "reliability" => {
                entry.reliability = Some(match value {
                    "reliable" => Reliability::Reliable {
                        when_full: WhenFull::DEFAULT,
                    },
                    "best_effort" => Reliability::BestEffort,
                    _ => return Err("reliability: expected reliable or best_effort".into()),
                })
            }
            "durability" => {
                entry.durability = Some(match value {
                    "volatile" => Durability::Volatile,
                    "transient_local" => Durability::TransientLocal,
                    _ => return Err("durability: expected volatile or transient_local".into()),
                })
            }
            "history" => {
                entry.keep_all = Some(match value {
                    "keep_all" => true,
                    "keep_last" => false,
                    _ => return Err("history: expected keep_last or keep_all".into()),
                })
            }
            "depth" => {
                entry.depth = Some(
                    value
                        .parse::<usize>()
                        .ok()
                        .filter(|d| *d > 0)
                        .ok_or("depth: expected a positive integer")?,
                )
            }
            other => {
                return Err(format!(
                    "unknown policy '{other}' (reliability, durability, history, depth)"
                ))
            }
        }
        Ok(())
    }

    /// `base` with the overrides of `topic`'s `end` applied.
    pub fn qos(&self, topic: &str, end: QosEntity, base: QosProfile) -> QosProfile {
        match self.by_topic.get(&(topic.to_string(), end)) {
            Some(o) => o.apply(base),
            None => base,
        }
    }

    /// Topics with an override (to warn about ones the node does not use).
    pub fn topics(&self) -> impl Iterator<Item = (&str, QosEntity)> {
        self.by_topic.keys().map(|(t, e)| (t.as_str(), *e))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn overrides_parse_and_apply() {
        let mut o = QosOverrides::default();
        o.set("/cam1/image_raw.subscription.reliability", "reliable")
            .unwrap();
        o.set("/cam1/image_raw.subscription.depth", "7").unwrap();
        o.set("/tf_static.publisher.durability", "volatile")
            .unwrap();
        o.set("/depth.publisher.history", "keep_all").unwrap();
        let base = QosProfile::subscription_default();
        let cam = o.qos("/cam1/image_raw", QosEntity::Subscription, base.clone());
        assert!(matches!(cam.reliability, Reliability::Reliable { .. }));
        assert_eq!(cam.history, History::KeepLast { depth: 7 });
        assert_eq!(cam.durability, Durability::Volatile);
        // Other topics and the other end keep the default.
        assert_eq!(
            o.qos("/cam2/image_raw", QosEntity::Subscription, base.clone()),
            base
        );
        assert_eq!(
            o.qos("/cam1/image_raw", QosEntity::Publisher, base.clone()),
            base
        );
        let tf = o.qos(
            "/tf_static",
            QosEntity::Publisher,
            QosProfile::publisher_default().durability(Durability::TransientLocal),
        );
        assert_eq!(tf.durability, Durability::Volatile);
        let depth = o.qos(
            "/depth",
            QosEntity::Publisher,
            QosProfile::publisher_default(),
        );
        assert_eq!(depth.history, History::KeepAll);
        for (name, value, needle) in [
            (
                "/cam1/image_raw.subscription.reliability",
                "sometimes",
                "reliable or best_effort",
            ),
            (
                "/cam1/image_raw.reader.depth",
                "3",
                "publisher or subscription",
            ),
            (
                "/cam1/image_raw.subscription.depth",
                "0",
                "positive integer",
            ),
            (
                "/cam1/image_raw.subscription.lifespan",
                "1",
                "unknown policy",
            ),
            ("cam1.subscription.depth", "1", "fully resolved"),
            ("nonsense", "1", "expected qos_overrides"),
        ] {
            let e = o.set(name, value).unwrap_err();
            assert!(e.contains(needle), "{name}: {e}");
        }
    }
}
