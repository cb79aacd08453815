//! The `points` output: an unorganized x y z rgb float32 cloud of the estimated range, each
//! point coloured by a camera that sees it (ERP panoramas see everything; a fisheye lens only
//! its field of view), and its decoder.

use super::PipelineError;
use mode360_core::frame::{FloatImage, RgbImage};
use mode360_core::geometry::{ErpGrid, PixelCoord, Projection};
use mode360_io::msgs::{Header, PointCloud2, PointField};
use nalgebra::Vector3;

/// Bytes of one float32 value.
const F32_BYTES: u32 = 4;
/// Fields of a published point: x, y, z, rgb (all float32).
pub const POINT_FIELD_NAMES: [&str; 4] = ["x", "y", "z", "rgb"];
/// Bytes of one published point.
pub const POINT_STEP_BYTES: u32 = F32_BYTES * POINT_FIELD_NAMES.len() as u32;

/// A camera image points take their colour from, with its pose and model.
pub struct ColourSource<'a> {
    pub image: &'a RgbImage,
    pub cam_from_output: nalgebra::Isometry3<f64>,
    pub projection: &'a Projection,
}

impl ColourSource<'_> {
    /// The colour of the output-frame point `p_out`, `None` where the camera does not see it.
    fn colour_of(&self, p_out: &Vector3<f64>) -> Option<[u8; 3]> {
        let (w, h) = (self.image.width(), self.image.height());
        let p_cam = self
            .cam_from_output
            .transform_point(&(*p_out).into())
            .coords;
        let px = match self.projection.fisheye_model() {
            None => ErpGrid::new(w as usize).ok()?.pixel_from_dir(&p_cam),
            Some(model) => model.project(&p_cam)?,
        };
        let cu = (px.u.round().max(0.0) as u32).min(w.saturating_sub(1));
        let cv = (px.v.round().max(0.0) as u32).min(h.saturating_sub(1));
        Some(self.image.get_pixel(cu, cv).0)
    }
}

/// Packs an RGB colour as `0x00RRGGBB` and reinterprets the bits as f32.
pub fn pack_rgb(r: u8, g: u8, b: u8) -> f32 {
    f32::from_bits((u32::from(r) << 16) | (u32::from(g) << 8) | u32::from(b))
}

/// Inverse of [`pack_rgb`].
pub fn unpack_rgb(packed: f32) -> [u8; 3] {
    let bits = packed.to_bits();
    [(bits >> 16) as u8, (bits >> 8) as u8, bits as u8]
}

/// True when a range becomes a point: finite, positive and nearer than `max_depth_m`.
pub fn is_point_range(range_m: f32, max_depth_m: f32) -> bool {
    range_m.is_finite() && range_m > 0.0 && range_m < max_depth_m
}

/// An unorganized (height 1) cloud of x y z rgb float32 points for every pixel of `range`
/// passing [`is_point_range`], each coloured by the first of `colours` that sees it (black
/// where none does).
pub fn point_cloud(
    header: Header,
    range: &FloatImage,
    max_depth_m: f32,
    colours: &[ColourSource<'_>],
) -> Result<PointCloud2, PipelineError> {
    let grid = ErpGrid::new(range.width)?;
    let mut data = Vec::new();
    let mut count: u32 = 0;
    for v in 0..range.height {
        for u in 0..range.width {
            let rho = range.data[v * range.width + u];
            if !is_point_range(rho, max_depth_m) {
                continue;
            }
            let dir = grid.dir_from_pixel(PixelCoord {
                u: u as f64,
                v: v as f64,
            });
            let p_out = dir * f64::from(rho);
            let [r, g, b] = colours
                .iter()
                .find_map(|c| c.colour_of(&p_out))
                .unwrap_or([0, 0, 0]);
            for value in [
                p_out.x as f32,
                p_out.y as f32,
                p_out.z as f32,
                pack_rgb(r, g, b),
            ] {
                data.extend_from_slice(&value.to_le_bytes());
            }
            count += 1;
        }
    }
    Ok(PointCloud2 {
        header,
        height: 1,
        width: count,
        fields: POINT_FIELD_NAMES
            .iter()
            .enumerate()
            .map(|(k, name)| PointField::new(*name, k as u32 * F32_BYTES, PointField::FLOAT32, 1))
            .collect(),
        is_bigendian: false,
        point_step: POINT_STEP_BYTES,
        row_step: POINT_STEP_BYTES * count,
        data,
        is_dense: true,
    })
}

/// One decoded point of a cloud written by [`point_cloud`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DecodedPoint {
    pub x_m: f32,
    pub y_m: f32,
    pub z_m: f32,
    pub rgb: [u8; 3],
}

/// Reads back the points of an x y z rgb float32 little-endian cloud (`None` if the layout
/// differs).
pub fn decode_points(cloud: &PointCloud2) -> Option<Vec<DecodedPoint>> {
    if cloud.point_step != POINT_STEP_BYTES || cloud.is_bigendian {
        return None;
    }
    let f = |c: &[u8], k: usize| {
        let o = k * F32_BYTES as usize;
        f32::from_le_bytes([c[o], c[o + 1], c[o + 2], c[o + 3]])
    };
    Some(
        cloud
            .data
            .chunks_exact(POINT_STEP_BYTES as usize)
            .map(|c| DecodedPoint {
                x_m: f(c, 0),
                y_m: f(c, 1),
                z_m: f(c, 2),
                rgb: unpack_rgb(f(c, 3)),
            })
            .collect(),
    )
}
