//! mode360's depth estimators ([`estimator`]): the learning-free photometric sweep and SSMODE,
//! whose network is `mode360_model::model`; both build on the windowed ZNCC matching of
//! `mode360_model::matching`. Also the rig's health checks (lens masks and blockage, the
//! calibration drift check) that run beside them.

pub mod estimator;
