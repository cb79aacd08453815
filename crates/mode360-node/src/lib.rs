//! mode360's ROS 2 node ([`node`]): subscriptions, camera sync, the depth pipeline shared with
//! offline replay, publishers, diagnostics and the Foxglove live view.

pub mod node;
