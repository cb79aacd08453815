//! mode360's depth estimators ([`estimator`]): the learning-free photometric sweep and SSMODE,
//! whose network is [`model`]; both build on the windowed ZNCC matching of [`matching`].

pub mod cpu;
pub mod estimator;
pub mod matching;
pub mod model;
