//! Analytic primitives (axis-aligned boxes, spheres, ellipsoids, axis-aligned cylinders, and
//! boxes, ellipsoids and cylinders with any orientation) and a bounding volume hierarchy over
//! them for closest-hit and any-hit ray queries.

use super::material::Material;
use nalgebra::{Matrix3, Vector3};

/// Hits closer than this along a ray are ignored (self-intersection guard), metres.
pub const RAY_EPSILON_M: f64 = 1e-6;
/// Leaves hold at most this many primitives.
const MAX_LEAF_PRIMS: usize = 4;
/// Traversal stack depth (the tree depth is about log2(n / leaf size)).
const STACK_DEPTH: usize = 64;

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

/// A shape with its material and the origin of its object's texture coordinates (moving
/// objects carry their texture with them).
#[derive(Clone, Copy, Debug)]
pub struct Prim {
    pub shape: Shape,
    pub material: Material,
    pub object_origin: Vector3<f64>,
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
            Shape::Box(b) => {
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
                SurfaceHit { t, normal: n }
            }
            Shape::Sphere { centre, radius_m } => {
                let oc = ray.origin - centre;
                let t = smallest_root(
                    ray.dir.norm_squared(),
                    oc.dot(&ray.dir),
                    oc.norm_squared() - radius_m * radius_m,
                )?;
                SurfaceHit {
                    t,
                    normal: (ray.at(t) - centre) / radius_m,
                }
            }
            Shape::Ellipsoid { centre, radii_m } => {
                let oc = (ray.origin - centre).component_div(&radii_m);
                let d = ray.dir.component_div(&radii_m);
                let t = smallest_root(d.norm_squared(), oc.dot(&d), oc.norm_squared() - 1.0)?;
                let p = ray.at(t) - centre;
                let n = p.component_div(&radii_m.component_mul(&radii_m));
                SurfaceHit {
                    t,
                    normal: n.normalize(),
                }
            }
            Shape::Cylinder {
                centre,
                axis,
                radius_m,
                half_length_m,
            } => {
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
                best?
            }
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

/// Below this depth splits use the SAH; the traversal stack (`STACK_DEPTH`) exceeds this
/// plus log2 of any realistic primitive count.
const SAH_MAX_DEPTH: usize = 32;
/// Number of bins of the binned surface-area-heuristic split.
const SAH_BINS: usize = 16;

fn half_area(b: &Aabb) -> f64 {
    let e = (b.max - b.min).sup(&Vector3::zeros());
    e.x * e.y + e.y * e.z + e.z * e.x
}

/// Partitions `items` along `axis` where the binned surface area heuristic
/// `A(L) n(L) + A(R) n(R)` is least; returns the split index (median if degenerate).
fn sah_split(items: &mut [(Aabb, Prim)], centroids: &Aabb, axis: usize) -> usize {
    let lo = centroids.min[axis];
    let extent = centroids.max[axis] - lo;
    let n = items.len();
    let median = |items: &mut [(Aabb, Prim)]| {
        let mid = n / 2;
        items.select_nth_unstable_by(mid, |a, b| {
            a.0.centre()[axis].total_cmp(&b.0.centre()[axis])
        });
        mid
    };
    if extent <= 1e-12 {
        return median(items);
    }
    let bin_of = |b: &Aabb| {
        (((b.centre()[axis] - lo) / extent * SAH_BINS as f64) as usize).min(SAH_BINS - 1)
    };
    let mut counts = [0usize; SAH_BINS];
    let mut bounds = [Aabb::empty(); SAH_BINS];
    for (b, _) in items.iter() {
        let k = bin_of(b);
        counts[k] += 1;
        bounds[k] = bounds[k].union(b);
    }
    // Costs of splitting after bin k: sweep from the left and from the right.
    let mut left_cost = [0.0f64; SAH_BINS];
    let (mut acc, mut cnt) = (Aabb::empty(), 0usize);
    for k in 0..SAH_BINS - 1 {
        acc = acc.union(&bounds[k]);
        cnt += counts[k];
        left_cost[k] = if cnt > 0 {
            half_area(&acc) * cnt as f64
        } else {
            0.0
        };
    }
    let (mut best_k, mut best_cost) = (usize::MAX, f64::INFINITY);
    let (mut acc, mut cnt) = (Aabb::empty(), 0usize);
    for k in (0..SAH_BINS - 1).rev() {
        acc = acc.union(&bounds[k + 1]);
        cnt += counts[k + 1];
        let left_n: usize = n - cnt;
        if cnt == 0 || left_n == 0 {
            continue;
        }
        let cost = left_cost[k] + half_area(&acc) * cnt as f64;
        if cost < best_cost {
            best_cost = cost;
            best_k = k;
        }
    }
    if best_k == usize::MAX {
        return median(items);
    }
    // In-place partition: bins 0..=best_k to the front.
    let mut i = 0;
    for j in 0..n {
        if bin_of(&items[j].0) <= best_k {
            items.swap(i, j);
            i += 1;
        }
    }
    i
}

/// A flattened BVH node: a leaf when `count > 0` (prims `first..first+count`), else an inner
/// node whose children are `first` and `first + 1`.
#[derive(Clone, Copy, Debug)]
struct Node {
    bounds: Aabb,
    first: u32,
    count: u32,
}

/// The closest primitive hit.
#[derive(Clone, Copy, Debug)]
pub struct PrimHit {
    pub prim: usize,
    pub hit: SurfaceHit,
}

/// Bounding volume hierarchy with median splits on the longest axis of the centroid bounds.
#[derive(Clone, Debug)]
pub struct Bvh {
    pub prims: Vec<Prim>,
    nodes: Vec<Node>,
}

impl Bvh {
    pub fn build(prims: Vec<Prim>) -> Self {
        let mut items: Vec<(Aabb, Prim)> = prims.into_iter().map(|p| (p.shape.aabb(), p)).collect();
        let mut nodes = vec![Node {
            bounds: Aabb::empty(),
            first: 0,
            count: 0,
        }];
        if !items.is_empty() {
            Self::build_node(&mut items, 0, 0, 0, &mut nodes);
        }
        Self {
            prims: items.into_iter().map(|(_, p)| p).collect(),
            nodes,
        }
    }

