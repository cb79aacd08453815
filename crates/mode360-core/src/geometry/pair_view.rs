//! A camera pair as PSMODE's first stage matches it (paper section 4.2.1): both cameras'
//! panoramas turned into the pair's GEER frame, and the pair's range brought back into the
//! rig's output frame.
//!
//! The pair panorama is GEER stored transposed: an ERP panorama of the *pair frame*, whose
//! `z` axis is the baseline `O_r -> O_l` (GEER's `x`), `x` is GEER's `z` and `y` is GEER's
//! `-y`. In ERP terms
//!
//! ```text
//! row    v = phi H / pi - 1/2          phi   = angle from the baseline (GEER column)
//! column u = (1 + theta / pi) W / 2 - 1/2   theta = angle about the baseline (GEER row, mirrored)
//! ```
//!
//! so both cameras see a point in the same column (epipolar lines are columns), the angular
//! disparity `d = phi_l - phi_r` is a shift along the column of `d H / pi` rows, and the range
//! from the left camera is `rho_l = B sin(phi_r) / sin(d)` (paper Eq. 3,
//! [`GeerPair::range_from_disparity`]). Storing it as an ERP panorama lets the network's
//! longitude wrap serve GEER's `theta` wrap.

use super::erp::{ErpGrid, PixelCoord};
use super::erp_rotation::ErpRotation;
use super::geer::GeerPair;
use super::panorama::{rig_panoramas, CameraPanorama};
use super::rig::{Projection, Rig, RigCamera};
use super::GeometryError;
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use std::f64::consts::PI;

/// Neighbouring pair pixels whose ranges differ by at most this share lie on one surface, and
/// the output pixels between their points are filled ([`PairView::align`]).
const SAME_SURFACE_REL: f32 = 0.1;
/// A splat footprint larger than this many output pixels on a side (columns counted at their
/// width on the sphere) is a tear: the point then fills only the 2x2 pixels around it.
const MAX_FOOTPRINT_PX: f64 = 16.0;
/// Within this angle of the baseline a pair has too little parallax to trust: its confidence
/// there is scaled by `sin(phi) / sin(BLIND_CONE_RAD)` (0 on the baseline, 1 from here out).
const BLIND_CONE_RAD: f64 = 15.0 * PI / 180.0;
/// Passes of the hole filling after splatting ([`PairView::align`]).
const HOLE_FILL_PASSES: usize = 2;
/// A filled hole keeps this share of its neighbour's confidence.
const HOLE_CONFIDENCE_SCALE: f32 = 0.5;

/// Two cameras of a rig, by index: `left` is the camera whose range stage 1 returns.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct CameraPair {
    pub left: usize,
    pub right: usize,
}

impl CameraPair {
    /// Every unordered pair of `cameras` cameras, the lower index on the left:
    /// `(0, 1), (0, 2), ..., (n-2, n-1)`.
    pub fn all(cameras: usize) -> Vec<Self> {
        (0..cameras)
            .flat_map(|left| (left + 1..cameras).map(move |right| Self { left, right }))
            .collect()
    }
}

/// A pair's range and confidence brought into the output frame.
#[derive(Clone, Debug, PartialEq)]
pub struct AlignedRange {
    /// Row-major on the output grid; NaN where the pair says nothing.
    pub range_m: Vec<f32>,
    /// Row-major on the output grid; 0 where the pair says nothing.
    pub confidence: Vec<f32>,
}

/// One camera pair of a rig, in its GEER frame.
#[derive(Clone, Debug)]
pub struct PairView {
    pair: CameraPair,
    geer: GeerPair,
    /// The pair frame's axes in rig axes (see the module doc).
    rig_from_pair: Rotation3<f64>,
    left: CameraPanorama,
    right: CameraPanorama,
    pair_rig: Rig,
}

/// `p_geer = GEER_FROM_PAIR p_pair`: GEER `x` is pair `z`, GEER `y` is pair `-y`, GEER `z` is
/// pair `x` (a proper rotation).
fn geer_from_pair() -> Rotation3<f64> {
    Rotation3::from_matrix_unchecked(Matrix3::new(
        0.0, 0.0, 1.0, //
        0.0, -1.0, 0.0, //
        1.0, 0.0, 0.0,
    ))
}

