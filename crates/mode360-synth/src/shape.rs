//! Analytic primitives: axis-aligned boxes, spheres, ellipsoids and axis-aligned cylinders,
//! and boxes, ellipsoids and cylinders with any orientation, with ray intersection.

use nalgebra::{Matrix3, Vector3};

/// Hits closer than this along a ray are ignored (self-intersection guard), metres.
pub const RAY_EPSILON_M: f64 = 1e-6;

/// A ray `o + t d`; `inv_d` caches `1 / d` per axis.
#[derive(Clone, Copy, Debug)]
pub struct Ray {
    pub origin: Vector3<f64>,
    pub dir: Vector3<f64>,
    pub inv_dir: Vector3<f64>,
}

impl Ray {
    pub fn new(origin: Vector3<f64>, dir: Vector3<f64>) -> Self {
        Self {
            origin,
            dir,
            inv_dir: Vector3::new(1.0 / dir.x, 1.0 / dir.y, 1.0 / dir.z),
        }
    }

    pub fn at(&self, t: f64) -> Vector3<f64> {
        self.origin + self.dir * t
    }
}

/// Axis-aligned bounding box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    pub min: Vector3<f64>,
    pub max: Vector3<f64>,
}

impl Aabb {
    pub fn empty() -> Self {
        Self {
            min: Vector3::repeat(f64::INFINITY),
            max: Vector3::repeat(f64::NEG_INFINITY),
        }
    }

    pub fn union(&self, o: &Aabb) -> Aabb {
        Aabb {
            min: self.min.inf(&o.min),
            max: self.max.sup(&o.max),
        }
    }

    pub fn centre(&self) -> Vector3<f64> {
        (self.min + self.max) * 0.5
    }

    /// Slab test: entry distance if the ray meets the box within `(0, t_max)`.
    #[inline]
    pub fn hit(&self, ray: &Ray, t_max: f64) -> Option<f64> {
        let mut t0 = 0.0f64;
        let mut t1 = t_max;
        for a in 0..3 {
            let ta = (self.min[a] - ray.origin[a]) * ray.inv_dir[a];
            let tb = (self.max[a] - ray.origin[a]) * ray.inv_dir[a];
            let (lo, hi) = if ta < tb { (ta, tb) } else { (tb, ta) };
            // NaN (0 * inf) compares false and leaves the interval unchanged.
            if lo > t0 {
                t0 = lo;
            }
            if hi < t1 {
                t1 = hi;
            }
            if t0 > t1 {
                return None;
            }
        }
        Some(t0)
    }
}

/// Geometric shapes, all in world coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    /// Axis-aligned box.
    Box(Aabb),
    /// Sphere `|p - centre| = radius`.
    Sphere { centre: Vector3<f64>, radius_m: f64 },
    /// Axis-aligned ellipsoid `sum(((p - c) / r)^2) = 1`.
    Ellipsoid {
        centre: Vector3<f64>,
        radii_m: Vector3<f64>,
    },
    /// Capped cylinder along coordinate axis `axis` (0 x, 1 y, 2 z) through `centre`,
    /// spanning `centre[axis] +- half_length_m`.
    Cylinder {
        centre: Vector3<f64>,
        axis: usize,
        radius_m: f64,
        half_length_m: f64,
    },
    /// A box, ellipsoid or capped cylinder centred at `centre` in its own frame, rotated:
    /// a point `p` is inside when `local_from_world * (p - centre)` is inside the canonical
    /// shape with half extents `half_extents_m` (box: `|x_i| <= h_i`; ellipsoid: radii `h`;
    /// cylinder: along local z, radius `h.x`, half length `h.z`). `local_from_world` is a
    /// rotation matrix.
    Oriented {
        kind: OrientedKind,
        centre: Vector3<f64>,
        half_extents_m: Vector3<f64>,
        local_from_world: Matrix3<f64>,
    },
}

/// The canonical shape of a [`Shape::Oriented`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OrientedKind {
    Box,
    Ellipsoid,
    Cylinder,
}