    fn build_node(
        items: &mut [(Aabb, Prim)],
        offset: usize,
        node: usize,
        depth: usize,
        nodes: &mut Vec<Node>,
    ) {
        let bounds = items.iter().fold(Aabb::empty(), |b, (a, _)| b.union(a));
        if items.len() <= MAX_LEAF_PRIMS {
            nodes[node] = Node {
                bounds,
                first: offset as u32,
                count: items.len() as u32,
            };
            return;
        }
        let cb = items.iter().fold(Aabb::empty(), |b, (a, _)| {
            let c = a.centre();
            b.union(&Aabb { min: c, max: c })
        });
        let ext = cb.max - cb.min;
        let axis = if ext.x >= ext.y && ext.x >= ext.z {
            0
        } else if ext.y >= ext.z {
            1
        } else {
            2
        };
        // Deep in the tree fall back to median splits, which bound the depth (and so the
        // traversal stack) by log2(n).
        let mid = if depth < SAH_MAX_DEPTH {
            sah_split(items, &cb, axis)
        } else {
            let mid = items.len() / 2;
            items.select_nth_unstable_by(mid, |a, b| {
                a.0.centre()[axis].total_cmp(&b.0.centre()[axis])
            });
            mid
        };
        let left = nodes.len();
        nodes.push(Node {
            bounds: Aabb::empty(),
            first: 0,
            count: 0,
        });
        nodes.push(Node {
            bounds: Aabb::empty(),
            first: 0,
            count: 0,
        });
        nodes[node] = Node {
            bounds,
            first: left as u32,
            count: 0,
        };
        let (l, r) = items.split_at_mut(mid);
        Self::build_node(l, offset, left, depth + 1, nodes);
        Self::build_node(r, offset + mid, left + 1, depth + 1, nodes);
    }

