//! `mode360 bench-node`: the live node under a looped bag, measured end to end.
//!
//! The node runs in-process on a private DDS domain (loopback only). A player thread plays a
//! rig bag into it in a loop (restamped, see [`super::play`]) at the recorded rate, and the
//! bench listens to `depth`. Measured:
//!
//! * latency: wall time from publishing the last image of a group to receiving the node's
//!   `depth` with that group's stamp (queueing in the 1-slot mailbox included);
//! * rates: complete groups published per second (input) and `depth` messages received per
//!   second (output), both over the playing window;
//! * groups the node synchronized, processed and dropped (mailbox), and groups published but
//!   never synchronized (lost on best-effort DDS or unmatched);
//! * resident memory of the process (node, player and listener; VmRSS from
//!   `/proc/self/status`) every second: start, max, end, and the least-squares slope in MiB/min
//!   over the steady state, the second half of the time after the first depth arrived
//!   (allocator arenas and DDS buffers fill up during the first half; growth after that
//!   means a leak).

use super::estimator_args::EstimatorArgs;
use anyhow::{anyhow, bail, Context, Result};
use mode360_core::memory::resident_mib;
use mode360_estimator::EstimatorSpec;
use mode360_io::msgs::{CompressedImage, Image, RosMessage};
use mode360_node::params::DEFAULT_RIG_FILE;
use mode360_node::player::{play_bag_until, PlayOptions, PlaySummary, Published};
use mode360_node::{
    create_subscription, dds_context, runtime, spawn_node, DdsOptions, NodeHandle, NodeHealth,
    NodeParams, ShutdownSignals, SpunNode,
};

mod input;
mod report;
use clap::Args;
use futures::StreamExt;
use input::{check_estimator, prepare_input, BenchInput};
use report::load_average_1m;
pub use report::{percentile, slope_mib_per_min, BenchReport, LatencyStats, RssStats};
use ros2_client::qos::History;
use ros2_client::QosProfile;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// The bundled bag, used when its width is the one asked for.
/// Default width (of the rendered input and of the node's output).
pub const DEFAULT_WIDTH: usize = 512;
/// Frames rendered when the bundled bag does not fit.
pub const RENDERED_FRAMES: usize = 8;
/// Private DDS domain of the bench.
pub const DEFAULT_BENCH_DOMAIN: u16 = 87;
/// How long to wait for DDS discovery.
const DISCOVERY_TIMEOUT: Duration = Duration::from_secs(20);
/// Longest wait for the node to synchronize groups in flight when playing stops.
const SETTLE_TIMEOUT: Duration = Duration::from_secs(2);
const SETTLE_POLL: Duration = Duration::from_millis(20);
/// Memory sampling period.
const RSS_PERIOD: Duration = Duration::from_secs(1);

/// What to run.
#[derive(Clone, Debug)]
pub struct BenchOptions {
    /// The estimator and its weights (default: the shipped ones).
    pub estimator: EstimatorSpec,
    /// Output width (and width of the rendered input); default: the bag's width, or
    /// [`DEFAULT_WIDTH`] without a bag.
    pub width: Option<usize>,
    /// How long to play.
    pub duration: Duration,
    /// Rig bag to play; default: the bundled bag if its width fits, else frames rendered
    /// with `rig_file`.
    pub bag: Option<PathBuf>,
    /// Rig of rendered frames.
    pub rig_file: PathBuf,
    /// Playback speed factor (1 = the bag's own frame rate).
    pub rate: f64,
    /// The node's `rig_health_checks` (lens and calibration drift checks).
    pub rig_health_checks: bool,
    pub dds: DdsOptions,
}

impl Default for BenchOptions {
    fn default() -> Self {
        Self {
            estimator: EstimatorSpec::default(),
            duration: Duration::from_secs(60),
            width: None,
            bag: None,
            rig_file: DEFAULT_RIG_FILE.into(),
            rate: 1.0,
            rig_health_checks: true,
            dds: DdsOptions {
                domain_id: DEFAULT_BENCH_DOMAIN,
                loopback_only: true,
            },
        }
    }
}

/// Per-stamp publication state of the player.
#[derive(Default)]
struct PlayerState {
    /// stamp -> (images published, time of the last one).
    images: HashMap<u64, (usize, Instant)>,
    /// Groups with all cameras published.
    complete: u64,
    first_publish: Option<Instant>,
}

