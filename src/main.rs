//! The `mode360` command line: a thin layer over the library.

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use mode360::estimator::{DepthEstimator, EstimatorKind, EstimatorSpec};
use mode360::eval::{self, EvalOptions, ViewMode};
use mode360::geometry::Rig;
use mode360::model::Preset;
use mode360::record::{self, RecordOptions};
use mode360::synth::{SceneKind, StreetStyle, SynthConfig};
use std::path::PathBuf;

/// Log filter when RUST_LOG is unset: RustDDS is quiet and ros2-client reports only problems
/// unless asked (RUST_LOG=info,rustdds=warn).
/// jemalloc keeps freed pages for reuse: the network's tensors are tens of megabytes, and the
/// system allocator returns each one to the kernel on free, so the next pass page-faults its
/// memory in again (a quarter of a training step's time, measured with perf).
#[global_allocator]
static GLOBAL: tikv_jemallocator::Jemalloc = tikv_jemallocator::Jemalloc;

/// jemalloc options (overridden by `_RJEM_MALLOC_CONF`): large tensors go to the ordinary
/// arenas, and purged pages are released lazily (`MADV_FREE`, reclaimed by the kernel only
/// under memory pressure) instead of unmapped at once, so the next frame reuses them without
/// page faults. Measured with `perf stat -e page-faults` on `bench-model --presets parallax`:
/// 2.2 M -> 1.5 M faults, network median 0.49 -> 0.40 s.
#[allow(non_upper_case_globals)]
#[export_name = "_rjem_malloc_conf"]
pub static malloc_conf: &[u8] = b"oversize_threshold:0,muzzy_decay_ms:-1\0";

const DEFAULT_LOG_FILTER: &str = "info,rustdds=off,ros2_client=warn";

#[derive(Parser)]
#[command(
    name = "mode360",
    version,
    about = "Multi-camera 360° depth: synthetic rig bags, spherical sweep, evaluation"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render synthetic scenes (streets or random objects) seen by a rig into a ROS 2 MCAP bag
    /// with ground truth.
    Synth(SynthArgs),
    /// Score a depth estimator on rig bags with the paper's metrics.
    Eval(EvalArgs),
    /// Train SSMODE on synthetic scenes rendered on the fly (randomized rigs, clean and soiled).
    Train(TrainArgs),
    /// Run the ROS 2 node: `mode360 node --ros-args --params-file launch_configs/mode360.params.yaml`.
    #[command(disable_help_flag = true)]
    Node {
        /// Arguments as `ros2 run` / `ros2 launch` pass them (`--ros-args ...`).
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<String>,
    },
    /// Run every frame of a rig bag through the node's pipeline (no DDS) into an output bag.
    Replay(ReplayArgs),
    /// Publish a bag on DDS with its original timing (like `ros2 bag play`).
    Play(PlayArgs),
    /// Benchmark the live node: a looped bag over loopback DDS; latency, rates, memory.
    BenchNode(BenchNodeArgs),
    /// The whole thing: node + bag played into it over loopback DDS, outputs recorded, previews, metrics.
    Demo(DemoArgs),
    /// Benchmark SSMODE forward passes: time and GFLOP/s per stage, end-to-end time, peak memory.
    BenchModel(BenchModelArgs),
    /// Convert frames of the paper's Deep360 dataset on disk into a rig bag (for eval, replay).
    Deep360Bag(Deep360BagArgs),
    /// Copy a rig bag with the reference camera's image on every camera topic (geometry check).
    SameImageBag(SameImageBagArgs),
}

#[derive(Args)]
struct SameImageBagArgs {
    /// Input rig bag.
    #[arg(long)]
    bag: PathBuf,
    /// Output bag: every camera topic carries the reference camera's image of the same stamp.
    #[arg(long)]
    out: PathBuf,
}

