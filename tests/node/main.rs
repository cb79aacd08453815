//! The live ROS 2 node over real DDS on loopback, each test on its own `ROS_DOMAIN_ID`: a bag
//! played into it (`dds`), camera dropout (`dropout`), the binary under `use_sim_time` and
//! SIGINT (`process`), Eclipse Cyclone DDS peers both ways (`cyclone`), Fast DDS peers both
//! ways (`fastdds`), real ROS 2 clients (rclpy of Jazzy and Kilted: decoding, feeding, every
//! output of a reliable stream, parameters; `rclpy`), bad input seen on `/diagnostics` (`bad_input`), a hostile sender's
//! malformed and oversized samples (`fuzz`), outputs built only while
//! subscribed (`lazy`), QoS overrides and `publish_tf` (`qos`), the parameter services
//! (`params`), the bag player's delivery at 512 (`player`), extrinsics from TF (`tf`), the Foxglove live view read by Foxglove's own
//! client (`foxglove`), the binary's log records on `/rosout` (`rosout`) and the binary's demo
//! run from an empty folder, away from its source tree (`installed`). The tests take [`common::live_node_lock`] so that one node runs at a
//! time.

#[path = "../common/mod.rs"]
mod common;

mod bad_input;
mod cyclone;
mod dds;
mod dds_peer;
mod dropout;
mod fastdds;
mod foxglove;
mod fuzz;
mod harness;
mod installed;
mod lazy;
mod node_process;
mod params;
mod player;
mod process;
mod qos;
mod rclpy;
mod rclpy_time;
mod rosout;
mod tf;
