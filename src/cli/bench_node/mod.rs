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

use super::bundled_bag::BUNDLED_BAG;
use super::estimator_args::EstimatorArgs;
use anyhow::{anyhow, bail, Context, Result};
use mode360_core::memory::resident_mib;
use mode360_core::shipped::{self, Origin};
use mode360_estimator::estimator::EstimatorSpec;
use mode360_io::bag::RigBagReader;
use mode360_io::msgs::{CompressedImage, Image, RosMessage};
use mode360_node::node::params::DEFAULT_RIG_FILE;
use mode360_node::node::player::{play_bag_until, PlayOptions, PlaySummary, Published};
use mode360_node::node::{
    create_subscription, dds_context, runtime, spawn_node, DdsOptions, NodeHealth, NodeParams,
    ShutdownSignals, SpunNode,
};
use mode360_synth::synth::record::{record_synthetic_bag, RecordOptions};
use mode360_synth::synth::SynthConfig;

mod report;
use clap::Args;
use futures::StreamExt;
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

/// A temporary file removed on drop.
struct TempFile(PathBuf);

impl Drop for TempFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

fn temp_path(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("mode360_bench_{}_{name}", std::process::id()))
}

/// Width of the first camera image of a rig bag.
fn bag_width(reader: &RigBagReader) -> Result<usize> {
    let frame = reader
        .frames()
        .next()
        .ok_or_else(|| anyhow!("the bag has no complete frame"))??;
    Ok(frame.images[0].width() as usize)
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

/// Runs the bench (see the module docs).
pub fn run_bench(opts: &BenchOptions) -> Result<BenchReport> {
    check_estimator(opts)?;
    let mut temps = Vec::new();
    let bag_path = bench_input(opts, &mut temps)?;
    let reader = RigBagReader::open(&bag_path)?;
    let rig = reader.rig().clone();
    let input_width = bag_width(&reader)?;
    let output_width = opts.width.unwrap_or(input_width);
    drop(reader);
    let rig_path = temp_path("rig.yaml");
    std::fs::write(&rig_path, rig.to_yaml())
        .with_context(|| format!("writing {}", rig_path.display()))?;
    temps.push(TempFile(rig_path.clone()));
    let camera_topics: Vec<String> = rig.cameras.iter().map(|c| c.topic.clone()).collect();

    let rt = runtime()?;
    let mut signals = {
        let _guard = rt.enter();
        ShutdownSignals::install()?
    };
    let load_start = load_average_1m();
    let bench_start = Instant::now();
    let node = spawn_node(
        NodeParams {
            rig_file: rig_path.clone(),
            estimator: opts.estimator.clone(),
            output_width,
            camera_timeout_s: 60.0,
            rig_health_checks: opts.rig_health_checks,
            ..Default::default()
        },
        opts.dds.clone(),
    )?;
    let context = dds_context(&opts.dds)?;
    let mut listener = SpunNode::new(&context, "/", "mode360_bench_listener")?;
    let depth_sub = create_subscription::<Image>(
        &mut listener.node,
        "/depth",
        QosProfile::publisher_default().history(History::KeepLast { depth: 10 }),
    )?;
    rt.block_on(async {
        let _ = tokio::time::timeout(
            DISCOVERY_TIMEOUT,
            depth_sub.wait_for_publisher(&listener.node),
        )
        .await;
    });
    let mut rss_samples: Vec<(f64, f64)> = Vec::new();
    if let Some(mib) = resident_mib() {
        rss_samples.push((bench_start.elapsed().as_secs_f64(), mib));
    }

    let published = Arc::new(Mutex::new(PlayerState::default()));
    let stop = Arc::new(AtomicBool::new(false));
    let player = spawn_player(opts, &bag_path, &camera_topics, &published, &stop)?;
    let heard = rt.block_on(listen(
        opts,
        &depth_sub,
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
    // Groups still in flight when the player stopped are not lost: let the node take them.
    let groups_published = lock_published(&published).complete;
    let t0 = Instant::now();
    while node.health().sync.groups < groups_published && t0.elapsed() < SETTLE_TIMEOUT {
        std::thread::sleep(SETTLE_POLL);
    }
    if let Some(mib) = resident_mib() {
        rss_samples.push((bench_start.elapsed().as_secs_f64(), mib));
    }
    let load_end = load_average_1m();
    drop(depth_sub);
    listener.stop()?;
    drop(context);
    let health: NodeHealth = node.shutdown()?;
    play_result?;
    if heard.interrupted {
        tracing::warn!("interrupted: the figures cover {window_s:.1} s");
    }
    let end_s = bench_start.elapsed().as_secs_f64();
    let per_s = |n: u64| {
        if window_s > 0.0 {
            n as f64 / window_s
        } else {
            0.0
        }
    };
    Ok(BenchReport {
        estimator: opts.estimator.kind.to_string(),
        device: opts.estimator.device.to_string(),
        bag: bag_path.display().to_string(),
        input_width,
        output_width,
        cameras: camera_topics.len(),
        play_rate: opts.rate,
        window_s,
        groups_published,
        input_rate_hz: per_s(groups_published),
        depth_received: heard.depth_received,
        output_rate_hz: per_s(heard.depth_received),
        groups_synced: health.sync.groups,
        groups_processed: health.groups_processed,
        groups_dropped: health.groups_dropped,
        groups_lost: groups_published.saturating_sub(health.sync.groups),
        pipeline_errors: health.pipeline_errors,
        mean_inference_ms: health.mean_latency_ms,
        latency: LatencyStats::from_samples(&heard.latencies_ms),
        rss: rss_stats(&rss_samples, heard.first_depth_s, end_s),
        cpus: std::thread::available_parallelism().map_or(1, |n| n.get()),
        load_average_1m_start: load_start,
        load_average_1m_end: load_end,
    })
}

/// Fails before rendering or starting anything when the estimator cannot run: its GPU cannot
/// be had, or its weights file is missing.
fn check_estimator(opts: &BenchOptions) -> Result<()> {
    if opts.estimator.device.is_cuda() {
        opts.estimator
            .device
            .open()
            .context("the device of the node's estimator (--device)")?;
    }
    if let Some(path) = opts.estimator.weights_path() {
        if !path.exists() {
            bail!(
                "estimator 'ssmode' needs trained weights at {}, which does not exist",
                path.display()
            );
        }
    }
    Ok(())
}

/// The bag to play: the one given, the bundled one when its width fits, or frames rendered
/// into a temporary file (added to `temps`).
fn bench_input(opts: &BenchOptions, temps: &mut Vec<TempFile>) -> Result<PathBuf> {
    if let Some(b) = &opts.bag {
        return Ok(b.clone());
    }
    let width = opts.width.unwrap_or(DEFAULT_WIDTH);
    let bundled = shipped::locate(Path::new(BUNDLED_BAG), &[]);
    if bundled.origin != Origin::NotFound
        && bag_width(&RigBagReader::open(&bundled.path)?)? == width
    {
        return Ok(bundled.path);
    }
    let out = temp_path("input.mcap");
    temps.push(TempFile(out.clone()));
    tracing::info!("rendering {RENDERED_FRAMES} frames at {width} px");
    record_synthetic_bag(&RecordOptions {
        rig: mode360_core::geometry::Rig::from_file_or_shipped(&opts.rig_file)?,
        config: SynthConfig {
            width,
            seed: 1,
            ..Default::default()
        },
        frames: RENDERED_FRAMES,
        first_frame: 0,
        out: out.clone(),
        show_progress: false,
    })
    .context("rendering the bench input")?;
    Ok(out)
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
