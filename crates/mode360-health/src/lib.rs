//! mode360's rig health checks, run beside the depth estimators on the same frames:
//!
//! * lens health: which part of each lens is blocked (dirt, a sticker, a wiper), from where a
//!   camera disagrees with the others ([`lens_health`]) and where its picture never moves
//!   ([`lens_motion`]), voted over a window of frames ([`lens_window`]); the blocked parts
//!   become the estimators' lens masks ([`mode360_estimator::lens_mask`]), applied by
//!   [`lens_guard`];
//! * calibration: each camera's rotation checked and refined against the others
//!   ([`calibration`]), and its drift followed over time ([`calibration_drift`]).
//!
//! Above `mode360-estimator` (the checks sample panoramas as the photometric sweep does and
//! wrap an estimator), below the node and the commands.

pub mod calibration;
pub mod calibration_drift;
pub mod lens_guard;
pub mod lens_health;
pub mod lens_motion;
pub mod lens_window;