impl PairView {
    /// The pair `pair` of `rig` (GEER `z` from the rig frame's up, `+z`); an error for an
    /// unknown camera or coincident centres.
    pub fn new(rig: &Rig, pair: CameraPair) -> Result<Self, GeometryError> {
        let count = rig.cameras.len();
        for index in [pair.left, pair.right] {
            if index >= count {
                return Err(GeometryError::NoSuchCamera { index, count });
            }
        }
        let panoramas = rig_panoramas(rig);
        let left = panoramas[pair.left].clone();
        let right = panoramas[pair.right].clone();
        let origin = |p: &CameraPanorama| p.rig_from_panorama.translation.vector;
        // width 1: only the frame is used here, pixels are the ERP grid's
        let geer = GeerPair::new(origin(&left), origin(&right), Vector3::z(), 1)?;
        let rig_from_pair = geer.rig_from_geer() * geer_from_pair();
        let camera = |index: usize, pano: &CameraPanorama| RigCamera {
            projection: Projection::Equirectangular,
            rig_from_cam: pose(origin(pano), &rig_from_pair),
            ..rig.cameras[index].clone()
        };
        let pair_rig = Rig {
            rig_frame: rig.rig_frame.clone(),
            cameras: vec![camera(pair.left, &left), camera(pair.right, &right)],
            reference: 0,
            output_frame_id: rig.cameras[pair.left].frame_id.clone(),
            rig_from_output: pose(origin(&left), &rig_from_pair),
        };
        Ok(Self {
            pair,
            geer,
            rig_from_pair,
            left,
            right,
            pair_rig,
        })
    }

    pub fn pair(&self) -> CameraPair {
        self.pair
    }

    /// The pair's GEER frame (baseline, Eq. 3).
    pub fn geer(&self) -> &GeerPair {
        &self.geer
    }

    pub fn baseline_m(&self) -> f64 {
        self.geer.baseline_m()
    }

    /// The pair as a two-camera rig of ERP cameras in the pair frame, left first; its output
    /// frame is the left camera's pair frame, so a sweep of it is a search along columns.
    pub fn pair_rig(&self) -> &Rig {
        &self.pair_rig
    }

    fn panorama(&self, side: PairSide) -> &CameraPanorama {
        match side {
            PairSide::Left => &self.left,
            PairSide::Right => &self.right,
        }
    }

    /// `side`'s panorama frame from the pair frame (a rotation: both share the camera's centre).
    pub fn panorama_from_pair(&self, side: PairSide) -> Rotation3<f64> {
        self.panorama(side)
            .rig_from_panorama
            .rotation
            .to_rotation_matrix()
            .inverse()
            * self.rig_from_pair
    }

    /// The resampling of a camera's panorama (`side`'s panorama frame, on `src`) into the pair
    /// panorama on `dst`.
    pub fn rotation_into_pair(&self, side: PairSide, src: ErpGrid, dst: ErpGrid) -> ErpRotation {
        ErpRotation::new(src, dst, &self.panorama_from_pair(side))
    }

    /// Per pixel of a pair panorama on `grid`, whether `side`'s camera sees that direction
    /// (always for a 360° camera).
    pub fn seen_in_pair(&self, side: PairSide, grid: ErpGrid) -> Vec<bool> {
        let pano = self.panorama(side);
        let pano_from_pair = self.panorama_from_pair(side);
        (0..grid.len())
            .map(|k| pano.sees(&(pano_from_pair * grid.dir_from_pixel(pixel(grid, k)))))
            .collect()
    }

    /// Per pixel of `output` (an ERP grid of the frame `rig_from_output`), the pair's parallax
    /// for a point one metre out along the pixel's ray, `B |dir x b_hat|` in metres (0 along
    /// the baseline, `B` across it): how well the pair can range that pixel at all.
    pub fn parallax_on(&self, output: ErpGrid, rig_from_output: &Isometry3<f64>) -> Vec<f32> {
        let b_hat = self.rig_from_pair * Vector3::z();
        (0..output.len())
            .map(|k| {
                let dir = rig_from_output.rotation * output.dir_from_pixel(pixel(output, k));
                (self.baseline_m() * dir.cross(&b_hat).norm()) as f32
            })
            .collect()
    }

    /// The angular disparity, in rows of a pair panorama `grid`, of the point at `range_m`
    /// from the left camera in row `v`: `(phi_l - phi_r) H / pi`.
    pub fn disparity_rows(&self, grid: ErpGrid, v: f64, range_m: f64) -> f64 {
        let phi_l = std::f64::consts::PI * (v + 0.5) / grid.height() as f64;
        let d = self.geer.disparity_from_range(phi_l, range_m);
        d * grid.height() as f64 / std::f64::consts::PI
    }

