//! Which cameras see each point of a range image, with that image's own nearer surfaces in the
//! way (issue 38: where no second camera sees a pixel, behind an obstacle, its range is a
//! guess and the estimate should say so).
//!
//! Every point of the range image is moved into each camera's panorama frame and splatted into
//! a z-buffer on that panorama's ERP grid (the output grid's width). A camera sees a point
//! unless a nearer point of the same image falls into the same z-buffer cell, within
//! [`OCCLUDER_MAX_RANGE_M`] of that camera and more than [`OCCLUSION_RATIO`] times nearer:
//!
//! ```text
//! p_j(k)  = panorama_j_from_output (r_k dir_k),   d_j(k) = |p_j(k)|
//! Z_j(c)  = min { d_j(k') : cell_j(k') = c }
//! sees_j(k) = camera j's lens sees p_j(k)
//!             and not (Z_j(cell_j(k)) < OCCLUDER_MAX_RANGE_M and d_j(k) > OCCLUSION_RATIO Z_j(cell_j(k)))
//! ```
//!
//! The limits keep a surface from hiding itself: ground seen at a grazing angle spans a range
//! of distances within one cell (at 512 wide, a 0.7° cell of ground 10 m from a camera 1.5 m
//! high spans distances within 1.1 times of each other; 1.4 times at about 40 m, which is why
//! occluders count only within 10 m).

use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;

use super::erp::ErpGrid;
use super::panorama::rig_panoramas;
use super::rig::Rig;
use super::GeometryError;

/// Occluders farther than this from a camera are not counted, metres (see the module doc).
pub const OCCLUDER_MAX_RANGE_M: f64 = 10.0;
/// How much farther than the nearest point of its z-buffer cell a point must be to be hidden.
pub const OCCLUSION_RATIO: f64 = 1.5;

