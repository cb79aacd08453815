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
//!   `/proc/self/status`) every second: start, max, end, and the least-squares slope in MB/min
//!   over the steady state, the second half of the time after the first depth arrived
//!   (allocator arenas and DDS buffers fill up during the first half; growth after that
//!   means a leak).

use super::play::{play_bag_until, PlayError, PlayOptions, Published};
use super::{create_subscription, dds_context, runtime, ShutdownSignals, SpunNode};
use super::{spawn_node, DdsOptions, NodeError, NodeHealth, NodeParams};
use crate::bag::{BagError, RigBagReader};
use crate::estimator::EstimatorSpec;
use crate::msgs::{CompressedImage, Image, RosMessage};
use crate::record::{record_synthetic_bag, RecordOptions};
use crate::synth::SynthConfig;
use futures::StreamExt;
use ros2_client::qos::History;
use ros2_client::QosProfile;
use serde::Serialize;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// The bundled bag, used when its width is the one asked for.
pub const BUNDLED_BAG: &str = "bags/demo_deep360.mcap";
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
/// Seconds per minute, for the RSS slope.
const SECS_PER_MIN: f64 = 60.0;

#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error("estimator 'ssmode' needs trained weights at {path}, which does not exist")]
    MissingWeights { path: String },
    #[error(transparent)]
    Node(#[from] NodeError),
    #[error(transparent)]
    Bag(#[from] BagError),
    #[error(transparent)]
    Play(Box<PlayError>),
    #[error("bench: {0}")]
    Other(String),
}

impl From<PlayError> for BenchError {
    fn from(e: PlayError) -> Self {
        Self::Play(Box::new(e))
    }
}

fn other(e: impl std::fmt::Display) -> BenchError {
    BenchError::Other(e.to_string())
}

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
    pub dds: DdsOptions,
}

impl Default for BenchOptions {
    fn default() -> Self {
        Self {
            estimator: EstimatorSpec::default(),
            duration: Duration::from_secs(60),
            width: None,
            bag: None,
            rig_file: super::params::DEFAULT_RIG_FILE.into(),
            rate: 1.0,
            dds: DdsOptions {
                domain_id: DEFAULT_BENCH_DOMAIN,
                loopback_only: true,
            },
        }
    }
}

/// Latency distribution, milliseconds.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct LatencyStats {
    pub count: usize,
    pub min_ms: f64,
    pub median_ms: f64,
    pub p95_ms: f64,
    pub max_ms: f64,
}

impl LatencyStats {
    /// Of `samples_ms` (any order); `None` when empty.
    pub fn from_samples(samples_ms: &[f64]) -> Option<Self> {
        let mut v: Vec<f64> = samples_ms
            .iter()
            .copied()
            .filter(|x| x.is_finite())
            .collect();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        Some(Self {
            count: v.len(),
            min_ms: v[0],
            median_ms: percentile(&v, 50.0),
            p95_ms: percentile(&v, 95.0),
            max_ms: v[v.len() - 1],
        })
    }
}

/// Percentile `p` (0..=100) of sorted, non-empty `v`, interpolating linearly between ranks
/// (numpy's default).
pub fn percentile(v: &[f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let pos = (p.clamp(0.0, 100.0) / 100.0) * (v.len() - 1) as f64;
    let lo = pos.floor() as usize;
    let hi = pos.ceil() as usize;
    v[lo] + (v[hi] - v[lo]) * (pos - lo as f64)
}

/// Least-squares slope of `(seconds, megabytes)` samples, in MB per minute (`None` for fewer
/// than two distinct times).
pub fn slope_mb_per_min(samples: &[(f64, f64)]) -> Option<f64> {
    let n = samples.len() as f64;
    if samples.len() < 2 {
        return None;
    }
    let mt = samples.iter().map(|s| s.0).sum::<f64>() / n;
    let mm = samples.iter().map(|s| s.1).sum::<f64>() / n;
    let stt: f64 = samples.iter().map(|s| (s.0 - mt).powi(2)).sum();
    if stt <= 0.0 {
        return None;
    }
    let stm: f64 = samples.iter().map(|s| (s.0 - mt) * (s.1 - mm)).sum();
    Some(stm / stt * SECS_PER_MIN)
}

/// Resident memory of this process in MB (VmRSS of `/proc/self/status`), if readable.
pub fn rss_mb() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/self/status").ok()?;
    parse_vm_rss_mb(&text)
}