/// What a bench run measured outside the node.
struct Measured {
    /// Seconds from the first publish to the end of listening.
    window_s: f64,
    /// Complete groups the player published.
    groups_published: u64,
    heard: Heard,
    /// Resident memory samples `(s since start, MiB)`.
    rss_samples: Vec<(f64, f64)>,
    /// Seconds from the bench's start to the node's shutdown.
    end_s: f64,
    load_start: Option<f64>,
    load_end: Option<f64>,
}

/// The report of a run on `input` from what was measured and the node's final `health`.
fn assemble_report(
    opts: &BenchOptions,
    input: BenchInput,
    m: Measured,
    health: &NodeHealth,
) -> BenchReport {
    let window_s = m.window_s;
    let per_s = |n: u64| {
        if window_s > 0.0 {
            n as f64 / window_s
        } else {
            0.0
        }
    };
    BenchReport {
        estimator: opts.estimator.kind.to_string(),
        device: opts.estimator.device.to_string(),
        bag: input.bag_path.display().to_string(),
        input_width: input.input_width,
        output_width: input.output_width,
        cameras: input.camera_topics.len(),
        play_rate: opts.rate,
        window_s,
        groups_published: m.groups_published,
        input_rate_hz: per_s(m.groups_published),
        depth_received: m.heard.depth_received,
        output_rate_hz: per_s(m.heard.depth_received),
        groups_synced: health.sync.groups,
        groups_processed: health.groups_processed,
        groups_dropped: health.groups_dropped,
        groups_lost: m.groups_published.saturating_sub(health.sync.groups),
        pipeline_errors: health.pipeline_errors,
        mean_inference_ms: health.mean_latency_ms,
        mean_mailbox_wait_ms: health.mean_mailbox_wait_ms,
        latency: LatencyStats::from_samples(&m.heard.latencies_ms),
        rss: rss_stats(&m.rss_samples, m.heard.first_depth_s, m.end_s),
        cpus: std::thread::available_parallelism().map_or(1, |n| n.get()),
        load_average_1m_start: m.load_start,
        load_average_1m_end: m.load_end,
    }
}

/// Waits up to [`SETTLE_TIMEOUT`] for the node to synchronize the groups still in flight
/// when the player stopped (they are not lost).
fn settle(node: &NodeHandle, groups_published: u64) {
    let t0 = Instant::now();
    while node.health().sync.groups < groups_published && t0.elapsed() < SETTLE_TIMEOUT {
        std::thread::sleep(SETTLE_POLL);
    }
}

/// The bench's own DDS node, listening to the node's `depth` (fields in drop order).
struct DepthListener {
    depth_sub: ros2_client::Subscription<Image>,
    node: SpunNode,
    context: ros2_client::Context,
}

impl DepthListener {
    /// Joins the bench's DDS domain, subscribes to `/depth` and waits up to
    /// [`DISCOVERY_TIMEOUT`] for its publisher.
    fn open(rt: &tokio::runtime::Runtime, dds: &DdsOptions) -> Result<Self> {
        let context = dds_context(dds)?;
        let mut node = SpunNode::new(&context, "/", "mode360_bench_listener")?;
        let depth_sub = create_subscription::<Image>(
            &mut node.node,
            "/depth",
            QosProfile::publisher_default().history(History::KeepLast { depth: 10 }),
        )?;
        rt.block_on(async {
            let _ =
                tokio::time::timeout(DISCOVERY_TIMEOUT, depth_sub.wait_for_publisher(&node.node))
                    .await;
        });
        Ok(Self {
            depth_sub,
            node,
            context,
        })
    }

    /// Drops the subscription, stops the listener node, then leaves the domain.
    fn close(self) -> Result<()> {
        let Self {
            depth_sub,
            node,
            context,
        } = self;
        drop(depth_sub);
        node.stop()?;
        drop(context);
        Ok(())
    }
}

