//! mode360's SSMODE training ([`train`]): rendered or Deep360 samples, the loss, the optimizer,
//! checkpoints and logs.

pub mod train;