#[derive(Args)]
struct Deep360BagArgs {
    /// Dataset root: the directory holding ep1_500frames ... ep6_500frames.
    root: PathBuf,
    /// Split: train, val or test.
    #[arg(long)]
    split: mode360::deep360::Deep360Split,
    /// Use the soiled images (rgb_soiled/) instead of the clean ones (rgb/).
    #[arg(long)]
    soiled: bool,
    /// Panorama width in pixels (height = width / 2).
    #[arg(long, default_value_t = 512)]
    width: usize,
    /// Convert at most this many frames.
    #[arg(long)]
    max_frames: Option<usize>,
    /// Only this episode (1 to 6).
    #[arg(long)]
    episode: Option<u32>,
    /// Output bag.
    #[arg(long)]
    out: PathBuf,
}

#[derive(Args)]
struct BenchModelArgs {
    /// Presets to measure (comma separated; parallax is the shipped one).
    #[arg(long, value_enum, value_delimiter = ',', default_values_t = [Preset::Parallax, Preset::Compact])]
    presets: Vec<Preset>,
    /// Input widths (comma separated, height = width / 2).
    #[arg(long, value_delimiter = ',', default_value = "256,512")]
    widths: Vec<usize>,
    /// Trained weights, used for the preset they were trained as (default: the shipped weights
    /// of each preset when present; random weights cost the same).
    #[arg(long)]
    weights: Option<PathBuf>,
    /// Rig calibration YAML (its camera count is the number of views).
    #[arg(long, default_value = "launch_configs/rig_deep360.yaml")]
    rig: PathBuf,
    /// Timed passes per case (after one warm-up pass).
    #[arg(long, default_value_t = 3)]
    runs: usize,
    /// Write all cases as JSON here.
    #[arg(long, default_value = "bench_model.json")]
    json: PathBuf,
    /// Run the cases in this process instead of one child process per case (peak memory then
    /// includes earlier cases where the kernel cannot reset it).
    #[arg(long)]
    in_process: bool,
}

#[derive(Args)]
struct DemoArgs {
    /// Bag to play into the node.
    #[arg(long, default_value = "bags/demo_deep360.mcap")]
    bag: PathBuf,
    /// Rig calibration YAML.
    #[arg(long, default_value = "launch_configs/rig_deep360.yaml")]
    rig: PathBuf,
    /// Depth estimator.
    #[arg(long, value_enum, default_value_t = EstimatorKind::Photometric)]
    estimator: EstimatorKind,
    /// SSMODE weights file (default: the shipped weights; an error with other estimators).
    #[arg(long)]
    weights: Option<PathBuf>,
    /// Output bag: inputs plus what the node published.
    #[arg(long, default_value = "demo_out.mcap")]
    out: PathBuf,
    /// Folder for the preview PNGs.
    #[arg(long, default_value = "demo_out")]
    png_dir: PathBuf,
    /// Playback speed factor: slow enough that every frame is processed.
    #[arg(long, default_value_t = 0.03)]
    rate: f64,
}

#[derive(Args)]
struct BenchNodeArgs {
    /// Depth estimator.
    #[arg(long, value_enum, default_value_t = EstimatorKind::Photometric)]
    estimator: EstimatorKind,
    /// SSMODE weights file (default: the shipped weights).
    #[arg(long)]
    weights: Option<PathBuf>,
    /// Output width (and width of rendered input); default: the bag's, or 512 without --bag.
    #[arg(long)]
    width: Option<usize>,
    /// How long to play, seconds.
    #[arg(long, default_value_t = 60.0)]
    duration_s: f64,
    /// Rig bag to play in a loop (default: the bundled bag, or frames rendered at --width).
    #[arg(long)]
    bag: Option<PathBuf>,
    /// Rig calibration of rendered frames.
    #[arg(long, default_value = "launch_configs/rig_deep360.yaml")]
    rig: PathBuf,
    /// Playback speed factor (1 = the bag's frame rate).
    #[arg(long, default_value_t = 1.0)]
    rate: f64,
    /// Private DDS domain (loopback only).
    #[arg(long, default_value_t = mode360::node::bench::DEFAULT_BENCH_DOMAIN)]
    domain_id: u16,
    /// Also write the report as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
}

