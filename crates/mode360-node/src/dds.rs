//! DDS plumbing over ros2-client (RustDDS, no ROS install needed), the node's small public
//! API: how to attach to a domain ([`DdsOptions`], [`dds_context`]), the QoS profiles
//! ([`sensor_qos`], [`output_qos`], [`latched_qos`], [`clock_qos`]), typed publishers and
//! subscriptions ([`create_publisher`], [`create_subscription`]), a node with its spinner
//! thread ([`SpunNode`]: ros2-client's spinner runs discovery on its own tokio runtime;
//! [`SpunNode::stop`] stops it and waits for it) and the current-thread tokio [`runtime`]
//! every node thread runs. `play`, `bench`, the demo and the tests use it as well.

use super::discovery_range::DiscoverySettings;
use super::{NodeError, ROS_DOMAIN_ID_ENV};
use mode360_io::msgs::{type_hash, RosMessage};
use ros2_client::dds::rustdds::{set_endpoint_user_data, DomainParticipantBuilder};
use ros2_client::{
    Context, ContextOptions, MessageTypeName, Name, Node, NodeName, NodeOptions, Publisher,
    QosProfile,
};
use std::net::{IpAddr, Ipv4Addr};
use std::sync::Once;
use std::thread::JoinHandle;

/// Depth of the sensor-data subscriptions.
pub const SENSOR_QOS_DEPTH: usize = 5;
/// Depth of the output publishers.
pub const OUTPUT_QOS_DEPTH: usize = 2;
/// Largest valid ROS 2 domain id.
pub const MAX_DOMAIN_ID: u16 = 232;

/// A current-thread tokio runtime with timers and the I/O driver (signals need it).
pub fn runtime() -> Result<tokio::runtime::Runtime, NodeError> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| NodeError::Runtime {
            what: "building the runtime".into(),
            problem: e.to_string(),
        })
}

/// How to attach to DDS.
#[derive(Clone, Debug, PartialEq)]
pub struct DdsOptions {
    pub domain_id: u16,
    /// Use only the loopback interface (tests, single-host setups,
    /// `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`, `ROS_LOCALHOST_ONLY=1`).
    pub loopback_only: bool,
}

impl DdsOptions {
    /// Domain from `ROS_DOMAIN_ID` (default 0); the interfaces from the discovery range
    /// ([`DiscoverySettings`]: loopback only for `LOCALHOST`, else all), its notes logged as
    /// warnings.
    pub fn from_env() -> Result<Self, NodeError> {
        let discovery = DiscoverySettings::from_env()?;
        for note in &discovery.notes {
            tracing::warn!("{note}");
        }
        let domain_id = match std::env::var(ROS_DOMAIN_ID_ENV) {
            Ok(value) => value
                .trim()
                .parse::<u16>()
                .ok()
                .filter(|d| *d <= MAX_DOMAIN_ID)
                .ok_or(NodeError::DomainId { value })?,
            Err(_) => 0,
        };
        Ok(Self {
            domain_id,
            loopback_only: discovery.range.loopback_only(),
        })
    }
}

/// Registers with RustDDS the REP 2011 type hash of every type our endpoints and
/// ros2-client's (`/rosout`, `/parameter_events`, `ros_discovery_info`, the parameter
/// services) carry, so each endpoint announces `typehash=RIHS01_<hex>;` in its USER_DATA as
/// rmw does, and `ros2 topic info -v` and rmw_zenoh bridges can match on it. Runs once, before
/// the first participant makes any endpoint.
pub fn register_type_hashes() {
    static REGISTERED: Once = Once::new();
    REGISTERED.call_once(|| {
        for type_name in type_hash::endpoint_type_names() {
            match type_hash::type_hash(&type_name) {
                Ok(hash) => set_endpoint_user_data(
                    &type_hash::dds_type_name(&type_name),
                    hash.user_data().into_bytes(),
                ),
                Err(e) => tracing::warn!("no type hash for {type_name}: {e}"),
            }
        }
    });
}

/// A ros2-client context on `opts` (with the type hashes registered first).
pub fn dds_context(opts: &DdsOptions) -> Result<Context, NodeError> {
    register_type_hashes();
    if opts.loopback_only {
        let dp = DomainParticipantBuilder::new(opts.domain_id)
            .with_only_networks([IpAddr::V4(Ipv4Addr::LOCALHOST)])
            .build()
            .map_err(|e| NodeError::Dds {
                what: "creating the domain participant".into(),
                problem: e.to_string(),
            })?;
        Context::from_domain_participant(dp).map_err(|e| NodeError::Dds {
            what: "creating the context".into(),
            problem: e.to_string(),
        })
    } else {
        Context::with_options(ContextOptions::new().domain_id(opts.domain_id)).map_err(|e| {
            NodeError::Dds {
                what: "creating the context".into(),
                problem: e.to_string(),
            }
        })
    }
}

/// ros2-client's type name of one of our messages (`sensor_msgs/msg/Image`).
pub fn message_type_name<T: RosMessage>() -> MessageTypeName {
    let mut parts = T::TYPE_NAME.split('/');
    let package = parts.next().unwrap_or_default();
    let name = parts.next_back().unwrap_or_default();
    MessageTypeName::new(package, name)
}

