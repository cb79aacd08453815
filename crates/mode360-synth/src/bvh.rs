//! A bounding volume hierarchy over analytic primitives ([`super::shape`]) for closest-hit
//! and any-hit ray queries.

pub use super::shape::{Aabb, OrientedKind, Ray, Shape, SurfaceHit, RAY_EPSILON_M};
use nalgebra::Vector3;

/// Leaves hold at most this many primitives.
const MAX_LEAF_PRIMS: usize = 4;
/// Traversal stack depth (the tree depth is about log2(n / leaf size)).
const STACK_DEPTH: usize = 64;

/// A shape with its surface description `M` (the renderer's material; the BVH only reads the
/// shape) and the origin of its object's texture coordinates (moving objects carry their
/// texture with them).
#[derive(Clone, Copy, Debug)]
pub struct Prim<M> {
    pub shape: Shape,
    pub material: M,
    pub object_origin: Vector3<f64>,
    /// What the primitive is part of (the ground truth's labels).
    pub label: PrimLabel,
}

/// What a primitive is part of: the ground surface, the fixed structure of the scene, or one
/// object instance (ids from 1, unique within a frame; a scene's objects may be made of
/// several primitives).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PrimLabel {
    Ground,
    #[default]
    Structure,
    Object(u16),
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
fn sah_split<M>(items: &mut [(Aabb, Prim<M>)], centroids: &Aabb, axis: usize) -> usize {
    let lo = centroids.min[axis];
    let extent = centroids.max[axis] - lo;
    let n = items.len();
    let median = |items: &mut [(Aabb, Prim<M>)]| {
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
pub struct Bvh<M> {
    pub prims: Vec<Prim<M>>,
    nodes: Vec<Node>,
}

impl<M> Bvh<M> {
    pub fn build(prims: Vec<Prim<M>>) -> Self {
        let mut items: Vec<(Aabb, Prim<M>)> =
            prims.into_iter().map(|p| (p.shape.aabb(), p)).collect();
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
        items: &mut [(Aabb, Prim<M>)],
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

    fn prim(shape: Shape) -> Prim<()> {
        Prim {
            shape,
            material: (),
            object_origin: Vector3::zeros(),
            label: PrimLabel::Structure,
        }
    }

    #[test]
    fn bvh_matches_brute_force() {
        let mut rng = crate::noise::Rng::new(&[42]);
        let prims: Vec<Prim<()>> = (0..300)
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