#[derive(Args)]
struct ReplayArgs {
    /// Input rig bag.
    input: PathBuf,
    /// Output bag: inputs plus depth, points, confidence, /tf_static, /diagnostics.
    #[arg(long)]
    out: PathBuf,
    /// Depth estimator.
    #[arg(long, value_enum, default_value_t = EstimatorKind::Photometric)]
    estimator: EstimatorKind,
    /// SSMODE weights file (default: the shipped weights; an error with other estimators).
    #[arg(long)]
    weights: Option<PathBuf>,
    /// Output panorama width (default: the input width).
    #[arg(long)]
    output_width: Option<usize>,
    /// Process at most this many frames.
    #[arg(long)]
    max_frames: Option<usize>,
}

#[derive(Args)]
struct PlayArgs {
    /// Bag to publish.
    input: PathBuf,
    /// Playback speed factor (1 = recorded timing).
    #[arg(long, default_value_t = 1.0)]
    rate: f64,
    /// Play the bag this many times (stamps keep increasing from one repetition to the next).
    #[arg(long, default_value_t = 1)]
    loops: usize,
    /// Play the bag over and over until Ctrl-C (like `ros2 bag play --loop`).
    #[arg(long = "loop", conflicts_with = "loops")]
    forever: bool,
    /// Do not publish /clock.
    #[arg(long)]
    no_clock: bool,
}

#[derive(Args)]
struct TrainArgs {
    /// Network preset (parallax is the shipped one).
    #[arg(long, value_enum, default_value_t = Preset::Parallax)]
    preset: Preset,
    /// Override the preset's input width (height = width / 2).
    #[arg(long)]
    width: Option<usize>,
    /// Total optimizer steps (a resumed run continues up to this).
    #[arg(long, default_value_t = 10_000)]
    steps: usize,
    /// Run folder: checkpoint/, train.csv, val.csv, curves.png, final weights.
    #[arg(long)]
    out: PathBuf,
    /// Continue from <out>/checkpoint.
    #[arg(long)]
    resume: bool,
    /// Samples per step (gradient accumulation).
    #[arg(long, default_value_t = 1)]
    batch_size: usize,
    /// Peak learning rate (linear warmup, then cosine decay).
    #[arg(long, default_value_t = 1e-3)]
    lr: f64,
    /// Validate on the held-out set every this many steps.
    #[arg(long, default_value_t = 250)]
    val_every: usize,
    /// Checkpoint every this many steps (also every 5 minutes).
    #[arg(long, default_value_t = 250)]
    checkpoint_every: usize,
    /// Data seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Mix training frames of the paper's Deep360 dataset at this root into the samples.
    #[arg(long)]
    deep360: Option<PathBuf>,
    /// Fraction of samples taken from --deep360 (the rest are rendered).
    #[arg(long, default_value_t = 1.0, requires = "deep360")]
    deep360_fraction: f64,
    /// Fine-tune: start a new run from these weights (e.g. models/ssmode_compact.safetensors)
    /// instead of a random initialisation. Ignored when --resume finds a checkpoint.
    #[arg(long)]
    init_weights: Option<PathBuf>,
    /// Fraction of rendered samples that are random-objects scenes (1: pretraining for
    /// matching; the rest are streets).
    #[arg(long, default_value_t = 0.0)]
    objects_fraction: f64,
    /// Layout variation of the training streets.
    #[arg(long, value_enum, default_value_t = mode360::synth::StreetStyle::Regular)]
    street: mode360::synth::StreetStyle,
    /// Fraction of samples with lens soiling.
    #[arg(long, default_value_t = 0.3)]
    soiled_fraction: f64,
    /// Fraction of rendered street and object samples on the Deep360 rig (the rest on random
    /// roof racks of 2 to 5 cameras).
    #[arg(long, default_value_t = 0.25)]
    deep360_rig_fraction: f64,
    /// Clip the global gradient norm to this (off when absent).
    #[arg(long)]
    max_grad_norm: Option<f64>,
}

