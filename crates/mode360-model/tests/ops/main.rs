//! The network on its own (`cargo test -p mode360-model`): custom tensor ops against nested-loop
//! f64 references and their composites, gradients against central differences, and the
//! network's composite layers and SSMODE's layers against references.

#[path = "../common/mod.rs"]
mod common;

mod model_composites;
mod model_ssmode_layers;
mod ops_composite;
mod ops_conv3d;
mod ops_sample;
