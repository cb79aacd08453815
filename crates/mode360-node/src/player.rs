//! The bag player: a bag's messages published on DDS with their recorded timing (what
//! `mode360 play`, `demo` and `bench-node` drive the node with).
//!
//! Message `k` is sent at `start + (log_time_k - log_time_0) / rate`. `/tf_static` goes out
//! latched (reliable, transient local); with `publish_clock`, `/clock` carries each message's
//! log time before the message itself, so nodes with `use_sim_time` follow the bag. Supported
//! types: Image, CompressedImage, PointCloud2, TFMessage, DiagnosticArray, Clock; topics of
//! other types are skipped and listed in the summary.
//!
//! Looping: repetition `k` (0 for the first) is shifted by `k * (duration + period)`, where
//! `duration` is the last minus the first log time of the played messages and `period` the
//! bag's frame period ([`LoopTiming`]). Its header stamps, `/clock` and `/tf` stamps get the
//! same offset, so time keeps increasing by one frame period across the seam and a node's
//! synchronizer never sees a stamp go backwards. `/tf_static` is sent once, unchanged.

use super::dds::{
    create_publisher, dds_context, latched_qos, output_qos, runtime, sensor_qos, DdsOptions,
    SpunNode,
};
use super::topics::{CLOCK_TOPIC, TF_STATIC_TOPIC};
use super::NodeError;
use futures::future::BoxFuture;
use futures::FutureExt;
use mode360_io::bag::{BagError, BagMessage, BagReader};
use mode360_io::msgs::{
    Clock, CompressedImage, DiagnosticArray, Header, Image, PointCloud2, RosMessage, TFMessage,
    Time,
};
use ros2_client::Publisher;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// Why playing a bag failed.
#[derive(Debug, thiserror::Error)]
pub enum PlayError {
    #[error("rate must be a positive number, got {0}")]
    BadRate(f64),
    #[error(transparent)]
    Bag(#[from] BagError),
    #[error(transparent)]
    Node(#[from] NodeError),
    #[error("DDS: publishing on '{topic}': {problem}")]
    Publish { topic: String, problem: String },
}

/// Longest single sleep while pacing, so that a stop request is seen quickly.
const STOP_POLL: Duration = Duration::from_millis(50);
/// Largest wait before one message, seconds (guards against bags with absurd time gaps).
const MAX_OFFSET_S: f64 = 24.0 * 3600.0;
/// After every waited-for topic has a subscriber, wait this long more before the first
/// message. Discovery is two one-way handshakes: the player's writer learns of the subscriber
/// before the subscriber has learnt of the writer, and a sample sent in between is dropped by
/// the subscriber as coming from an unknown writer (the node then lost a bag's whole first
/// frame now and then on a loaded machine).
pub const SUBSCRIBER_SETTLE: Duration = Duration::from_secs(1);
/// After the last message, keep the player's writers this long before they go: RustDDS
/// paces the fragments of large samples (a frame of four 512-wide images, 1.6 MB, leaves in
/// about 50 ms; docs/node.md) and a lost fragment is repaired after the writer's next
/// heartbeat. Without it the demo lost its last frame.
pub const FLUSH_LINGER: Duration = Duration::from_secs(1);
/// Loop gap when the bag has no measurable frame period (one message per topic).
pub const DEFAULT_LOOP_GAP_NS: u64 = 100_000_000;

/// What to play.
#[derive(Clone, Debug)]
pub struct PlayOptions {
    pub input: PathBuf,
    /// Playback speed factor (1 = recorded timing).
    pub rate: f64,
    /// Play the bag this many times (at least once; `usize::MAX` plays until stopped).
    pub loops: usize,
    pub publish_clock: bool,
    pub dds: DdsOptions,
    /// Before playing, wait up to this long until every topic in `wait_topics` has a
    /// matched subscriber, then [`SUBSCRIBER_SETTLE`] more.
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
    pub elapsed_s: f64,
    /// Repetitions started (the last one may have been cut short by a stop request).
    pub loops_played: usize,
    /// Timing of one repetition (`None` for a bag with nothing to play).
    pub timing: Option<LoopTiming>,
}

/// Timing of one pass through a bag, from the log times of the played messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LoopTiming {
    /// Log time of the first played message, ns.
    pub first_ns: u64,
    /// Last minus first log time, ns.
    pub duration_ns: u64,
    /// Frame period: the median gap between consecutive messages of the same topic, ns
    /// ([`DEFAULT_LOOP_GAP_NS`] when no topic has two messages).
    pub period_ns: u64,
}

impl LoopTiming {
    /// From each topic's log times in order; `None` when there are none.
    pub fn from_log_times<'a>(per_topic: impl IntoIterator<Item = &'a [u64]>) -> Option<Self> {
        let mut first = u64::MAX;
        let mut last = 0;
        let mut gaps = Vec::new();
        for times in per_topic {
            for w in times.windows(2) {
                if w[1] > w[0] {
                    gaps.push(w[1] - w[0]);
                }
            }
            if let (Some(&a), Some(&b)) = (times.first(), times.last()) {
                first = first.min(a);
                last = last.max(b);
            }
        }
        if first > last {
            return None;
        }
        gaps.sort_unstable();
        Some(Self {
            first_ns: first,
            duration_ns: last - first,
            period_ns: gaps
                .get(gaps.len() / 2)
                .copied()
                .unwrap_or(DEFAULT_LOOP_GAP_NS),
        })
    }

