//! `mode360 node`: the ROS 2 node, with arguments as `ros2 run` / `ros2 launch` pass them.

use anyhow::Result;
use mode360_node::run_node;

/// Runs the node until a shutdown signal and prints its summary line.
pub fn run(ros_args: Vec<String>) -> Result<()> {
    let run = run_node(ros_args)?;
    println!("{}", run.summary_line());
    Ok(())
}