/// Runs the bench (see the module docs).
pub fn run_bench(opts: &BenchOptions) -> Result<BenchReport> {
    check_estimator(opts)?;
    let mut temps = Vec::new();
    let input = prepare_input(opts, &mut temps)?;

    let rt = runtime()?;
    let mut signals = {
        let _guard = rt.enter();
        ShutdownSignals::install()?
    };
    let load_start = load_average_1m();
    let bench_start = Instant::now();
    let node = spawn_node(
        NodeParams {
            rig_file: input.rig_path.clone(),
            estimator: opts.estimator.clone(),
            output_width: input.output_width,
            camera_timeout_s: 60.0,
            rig_health_checks: opts.rig_health_checks,
            ..Default::default()
        },
        opts.dds.clone(),
    )?;
    let listener = DepthListener::open(&rt, &opts.dds)?;
    let mut rss_samples: Vec<(f64, f64)> = Vec::new();
    if let Some(mib) = resident_mib() {
        rss_samples.push((bench_start.elapsed().as_secs_f64(), mib));
    }

    let published = Arc::new(Mutex::new(PlayerState::default()));
    let stop = Arc::new(AtomicBool::new(false));
    let player = spawn_player(
        opts,
        &input.bag_path,
        &input.camera_topics,
        &published,
        &stop,
    )?;
    let heard = rt.block_on(listen(
        opts,
        &listener.depth_sub,
        &mut signals,
        Watched {
            published: &published,
            player: &player,
            bench_start,
        },
        &mut rss_samples,
    ));
    let window_s = lock_published(&published)
        .first_publish
        .map_or(0.0, |s| s.elapsed().as_secs_f64());
    stop.store(true, Ordering::SeqCst);
    let play_result = player
        .join()
        .map_err(|_| anyhow!("the player thread panicked"))?;
    let groups_published = lock_published(&published).complete;
    settle(&node, groups_published);
    if let Some(mib) = resident_mib() {
        rss_samples.push((bench_start.elapsed().as_secs_f64(), mib));
    }
    let load_end = load_average_1m();
    listener.close()?;
    let health: NodeHealth = node.shutdown()?;
    play_result?;
    if heard.interrupted {
        tracing::warn!("interrupted: the figures cover {window_s:.1} s");
    }
    let measured = Measured {
        window_s,
        groups_published,
        heard,
        rss_samples,
        end_s: bench_start.elapsed().as_secs_f64(),
        load_start,
        load_end,
    };
    Ok(assemble_report(opts, input, measured, &health))
}

/// The player thread and what it returns.
type PlayerThread = std::thread::JoinHandle<Result<PlaySummary>>;

/// Plays the bag in a loop until `stop`, noting in `published` when each group's images went
/// out.
fn spawn_player(
    opts: &BenchOptions,
    bag_path: &Path,
    camera_topics: &[String],
    published: &Arc<Mutex<PlayerState>>,
    stop: &Arc<AtomicBool>,
) -> Result<PlayerThread> {
    let published = published.clone();
    let stop = stop.clone();
    let play_opts = PlayOptions {
        input: bag_path.to_path_buf(),
        rate: opts.rate,
        loops: usize::MAX,
        publish_clock: false,
        dds: opts.dds.clone(),
        wait_for_subscribers: Some(DISCOVERY_TIMEOUT),
        wait_topics: camera_topics.to_vec(),
    };
    let topics = camera_topics.to_vec();
    let n_cams = topics.len();
    std::thread::Builder::new()
        .name("mode360-bench-player".into())
        .spawn(move || {
            play_bag_until(&play_opts, &stop, |p: &Published<'_>| {
                let is_image =
                    p.type_name == Image::TYPE_NAME || p.type_name == CompressedImage::TYPE_NAME;
                let Some(stamp) = p.stamp_ns else { return };
                if !is_image || !topics.iter().any(|t| t == p.topic) {
                    return;
                }
                let now = Instant::now();
                let mut st = lock_published(&published);
                st.first_publish.get_or_insert(now);
                let entry = st.images.entry(stamp).or_insert((0, now));
                entry.0 += 1;
                entry.1 = now;
                if entry.0 == n_cams {
                    st.complete += 1;
                }
            })
            .map_err(anyhow::Error::from)
        })
        .context("starting the player thread")
}

/// What the listener watches besides `depth`.
struct Watched<'a> {
    published: &'a Mutex<PlayerState>,
    player: &'a PlayerThread,
    bench_start: Instant,
}

/// What the listener heard.
struct Heard {
    latencies_ms: Vec<f64>,
    depth_received: u64,
    /// Seconds from the bench's start to the first depth image.
    first_depth_s: Option<f64>,
    /// Stopped by a signal.
    interrupted: bool,
}