    /// Distance between the starts of two repetitions, ns.
    pub fn stride_ns(&self) -> u64 {
        self.duration_ns.saturating_add(self.period_ns)
    }

    /// Stamp offset of repetition `k` (0 for the first), ns.
    pub fn offset_ns(&self, k: usize) -> u64 {
        (k as u64).saturating_mul(self.stride_ns())
    }
}

/// `t + offset_ns`.
pub fn shift_time(t: Time, offset_ns: u64) -> Time {
    Time::from_nanos(t.to_nanos().saturating_add(offset_ns))
}

/// Messages whose time stamps a looped playback shifts.
pub trait Restamp {
    /// Adds `offset_ns` to every stamp in the message.
    fn restamp(&mut self, offset_ns: u64);
    /// The message's (first) stamp, ns.
    fn stamp_ns(&self) -> Option<u64>;
}

impl Restamp for Header {
    fn restamp(&mut self, offset_ns: u64) {
        self.stamp = shift_time(self.stamp, offset_ns);
    }
    fn stamp_ns(&self) -> Option<u64> {
        Some(self.stamp.to_nanos())
    }
}

macro_rules! restamp_header {
    ($($ty:ty),*) => {
        $(impl Restamp for $ty {
            fn restamp(&mut self, offset_ns: u64) {
                self.header.restamp(offset_ns);
            }
            fn stamp_ns(&self) -> Option<u64> {
                self.header.stamp_ns()
            }
        })*
    };
}

restamp_header!(Image, CompressedImage, PointCloud2, DiagnosticArray);

impl Restamp for TFMessage {
    fn restamp(&mut self, offset_ns: u64) {
        for t in &mut self.transforms {
            t.header.restamp(offset_ns);
        }
    }
    fn stamp_ns(&self) -> Option<u64> {
        self.transforms.first().and_then(|t| t.header.stamp_ns())
    }
}

impl Restamp for Clock {
    fn restamp(&mut self, offset_ns: u64) {
        self.clock = shift_time(self.clock, offset_ns);
    }
    fn stamp_ns(&self) -> Option<u64> {
        Some(self.clock.to_nanos())
    }
}

/// One published message, as reported to the observer of [`play_bag_until`].
#[derive(Clone, Copy, Debug)]
pub struct Published<'a> {
    pub topic: &'a str,
    pub type_name: &'a str,
    /// Stamp as sent (after restamping), ns.
    pub stamp_ns: Option<u64>,
    /// Repetition, 0 for the first.
    pub loop_index: usize,
}

enum AnyPublisher {
    Image(Publisher<Image>),
    Compressed(Publisher<CompressedImage>),
    Points(Publisher<PointCloud2>),
    Tf(Publisher<TFMessage>),
    Diagnostics(Publisher<DiagnosticArray>),
    Clock(Publisher<Clock>),
}

