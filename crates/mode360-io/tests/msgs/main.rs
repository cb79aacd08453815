//! ROS 2 message encoding on its own (`cargo test -p mode360-io`): CDR of every message the
//! node reads and writes.

mod msgs_cdr;