#[derive(Args)]
struct SynthArgs {
    /// Rig calibration YAML.
    #[arg(long, default_value = "launch_configs/rig_deep360.yaml")]
    rig: PathBuf,
    /// Number of frames to render.
    #[arg(long, default_value_t = 10)]
    frames: usize,
    /// Index of the first frame along the drive.
    #[arg(long, default_value_t = 0)]
    first_frame: usize,
    /// Panorama width in pixels (height = width / 2).
    #[arg(long, default_value_t = 512)]
    width: usize,
    /// Soil one or two lenses per frame (mud, water drops, glare).
    #[arg(long)]
    soiled: bool,
    /// Scene seed: the same seed gives the same bag.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Sky and far-field ground-truth range, metres.
    #[arg(long, default_value_t = 1000.0)]
    max_depth_m: f64,
    /// Scene kind: a procedural street, or random textured objects all around the rig (new
    /// per frame; defeats monocular depth guessing).
    #[arg(long, value_enum, default_value_t = SceneKind::Street)]
    scene: SceneKind,
    /// Street layout: regular (same cross-section for every seed) or varied per seed (road,
    /// lane and sidewalk widths, setbacks, heights, parked cars, trees, rig height and tilt).
    #[arg(long, value_enum, default_value_t = StreetStyle::Regular)]
    street: StreetStyle,
    /// Output bag.
    #[arg(long)]
    out: PathBuf,
}

#[derive(Args)]
struct EvalArgs {
    /// Bag(s) to evaluate (repeat for clean and soiled bags).
    #[arg(long = "bag", required = true)]
    bags: Vec<PathBuf>,
    /// Depth estimator.
    #[arg(long, value_enum, default_value_t = EstimatorKind::Photometric)]
    estimator: EstimatorKind,
    /// Cameras to use, 1-based in rig order, e.g. 1,2,3 (default: all).
    #[arg(long, value_delimiter = ',')]
    cameras: Option<Vec<usize>>,
    /// Evaluate at most this many frames per bag.
    #[arg(long)]
    max_frames: Option<usize>,
    /// Write the table as JSON here.
    #[arg(long, default_value = "eval.json")]
    json: PathBuf,
    /// Write preview PNGs (panorama, predicted and true range) of the first frames here.
    #[arg(long)]
    png_dir: Option<PathBuf>,
    /// SSMODE weights file (default: models/ssmode_compact.safetensors).
    #[arg(long)]
    weights: Option<PathBuf>,
    /// Feed every camera the reference camera's image (no parallax; the geometry check).
    #[arg(long, conflicts_with = "geometry_share")]
    same_image: bool,
    /// Evaluate with true views and with --same-image views; print both and the δ1 difference.
    #[arg(long)]
    geometry_share: bool,
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| DEFAULT_LOG_FILTER.into()),
        )
        .with_writer(std::io::stderr)
        .init();
    match Cli::parse().command {
        Command::Synth(a) => synth(a),
        Command::Eval(a) => run_eval(a),
        Command::Train(a) => train(a),
        Command::Node { args } => {
            let run = mode360::node::run_node(args)?;
            println!("{}", run.summary_line());
            Ok(())
        }
        Command::Replay(a) => replay(a),
        Command::Play(a) => play(a),
        Command::BenchNode(a) => bench_node(a),
        Command::Demo(a) => demo(a),
        Command::BenchModel(a) => bench_model(a),
        Command::Deep360Bag(a) => deep360_bag(a),
        Command::SameImageBag(a) => {
            let s = mode360::bag::write_same_image_bag(&a.bag, &a.out)?;
            println!(
                "wrote {} frames to {}, every camera carrying camera '{}'",
                s.frames,
                a.out.display(),
                s.reference_camera
            );
            Ok(())
        }
    }
}