/// Per pixel of `grid` (row-major), how many cameras of `rig` see the point at `range_m`
/// along that pixel's ray (output frame) without a nearer point of the same range image in
/// the way (see the module doc). 0 where the range is not finite and positive (sky, no
/// estimate). `range_m` must hold one value per pixel of `grid`.
pub fn unoccluded_views(
    rig: &Rig,
    grid: ErpGrid,
    range_m: &[f32],
) -> Result<Vec<u8>, GeometryError> {
    if range_m.len() != grid.len() {
        return Err(GeometryError::WrongImageSize {
            expected: (grid.width(), grid.height()),
            got: (range_m.len(), 1),
        });
    }
    let dirs: Vec<Vector3<f64>> = (0..grid.len())
        .into_par_iter()
        .with_min_len(grid.width())
        .map(|k| grid.dir_from_pixel(grid.pixel_of_index(k)))
        .collect();
    let mut views = vec![0u8; grid.len()];
    for pano in rig_panoramas(rig) {
        let panorama_from_output: Isometry3<f64> =
            pano.rig_from_panorama.inverse() * rig.rig_from_output;
        // (z-buffer cell, distance from the camera) of every point this camera's lens sees
        let splats: Vec<Option<(usize, f64)>> = (0..grid.len())
            .into_par_iter()
            .with_min_len(grid.width())
            .map(|k| {
                let r = f64::from(range_m[k]);
                if !(r.is_finite() && r > 0.0) {
                    return None;
                }
                let p = panorama_from_output * Point3::from(dirs[k] * r);
                let d = p.coords.norm();
                (d > 0.0 && pano.sees(&p.coords)).then(|| (grid.index_from_dir(&p.coords), d))
            })
            .collect();
        let mut zbuffer = vec![f64::INFINITY; grid.len()];
        for &(cell, d) in splats.iter().flatten() {
            zbuffer[cell] = zbuffer[cell].min(d);
        }
        for (v, splat) in views.iter_mut().zip(&splats) {
            if let Some((cell, d)) = *splat {
                let nearest = zbuffer[cell];
                let hidden = nearest < OCCLUDER_MAX_RANGE_M && d > OCCLUSION_RATIO * nearest;
                if !hidden {
                    *v = v.saturating_add(1);
                }
            }
        }
    }
    Ok(views)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::rig::RigCamera;
    use crate::geometry::Projection;
    use nalgebra::{Translation3, UnitQuaternion};

    const WIDTH: usize = 256;

    /// Two ERP cameras: the reference at the origin (the output frame) and one 1 m to its left.
    fn pair() -> Rig {
        let cam = |name: &str, y: f64| RigCamera {
            name: name.into(),
            topic: format!("/{name}/image_raw"),
            frame_id: name.into(),
            projection: Projection::Equirectangular,
            rig_from_cam: Isometry3::from_parts(
                Translation3::new(0.0, y, 0.0),
                UnitQuaternion::identity(),
            ),
        };
        Rig::new(
            "base_link",
            vec![cam("cam1", 0.0), cam("cam2", 1.0)],
            0,
            None,
        )
        .expect("rig")
    }

    /// A wall at 10 m all around, and a post 1 m in front of the reference covering the
    /// longitudes within `half_width_deg` of forward at every latitude.
    fn post_before_wall(grid: ErpGrid, half_width_deg: f64) -> Vec<f32> {
        (0..grid.len())
            .map(|k| {
                let ll = grid.lonlat_from_pixel(grid.pixel_of_index(k));
                if ll.lon_rad.to_degrees().abs() < half_width_deg {
                    1.0
                } else {
                    10.0
                }
            })
            .collect()
    }

    #[test]
    fn the_wall_behind_a_post_is_hidden_from_the_other_camera_only_where_the_post_covers_it() {
        let grid = ErpGrid::new(WIDTH).expect("grid");
        let rig = pair();
        let range = post_before_wall(grid, 5.0);
        let views = unoccluded_views(&rig, grid, &range).expect("views");
        // The equator row: the post (|lon| < 5°) is seen by both; the wall just right of it
        // (negative longitude, away from cam2 at +y) is hidden from cam2 where cam2's ray
        // to it crosses the post, and seen by both beyond.
        let v = grid.height() / 2;
        let at = |lon_deg: f64| {
            let p = grid.pixel_from_lonlat(crate::geometry::LonLat {
                lon_rad: lon_deg.to_radians(),
                lat_rad: 0.0,
            });
            views[v * WIDTH + p.u.round() as usize]
        };
        assert_eq!(at(0.0), 2, "the post");
        assert_eq!(at(90.0), 2, "the wall to the left");
        assert_eq!(at(180.0), 2, "the wall behind");
        // cam2's ray to the wall at reference longitude L crosses the post's unit circle again
        // at t = -2 C.(W - C) / |W - C|^2 (C = cam2, W = the wall point): hidden where that
        // crossing lies within the post, which is for L from about -43.7 to -38.3 degrees.
        let behind_post = |lon_deg: f64| {
            let (c, w) = (
                Vector3::new(0.0, 1.0, 0.0),
                Vector3::new(
                    10.0 * lon_deg.to_radians().cos(),
                    10.0 * lon_deg.to_radians().sin(),
                    0.0,
                ),
            );
            let t = -2.0 * c.dot(&(w - c)) / (w - c).norm_squared();
            let x = c + t * (w - c);
            t > 0.0 && t < 1.0 && x.y.atan2(x.x).to_degrees().abs() < 5.0
        };
        let cell_deg = 360.0 / WIDTH as f64;
        let mut checked_hidden = 0;
        for u in 0..WIDTH {
            let lon = grid
                .lonlat_from_pixel(grid.pixel_of_index(v * WIDTH + u))
                .lon_rad
                .to_degrees();
            let inside = behind_post(lon - cell_deg) && behind_post(lon + cell_deg);
            let outside = !behind_post(lon - cell_deg) && !behind_post(lon + cell_deg);
            let n = views[v * WIDTH + u];
            if inside {
                assert_eq!(n, 1, "the wall at {lon:.1}° is behind the post for cam2");
                checked_hidden += 1;
            } else if outside {
                assert_eq!(n, 2, "at {lon:.1}° both cameras see");
            }
        }
        assert!(
            checked_hidden >= 2,
            "{checked_hidden} pixels checked behind the post"
        );
        assert!(behind_post(-41.0) && !behind_post(-36.0) && !behind_post(-46.0));
        // Nothing is hidden from the reference, whose own image this is.
        assert!(views.iter().all(|&n| n >= 1));
    }

    #[test]
    fn a_plain_wall_and_the_sky_hide_nothing() {
        let grid = ErpGrid::new(WIDTH).expect("grid");
        let rig = pair();
        let wall = vec![10.0f32; grid.len()];
        assert!(unoccluded_views(&rig, grid, &wall)
            .expect("views")
            .iter()
            .all(|&n| n == 2));
        let mut sky = vec![f32::INFINITY; grid.len()];
        sky[0] = f32::NAN;
        assert!(unoccluded_views(&rig, grid, &sky)
            .expect("views")
            .iter()
            .all(|&n| n == 0));
    }

    #[test]
    fn a_range_image_of_the_wrong_size_is_refused() {
        let grid = ErpGrid::new(WIDTH).expect("grid");
        let err = unoccluded_views(&pair(), grid, &[1.0; 10]).expect_err("too short");
        assert!(matches!(err, GeometryError::WrongImageSize { .. }), "{err}");
    }
}
