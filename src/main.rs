//! The `mode360` command line: the argument enum and the dispatch. Each command lives in
//! [`mode360::cli`], over the library.

use anyhow::Result;
use clap::{Parser, Subcommand};
use mode360::cli;
use mode360_node::ros_args;
use std::process::ExitCode;

/// jemalloc keeps freed pages for reuse: the network's tensors are tens of megabytes, and the
/// system allocator returns each one to the kernel on free, so the next pass page-faults its
/// memory in again (a quarter of a training step's time, measured with perf).
#[global_allocator]
static GLOBAL: ZeroByMemset<tikv_jemallocator::Jemalloc> =
    ZeroByMemset(tikv_jemallocator::Jemalloc);

/// An allocator whose zeroed allocations are plain allocations cleared with `memset`.
///
/// jemalloc's `calloc` of a large size that reuses freed pages zeroes them by handing them
/// back to the kernel (`MADV_DONTNEED`), so the first write page-faults every 4 KiB in again:
/// every `vec![0.0; n]` of a tensor-sized buffer (conv outputs, the cost volume, the sweep's
/// samples) costs a fault per page on every frame. Clearing the reused pages in place is
/// cheaper. Measured on `bench-model --presets parallax_zncc_log --widths 256` (docs/benchmarks.md).
struct ZeroByMemset<A>(A);

