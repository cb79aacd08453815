//! The far field of a sweep: per output pixel, how many hypotheses, counted from the far
//! plane, the rig cannot tell from the far plane.
//!
//! For output pixel `p` with ray `dir(p)` and hypothesis `i` at range `rho_i` (index 0 the far
//! plane), camera `c` sees the point in direction `x_c(i) = cam_from_output * (rho_i dir(p))`,
//! shifted from where it sees the far plane by
//!
//! ```text
//! a_c(i) = angle(x_c(i), x_c(0))
//! ```
//!
//! Two cameras' views of the point move against each other by at most the sum of their
//! shifts, so hypothesis `i` looks the same as the far plane to every camera pair when the two
//! largest shifts among the cameras that see both points sum to less than `max_shift_rad`:
//!
//! ```text
//! count(p) = 1 + #{ i >= 1 : a_(1)(j) + a_(2)(j) < max_shift_rad for every 1 <= j <= i }
//! ```
//!
//! A matching cost is flat over those hypotheses, so a readout should count their probability
//! as the far plane's rather than average over them: with a 0.3 m baseline everything beyond
//! about 25 m is one and the same far plane to the rig.

use super::sweep::SweepGeometry;
use nalgebra::Vector3;
use rayon::prelude::*;

/// Per output pixel (row-major over the sweep's output grid), the number of hypotheses from
/// the far plane (index 0) that the rig cannot tell from it; at least 1 (the far plane itself).
#[derive(Clone, Debug, PartialEq)]
pub struct FarField {
    counts: Vec<u16>,
    max_shift_rad: f64,
}

impl FarField {
    /// The far field of `geometry`'s output grid and hypotheses for a largest pair shift of
    /// `max_shift_rad` (see the module docs). A non-positive or NaN shift leaves only the far
    /// plane itself in every pixel's count.
    pub fn new(geometry: &SweepGeometry, max_shift_rad: f64) -> Self {
        let output = geometry.output();
        let w = output.width();
        let ranges_m = geometry.hypotheses().depths_m();
        let cameras = geometry.camera_count();
        let counts = (0..output.len())
            .into_par_iter()
            .with_min_len(w)
            .map(|k| {
                if max_shift_rad.is_nan() || max_shift_rad <= 0.0 {
                    return 1;
                }
                let p = output.pixel_of_index(k);
                let far: Vec<Vector3<f64>> = (0..cameras)
                    .map(|cam| geometry.point_in_camera_m(cam, p, ranges_m[0]))
                    .collect();
                let mut count = 1usize;
                for &range_m in &ranges_m[1..] {
                    let (mut first, mut second) = (0.0f64, 0.0f64);
                    for (cam, far_point) in far.iter().enumerate() {
                        let point = geometry.point_in_camera_m(cam, p, range_m);
                        if !geometry.sees_point(cam, &point) || !geometry.sees_point(cam, far_point)
                        {
                            continue;
                        }
                        let shift = angle_rad(&point, far_point);
                        if shift > first {
                            second = first;
                            first = shift;
                        } else if shift > second {
                            second = shift;
                        }
                    }
                    if first + second >= max_shift_rad {
                        break;
                    }
                    count += 1;
                }
                u16::try_from(count).unwrap_or(u16::MAX)
            })
            .collect();
        Self {
            counts,
            max_shift_rad,
        }
    }

    /// Row-major counts over the output grid.
    pub fn counts(&self) -> &[u16] {
        &self.counts
    }

    /// The largest pair shift the counts were made with, radians.
    pub fn max_shift_rad(&self) -> f64 {
        self.max_shift_rad
    }
}

/// Angle between two (non-zero) vectors, radians, accurate for small angles.
fn angle_rad(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    a.cross(b).norm().atan2(a.dot(b))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{DepthHypotheses, DepthRange, ErpGrid, HypothesisSpacing, Rig};

    /// Two 360° cameras `baseline_m` apart on a vertical mast; the upper one is the output.
    fn vertical_pair(baseline_m: f64) -> Rig {
        let yaml = format!(
            "rig_frame: base_link\nreference_camera: top\ncameras:\n\
             - {{name: top, topic: /top, frame_id: top, projection: equirectangular,\
             rig_from_cam: {{translation: [0, 0, 2.0], rotation_xyzw: [0, 0, 0, 1]}}}}\n\
             - {{name: bottom, topic: /bottom, frame_id: bottom, projection: equirectangular,\
             rig_from_cam: {{translation: [0, 0, {}], rotation_xyzw: [0, 0, 0, 1]}}}}\n",
            2.0 - baseline_m
        );
        Rig::from_yaml_str(&yaml, "test rig").expect("rig")
    }

    fn geometry(rig: &Rig, width: usize) -> SweepGeometry {
        let grid = ErpGrid::new(width).expect("grid");
        let hypotheses =
            DepthHypotheses::with_spacing(DepthRange::paper(), 96, HypothesisSpacing::LogDepth)
                .expect("hypotheses");
        SweepGeometry::new(rig, grid, vec![grid; rig.cameras.len()], hypotheses).expect("sweep")
    }

    /// Sideways from a vertical pair the far field ends where the pair's parallax
    /// `B / rho` reaches the shift; along the baseline (the zenith) it takes in far more.
    #[test]
    fn the_far_field_ends_where_the_parallax_reaches_the_shift() {
        let (baseline_m, shift_rad) = (0.3, 0.01);
        let g = geometry(&vertical_pair(baseline_m), 64);
        let field = FarField::new(&g, shift_rad);
        let hyp = g.hypotheses();
        // The horizon row (v = H/2) sees the baseline side-on: parallax B / rho, so the last
        // indistinguishable hypothesis is near B / shift = 30 m.
        let horizon = field.counts()[16 * 64];
        let nearest_far_m = hyp.depth_m(f64::from(horizon - 1));
        let bound_m = baseline_m / shift_rad;
        assert!(
            (nearest_far_m - bound_m).abs() / bound_m < 0.1,
            "horizon count {horizon}: {nearest_far_m} m against about {bound_m} m"
        );
        // Near the zenith the baseline is almost along the ray: more hypotheses are far.
        let zenith = field.counts()[0];
        assert!(zenith > horizon + 10, "zenith {zenith} horizon {horizon}");
        // No shift: only the far plane itself.
        assert!(FarField::new(&g, 0.0).counts().iter().all(|&c| c == 1));
    }

    /// A wider baseline resolves farther: fewer hypotheses in the far field everywhere.
    #[test]
    fn a_wider_baseline_shrinks_the_far_field() {
        let narrow = FarField::new(&geometry(&vertical_pair(0.3), 32), 0.01);
        let wide = FarField::new(&geometry(&vertical_pair(1.2), 32), 0.01);
        for (k, (n, w)) in narrow.counts().iter().zip(wide.counts()).enumerate() {
            assert!(w <= n, "pixel {k}: wide {w} narrow {n}");
        }
        let (sum_n, sum_w): (u32, u32) = (
            narrow.counts().iter().map(|&c| u32::from(c)).sum(),
            wide.counts().iter().map(|&c| u32::from(c)).sum(),
        );
        assert!(sum_w + 8 * 512 < sum_n, "wide {sum_w} narrow {sum_n}");
    }
}
