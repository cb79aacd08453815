//! The longitude seam of the 3-D cost aggregation.
//!
//! The planar feature convolutions pad the ERP circularly in longitude ([`super::feature`]), but
//! the 3-D convolutions of the aggregation pad every axis with zeros, so cells near longitude
//! ±180° would be aggregated as if the sphere ended there. After its entry convolution (stride
//! `s`, at `1 / s` of the cost volume's size, so the copy is `s³` times smaller than the
//! volume's) the aggregation's input is widened by `q = p / s` columns copied across the seam on
//! each side,
//!
//! ```text
//! padded[.., u, ..] = x[.., (u − q) mod W, ..]      u = 0 .. W + 2 q
//! ```
//!
//! and each regression head's cost is cropped back to the sphere's own `W` columns. Inside `q`
//! columns of the padded border the layers still meet their zeros, but those cells are cropped
//! away; at the seam every cell has `q` true neighbours on each side (only the entry
//! convolution's first column saw one zero column). The presets train with it
//! ([`super::config::DEFAULT_SEAM_PAD_CELLS`]); weights files without the field keep the zero
//! padding they were trained with. Measured with weights trained without it (models/README.md,
//! "Longitude seam"): random objects +0.7 δ1 points on the validation seed at `p = 8`, other
//! rows within 0.05.

use candle_core::{Result, Tensor};

use crate::model::ops::OpsError;

/// Axis of longitude in the aggregation's volumes `(B, D, H, W, C)` and in the aggregated cost
/// `(B, D, H, W)`.
const LONGITUDE_AXIS: usize = 3;

/// `(B, D, H, W, C)` -> `(B, D, H, W + 2 p, C)`: `p` columns from each side of the seam copied to
/// the other (see the module doc). `p = 0` returns the volume as it is.
pub fn wrap_longitude(volume: &Tensor, pad_cells: usize) -> Result<Tensor> {
    if pad_cells == 0 {
        return Ok(volume.clone());
    }
    let w = volume.dim(LONGITUDE_AXIS)?;
    if pad_cells > w {
        return Err(OpsError::Shape {
            op: "wrap_longitude",
            what: format!("{pad_cells} pad cells exceed the volume's width {w}"),
        }
        .into());
    }
    let left = volume.narrow(LONGITUDE_AXIS, w - pad_cells, pad_cells)?;
    let right = volume.narrow(LONGITUDE_AXIS, 0, pad_cells)?;
    Tensor::cat(&[&left, volume, &right], LONGITUDE_AXIS)
}

/// The aggregated cost `(B, D/s, H/s, W/s + 2 p/s)` of an aggregation widened by `p / s`
/// columns ([`wrap_longitude`] after its entry stride `s`) -> `(B, D/s, H/s, W/s)`: the columns
/// of the sphere itself.
pub fn crop_longitude(cost: &Tensor, pad_cells: usize, stride: usize) -> Result<Tensor> {
    if pad_cells == 0 {
        return Ok(cost.clone());
    }
    let pad = pad_cells / stride.max(1);
    let w = cost.dim(LONGITUDE_AXIS)?;
    if 2 * pad >= w {
        return Err(OpsError::Shape {
            op: "crop_longitude",
            what: format!("cost of width {w} is narrower than its padding 2 x {pad}"),
        }
        .into());
    }
    cost.narrow(LONGITUDE_AXIS, pad, w - 2 * pad)?.contiguous()
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    #[test]
    fn wrap_copies_columns_across_the_seam_and_crop_takes_them_back() {
        // (1, 1, 1, 4, 2): column u holds (u, 10 u)
        let data: Vec<f32> = (0..4).flat_map(|u| [u as f32, 10.0 * u as f32]).collect();
        let v = Tensor::from_vec(data, (1, 1, 1, 4, 2), &Device::Cpu).unwrap();
        let p = wrap_longitude(&v, 2).unwrap();
        assert_eq!(p.dims(), &[1, 1, 1, 8, 2]);
        let cols: Vec<f32> = p
            .narrow(4, 0, 1)
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1()
            .unwrap();
        assert_eq!(cols, [2.0, 3.0, 0.0, 1.0, 2.0, 3.0, 0.0, 1.0]);
        // an aggregated cost at stride 2 of the padded volume: (1, 1, 1, 4) -> the middle 2
        let cost = Tensor::new(&[[[[7f32, 8.0, 9.0, 6.0]]]], &Device::Cpu).unwrap();
        let c = crop_longitude(&cost, 2, 2).unwrap();
        let got: Vec<f32> = c.flatten_all().unwrap().to_vec1().unwrap();
        assert_eq!(got, [8.0, 9.0]);
        // no padding: unchanged
        assert_eq!(wrap_longitude(&v, 0).unwrap().dims(), v.dims());
        assert!(wrap_longitude(&v, 5).is_err());
        assert!(crop_longitude(&cost, 4, 1).is_err());
    }
}