    /// The pair's range (from the left camera, on the pair panorama `pair_grid`) as range from
    /// the rig's output frame on `output`: each pixel's point is splatted over the output
    /// pixels between it and its right, lower and diagonal neighbours on the same surface
    /// (ranges within [`SAME_SURFACE_REL`]; at least the 2x2 pixels around it), the nearest
    /// range winning; points either camera does not see are dropped; within [`BLIND_CONE_RAD`]
    /// of the baseline the confidence falls with `sin(phi)` to 0 (the blind points); then up to
    /// [`HOLE_FILL_PASSES`] passes fill an empty pixel from its nearest 8-neighbour at
    /// [`HOLE_CONFIDENCE_SCALE`] of its confidence.
    pub fn align(
        &self,
        pair_grid: ErpGrid,
        range_m: &[f32],
        confidence: &[f32],
        rig_from_output: &Isometry3<f64>,
        output: ErpGrid,
    ) -> Result<AlignedRange, GeometryError> {
        if range_m.len() != pair_grid.len() || confidence.len() != pair_grid.len() {
            return Err(GeometryError::WrongImageSize {
                expected: (pair_grid.width(), pair_grid.height()),
                got: (
                    range_m.len().min(confidence.len()) / pair_grid.height().max(1),
                    0,
                ),
            });
        }
        let left_origin = self.left.rig_from_panorama.translation.vector;
        let output_from_rig = rig_from_output.inverse();
        let left_from_rig = self.left.rig_from_panorama.inverse();
        let right_from_rig = self.right.rig_from_panorama.inverse();
        // each pair pixel's point in the output frame: continuous pixel and range
        let projected: Vec<Option<(f64, f64, f32)>> = (0..pair_grid.len())
            .map(|k| {
                let rho = f64::from(range_m[k]);
                if !(rho.is_finite() && rho > 0.0) {
                    return None;
                }
                let dir_rig = self.rig_from_pair * pair_grid.dir_from_pixel(pixel(pair_grid, k));
                let p_rig = Point3::from(left_origin + rho * dir_rig);
                let seen = self.left.sees(&(left_from_rig * p_rig).coords)
                    && self.right.sees(&(right_from_rig * p_rig).coords);
                if !seen {
                    return None;
                }
                let p_out = output_from_rig * p_rig;
                let at = output.pixel_from_dir(&p_out.coords);
                Some((at.u, at.v, p_out.coords.norm() as f32))
            })
            .collect();
        let mut range = vec![f32::NAN; output.len()];
        let mut conf = vec![0.0f32; output.len()];
        let (w, h) = (output.width() as i64, output.height() as i64);
        let (pw, ph) = (pair_grid.width(), pair_grid.height());
        for k in 0..pair_grid.len() {
            let Some((_, _, r)) = projected[k] else {
                continue;
            };
            // blind points: no parallax along the baseline, phi = pi (row + 1/2) / H
            let phi = PI * ((k / pw) as f64 + 0.5) / ph as f64;
            let c = confidence[k] * (phi.sin() / BLIND_CONE_RAD.sin()).min(1.0) as f32;
            let (u0, u1, v0, v1) = footprint(&projected, k, pair_grid, output);
            for vv in (v0 as i64)..=(v1 as i64) {
                let vv = vv.clamp(0, h - 1);
                for uu in (u0 as i64)..=(u1 as i64) {
                    let o = (vv * w + uu.rem_euclid(w)) as usize;
                    if range[o].is_nan() || r < range[o] {
                        range[o] = r;
                        conf[o] = c;
                    }
                }
            }
        }
        fill_holes(&mut range, &mut conf, output);
        Ok(AlignedRange {
            range_m: range,
            confidence: conf,
        })
    }
}

/// Which camera of a pair.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PairSide {
    Left,
    Right,
}

fn pose(origin: Vector3<f64>, rotation: &Rotation3<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(origin),
        UnitQuaternion::from_rotation_matrix(rotation),
    )
}

fn pixel(grid: ErpGrid, k: usize) -> PixelCoord {
    PixelCoord {
        u: (k % grid.width()) as f64,
        v: (k / grid.width()) as f64,
    }
}