impl OrientedKind {
    /// The canonical (axis-aligned, centred at the origin) shape with half extents `h`.
    fn local_shape(self, h: &Vector3<f64>) -> Shape {
        match self {
            OrientedKind::Box => Shape::Box(Aabb { min: -h, max: *h }),
            OrientedKind::Ellipsoid => Shape::Ellipsoid {
                centre: Vector3::zeros(),
                radii_m: *h,
            },
            OrientedKind::Cylinder => Shape::Cylinder {
                centre: Vector3::zeros(),
                axis: 2,
                radius_m: h.x,
                half_length_m: h.z,
            },
        }
    }
}

/// A surface hit: distance along the ray and unit outward normal.
#[derive(Clone, Copy, Debug)]
pub struct SurfaceHit {
    pub t: f64,
    pub normal: Vector3<f64>,
}

/// Smallest root of `a t^2 + 2 b t + c = 0` that is greater than `RAY_EPSILON_M`.
#[inline]
fn smallest_root(a: f64, b: f64, c: f64) -> Option<f64> {
    let disc = b * b - a * c;
    if disc < 0.0 {
        return None;
    }
    let s = disc.sqrt();
    let t0 = (-b - s) / a;
    if t0 > RAY_EPSILON_M {
        return Some(t0);
    }
    let t1 = (-b + s) / a;
    (t1 > RAY_EPSILON_M).then_some(t1)
}

impl Shape {
    pub fn aabb(&self) -> Aabb {
        match *self {
            Shape::Box(b) => b,
            Shape::Sphere { centre, radius_m } => Aabb {
                min: centre - Vector3::repeat(radius_m),
                max: centre + Vector3::repeat(radius_m),
            },
            Shape::Ellipsoid { centre, radii_m } => Aabb {
                min: centre - radii_m,
                max: centre + radii_m,
            },
            Shape::Cylinder {
                centre,
                axis,
                radius_m,
                half_length_m,
            } => {
                let mut h = Vector3::repeat(radius_m);
                h[axis] = half_length_m;
                Aabb {
                    min: centre - h,
                    max: centre + h,
                }
            }
            Shape::Oriented {
                kind,
                centre,
                half_extents_m,
                local_from_world,
            } => {
                // The rotated box bounds every canonical shape; the cylinder's local box has
                // x and y half extents equal to its radius.
                let mut h = half_extents_m;
                if kind == OrientedKind::Cylinder {
                    h.y = h.x;
                }
                let e = local_from_world.transpose().abs() * h;
                Aabb {
                    min: centre - e,
                    max: centre + e,
                }
            }
        }
    }

    /// Closest intersection within `(RAY_EPSILON_M, t_max)`.
    pub fn intersect(&self, ray: &Ray, t_max: f64) -> Option<SurfaceHit> {
        let hit = match *self {
            Shape::Box(b) => box_hit(&b, ray)?,
            Shape::Sphere { centre, radius_m } => sphere_hit(&centre, radius_m, ray)?,
            Shape::Ellipsoid { centre, radii_m } => ellipsoid_hit(&centre, &radii_m, ray)?,
            Shape::Cylinder {
                centre,
                axis,
                radius_m,
                half_length_m,
            } => cylinder_hit(&centre, axis, radius_m, half_length_m, ray)?,
            Shape::Oriented {
                kind,
                centre,
                half_extents_m,
                local_from_world,
            } => {
                // Rotations keep lengths, so t is the same in the local frame.
                let local = Ray::new(
                    local_from_world * (ray.origin - centre),
                    local_from_world * ray.dir,
                );
                let h = kind.local_shape(&half_extents_m).intersect(&local, t_max)?;
                SurfaceHit {
                    t: h.t,
                    normal: local_from_world.transpose() * h.normal,
                }
            }
        };
        (hit.t < t_max).then_some(hit)
    }
}