fn send<T>(p: &Publisher<T>, msg: &BagMessage<'_>, offset_ns: u64) -> Result<Option<u64>, PlayError>
where
    T: RosMessage + Restamp + std::fmt::Debug,
{
    let mut m: T = msg.decode()?;
    if offset_ns > 0 {
        m.restamp(offset_ns);
    }
    let stamp = m.stamp_ns();
    p.publish(m).map_err(|e| PlayError::Publish {
        topic: msg.topic.to_string(),
        problem: format!("{e:?}"),
    })?;
    Ok(stamp)
}

impl AnyPublisher {
    /// Publishes `msg` with its stamps shifted by `offset_ns`; returns the stamp sent.
    fn publish(&self, msg: &BagMessage<'_>, offset_ns: u64) -> Result<Option<u64>, PlayError> {
        match self {
            Self::Image(p) => send(p, msg, offset_ns),
            Self::Compressed(p) => send(p, msg, offset_ns),
            Self::Points(p) => send(p, msg, offset_ns),
            Self::Tf(p) => send(p, msg, offset_ns),
            Self::Diagnostics(p) => send(p, msg, offset_ns),
            Self::Clock(p) => send(p, msg, offset_ns),
        }
    }

    /// Resolves once a subscription matched (needs the node's spinner running).
    fn wait_for_subscription<'a>(&'a self, node: &'a ros2_client::Node) -> BoxFuture<'a, ()> {
        match self {
            Self::Image(p) => p.wait_for_subscription(node).boxed(),
            Self::Compressed(p) => p.wait_for_subscription(node).boxed(),
            Self::Points(p) => p.wait_for_subscription(node).boxed(),
            Self::Tf(p) => p.wait_for_subscription(node).boxed(),
            Self::Diagnostics(p) => p.wait_for_subscription(node).boxed(),
            Self::Clock(p) => p.wait_for_subscription(node).boxed(),
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
    play_bag_until(opts, &AtomicBool::new(false), |_| {})
}

/// Sleeps until `t0 + at`, in slices, returning false early when `stop` turns true.
fn pace(t0: Instant, at: Duration, stop: &AtomicBool) -> bool {
    loop {
        if stop.load(Ordering::SeqCst) {
            return false;
        }
        let now = t0.elapsed();
        if now >= at {
            return true;
        }
        std::thread::sleep((at - now).min(STOP_POLL));
    }
}

/// A publisher for every topic of the bag whose type the player knows (the others are listed
/// in `summary.skipped_topics`), with its type name.
fn topic_publishers(
    bag: &BagReader,
    spun: &mut SpunNode,
    summary: &mut PlaySummary,
) -> Result<BTreeMap<String, (AnyPublisher, String)>, PlayError> {
    let mut publishers = BTreeMap::new();
    for info in bag.topics() {
        match publisher_for(&mut spun.node, &info.topic, &info.type_name)? {
            Some(p) => {
                publishers.insert(info.topic.clone(), (p, info.type_name.clone()));
            }
            None => summary.skipped_topics.push(info.topic.clone()),
        }
    }
    Ok(publishers)
}

/// Timing of one pass over the messages played in the loop (all but `/tf_static`).
fn loop_timing(bag: &BagReader) -> Result<Option<LoopTiming>, PlayError> {
    let mut log_times: BTreeMap<&str, Vec<u64>> = BTreeMap::new();
    for msg in bag.messages() {
        let msg = msg?;
        if msg.topic != TF_STATIC_TOPIC {
            log_times
                .entry(msg.topic)
                .or_default()
                .push(msg.log_time_ns);
        }
    }
    Ok(LoopTiming::from_log_times(
        log_times.values().map(|v| v.as_slice()),
    ))
}

/// Waits up to `limit` until every topic of `topics` the bag has is subscribed to, or `stop`,
/// then [`SUBSCRIBER_SETTLE`] for the subscribers to learn of the player's writers.
fn wait_for_subscribers(
    topics: &[String],
    publishers: &BTreeMap<String, (AnyPublisher, String)>,
    spun: &SpunNode,
    stop: &AtomicBool,
    limit: Duration,
) -> Result<(), PlayError> {
    let matched = futures::future::join_all(
        topics
            .iter()
            .filter_map(|t| publishers.get(t))
            .map(|(p, _)| p.wait_for_subscription(&spun.node)),
    );
    let stopped = async {
        while !stop.load(Ordering::SeqCst) {
            tokio::time::sleep(STOP_POLL).await;
        }
    };
    runtime()?.block_on(async {
        tokio::select! {
            _ = tokio::time::timeout(limit, matched) => {}
            _ = stopped => {}
        }
    });
    pace(Instant::now(), SUBSCRIBER_SETTLE, stop);
    Ok(())
}

/// Plays `opts.input` on DDS until done or until `stop` turns true, calling `on_published`
/// right after each message went out.
pub fn play_bag_until(
    opts: &PlayOptions,
    stop: &AtomicBool,
    mut on_published: impl FnMut(&Published<'_>),
) -> Result<PlaySummary, PlayError> {
    if !(opts.rate.is_finite() && opts.rate > 0.0) {
        return Err(PlayError::BadRate(opts.rate));
    }
    let bag = BagReader::open(&opts.input)?;
    let context = dds_context(&opts.dds)?;
    let mut spun = SpunNode::new(
        &context,
        "/",
        &format!("mode360_play_{}", std::process::id()),
    )?;
    let mut summary = PlaySummary::default();
    let publishers = topic_publishers(&bag, &mut spun, &mut summary)?;
    let clock: Option<Publisher<Clock>> =
        if opts.publish_clock && !publishers.contains_key(CLOCK_TOPIC) {
            Some(create_publisher(&mut spun.node, CLOCK_TOPIC, output_qos())?)
        } else {
            None
        };
    let timing = loop_timing(&bag)?;
    summary.timing = timing;
    if let Some(limit) = opts.wait_for_subscribers {
        wait_for_subscribers(&opts.wait_topics, &publishers, &spun, stop, limit)?;
    }
    // Latched topics first: /tf_static may be logged at time 0, long before the data.
    if let Some((p, type_name)) = publishers.get(TF_STATIC_TOPIC) {
        for msg in bag.messages_on(TF_STATIC_TOPIC) {
            let stamp_ns = p.publish(&msg, 0)?;
            *summary
                .published
                .entry(TF_STATIC_TOPIC.to_string())
                .or_default() += 1;
            on_published(&Published {
                topic: TF_STATIC_TOPIC,
                type_name,
                stamp_ns,
                loop_index: 0,
            });
        }
    }
    let t0 = Instant::now();
    if let Some(timing) = timing {
        let secs = |ns: u64| ns as f64 / 1e9 / opts.rate;
        let stride = Duration::from_secs_f64(
            secs(timing.duration_ns).min(MAX_OFFSET_S) + secs(timing.period_ns),
        );
        let mut last_clock_ns: Option<u64> = None;
        'repetitions: for k in 0..opts.loops.max(1) {
            if stop.load(Ordering::SeqCst) {
                break;
            }
            summary.loops_played = k + 1;
            let offset_ns = timing.offset_ns(k);
            let loop_start = stride.saturating_mul(u32::try_from(k).unwrap_or(u32::MAX));
            for msg in bag.messages() {
                let msg = msg?;
                if msg.topic == TF_STATIC_TOPIC {
                    continue;
                }
                let within = secs(msg.log_time_ns.saturating_sub(timing.first_ns));
                let at = loop_start + Duration::from_secs_f64(within.min(MAX_OFFSET_S));
                if !pace(t0, at, stop) {
                    break 'repetitions;
                }
                let log_ns = msg.log_time_ns.saturating_add(offset_ns);
                if let Some(c) = &clock {
                    if last_clock_ns != Some(log_ns) {
                        let _ = c.publish(Clock {
                            clock: Time::from_nanos(log_ns),
                        });
                        last_clock_ns = Some(log_ns);
                    }
                }
                if let Some((p, type_name)) = publishers.get(msg.topic) {
                    let stamp_ns = p.publish(&msg, offset_ns)?;
                    *summary.published.entry(msg.topic.to_string()).or_default() += 1;
                    on_published(&Published {
                        topic: msg.topic,
                        type_name,
                        stamp_ns,
                        loop_index: k,
                    });
                }
            }
        }
    }
    summary.elapsed_s = t0.elapsed().as_secs_f64();
    // The last messages may still be on their way (paced fragments, repair): linger.
    pace(Instant::now(), FLUSH_LINGER, stop);
    drop(clock);
    drop(publishers);
    spun.stop()?;
    drop(context);
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;
    const T0: u64 = 1_700_000_000_000_000_000;

    #[test]
    fn loop_timing_is_duration_plus_one_frame_period() {
        // Four cameras and ground truth at 10 Hz, 4 frames, cameras logged 2 ms apart.
        let cams: Vec<Vec<u64>> = (0..4)
            .map(|c| (0..4).map(|f| T0 + f * 100 * MS + c * 2 * MS).collect())
            .collect();
        let gt: Vec<u64> = (0..4).map(|f| T0 + f * 100 * MS).collect();
        let timing =
            LoopTiming::from_log_times(cams.iter().map(|v| v.as_slice()).chain([gt.as_slice()]))
                .unwrap();
        assert_eq!(timing.first_ns, T0);
        assert_eq!(timing.duration_ns, 306 * MS);
        assert_eq!(timing.period_ns, 100 * MS);
        assert_eq!(timing.stride_ns(), 406 * MS);
        assert_eq!(timing.offset_ns(0), 0);
        assert_eq!(timing.offset_ns(1), 406 * MS);
        assert_eq!(timing.offset_ns(3), 1218 * MS);
        // Frame f of repetition k is stamped T0 + f*100ms + k*406ms: strictly increasing
        // across the seam, one frame period after the last frame of the previous loop.
        let stamp = |k: usize, f: u64| T0 + f * 100 * MS + timing.offset_ns(k);
        assert_eq!(stamp(1, 0) - stamp(0, 3), 106 * MS);
        assert!(stamp(1, 0) > stamp(0, 3));
    }

    #[test]
    fn loop_timing_edge_cases() {
        assert_eq!(LoopTiming::from_log_times(Vec::<&[u64]>::new()), None);
        assert_eq!(LoopTiming::from_log_times([&[][..]]), None);
        let one = [T0];
        let t = LoopTiming::from_log_times([&one[..]]).unwrap();
        assert_eq!((t.duration_ns, t.period_ns), (0, DEFAULT_LOOP_GAP_NS));
        assert_eq!(t.offset_ns(2), 2 * DEFAULT_LOOP_GAP_NS);
        // Median gap, not the smallest: one irregular gap does not set the period.
        let times = [0, 100 * MS, 200 * MS, 205 * MS, 305 * MS, 405 * MS];
        let t = LoopTiming::from_log_times([&times[..]]).unwrap();
        assert_eq!(t.period_ns, 100 * MS);
        assert_eq!(t.offset_ns(usize::MAX), u64::MAX);
    }

    #[test]
    fn restamping_shifts_every_stamp() {
        let offset = 1_406 * MS;
        let mut img = Image {
            header: Header::new(T0 + 5, "cam1_link"),
            ..Default::default()
        };
        img.restamp(offset);
        assert_eq!(img.header.stamp.to_nanos(), T0 + 5 + offset);
        assert_eq!(img.stamp_ns(), Some(T0 + 5 + offset));
        assert_eq!(img.header.frame_id, "cam1_link");
        let mut clock = Clock {
            clock: Time::from_nanos(T0),
        };
        clock.restamp(offset);
        assert_eq!(clock.clock.to_nanos(), T0 + offset);
        let mut tf = TFMessage {
            transforms: vec![Default::default(), Default::default()],
        };
        tf.transforms[0].header = Header::new(T0, "base_link");
        tf.transforms[1].header = Header::new(T0 + 1, "base_link");
        tf.restamp(offset);
        assert_eq!(tf.transforms[0].header.stamp.to_nanos(), T0 + offset);
        assert_eq!(tf.transforms[1].header.stamp.to_nanos(), T0 + 1 + offset);
        assert_eq!(tf.stamp_ns(), Some(T0 + offset));
        // Nanoseconds carry into seconds.
        let t = shift_time(
            Time {
                sec: 10,
                nanosec: 999_999_999,
            },
            2,
        );
        assert_eq!((t.sec, t.nanosec), (11, 1));
    }
}