/// The output pixels pair pixel `k` covers, `(u0, u1, v0, v1)` inclusive: the box spanned
/// with its right, lower and diagonal neighbours that lie on the same surface (range within
/// [`SAME_SURFACE_REL`]; columns wrap, rows stop at the poles), or its own 2x2 pixels where
/// that box is wider than [`MAX_FOOTPRINT_PX`] on the sphere (columns shrink by cos(latitude)).
fn footprint(
    projected: &[Option<(f64, f64, f32)>],
    k: usize,
    pair_grid: ErpGrid,
    output: ErpGrid,
) -> (f64, f64, f64, f64) {
    let (pw, ph) = (pair_grid.width(), pair_grid.height());
    let half_w = output.width() as f64 / 2.0;
    let Some((u, v, r)) = projected[k] else {
        return (0.0, -1.0, 0.0, -1.0);
    };
    let (col, row) = (k % pw, k / pw);
    let (mut u_lo, mut u_hi, mut v_lo, mut v_hi) = (u, u, v, v);
    for (dc, dr) in [(1, 0), (0, 1), (1, 1)] {
        if row + dr >= ph {
            continue;
        }
        let n = (row + dr) * pw + (col + dc) % pw;
        let Some((nu, nv, nr)) = projected[n] else {
            continue;
        };
        if (nr - r).abs() > SAME_SURFACE_REL * r {
            continue;
        }
        // the neighbour's column unwrapped next to this one's
        let du = (nu - u + half_w).rem_euclid(2.0 * half_w) - half_w;
        u_lo = u_lo.min(u + du);
        u_hi = u_hi.max(u + du);
        v_lo = v_lo.min(nv);
        v_hi = v_hi.max(nv);
    }
    let lat_cos = |v: f64| (PI * (v + 0.5) / output.height() as f64).sin();
    let arc_width = (u_hi - u_lo) * lat_cos(v_lo).max(lat_cos(v_hi));
    let too_big =
        arc_width > MAX_FOOTPRINT_PX || u_hi - u_lo > half_w || v_hi - v_lo > MAX_FOOTPRINT_PX;
    if too_big {
        (u.floor(), u.floor() + 1.0, v.floor(), v.floor() + 1.0)
    } else {
        (u_lo.floor(), u_hi.ceil(), v_lo.floor(), v_hi.ceil())
    }
}

