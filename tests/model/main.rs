//! Depth estimators end to end: SSMODE (network, weights, estimator, benchmark case), PSMODE,
//! the photometric sweep, the lens checks, the geometry check (same-image views). The
//! network's ops and layers are tested in mode360-model, training in mode360-train.

#[path = "../common/mod.rs"]
mod common;

mod far_field;
mod fisheye_sweep;
mod geometry_check;
mod lens_health;
mod lens_mask;
mod model_estimator;
mod model_ssmode;
mod photometric_channel;
mod photometric_scene;
mod photometric_sweep;
mod psmode;