/// The nearest hit beyond [`RAY_EPSILON_M`] of `ray` on the axis-aligned box `b` (entering,
/// or leaving when the ray starts inside), its normal along the slab's axis.
#[inline]
fn box_hit(b: &Aabb, ray: &Ray) -> Option<SurfaceHit> {
    let mut t0 = f64::NEG_INFINITY;
    let mut t1 = f64::INFINITY;
    let mut axis0 = 0;
    let mut axis1 = 0;
    for a in 0..3 {
        let ta = (b.min[a] - ray.origin[a]) * ray.inv_dir[a];
        let tb = (b.max[a] - ray.origin[a]) * ray.inv_dir[a];
        let (lo, hi) = if ta < tb { (ta, tb) } else { (tb, ta) };
        if lo > t0 {
            t0 = lo;
            axis0 = a;
        }
        if hi < t1 {
            t1 = hi;
            axis1 = a;
        }
    }
    if t0 > t1 {
        return None;
    }
    let (t, axis, sign) = if t0 > RAY_EPSILON_M {
        (t0, axis0, -ray.dir[axis0].signum())
    } else if t1 > RAY_EPSILON_M {
        (t1, axis1, ray.dir[axis1].signum())
    } else {
        return None;
    };
    let mut n = Vector3::zeros();
    n[axis] = sign;
    Some(SurfaceHit { t, normal: n })
}

/// The nearest hit beyond [`RAY_EPSILON_M`] of `ray` on the sphere of `radius_m` about
/// `centre`.
#[inline]
fn sphere_hit(centre: &Vector3<f64>, radius_m: f64, ray: &Ray) -> Option<SurfaceHit> {
    let oc = ray.origin - centre;
    let t = smallest_root(
        ray.dir.norm_squared(),
        oc.dot(&ray.dir),
        oc.norm_squared() - radius_m * radius_m,
    )?;
    Some(SurfaceHit {
        t,
        normal: (ray.at(t) - centre) / radius_m,
    })
}

/// The nearest hit beyond [`RAY_EPSILON_M`] of `ray` on the axis-aligned ellipsoid with
/// radii `radii_m` about `centre`.
#[inline]
fn ellipsoid_hit(centre: &Vector3<f64>, radii_m: &Vector3<f64>, ray: &Ray) -> Option<SurfaceHit> {
    let oc = (ray.origin - centre).component_div(radii_m);
    let d = ray.dir.component_div(radii_m);
    let t = smallest_root(d.norm_squared(), oc.dot(&d), oc.norm_squared() - 1.0)?;
    let p = ray.at(t) - centre;
    let n = p.component_div(&radii_m.component_mul(radii_m));
    Some(SurfaceHit {
        t,
        normal: n.normalize(),
    })
}

