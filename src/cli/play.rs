//! `mode360 play`: publish a bag's messages on DDS with their recorded timing
//! ([`mode360_node::player`]).

use anyhow::Result;
use clap::Args;
use mode360_node::player::{play_bag_until, PlayOptions};
use mode360_node::DdsOptions;
use std::path::PathBuf;

#[derive(Args)]
pub struct PlayArgs {
    /// Bag to publish.
    pub input: PathBuf,
    /// Playback speed factor (1 = recorded timing).
    #[arg(long, default_value_t = 1.0)]
    pub rate: f64,
    /// Play the bag this many times (stamps keep increasing from one repetition to the next).
    #[arg(long, default_value_t = 1)]
    pub loops: usize,
    /// Play the bag over and over until Ctrl-C (like `ros2 bag play --loop`).
    #[arg(long = "loop", conflicts_with = "loops")]
    pub forever: bool,
    /// Do not publish /clock.
    #[arg(long)]
    pub no_clock: bool,
}

/// `mode360 play`: publishes a bag (looping as asked) and prints what went out.
pub fn run(a: PlayArgs) -> Result<()> {
    let stop = mode360_node::stop_flag_on_signals()?;
    let summary = play_bag_until(
        &PlayOptions {
            input: a.input,
            rate: a.rate,
            loops: if a.forever { usize::MAX } else { a.loops },
            publish_clock: !a.no_clock,
            dds: DdsOptions::from_env()?,
            wait_for_subscribers: None,
            wait_topics: Vec::new(),
        },
        &stop,
        |_| {},
    )?;
    let total: u64 = summary.published.values().sum();
    println!(
        "played {total} messages in {:.1} s ({} repetitions); per topic: {:?}",
        summary.elapsed_s, summary.loops_played, summary.published
    );
    if !summary.skipped_topics.is_empty() {
        println!("skipped (unsupported types): {:?}", summary.skipped_topics);
    }
    Ok(())
}
