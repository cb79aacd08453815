//! The SSMODE network and its building blocks (candle).

pub mod ops;