/// VmRSS in MB (10^6 bytes) from the text of `/proc/<pid>/status`.
pub fn parse_vm_rss_mb(status: &str) -> Option<f64> {
    crate::bench::status_field_kb(status, "VmRSS:").map(|kb| kb * 1024.0 / 1e6)
}

/// 1-minute load average, if readable.
fn load_average_1m() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// Resident memory over the run, MB.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RssStats {
    pub start_mb: f64,
    pub max_mb: f64,
    pub end_mb: f64,
    /// Over the steady state: the second half of the time after the first depth.
    pub slope_mb_per_min: Option<f64>,
    /// Start of the steady state, seconds since the start.
    pub steady_from_s: Option<f64>,
    /// Band of the steady-state samples (RSS rises and falls with each inference).
    pub steady_min_mb: Option<f64>,
    pub steady_max_mb: Option<f64>,
    /// `(seconds since the start, MB)`, one a second.
    pub samples: Vec<(f64, f64)>,
}

/// Everything measured.
#[derive(Clone, Debug, Serialize)]
pub struct BenchReport {
    pub estimator: String,
    pub bag: String,
    pub input_width: usize,
    pub output_width: usize,
    pub cameras: usize,
    pub play_rate: f64,
    /// Playing window, seconds.
    pub window_s: f64,
    /// Complete groups (all cameras) published.
    pub groups_published: u64,
    pub input_rate_hz: f64,
    pub depth_received: u64,
    pub output_rate_hz: f64,
    /// Groups the node synchronized / ran through the pipeline / dropped in its mailbox.
    pub groups_synced: u64,
    pub groups_processed: u64,
    pub groups_dropped: u64,
    /// Published but never synchronized (lost on best-effort DDS, or unmatched).
    pub groups_lost: u64,
    pub pipeline_errors: u64,
    /// The node's own pipeline time (estimator + messages), mean, milliseconds.
    pub mean_inference_ms: Option<f64>,
    pub latency: Option<LatencyStats>,
    pub rss: Option<RssStats>,
    pub cpus: usize,
    pub load_average_1m_start: Option<f64>,
    pub load_average_1m_end: Option<f64>,
}

