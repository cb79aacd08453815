//! Depth estimators end to end: SSMODE (network, weights, estimator, benchmark case), the
//! photometric sweep, the geometry check (same-image views), and training (data, loss,
//! resumable runs).

#[path = "../common/mod.rs"]
mod common;

mod far_field;
mod fisheye_sweep;
mod geometry_check;
mod lens_health;
mod lens_mask;
mod model_composites;
mod model_estimator;
mod model_ssmode;
mod model_ssmode_layers;
mod photometric_channel;
mod photometric_scene;
mod photometric_sweep;
mod psmode;
mod train_data;
mod train_loss;
mod train_rig_layouts;
mod train_run;