/// The nearest hit beyond [`RAY_EPSILON_M`] of `ray` on the capped cylinder along
/// coordinate axis `axis` through `centre`: the side first, then a nearer cap if any.
#[inline]
fn cylinder_hit(
    centre: &Vector3<f64>,
    axis: usize,
    radius_m: f64,
    half_length_m: f64,
    ray: &Ray,
) -> Option<SurfaceHit> {
    let (i, j) = ((axis + 1) % 3, (axis + 2) % 3);
    let o = ray.origin - centre;
    let d = &ray.dir;
    let mut best: Option<SurfaceHit> = None;
    // Side: (o_i + t d_i)^2 + (o_j + t d_j)^2 = r^2, |o_a + t d_a| <= h.
    let a = d[i] * d[i] + d[j] * d[j];
    if a > 1e-18 {
        let b = o[i] * d[i] + o[j] * d[j];
        let c = o[i] * o[i] + o[j] * o[j] - radius_m * radius_m;
        let disc = b * b - a * c;
        if disc >= 0.0 {
            let s = disc.sqrt();
            for t in [(-b - s) / a, (-b + s) / a] {
                if t > RAY_EPSILON_M && (o[axis] + t * d[axis]).abs() <= half_length_m {
                    let mut n = o + d * t;
                    n[axis] = 0.0;
                    best = Some(SurfaceHit {
                        t,
                        normal: n / radius_m,
                    });
                    break;
                }
            }
        }
    }
    // Caps: o_a + t d_a = +-h with radius check.
    if d[axis].abs() > 1e-18 {
        for sign in [-1.0, 1.0] {
            let t = (sign * half_length_m - o[axis]) / d[axis];
            if t > RAY_EPSILON_M && best.is_none_or(|h| t < h.t) {
                let p = o + d * t;
                if p[i] * p[i] + p[j] * p[j] <= radius_m * radius_m {
                    let mut n = Vector3::zeros();
                    n[axis] = sign;
                    best = Some(SurfaceHit { t, normal: n });
                }
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shapes_hit_at_analytic_distances() {
        let ray = Ray::new(Vector3::new(-10.0, 0.0, 0.0), Vector3::new(1.0, 0.0, 0.0));
        let b = Shape::Box(Aabb {
            min: Vector3::new(-1.0, -1.0, -1.0),
            max: Vector3::new(1.0, 1.0, 1.0),
        });
        let h = b.intersect(&ray, 100.0).map(|h| (h.t, h.normal.x));
        assert_eq!(h, Some((9.0, -1.0)));
        let s = Shape::Sphere {
            centre: Vector3::zeros(),
            radius_m: 2.0,
        };
        assert!((s.intersect(&ray, 100.0).map_or(0.0, |h| h.t) - 8.0).abs() < 1e-12);
        let e = Shape::Ellipsoid {
            centre: Vector3::zeros(),
            radii_m: Vector3::new(3.0, 1.0, 1.0),
        };
        assert!((e.intersect(&ray, 100.0).map_or(0.0, |h| h.t) - 7.0).abs() < 1e-12);
        let c = Shape::Cylinder {
            centre: Vector3::zeros(),
            axis: 2,
            radius_m: 0.5,
            half_length_m: 1.0,
        };
        assert!((c.intersect(&ray, 100.0).map_or(0.0, |h| h.t) - 9.5).abs() < 1e-12);
        // Along the axis the cap is hit.
        let cap = Shape::Cylinder {
            centre: Vector3::zeros(),
            axis: 0,
            radius_m: 0.5,
            half_length_m: 1.0,
        };
        assert!((cap.intersect(&ray, 100.0).map_or(0.0, |h| h.t) - 9.0).abs() < 1e-12);
    }

    #[test]
    fn oriented_shapes_match_their_axis_aligned_twins() {
        use nalgebra::Rotation3;
        let rot = Rotation3::from_euler_angles(0.3, -0.7, 1.1);
        let c = Vector3::new(5.0, -2.0, 1.0);
        let h = Vector3::new(1.0, 0.5, 2.0);
        let mut rng = crate::noise::Rng::new(&[9]);
        for kind in [
            OrientedKind::Box,
            OrientedKind::Ellipsoid,
            OrientedKind::Cylinder,
        ] {
            let oriented = Shape::Oriented {
                kind,
                centre: c,
                half_extents_m: h,
                local_from_world: *rot.inverse().matrix(),
            };
            let local = kind.local_shape(&h);
            let bounds = oriented.aabb();
            let mut hits = 0;
            for _ in 0..400 {
                let o = Vector3::new(rng.range(-5.0, 0.0), rng.range(-5.0, 5.0), 0.0);
                let target = c + Vector3::new(
                    rng.range(-2.0, 2.0),
                    rng.range(-2.0, 2.0),
                    rng.range(-2.0, 2.0),
                );
                let d = (target - o).normalize();
                let world = oriented.intersect(&Ray::new(o, d), 1e9);
                let lray = Ray::new(rot.inverse() * (o - c), rot.inverse() * d);
                let expect = local.intersect(&lray, 1e9);
                assert_eq!(world.is_some(), expect.is_some());
                if let (Some(w), Some(e)) = (world, expect) {
                    hits += 1;
                    assert!((w.t - e.t).abs() < 1e-9);
                    assert!((w.normal - rot * e.normal).norm() < 1e-12);
                    let p = o + d * w.t;
                    assert!((0..3)
                        .all(|a| { p[a] >= bounds.min[a] - 1e-9 && p[a] <= bounds.max[a] + 1e-9 }));
                }
            }
            assert!(hits > 50, "{kind:?}: {hits} hits");
        }
    }
}