    /// Closest hit within `(0, t_max)`.
    pub fn closest(&self, ray: &Ray, t_max: f64) -> Option<PrimHit> {
        let mut best: Option<PrimHit> = None;
        let mut t_best = t_max;
        let mut stack = [0u32; STACK_DEPTH];
        let mut sp = 0usize;
        if self.nodes[0].bounds.hit(ray, t_best).is_some() {
            stack[0] = 0;
            sp = 1;
        }
        while sp > 0 {
            sp -= 1;
            let node = &self.nodes[stack[sp] as usize];
            if node.count > 0 {
                let first = node.first as usize;
                for k in first..first + node.count as usize {
                    if let Some(h) = self.prims[k].shape.intersect(ray, t_best) {
                        t_best = h.t;
                        best = Some(PrimHit { prim: k, hit: h });
                    }
                }
                continue;
            }
            let l = node.first as usize;
            let tl = self.nodes[l].bounds.hit(ray, t_best);
            let tr = self.nodes[l + 1].bounds.hit(ray, t_best);
            match (tl, tr) {
                (Some(a), Some(b)) if sp + 2 <= STACK_DEPTH => {
                    // Push the farther child first so the nearer one is popped next.
                    let (near, far) = if a <= b { (l, l + 1) } else { (l + 1, l) };
                    stack[sp] = far as u32;
                    stack[sp + 1] = near as u32;
                    sp += 2;
                }
                (Some(_), _) if sp < STACK_DEPTH => {
                    stack[sp] = l as u32;
                    sp += 1;
                }
                (_, Some(_)) if sp < STACK_DEPTH => {
                    stack[sp] = (l + 1) as u32;
                    sp += 1;
                }
                _ => {}
            }
        }
        best
    }

    /// Whether anything is hit within `(0, t_max)` (shadow rays).
    pub fn any(&self, ray: &Ray, t_max: f64) -> bool {
        let mut stack = [0u32; STACK_DEPTH];
        let mut sp = 0usize;
        if self.nodes[0].bounds.hit(ray, t_max).is_some() {
            sp = 1;
        }
        while sp > 0 {
            sp -= 1;
            let node = &self.nodes[stack[sp] as usize];
            if node.count > 0 {
                let first = node.first as usize;
                if self.prims[first..first + node.count as usize]
                    .iter()
                    .any(|p| p.shape.intersect(ray, t_max).is_some())
                {
                    return true;
                }
                continue;
            }
            let l = node.first as usize;
            for c in [l, l + 1] {
                if sp < STACK_DEPTH && self.nodes[c].bounds.hit(ray, t_max).is_some() {
                    stack[sp] = c as u32;
                    sp += 1;
                }
            }
        }
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::material::Material;

    fn prim(shape: Shape) -> Prim {
        Prim {
            shape,
            material: Material::Concrete,
            object_origin: Vector3::zeros(),
        }
    }

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
        let mut rng = crate::synth::noise::Rng::new(&[9]);
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
                    assert!((0..3).all(|a| {
                        p[a] >= bounds.min[a] - 1e-9 && p[a] <= bounds.max[a] + 1e-9
                    }));
                }
            }
            assert!(hits > 50, "{kind:?}: {hits} hits");
        }
    }

    #[test]
    fn bvh_matches_brute_force() {
        let mut rng = crate::synth::noise::Rng::new(&[42]);
        let prims: Vec<Prim> = (0..300)
            .map(|_| {
                let c = Vector3::new(
                    rng.range(-50.0, 50.0),
                    rng.range(-50.0, 50.0),
                    rng.range(0.0, 5.0),
                );
                prim(Shape::Sphere {
                    centre: c,
                    radius_m: rng.range(0.2, 2.0),
                })
            })
            .collect();
        let bvh = Bvh::build(prims.clone());
        for k in 0..500 {
            let a = k as f64 * 0.0123;
            let ray = Ray::new(
                Vector3::new(0.0, 0.0, 2.0),
                Vector3::new(a.cos(), a.sin(), 0.01),
            );
            let brute = prims
                .iter()
                .filter_map(|p| p.shape.intersect(&ray, 1e9).map(|h| h.t))
                .fold(f64::INFINITY, f64::min);
            let fast = bvh.closest(&ray, 1e9).map_or(f64::INFINITY, |h| h.hit.t);
            assert_eq!(brute, fast);
            assert_eq!(bvh.any(&ray, 1e9), brute.is_finite());
        }
    }
}
