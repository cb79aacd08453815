//! Training on its own (`cargo test -p mode360-train`): the sample stream, the loss, random rig
//! layouts and short runs with checkpoint and resume.

mod train_data;
mod train_loss;
mod train_rig_layouts;
mod train_run;
