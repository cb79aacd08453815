//! mode360's messages and bags: ROS 2 message types and their CDR codecs ([`msgs`]), MCAP rig
//! bags ([`bag`]) and the paper's Deep360 dataset ([`deep360`]).

pub mod bag;
pub mod deep360;
pub mod msgs;