/// [`HOLE_FILL_PASSES`] passes: an empty (NaN) pixel takes its nearest non-empty 8-neighbour's
/// range (columns wrap) at [`HOLE_CONFIDENCE_SCALE`] of its confidence.
fn fill_holes(range: &mut [f32], conf: &mut [f32], grid: ErpGrid) {
    let (w, h) = (grid.width() as i64, grid.height() as i64);
    for _ in 0..HOLE_FILL_PASSES {
        let (r0, c0) = (range.to_vec(), conf.to_vec());
        for v in 0..h {
            for u in 0..w {
                let o = (v * w + u) as usize;
                if !r0[o].is_nan() {
                    continue;
                }
                let mut best: Option<(f32, f32)> = None;
                for dv in -1..=1i64 {
                    for du in -1..=1i64 {
                        let vv = v + dv;
                        if (dv, du) == (0, 0) || vv < 0 || vv >= h {
                            continue;
                        }
                        let n = (vv * w + (u + du).rem_euclid(w)) as usize;
                        if !r0[n].is_nan() && best.is_none_or(|(r, _)| r0[n] < r) {
                            best = Some((r0[n], c0[n]));
                        }
                    }
                }
                if let Some((r, c)) = best {
                    range[o] = r;
                    conf[o] = c * HOLE_CONFIDENCE_SCALE;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    fn rig(centres: &[[f64; 3]]) -> Rig {
        let cameras = centres
            .iter()
            .enumerate()
            .map(|(i, c)| RigCamera {
                name: format!("cam{i}"),
                topic: format!("/cam{i}/image_raw"),
                frame_id: format!("cam{i}"),
                projection: Projection::Equirectangular,
                rig_from_cam: Isometry3::from_parts(
                    Translation3::new(c[0], c[1], c[2]),
                    UnitQuaternion::from_euler_angles(0.1 * i as f64, 0.0, 0.7 * i as f64),
                ),
            })
            .collect();
        Rig {
            rig_frame: "base_link".into(),
            cameras,
            reference: 0,
            output_frame_id: "base_link".into(),
            rig_from_output: Isometry3::identity(),
        }
    }

    fn square() -> Rig {
        rig(&[
            [0.3, 0.3, 0.0],
            [0.3, -0.3, 0.0],
            [-0.3, -0.3, 0.05],
            [-0.3, 0.3, 0.0],
        ])
    }

    #[test]
    fn all_pairs_of_four_cameras_are_six() {
        let pairs = CameraPair::all(4);
        assert_eq!(pairs.len(), 6);
        assert!(pairs.iter().all(|p| p.left < p.right && p.right < 4));
        let e = PairView::new(&square(), CameraPair { left: 0, right: 7 }).unwrap_err();
        assert_eq!(e, GeometryError::NoSuchCamera { index: 7, count: 4 });
    }

    #[test]
    fn both_cameras_see_a_point_in_the_same_column_and_the_disparity_gives_its_range() {
        let rig = square();
        let grid = ErpGrid::new(512).unwrap();
        for pair in CameraPair::all(4) {
            let view = PairView::new(&rig, pair).unwrap();
            let pr = view.pair_rig();
            for point in [
                Vector3::new(3.0, 1.0, 0.5),
                Vector3::new(-2.0, 5.0, -1.2),
                Vector3::new(0.4, -9.0, 2.0),
            ] {
                let see = |cam: usize| {
                    let local = pr.cameras[cam].rig_from_cam.inverse() * Point3::from(point);
                    (grid.pixel_from_dir(&local.coords), local.coords.norm())
                };
                let ((pl, rho_l), (pr_px, _)) = (see(0), see(1));
                assert_relative_eq!(pl.u, pr_px.u, epsilon = 1e-9);
                // rows grow with phi, and the left camera sees the point farther from +baseline
                let d_rows = pl.v - pr_px.v;
                assert!(d_rows > 0.0, "{pair:?}: disparity {d_rows} rows");
                assert_relative_eq!(
                    view.disparity_rows(grid, pl.v, rho_l),
                    d_rows,
                    epsilon = 1e-6
                );
                let to_rad = std::f64::consts::PI / grid.height() as f64;
                let phi_r = (pr_px.v + 0.5) * to_rad;
                let rho = view.geer().range_from_disparity(phi_r, d_rows * to_rad);
                assert_relative_eq!(rho.unwrap(), rho_l, epsilon = 1e-6);
            }
        }
    }

    #[test]
    fn a_sphere_of_range_seen_by_a_pair_comes_back_as_the_same_sphere_from_the_output_frame() {
        let rig = square();
        let view = PairView::new(&rig, CameraPair { left: 1, right: 2 }).unwrap();
        let left_origin = view.pair_rig().rig_from_output.translation.vector;
        // 6 m: the pair's pixels are about the output's; 1 m (the cameras 0.42 m from the
        // centre): the near side is magnified about 1.7 times, so points alone leave holes
        for (radius_m, pair_width, out_width) in [(6.0, 128, 64), (1.0, 128, 128)] {
            let (pair_grid, output) = (
                ErpGrid::new(pair_width).unwrap(),
                ErpGrid::new(out_width).unwrap(),
            );
            // range from the left camera to the sphere about the output origin
            let range: Vec<f32> = (0..pair_grid.len())
                .map(|k| {
                    let d = view.rig_from_pair * pair_grid.dir_from_pixel(pixel(pair_grid, k));
                    let b = left_origin.dot(&d);
                    let c = left_origin.norm_squared() - radius_m * radius_m;
                    (-b + (b * b - c).sqrt()) as f32
                })
                .collect();
            let conf = vec![0.8f32; pair_grid.len()];
            let out = view
                .align(pair_grid, &range, &conf, &rig.rig_from_output, output)
                .unwrap();
            let filled = out.range_m.iter().filter(|r| !r.is_nan()).count();
            assert_eq!(filled, output.len(), "{radius_m} m: holes left");
            let worst = out
                .range_m
                .iter()
                .map(|r| (f64::from(*r) - radius_m).abs())
                .fold(0.0, f64::max);
            assert!(worst < 1e-3, "{radius_m} m: worst range error {worst} m");
            assert!(out.confidence.iter().all(|&c| (0.0..=0.8).contains(&c)));
            // along the baseline the pair has no parallax: the confidence vanishes where the
            // left camera's ray along it meets the sphere
            let d = view.rig_from_pair * Vector3::z();
            let b = left_origin.dot(&d);
            let rho = -b + (b * b - (left_origin.norm_squared() - radius_m * radius_m)).sqrt();
            let p_out = rig.rig_from_output.inverse() * Point3::from(left_origin + rho * d);
            let at = output.pixel_from_dir(&p_out.coords);
            let k = (at.v.round().max(0.0) as usize).min(output.height() - 1) * output.width()
                + (at.u.round().max(0.0) as usize) % output.width();
            assert!(
                out.confidence[k] < 0.15,
                "{radius_m} m: {} along the baseline",
                out.confidence[k]
            );
        }
    }
}