impl BenchReport {
    /// A Markdown table.
    pub fn to_table(&self) -> String {
        let opt = |v: Option<f64>, prec: usize| {
            v.map_or_else(|| "n/a".to_string(), |x| format!("{x:.prec$}"))
        };
        let mut rows: Vec<(String, String)> = vec![
            ("estimator".into(), self.estimator.clone()),
            ("bag".into(), self.bag.clone()),
            (
                "input / output width".into(),
                format!("{} / {} px", self.input_width, self.output_width),
            ),
            ("cameras".into(), self.cameras.to_string()),
            ("play rate".into(), format!("{}", self.play_rate)),
            ("window".into(), format!("{:.1} s", self.window_s)),
            (
                "input".into(),
                format!(
                    "{} groups, {:.2} groups/s",
                    self.groups_published, self.input_rate_hz
                ),
            ),
            (
                "output".into(),
                format!(
                    "{} depth, {:.3} depth/s",
                    self.depth_received, self.output_rate_hz
                ),
            ),
            (
                "node groups".into(),
                format!(
                    "synced {}, processed {}, dropped (mailbox) {}, lost before sync {}, errors {}",
                    self.groups_synced,
                    self.groups_processed,
                    self.groups_dropped,
                    self.groups_lost,
                    self.pipeline_errors
                ),
            ),
            (
                "inference (node, mean)".into(),
                format!("{} ms", opt(self.mean_inference_ms, 0)),
            ),
        ];
        match &self.latency {
            Some(l) => rows.push((
                "latency min / median / p95 / max".into(),
                format!(
                    "{:.0} / {:.0} / {:.0} / {:.0} ms (n = {})",
                    l.min_ms, l.median_ms, l.p95_ms, l.max_ms, l.count
                ),
            )),
            None => rows.push(("latency".into(), "no depth received".into())),
        }
        if let Some(r) = &self.rss {
            rows.push((
                "RSS start / max / end".into(),
                format!("{:.0} / {:.0} / {:.0} MB", r.start_mb, r.max_mb, r.end_mb),
            ));
            rows.push((
                "RSS slope (steady state)".into(),
                format!(
                    "{} MB/min (from {} s on, band {} to {} MB)",
                    opt(r.slope_mb_per_min, 2),
                    opt(r.steady_from_s, 0),
                    opt(r.steady_min_mb, 0),
                    opt(r.steady_max_mb, 0)
                ),
            ));
        }
        rows.push((
            "machine".into(),
            format!(
                "{} CPUs, load average {} -> {}",
                self.cpus,
                opt(self.load_average_1m_start, 2),
                opt(self.load_average_1m_end, 2)
            ),
        ));
        let mut out = String::from("| measure | value |\n|---|---|\n");
        for (k, v) in rows {
            out.push_str(&format!("| {k} | {v} |\n"));
        }
        out
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
fn bag_width(reader: &RigBagReader) -> Result<usize, BenchError> {
    let frame = reader
        .frames()
        .next()
        .ok_or_else(|| other("the bag has no complete frame"))??;
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
pub fn run_bench(opts: &BenchOptions) -> Result<BenchReport, BenchError> {
    if let Some(path) = opts.estimator.weights_path() {
        if !path.exists() {
            return Err(BenchError::MissingWeights {
                path: path.display().to_string(),
            });
        }
    }
    // The bag: given, bundled, or rendered.
    let mut temps = Vec::new();
    let bag_path = match (&opts.bag, opts.width) {
        (Some(b), _) => b.clone(),
        (None, w) => {
            let width = w.unwrap_or(DEFAULT_WIDTH);
            let bundled = Path::new(BUNDLED_BAG);
            let fits = bundled.exists() && bag_width(&RigBagReader::open(bundled)?)? == width;
            if fits {
                bundled.to_path_buf()
            } else {
                let out = temp_path("input.mcap");
                temps.push(TempFile(out.clone()));
                tracing::info!("rendering {RENDERED_FRAMES} frames at {width} px");
                record_synthetic_bag(&RecordOptions {
                    rig: crate::geometry::Rig::from_file(&opts.rig_file).map_err(other)?,
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
                .map_err(other)?;
                out
            }
        }
    };
    let reader = RigBagReader::open(&bag_path)?;
    let rig = reader.rig().clone();
    let input_width = bag_width(&reader)?;
    let output_width = opts.width.unwrap_or(input_width);
    drop(reader);
    let rig_path = temp_path("rig.yaml");
    std::fs::write(&rig_path, rig.to_yaml()).map_err(other)?;
    temps.push(TempFile(rig_path.clone()));
    let camera_topics: Vec<String> = rig.cameras.iter().map(|c| c.topic.clone()).collect();
    let n_cams = camera_topics.len();

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
            camera_timeout_secs: 60.0,
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
    if let Some(mb) = rss_mb() {
        rss_samples.push((bench_start.elapsed().as_secs_f64(), mb));
    }

    // Player.
    let published = Arc::new(Mutex::new(PlayerState::default()));
    let stop = Arc::new(AtomicBool::new(false));
    let player = {
        let published = published.clone();
        let stop = stop.clone();
        let play_opts = PlayOptions {
            input: bag_path.clone(),
            rate: opts.rate,
            loops: usize::MAX,
            publish_clock: false,
            dds: opts.dds.clone(),
            wait_for_subscribers: Some(DISCOVERY_TIMEOUT),
            wait_topics: camera_topics.clone(),
        };
        let topics = camera_topics.clone();
        std::thread::Builder::new()
            .name("mode360-bench-player".into())
            .spawn(move || {
                play_bag_until(&play_opts, &stop, |p: &Published<'_>| {
                    let is_image = p.type_name == Image::TYPE_NAME
                        || p.type_name == CompressedImage::TYPE_NAME;
                    let Some(stamp) = p.stamp_ns else { return };
                    if !is_image || !topics.iter().any(|t| t == p.topic) {
                        return;
                    }
                    let now = Instant::now();
                    let mut st = published.lock().unwrap_or_else(|e| e.into_inner());
                    st.first_publish.get_or_insert(now);
                    let entry = st.images.entry(stamp).or_insert((0, now));
                    entry.0 += 1;
                    entry.1 = now;
                    if entry.0 == n_cams {
                        st.complete += 1;
                    }
                })
            })
            .map_err(other)?
    };

    // Listen until the duration is over (counted from the first publish) or a signal.
    let mut latencies_ms: Vec<f64> = Vec::new();
    let mut depth_received = 0u64;
    let mut first_depth_s: Option<f64> = None;
    let interrupted = rt.block_on(async {
        let mut depth = depth_sub.async_stream().boxed();
        let mut rss_tick = tokio::time::interval(RSS_PERIOD);
        let mut started: Option<Instant> = None;
        loop {
            if started.is_none() {
                started = lock_published(&published).first_publish;
            }
            if started.is_some_and(|s| s.elapsed() >= opts.duration) {
                return false;
            }
            if player.is_finished() {
                return false;
            }
            tokio::select! {
                name = signals.recv() => {
                    tracing::info!("{name}: stopping the bench early");
                    return true;
                }
                Some(r) = depth.next() => {
                    let now = Instant::now();
                    if let Ok((m, _)) = r {
                        depth_received += 1;
                        first_depth_s.get_or_insert(bench_start.elapsed().as_secs_f64());
                        let stamp = m.header.stamp.to_nanos();
                        if let Some((_, t)) = lock_published(&published).images.get(&stamp) {
                            latencies_ms.push(now.duration_since(*t).as_secs_f64() * 1e3);
                        }
                    }
                }
                _ = rss_tick.tick() => {
                    if let Some(mb) = rss_mb() {
                        rss_samples.push((bench_start.elapsed().as_secs_f64(), mb));
                    }
                }
            }
        }
    });
    let window_s = lock_published(&published)
        .first_publish
        .map_or(0.0, |s| s.elapsed().as_secs_f64());
    stop.store(true, Ordering::SeqCst);
    let play_result = player
        .join()
        .map_err(|_| other("the player thread panicked"))?;
    // Groups still in flight when the player stopped are not lost: let the node take them.
    let groups_published = lock_published(&published).complete;
    let t0 = Instant::now();
    while node.health().sync.groups < groups_published && t0.elapsed() < SETTLE_TIMEOUT {
        std::thread::sleep(SETTLE_POLL);
    }
    if let Some(mb) = rss_mb() {
        rss_samples.push((bench_start.elapsed().as_secs_f64(), mb));
    }
    let load_end = load_average_1m();
    drop(depth_sub);
    listener.stop()?;
    drop(context);
    let health: NodeHealth = node.shutdown()?;
    play_result?;
    if interrupted {
        tracing::warn!("interrupted: the figures cover {window_s:.1} s");
    }
    let end_s = bench_start.elapsed().as_secs_f64();
    let steady_from_s = first_depth_s.map(|f| f + (end_s - f) / 2.0);
    let rss = (!rss_samples.is_empty()).then(|| {
        let steady: Vec<(f64, f64)> = rss_samples
            .iter()
            .copied()
            .filter(|(t, _)| steady_from_s.is_some_and(|f| *t >= f))
            .collect();
        RssStats {
            start_mb: rss_samples[0].1,
            max_mb: rss_samples.iter().map(|s| s.1).fold(f64::MIN, f64::max),
            end_mb: rss_samples[rss_samples.len() - 1].1,
            slope_mb_per_min: slope_mb_per_min(&steady),
            steady_from_s,
            steady_min_mb: steady.iter().map(|s| s.1).reduce(f64::min),
            steady_max_mb: steady.iter().map(|s| s.1).reduce(f64::max),
            samples: rss_samples.clone(),
        }
    });
    let per_s = |n: u64| {
        if window_s > 0.0 {
            n as f64 / window_s
        } else {
            0.0
        }
    };
    Ok(BenchReport {
        estimator: opts.estimator.kind.to_string(),
        bag: bag_path.display().to_string(),
        input_width,
        output_width,
        cameras: n_cams,
        play_rate: opts.rate,
        window_s,
        groups_published,
        input_rate_hz: per_s(groups_published),
        depth_received,
        output_rate_hz: per_s(depth_received),
        groups_synced: health.sync.groups,
        groups_processed: health.groups_processed,
        groups_dropped: health.groups_dropped,
        groups_lost: groups_published.saturating_sub(health.sync.groups),
        pipeline_errors: health.pipeline_errors,
        mean_inference_ms: health.mean_latency_ms,
        latency: LatencyStats::from_samples(&latencies_ms),
        rss,
        cpus: std::thread::available_parallelism().map_or(1, |n| n.get()),
        load_average_1m_start: load_start,
        load_average_1m_end: load_end,
    })
}

fn lock_published(p: &Mutex<PlayerState>) -> std::sync::MutexGuard<'_, PlayerState> {
    p.lock().unwrap_or_else(|e| e.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn latency_stats_interpolate_percentiles() {
        let samples: Vec<f64> = (1..=100).rev().map(f64::from).collect();
        let s = LatencyStats::from_samples(&samples).unwrap();
        assert_eq!(s.count, 100);
        assert_eq!(s.min_ms, 1.0);
        assert_eq!(s.max_ms, 100.0);
        assert!((s.median_ms - 50.5).abs() < 1e-12, "{s:?}");
        assert!((s.p95_ms - 95.05).abs() < 1e-9, "{s:?}");
        let one = LatencyStats::from_samples(&[42.0]).unwrap();
        assert_eq!(
            (one.min_ms, one.median_ms, one.p95_ms, one.max_ms),
            (42.0, 42.0, 42.0, 42.0)
        );
        assert_eq!(LatencyStats::from_samples(&[]), None);
        assert_eq!(LatencyStats::from_samples(&[f64::NAN]), None);
    }

    #[test]
    fn rss_slope_is_least_squares_mb_per_minute() {
        // 100 MB + 2 MB/min, sampled every second for a minute.
        let flat_growth: Vec<(f64, f64)> = (0..=60)
            .map(|s| (s as f64, 100.0 + 2.0 * s as f64 / 60.0))
            .collect();
        let slope = slope_mb_per_min(&flat_growth).unwrap();
        assert!((slope - 2.0).abs() < 1e-9, "{slope}");
        // +-1 MB of alternating noise on a flat line for a minute: sum (t - mean) x = -30
        // and sum (t - mean)^2 = 60 (60^2 - 1) / 12 = 17995, i.e. only -0.1 MB/min.
        let flat: Vec<(f64, f64)> = (0..60)
            .map(|s| (s as f64, 300.0 + if s % 2 == 0 { 1.0 } else { -1.0 }))
            .collect();
        let noisy = slope_mb_per_min(&flat).unwrap();
        assert!((noisy - (-30.0 / 17995.0 * 60.0)).abs() < 1e-9, "{noisy}");
        assert_eq!(slope_mb_per_min(&[(1.0, 5.0)]), None);
        assert_eq!(slope_mb_per_min(&[(1.0, 5.0), (1.0, 6.0)]), None);
    }

    #[test]
    fn vm_rss_is_parsed_in_megabytes() {
        let status = "Name:\tmode360\nVmPeak:\t  900000 kB\nVmRSS:\t  512000 kB\nThreads:\t9\n";
        assert_eq!(parse_vm_rss_mb(status), Some(512_000.0 * 1024.0 / 1e6));
        assert_eq!(parse_vm_rss_mb("Name: x\n"), None);
        let own = rss_mb().unwrap();
        assert!(own > 1.0 && own < 100_000.0, "{own}");
    }
}