/// A ros2-client [`Name`] of a topic such as `/cam1/image_raw` or `depth`.
pub fn ros_name(topic: &str) -> Result<Name, NodeError> {
    let err = |problem: String| NodeError::TopicName {
        topic: topic.to_string(),
        problem,
    };
    let (ns, base) = match topic.rsplit_once('/') {
        Some(("", base)) => ("/", base),
        Some((ns, base)) => (ns, base),
        None => ("", topic),
    };
    Name::new(ns, base).map_err(|e| err(format!("{e:?}")))
}

/// Sensor-data QoS: best effort, volatile, keep last [`SENSOR_QOS_DEPTH`].
pub fn sensor_qos() -> QosProfile {
    QosProfile::subscription_default().history(ros2_client::qos::History::KeepLast {
        depth: SENSOR_QOS_DEPTH,
    })
}

/// Output QoS: reliable, volatile, keep last [`OUTPUT_QOS_DEPTH`].
pub fn output_qos() -> QosProfile {
    QosProfile::publisher_default().history(ros2_client::qos::History::KeepLast {
        depth: OUTPUT_QOS_DEPTH,
    })
}

/// Latched QoS for `/tf_static`: reliable, transient local, keep last 1.
pub fn latched_qos() -> QosProfile {
    QosProfile::publisher_default()
        .durability(ros2_client::qos::Durability::TransientLocal)
        .history(ros2_client::qos::History::KeepLast { depth: 1 })
}

/// `/clock` subscription QoS (rclcpp's ClockQoS): best effort, keep last 1; matches
/// reliable and best-effort publishers.
pub fn clock_qos() -> QosProfile {
    QosProfile::subscription_default().history(ros2_client::qos::History::KeepLast { depth: 1 })
}

/// The DDS topic `topic` carrying `T`.
fn create_topic<T: RosMessage>(
    node: &mut Node,
    topic: &str,
    qos: &QosProfile,
) -> Result<ros2_client::dds::rustdds::Topic, NodeError> {
    node.create_topic(&ros_name(topic)?, message_type_name::<T>(), qos)
        .map_err(|e| NodeError::Dds {
            what: format!("creating topic '{topic}'"),
            problem: e.to_string(),
        })
}

/// Creates a publisher of `T` on `topic`.
pub fn create_publisher<T: RosMessage>(
    node: &mut Node,
    topic: &str,
    qos: QosProfile,
) -> Result<Publisher<T>, NodeError> {
    let t = create_topic::<T>(node, topic, &qos)?;
    node.create_publisher::<T>(&t, Some(qos))
        .map_err(|e| NodeError::Dds {
            what: format!("creating publisher on '{topic}'"),
            problem: e.to_string(),
        })
}

/// Creates a subscription of `T` on `topic`.
pub fn create_subscription<T: RosMessage + 'static>(
    node: &mut Node,
    topic: &str,
    qos: QosProfile,
) -> Result<ros2_client::Subscription<T>, NodeError> {
    let t = create_topic::<T>(node, topic, &qos)?;
    node.create_subscription::<T>(&t, Some(qos))
        .map_err(|e| NodeError::Dds {
            what: format!("creating subscription on '{topic}'"),
            problem: e.to_string(),
        })
}

/// A node plus its spinner thread; dropping without [`SpunNode::stop`] still stops the
/// spinner (ros2-client signals it on drop) but does not wait.
pub struct SpunNode {
    pub node: Node,
    spinner: Option<JoinHandle<()>>,
}

impl SpunNode {
    /// Creates node `name` in `namespace` and starts its spinner.
    pub fn new(context: &Context, namespace: &str, name: &str) -> Result<Self, NodeError> {
        Self::with_options(
            context,
            namespace,
            name,
            NodeOptions::new().enable_rosout(false),
        )
    }

    /// [`Self::new`] with `options` (declared parameters and their services).
    pub fn with_options(
        context: &Context,
        namespace: &str,
        name: &str,
        options: NodeOptions,
    ) -> Result<Self, NodeError> {
        let node_name = NodeName::new(namespace, name).map_err(|e| NodeError::TopicName {
            topic: format!("{namespace}/{name}"),
            problem: format!("{e:?}"),
        })?;
        let mut node = context
            .new_node(node_name, options)
            .map_err(|e| NodeError::Dds {
                what: "creating the node".into(),
                problem: format!("{e:?}"),
            })?;
        let spinner = node.spinner().map_err(|e| NodeError::Dds {
            what: "creating the spinner".into(),
            problem: e.to_string(),
        })?;
        let rt = runtime()?;
        let handle = std::thread::Builder::new()
            .name("mode360-spinner".into())
            .spawn(move || {
                if let Err(e) = rt.block_on(spinner.spin()) {
                    tracing::warn!("spinner stopped with error: {e}");
                }
            })
            .map_err(|e| NodeError::Dds {
                what: "starting the spinner thread".into(),
                problem: e.to_string(),
            })?;
        Ok(Self {
            node,
            spinner: Some(handle),
        })
    }

    /// Stops the spinner and waits for it. Dropping the node is what signals the spinner:
    /// ros2-client signals it again on drop, which after `stop_spinner` would log an error
    /// because the stopped spinner no longer listens.
    pub fn stop(self) -> Result<(), NodeError> {
        let Self { node, spinner } = self;
        drop(node);
        if let Some(h) = spinner {
            h.join().map_err(|_| NodeError::ThreadPanic {
                thread: "spinner".into(),
            })?;
        }
        Ok(())
    }
}