fn synth(a: SynthArgs) -> Result<()> {
    let rig = Rig::from_file(&a.rig)?;
    let config = SynthConfig {
        seed: a.seed,
        width: a.width,
        soiled: a.soiled,
        max_depth_m: a.max_depth_m,
        scene: a.scene,
        street: a.street,
        ..SynthConfig::default()
    };
    let summary = record::record_synthetic_bag(&RecordOptions {
        rig,
        config,
        frames: a.frames,
        first_frame: a.first_frame,
        out: a.out.clone(),
        show_progress: true,
    })
    .with_context(|| format!("writing {}", a.out.display()))?;
    println!(
        "wrote {} frames to {} ({:.1} MB) in {:.1} s ({:.2} frames/s)",
        summary.frames,
        a.out.display(),
        summary.bytes as f64 / 1e6,
        summary.seconds,
        summary.frames as f64 / summary.seconds.max(1e-9)
    );
    Ok(())
}

fn run_eval(a: EvalArgs) -> Result<()> {
    let cameras = match a.cameras {
        None => None,
        Some(list) => {
            if list.contains(&0) {
                bail!("--cameras is 1-based: camera 0 does not exist");
            }
            Some(list.iter().map(|c| c - 1).collect())
        }
    };
    let mut est: Box<dyn DepthEstimator> =
        EstimatorSpec::with_weights(a.estimator, a.weights).build()?;
    let opts = EvalOptions {
        bags: a.bags,
        cameras,
        max_frames: a.max_frames,
        show_progress: true,
        png_dir: a.png_dir,
        views: if a.same_image {
            ViewMode::SameImage
        } else {
            ViewMode::True
        },
    };
    let json = if a.geometry_share {
        let report = eval::geometry_share(&opts, est.as_mut())?;
        print!("{}", report.to_table());
        serde_json::to_string_pretty(&report)?
    } else {
        let report = eval::evaluate(&opts, est.as_mut())?;
        print!("{}", report.to_table());
        serde_json::to_string_pretty(&report)?
    };
    std::fs::write(&a.json, json).with_context(|| format!("writing {}", a.json.display()))?;
    println!("wrote {}", a.json.display());
    Ok(())
}

fn train(a: TrainArgs) -> Result<()> {
    let opts = mode360::train::TrainOptions {
        preset: a.preset,
        width: a.width,
        steps: a.steps,
        out_dir: a.out,
        resume: a.resume,
        batch_size: a.batch_size,
        lr: a.lr,
        val_every: a.val_every,
        checkpoint_every_steps: a.checkpoint_every,
        seed: a.seed,
        deep360_disk: a.deep360,
        deep360_disk_fraction: a.deep360_fraction,
        init_weights: a.init_weights,
        objects_fraction: a.objects_fraction,
        street: a.street,
        soiled_fraction: a.soiled_fraction,
        deep360_fraction: a.deep360_rig_fraction,
        max_grad_norm: a.max_grad_norm,
        ..mode360::train::TrainOptions::default()
    };
    let s = mode360::train::run_training(&opts)?;
    println!(
        "trained steps {}..{} ({:.2} s/step, peak RSS {:.0} MiB); weights: {}",
        s.start_step,
        s.final_step,
        s.mean_secs_per_step,
        s.peak_rss_mb,
        s.weights_path.display()
    );
    if let Some(v) = s.last_validation {
        println!("last validation: {v:?}");
    }
    Ok(())
}