// SAFETY: every call is forwarded to the inner allocator with the caller's layout; the zeroed
// allocation clears exactly `layout.size()` bytes of the block the inner allocator returned.
unsafe impl<A: std::alloc::GlobalAlloc> std::alloc::GlobalAlloc for ZeroByMemset<A> {
    unsafe fn alloc(&self, layout: std::alloc::Layout) -> *mut u8 {
        // SAFETY: forwarded with the caller's layout.
        unsafe { self.0.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: std::alloc::Layout) -> *mut u8 {
        // SAFETY: forwarded with the caller's layout; a non-null block holds `layout.size()`
        // writable bytes.
        unsafe {
            let ptr = self.0.alloc(layout);
            if !ptr.is_null() {
                std::ptr::write_bytes(ptr, 0, layout.size());
            }
            ptr
        }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: std::alloc::Layout) {
        // SAFETY: `ptr` came from this allocator (so from the inner one) with `layout`.
        unsafe { self.0.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: std::alloc::Layout, new_size: usize) -> *mut u8 {
        // SAFETY: as for `dealloc`; the caller guarantees `new_size` is valid for `layout`.
        unsafe { self.0.realloc(ptr, layout, new_size) }
    }
}

/// jemalloc options (overridden by `_RJEM_MALLOC_CONF`): large tensors go to the ordinary
/// arenas, and purged pages are released lazily (`MADV_FREE`, reclaimed by the kernel only
/// under memory pressure) instead of unmapped at once, so the next frame reuses them without
/// page faults. Measured with `perf stat -e page-faults` on `bench-model --presets parallax`:
/// 2.2 M -> 1.5 M faults, network median 0.49 -> 0.40 s.
#[allow(non_upper_case_globals)]
#[export_name = "_rjem_malloc_conf"]
pub static malloc_conf: &[u8] = b"oversize_threshold:0,muzzy_decay_ms:-1\0";

/// jemalloc's name for all arenas at once (`MALLCTL_ARENAS_ALL`) in `arena.<i>.purge`.
const PURGE_ALL_ARENAS: &std::ffi::CStr = c"arena.4096.purge";

/// Hands the pages jemalloc holds free (dirty and lazily purged ones, of every arena) back to
/// the kernel at once; true when jemalloc did. Registered with the node
/// (`mode360_node::page_release`), which calls it when memory was freed for good.
fn purge_jemalloc() -> bool {
    // SAFETY: `arena.<i>.purge` reads and writes nothing (all pointers null, length 0) and
    // the name is a NUL-terminated string; jemalloc locks each arena while purging it.
    let rc = unsafe {
        tikv_jemalloc_sys::mallctl(
            PURGE_ALL_ARENAS.as_ptr(),
            std::ptr::null_mut(),
            std::ptr::null_mut(),
            std::ptr::null_mut(),
            0,
        )
    };
    rc == 0
}

/// Log filter when RUST_LOG is unset: RustDDS is quiet and ros2-client reports only problems
/// unless asked (RUST_LOG=info,rustdds=warn); its ROS_DISTRO check, which calls every
/// distribution but Jazzy an ERROR, is replaced by the node's own (`node::ros_distro`).
const DEFAULT_LOG_FILTER: &str = "info,rustdds=off,ros2_client=warn,ros2_client::distributions=off";

/// Where the defaults' files are found (`mode360_core::shipped`), shown by `--help`.
const SHIPPED_FILES_HELP: &str =
    "Shipped files (the weights under models/, the rigs and parameter file under \
launch_configs/, the demo bag bags/demo_deep360.mcap) are found by their relative path: in the \
working directory, then in the data directory ($MODE360_DATA_DIR, else $XDG_DATA_HOME/mode360, \
else ~/.local/share/mode360), then beside the binary (BIN/../share/mode360, then BIN's folder), \
else the copy built into the binary is unpacked into DATA_DIR/builtin/ (the demo bag is rendered \
into DATA_DIR/bags/).";

#[derive(Parser)]
#[command(
    name = "mode360",
    version,
    about = "Multi-camera 360° depth: synthetic rig bags, SSMODE and the spherical sweep, the ROS 2 node, evaluation",
    after_help = SHIPPED_FILES_HELP
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render synthetic scenes (streets or random objects) seen by a rig into a ROS 2 MCAP bag
    /// with ground truth.
    Synth(cli::synth::SynthArgs),
    /// Score a depth estimator on rig bags with the paper's metrics.
    Eval(cli::eval::EvalArgs),
    /// Train SSMODE on synthetic scenes rendered on the fly (randomized rigs, clean and soiled).
    Train(cli::train::TrainArgs),
    /// Run the ROS 2 node: `mode360 node --ros-args --params-file launch_configs/mode360.params.yaml`.
    #[command(disable_help_flag = true)]
    Node {
        /// Arguments as `ros2 run` / `ros2 launch` pass them (`--ros-args ...`).
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<String>,
    },
    /// Run every frame of a rig bag through the node's pipeline (no DDS) into an output bag.
    Replay(cli::replay::ReplayArgs),
    /// Publish a bag on DDS with its original timing (like `ros2 bag play`).
    Play(cli::play::PlayArgs),
    /// Benchmark the live node: a looped bag over loopback DDS; latency, rates, memory.
    BenchNode(cli::bench_node::BenchNodeArgs),
    /// The whole thing: node + bag played into it over loopback DDS, outputs recorded, previews, metrics.
    Demo(cli::demo::DemoArgs),
    /// Benchmark SSMODE forward passes: time and GFLOP/s per stage, end-to-end time, peak memory; PSMODE per frame.
    BenchModel(cli::bench_model::BenchModelArgs),
    /// Convert frames of the paper's Deep360 dataset on disk into a rig bag (for eval, replay).
    Deep360Bag(cli::deep360_bag::Deep360BagArgs),
    /// Copy a rig bag with the reference camera's image on every camera topic (geometry check).
    SameImageBag(cli::same_image_bag::SameImageBagArgs),
    /// Rig calibration tools: `rig import` converts a Kalibr or Basalt calibration.
    Rig(cli::rig::RigArgs),
}

/// The log filter: `RUST_LOG` when set; else, for the node, the level of its
/// `--ros-args --log-level LEVEL` (as `ros2 launch` passes it) with the DDS stacks kept quiet;
/// else [`DEFAULT_LOG_FILTER`].
fn log_filter(command: &Command) -> tracing_subscriber::EnvFilter {
    if let Ok(filter) = tracing_subscriber::EnvFilter::try_from_default_env() {
        return filter;
    }
    let level = match command {
        Command::Node { args } => ros_args::log_level_arg(args).and_then(ros_args::tracing_level),
        _ => None,
    };
    match level {
        Some(level) => {
            format!("{level},rustdds=off,ros2_client=warn,ros2_client::distributions=off").into()
        }
        None => DEFAULT_LOG_FILTER.into(),
    }
}

/// Logs to stderr through `filter`, lines cut and repeats limited ([`cli::logging`]).
fn init_logging(filter: tracing_subscriber::EnvFilter) {
    use tracing_subscriber::layer::SubscriberExt;
    use tracing_subscriber::util::SubscriberInitExt;
    use tracing_subscriber::Layer;
    let limit = cli::logging::CallsiteRateLimit::default();
    // Decided per event: a cached per-callsite answer would defeat the count.
    let repeats = tracing_subscriber::filter::dynamic_filter_fn(move |meta, _| {
        // Warnings and errors repeat in loops (reconnecting clients); information does not.
        !meta.is_event()
            || *meta.level() > tracing::Level::WARN
            || limit.allow(meta.callsite(), std::time::Instant::now())
    })
    .with_callsite_filter(|_| tracing::subscriber::Interest::sometimes());
    tracing_subscriber::registry()
        .with(
            tracing_subscriber::fmt::layer()
                .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
                .with_writer(cli::logging::CutLines)
                .with_filter(repeats)
                .with_filter(filter),
        )
        .with(mode360_node::rosout::RosoutLayer.with_filter(mode360_node::rosout::rosout_filter()))
        .init();
}

/// The error as one line: each message of its chain once (a message already contained in
/// the ones before it, as `thiserror`'s `{source}` texts are, is not repeated).
fn describe(error: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in error.chain() {
        let message = cause.to_string();
        if out.contains(&message) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(&message);
    }
    out
}

fn main() -> ExitCode {
    mode360_node::page_release::set_page_release(purge_jemalloc);
    let cli = Cli::parse();
    init_logging(log_filter(&cli.command));
    match run(cli.command) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("Error: {}", describe(&e));
            ExitCode::FAILURE
        }
    }
}

fn run(command: Command) -> Result<()> {
    match command {
        Command::Synth(a) => cli::synth::run(a),
        Command::Eval(a) => cli::eval::run(a),
        Command::Train(a) => cli::train::run(a),
        Command::Node { args } => cli::node::run(args),
        Command::Replay(a) => cli::replay::run(a),
        Command::Play(a) => cli::play::run(a),
        Command::BenchNode(a) => cli::bench_node::run(a),
        Command::Demo(a) => cli::demo::run(a),
        Command::BenchModel(a) => cli::bench_model::run(a),
        Command::Deep360Bag(a) => cli::deep360_bag::run(a),
        Command::SameImageBag(a) => cli::same_image_bag::run(a),
        Command::Rig(a) => cli::rig::run(a),
    }
}
