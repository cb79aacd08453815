//! The command layer: one file (or folder) per `mode360` subcommand, over the domain library.
//!
//! Each command module holds its clap `...Args`, a `run(args)` that the binary dispatches to,
//! and the command's own work as a library function with an options struct (so tests and
//! other commands call it without a process). Commands report errors with `anyhow` and
//! context (which bag, which frame, which file); the domain modules below them keep their
//! `thiserror` enums.
//!
//! | module | command | what it does |
//! |---|---|---|
//! | [`synth`] | `synth` | renders synthetic frames into a rig bag (`mode360_synth::record`) |
//! | [`eval`] | `eval` | scores an estimator on rig bags, with the geometry share |
//! | [`train`] | `train` | trains SSMODE ([`mode360_train`]) |
//! | [`node`] | `node` | runs the ROS 2 node ([`mode360_node`]) |
//! | [`replay`] | `replay` | the node's pipeline over a bag, without DDS, into a bag |
//! | [`play`] | `play` | publishes a bag on DDS with its recorded timing |
//! | [`bench_node`] | `bench-node` | the live node under a looped bag: latency, rates, memory |
//! | [`demo`] | `demo` | node + play + listener end to end, previews and metrics |
//! | [`bench_model`] | `bench-model` | SSMODE forward passes: time per stage, GFLOP/s, peak memory; PSMODE per frame |
//! | [`deep360_bag`] | `deep360-bag` | the paper's Deep360 frames on disk into a rig bag |
//! | [`same_image_bag`] | `same-image-bag` | a bag with the reference image on every camera |
//! | [`rig`] | `rig import` | a Kalibr camchain or Basalt calibration into a rig YAML |
//!
//! `mode360_core::progress` holds the progress bars the long commands share, [`drops`] the tally of
//! malformed messages that `replay` and `eval` drop and go past.

pub mod bench_model;
pub mod bench_node;
pub mod bundled_bag;
pub mod deep360_bag;
pub mod demo;
pub mod drops;
pub mod estimator_args;
pub mod eval;
pub mod logging;
pub mod node;
pub mod play;
pub mod replay;
pub mod rig;
pub mod same_image_bag;
pub mod scores;
pub mod synth;
pub mod train;
