//! mode360's synthetic scenes ([`synth`]): worlds of streets and objects rendered for any rig,
//! with ground-truth depth, the paper's lens soiling and blocked lenses.

pub mod synth;
