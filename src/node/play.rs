//! `mode360 play`: publish a bag's messages on DDS with their recorded timing.
//!
//! Message `k` is sent at `start + (log_time_k - log_time_0) / rate`. `/tf_static` goes out
//! latched (reliable, transient local); with `publish_clock`, `/clock` carries each message's
//! log time before the message itself, so nodes with `use_sim_time` follow the bag. Supported
//! types: Image, CompressedImage, PointCloud2, TFMessage, DiagnosticArray, Clock; topics of
//! other types are skipped and listed in the summary.

use super::ros::{
    create_publisher, dds_context, latched_qos, output_qos, sensor_qos, DdsOptions, NodeError,
    SpunNode,
};
use super::{CLOCK_TOPIC, TF_STATIC_TOPIC};
use crate::bag::{BagError, BagMessage, BagReader};
use crate::msgs::{
    Clock, CompressedImage, DiagnosticArray, Image, PointCloud2, RosMessage, TFMessage, Time,
};
use ros2_client::Publisher;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// How often the subscriber wait re-checks matches.
const MATCH_POLL: Duration = Duration::from_millis(50);
/// Largest wait before one message, seconds (guards against bags with absurd time gaps).
const MAX_OFFSET_SECS: f64 = 24.0 * 3600.0;

#[derive(Debug, thiserror::Error)]
pub enum PlayError {
    #[error(transparent)]
    Bag(#[from] BagError),
    #[error(transparent)]
    Node(#[from] NodeError),
    #[error("rate must be a positive number, got {rate}")]
    BadRate { rate: f64 },
}

/// What to play.
#[derive(Clone, Debug)]
pub struct PlayOptions {
    pub input: PathBuf,
    /// Playback speed factor (1 = recorded timing).
    pub rate: f64,
    /// Play the bag this many times (at least once).
    pub loops: usize,
    pub publish_clock: bool,
    pub dds: DdsOptions,
    /// Before playing, wait up to this long until every topic in `wait_topics` has a
    /// matched subscriber.
    pub wait_for_subscribers: Option<Duration>,
    pub wait_topics: Vec<String>,
}

/// What was played.
#[derive(Clone, Debug, Default)]
pub struct PlaySummary {
    /// Messages published, per topic.
    pub published: BTreeMap<String, u64>,
    /// Topics skipped because their type is not supported.
    pub skipped_topics: Vec<String>,
    pub seconds: f64,
}

enum AnyPublisher {
    Image(Publisher<Image>),
    Compressed(Publisher<CompressedImage>),
    Points(Publisher<PointCloud2>),
    Tf(Publisher<TFMessage>),
    Diagnostics(Publisher<DiagnosticArray>),
    Clock(Publisher<Clock>),
}

impl AnyPublisher {
    fn publish(&self, msg: &BagMessage<'_>) -> Result<(), PlayError> {
        let fail = |e: String| {
            PlayError::Node(NodeError::Dds {
                what: format!("publishing on '{}'", msg.topic),
                problem: e,
            })
        };
        match self {
            Self::Image(p) => p.publish(msg.decode()?).map_err(|e| fail(format!("{e:?}"))),
            Self::Compressed(p) => p.publish(msg.decode()?).map_err(|e| fail(format!("{e:?}"))),
            Self::Points(p) => p.publish(msg.decode()?).map_err(|e| fail(format!("{e:?}"))),
            Self::Tf(p) => p.publish(msg.decode()?).map_err(|e| fail(format!("{e:?}"))),
            Self::Diagnostics(p) => p.publish(msg.decode()?).map_err(|e| fail(format!("{e:?}"))),
            Self::Clock(p) => p.publish(msg.decode()?).map_err(|e| fail(format!("{e:?}"))),
        }
    }

    fn subscription_count(&self, node: &ros2_client::Node) -> usize {
        match self {
            Self::Image(p) => p.get_subscription_count(node),
            Self::Compressed(p) => p.get_subscription_count(node),
            Self::Points(p) => p.get_subscription_count(node),
            Self::Tf(p) => p.get_subscription_count(node),
            Self::Diagnostics(p) => p.get_subscription_count(node),
            Self::Clock(p) => p.get_subscription_count(node),
        }
    }
}

fn publisher_for(
    node: &mut ros2_client::Node,
    topic: &str,
    type_name: &str,
) -> Result<Option<AnyPublisher>, NodeError> {
    let latched = topic == TF_STATIC_TOPIC;
    Ok(Some(match type_name {
        t if t == Image::TYPE_NAME => {
            AnyPublisher::Image(create_publisher(node, topic, sensor_qos())?)
        }
        t if t == CompressedImage::TYPE_NAME => {
            AnyPublisher::Compressed(create_publisher(node, topic, sensor_qos())?)
        }
        t if t == PointCloud2::TYPE_NAME => {
            AnyPublisher::Points(create_publisher(node, topic, output_qos())?)
        }
        t if t == TFMessage::TYPE_NAME => AnyPublisher::Tf(create_publisher(
            node,
            topic,
            if latched { latched_qos() } else { output_qos() },
        )?),
        t if t == DiagnosticArray::TYPE_NAME => {
            AnyPublisher::Diagnostics(create_publisher(node, topic, output_qos())?)
        }
        t if t == Clock::TYPE_NAME => {
            AnyPublisher::Clock(create_publisher(node, topic, output_qos())?)
        }
        _ => return Ok(None),
    }))
}

/// Plays `opts.input` on DDS.
pub fn play_bag(opts: &PlayOptions) -> Result<PlaySummary, PlayError> {
    if !(opts.rate.is_finite() && opts.rate > 0.0) {
        return Err(PlayError::BadRate { rate: opts.rate });
    }
    let bag = BagReader::open(&opts.input)?;
    let context = dds_context(&opts.dds)?;
    let mut spun = SpunNode::new(
        &context,
        "/",
        &format!("mode360_play_{}", std::process::id()),
    )?;
    let mut publishers: BTreeMap<String, AnyPublisher> = BTreeMap::new();
    let mut summary = PlaySummary::default();
    for info in bag.topics() {
        match publisher_for(&mut spun.node, &info.topic, &info.type_name)? {
            Some(p) => {
                publishers.insert(info.topic.clone(), p);
            }
            None => summary.skipped_topics.push(info.topic.clone()),
        }
    }
    let clock: Option<Publisher<Clock>> =
        if opts.publish_clock && !publishers.contains_key(CLOCK_TOPIC) {
            Some(create_publisher(&mut spun.node, CLOCK_TOPIC, output_qos())?)
        } else {
            None
        };
    if let Some(limit) = opts.wait_for_subscribers {
        let deadline = Instant::now() + limit;
        while Instant::now() < deadline {
            let all = opts.wait_topics.iter().all(|t| {
                publishers
                    .get(t)
                    .is_some_and(|p| p.subscription_count(&spun.node) > 0)
            });
            if all {
                break;
            }
            std::thread::sleep(MATCH_POLL);
        }
    }
    // Latched topics first: /tf_static may be logged at time 0, long before the data.
    if let Some(p) = publishers.get(TF_STATIC_TOPIC) {
        for msg in bag.messages_on(TF_STATIC_TOPIC) {
            p.publish(&msg)?;
            *summary
                .published
                .entry(TF_STATIC_TOPIC.to_string())
                .or_default() += 1;
        }
    }
    let t0 = Instant::now();
    let mut first_log_ns: Option<u64> = None;
    let mut last_clock_ns: Option<u64> = None;
    let mut offset = Duration::ZERO;
    for _ in 0..opts.loops.max(1) {
        let loop_start = offset;
        let mut loop_end = offset;
        for msg in bag.messages() {
            let msg = msg?;
            if msg.topic == TF_STATIC_TOPIC {
                continue;
            }
            let first = *first_log_ns.get_or_insert(msg.log_time_ns);
            let at = loop_start
                + Duration::from_secs_f64(
                    (msg.log_time_ns.saturating_sub(first) as f64 / 1e9 / opts.rate)
                        .min(MAX_OFFSET_SECS),
                );
            loop_end = loop_end.max(at);
            let now = t0.elapsed();
            if at > now {
                std::thread::sleep(at - now);
            }
            if let Some(c) = &clock {
                if last_clock_ns != Some(msg.log_time_ns) {
                    let _ = c.publish(Clock {
                        clock: Time::from_nanos(msg.log_time_ns),
                    });
                    last_clock_ns = Some(msg.log_time_ns);
                }
            }
            if let Some(p) = publishers.get(msg.topic) {
                p.publish(&msg)?;
                *summary.published.entry(msg.topic.to_string()).or_default() += 1;
            }
        }
        offset = loop_end + Duration::from_millis(1);
    }
    summary.seconds = t0.elapsed().as_secs_f64();
    drop(clock);
    drop(publishers);
    spun.stop()?;
    drop(context);
    Ok(summary)
}