fn replay(a: ReplayArgs) -> Result<()> {
    let summary = mode360::replay::replay_bag(&mode360::replay::ReplayOptions {
        input: a.input,
        output: a.out.clone(),
        estimator: EstimatorSpec::with_weights(a.estimator, a.weights),
        output_width: a.output_width,
        max_depth_m: None,
        max_frames: a.max_frames,
    })?;
    println!(
        "replayed {} frames into {} (mean latency {:.0} ms)",
        summary.frames,
        a.out.display(),
        summary.mean_latency_ms()
    );
    if let Some(m) = summary.metrics {
        println!(
            "against ground truth: delta1 {:.2} %, AbsRel {:.4}, MAE {:.3} m",
            m.delta1_pct, m.abs_rel, m.mae_m
        );
    }
    Ok(())
}

fn play(a: PlayArgs) -> Result<()> {
    let stop = mode360::node::stop_flag_on_signals()?;
    let summary = mode360::node::play_bag_until(
        &mode360::node::PlayOptions {
            input: a.input,
            rate: a.rate,
            loops: if a.forever { usize::MAX } else { a.loops },
            publish_clock: !a.no_clock,
            dds: mode360::node::DdsOptions::from_env()?,
            wait_for_subscribers: None,
            wait_topics: Vec::new(),
        },
        &stop,
        |_| {},
    )?;
    let total: u64 = summary.published.values().sum();
    println!(
        "played {total} messages in {:.1} s ({} repetitions); per topic: {:?}",
        summary.seconds, summary.loops_played, summary.published
    );
    if !summary.skipped_topics.is_empty() {
        println!("skipped (unsupported types): {:?}", summary.skipped_topics);
    }
    Ok(())
}