/// Listens to `depth` until the duration is over (counted from the first publish), the player
/// ends or a signal comes, sampling the resident size every [`RSS_PERIOD`].
async fn listen(
    opts: &BenchOptions,
    depth_sub: &ros2_client::Subscription<Image>,
    signals: &mut ShutdownSignals,
    watched: Watched<'_>,
    rss_samples: &mut Vec<(f64, f64)>,
) -> Heard {
    let mut heard = Heard {
        latencies_ms: Vec::new(),
        depth_received: 0,
        first_depth_s: None,
        interrupted: false,
    };
    let mut depth = depth_sub.async_stream().boxed();
    let mut rss_tick = tokio::time::interval(RSS_PERIOD);
    let mut started: Option<Instant> = None;
    loop {
        if started.is_none() {
            started = lock_published(watched.published).first_publish;
        }
        if started.is_some_and(|s| s.elapsed() >= opts.duration) || watched.player.is_finished() {
            return heard;
        }
        tokio::select! {
            name = signals.recv() => {
                tracing::info!("{name}: stopping the bench early");
                heard.interrupted = true;
                return heard;
            }
            Some(r) = depth.next() => {
                let now = Instant::now();
                if let Ok((m, _)) = r {
                    heard.depth_received += 1;
                    heard
                        .first_depth_s
                        .get_or_insert(watched.bench_start.elapsed().as_secs_f64());
                    let stamp = m.header.stamp.to_nanos();
                    if let Some((_, t)) = lock_published(watched.published).images.get(&stamp) {
                        heard.latencies_ms.push(now.duration_since(*t).as_secs_f64() * 1e3);
                    }
                }
            }
            _ = rss_tick.tick() => {
                if let Some(mib) = resident_mib() {
                    rss_samples.push((watched.bench_start.elapsed().as_secs_f64(), mib));
                }
            }
        }
    }
}

/// Memory figures of the samples `(s since start, MiB)`; the steady state is the second half
/// of the time after the first depth image.
fn rss_stats(samples: &[(f64, f64)], first_depth_s: Option<f64>, end_s: f64) -> Option<RssStats> {
    let (first, last) = (samples.first()?, samples.last()?);
    let steady_from_s = first_depth_s.map(|f| f + (end_s - f) / 2.0);
    let steady: Vec<(f64, f64)> = samples
        .iter()
        .copied()
        .filter(|(t, _)| steady_from_s.is_some_and(|f| *t >= f))
        .collect();
    Some(RssStats {
        start_mib: first.1,
        max_mib: samples.iter().map(|s| s.1).fold(f64::MIN, f64::max),
        end_mib: last.1,
        slope_mib_per_min: slope_mib_per_min(&steady),
        steady_from_s,
        steady_min_mib: steady.iter().map(|s| s.1).reduce(f64::min),
        steady_max_mib: steady.iter().map(|s| s.1).reduce(f64::max),
        samples: samples.to_vec(),
    })
}

fn lock_published(p: &Mutex<PlayerState>) -> std::sync::MutexGuard<'_, PlayerState> {
    p.lock().unwrap_or_else(|e| e.into_inner())
}

#[derive(Args)]
pub struct BenchNodeArgs {
    #[command(flatten)]
    pub estimator: EstimatorArgs,
    /// Output width (and width of rendered input); default: the bag's, or 512 without --bag.
    #[arg(long)]
    pub width: Option<usize>,
    /// How long to play, seconds.
    #[arg(long, default_value_t = 60.0)]
    pub duration_s: f64,
    /// Rig bag to play in a loop (default: the bundled bag, or frames rendered at --width).
    #[arg(long)]
    pub bag: Option<PathBuf>,
    /// Rig calibration of rendered frames.
    #[arg(long, default_value = "launch_configs/rig_deep360.yaml")]
    pub rig: PathBuf,
    /// Playback speed factor (1 = the bag's frame rate).
    #[arg(long, default_value_t = 1.0)]
    pub rate: f64,
    /// Run the node without its lens and calibration drift checks (their cost is the median
    /// latency's difference to a run with them).
    #[arg(long)]
    pub no_rig_health_checks: bool,
    /// Private DDS domain (loopback only).
    #[arg(long, default_value_t = DEFAULT_BENCH_DOMAIN)]
    pub domain_id: u16,
    /// Also write the report as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

/// `mode360 bench-node`: runs the bench and prints (and optionally saves) its report.
pub fn run(a: BenchNodeArgs) -> Result<()> {
    if !(a.duration_s.is_finite() && a.duration_s > 0.0) {
        bail!("--duration-s must be a positive number of seconds");
    }
    let report = run_bench(&BenchOptions {
        estimator: a.estimator.spec(),
        width: a.width,
        duration: std::time::Duration::from_secs_f64(a.duration_s),
        bag: a.bag,
        rig_file: a.rig,
        rate: a.rate,
        rig_health_checks: !a.no_rig_health_checks,
        dds: DdsOptions {
            domain_id: a.domain_id,
            loopback_only: true,
        },
    })?;
    print!("{}", report.to_table());
    if let Some(path) = a.json {
        mode360_core::atomic_file::write_atomic(&path, serde_json::to_string_pretty(&report)?)
            .with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