fn bench_node(a: BenchNodeArgs) -> Result<()> {
    if !(a.duration_s.is_finite() && a.duration_s > 0.0) {
        bail!("--duration-s must be a positive number of seconds");
    }
    let report = mode360::node::bench::run_bench(&mode360::node::bench::BenchOptions {
        estimator: EstimatorSpec::with_weights(a.estimator, a.weights),
        width: a.width,
        duration: std::time::Duration::from_secs_f64(a.duration_s),
        bag: a.bag,
        rig_file: a.rig,
        rate: a.rate,
        dds: mode360::node::DdsOptions {
            domain_id: a.domain_id,
            loopback_only: true,
        },
    })?;
    print!("{}", report.to_table());
    if let Some(path) = a.json {
        std::fs::write(&path, serde_json::to_string_pretty(&report)?)
            .with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

fn demo(a: DemoArgs) -> Result<()> {
    let mut dds = mode360::node::DdsOptions::from_env()?;
    dds.loopback_only = true;
    let s = mode360::demo::run_demo(&mode360::demo::DemoOptions {
        bag: a.bag,
        rig_file: a.rig,
        estimator: EstimatorSpec::with_weights(a.estimator, a.weights),
        out_bag: a.out.clone(),
        png_dir: a.png_dir.clone(),
        rate: a.rate,
        dds,
    })?;
    println!(
        "played {} frames; received {} depth images and {} point clouds ({:.0} points each)",
        s.frames_played, s.depth_received, s.points_received, s.mean_points
    );
    if let Some(m) = s.metrics {
        println!(
            "depth vs ground truth: MAE {:.3} m, RMSE {:.3} m, AbsRel {:.4}, SqRel {:.3}, SILog {:.3}, delta1 {:.2} %, delta2 {:.2} %, delta3 {:.2} %",
            m.mae_m, m.rmse_m, m.abs_rel, m.sq_rel_m, m.silog, m.delta1_pct, m.delta2_pct, m.delta3_pct
        );
    }
    println!(
        "wrote {} and previews in {}",
        a.out.display(),
        a.png_dir.display()
    );
    Ok(())
}

fn bench_model(a: BenchModelArgs) -> Result<()> {
    use mode360::bench::{bench_model_case, format_table, ModelBenchCase, ModelBenchOptions};
    let rig = Rig::from_file(&a.rig)?;
    // candidate weights, first match per preset: the given file, then the shipped ones
    let mut candidates = Vec::new();
    if let Some(w) = &a.weights {
        let cfg = mode360::model::read_config(w)
            .with_context(|| format!("reading the config of {}", w.display()))?;
        candidates.push((cfg.name, w.clone()));
    }
    for shipped in mode360::estimator::ssmode::shipped_weights_paths() {
        if let Ok(cfg) = mode360::model::read_config(&shipped) {
            candidates.push((cfg.name, shipped));
        }
    }
    let mut cases: Vec<ModelBenchCase> = Vec::new();
    for preset in &a.presets {
        for &width in &a.widths {
            let weights = candidates
                .iter()
                .find(|(name, _)| name == preset.as_str())
                .map(|(_, path)| path.clone());
            eprintln!("bench-model: {preset} at {width}x{} ...", width / 2);
            let case = if a.in_process || (a.presets.len() == 1 && a.widths.len() == 1) {
                bench_model_case(&ModelBenchOptions {
                    preset: *preset,
                    width: Some(width),
                    weights,
                    rig: rig.clone(),
                    runs: a.runs,
                    seed: 1,
                })?
            } else {
                bench_model_child(&a, *preset, width, weights.as_deref())?
            };
            cases.push(case);
        }
    }
    print!("{}", format_table(&cases));
    std::fs::write(&a.json, serde_json::to_string_pretty(&cases)?)
        .with_context(|| format!("writing {}", a.json.display()))?;
    println!("wrote {}", a.json.display());
    Ok(())
}

/// One case in a child process, so that its peak memory is its own.
fn bench_model_child(
    a: &BenchModelArgs,
    preset: Preset,
    width: usize,
    weights: Option<&std::path::Path>,
) -> Result<mode360::bench::ModelBenchCase> {
    let json = std::env::temp_dir().join(format!(
        "mode360-bench-{}-{preset}-{width}.json",
        std::process::id()
    ));
    let exe = std::env::current_exe().context("locating the mode360 binary")?;
    let mut cmd = std::process::Command::new(exe);
    cmd.arg("bench-model")
        .args(["--presets", preset.as_str()])
        .args(["--widths", &width.to_string()])
        .args(["--runs", &a.runs.to_string()])
        .arg("--rig")
        .arg(&a.rig)
        .arg("--json")
        .arg(&json)
        .stdout(std::process::Stdio::null());
    if let Some(w) = weights {
        cmd.arg("--weights").arg(w);
    }
    let status = cmd.status().context("starting the bench child process")?;
    if !status.success() {
        bail!("bench-model case {preset} at width {width} failed ({status})");
    }
    let text =
        std::fs::read_to_string(&json).with_context(|| format!("reading {}", json.display()))?;
    // Best effort: a leftover file in the temp dir is harmless.
    let _ = std::fs::remove_file(&json);
    let mut cases: Vec<mode360::bench::ModelBenchCase> = serde_json::from_str(&text)?;
    cases
        .pop()
        .with_context(|| format!("{} holds no case", json.display()))
}

fn deep360_bag(a: Deep360BagArgs) -> Result<()> {
    use mode360::deep360_bag::{convert_deep360_to_bag, Deep360BagOptions};
    let s = convert_deep360_to_bag(&Deep360BagOptions {
        root: a.root,
        split: a.split,
        soiled: a.soiled,
        width: a.width,
        max_frames: a.max_frames,
        episode: a.episode,
        out: a.out.clone(),
        show_progress: true,
    })
    .with_context(|| format!("converting Deep360 into {}", a.out.display()))?;
    println!(
        "wrote {} Deep360 frames ({} .. {}) to {} ({:.1} MB) in {:.1} s",
        s.frames,
        s.first,
        s.last,
        a.out.display(),
        s.bytes as f64 / 1e6,
        s.seconds
    );
    Ok(())
}
