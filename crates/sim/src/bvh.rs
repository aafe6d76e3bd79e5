//! Bounding volume hierarchy over primitive boxes: binned surface-area-heuristic build
//! (sequential and tie-broken by index, so it is deterministic) and a stack-based
//! nearest-hit traversal that visits the nearer child first. A street scene has a
//! thousand or so primitives; without this every ray would test all of them.

use crate::math::V3;
use crate::primitive::Aabb;

#[derive(Debug, Clone, Copy)]
struct Node {
    bounds: Aabb,
    /// Leaf: index of its first primitive in `order`; inner node: its left child.
    first: u32,
    /// Number of primitives for a leaf, 0 for an inner node.
    count: u32,
    /// Inner node: its right child.
    right: u32,
}

/// The hierarchy over (id, box) items; traversal reports the ids.
#[derive(Debug, Clone)]
pub struct Bvh {
    nodes: Vec<Node>,
    /// Item ids, leaves referring to ranges of this.
    ids: Vec<u32>,
}

#[cfg(test)]
thread_local! {
    /// Nodes visited (tests only), to check that the hierarchy prunes.
    pub static VISITS: std::cell::Cell<u64> = const { std::cell::Cell::new(0) };
}
const BINS: usize = 12;
const LEAF_SIZE: usize = 2;
const MAX_DEPTH: usize = 60;

impl Bvh {
    pub fn build(items: &[(u32, Aabb)]) -> Bvh {
        let boxes: Vec<Aabb> = items.iter().map(|i| i.1).collect();
        let mut order: Vec<u32> = (0..boxes.len() as u32).collect();
        let centroids: Vec<V3> = boxes.iter().map(Aabb::centroid).collect();
        let mut nodes = Vec::with_capacity(2 * boxes.len().max(1));
        if !boxes.is_empty() {
            build_node(
                &boxes,
                &centroids,
                &mut order,
                0,
                boxes.len(),
                0,
                &mut nodes,
            );
        }
        let ids = order.iter().map(|&k| items[k as usize].0).collect();
        Bvh { nodes, ids }
    }

    /// Visits the items whose boxes the ray `o + t d`, t ∈ [tmin, tmax], crosses,
    /// nearest box first. `test(id, tmax)` returns the hit distance (and any payload)
    /// if the item is hit closer than `tmax`; the closest is returned with its id.
    #[inline]
    pub fn closest<T: Copy>(
        &self,
        o: V3,
        d: V3,
        tmin: f64,
        mut tmax: f64,
        mut test: impl FnMut(u32, f64) -> Option<(f64, T)>,
    ) -> Option<(u32, T)> {
        if self.ids.is_empty() {
            return None;
        }
        let ray = Ray::new(o, d);
        let mut best: Option<(u32, T)> = None;
        let mut stack = [0u32; 2 * MAX_DEPTH + 4];
        let mut sp = 0usize;
        ray.hits(&self.nodes[0].bounds, tmin, tmax)?;
        let mut node = 0u32;
        loop {
            #[cfg(test)]
            VISITS.with(|v| v.set(v.get() + 1));
            let n = &self.nodes[node as usize];
            if n.count > 0 {
                for &p in &self.ids[n.first as usize..(n.first + n.count) as usize] {
                    if let Some((t, v)) = test(p, tmax)
                        && t <= tmax
                    {
                        tmax = t;
                        best = Some((p, v));
                    }
                }
            } else {
                let (l, r) = (n.first, n.right);
                let tl = ray.hits(&self.nodes[l as usize].bounds, tmin, tmax);
                let tr = ray.hits(&self.nodes[r as usize].bounds, tmin, tmax);
                match (tl, tr) {
                    (Some(a), Some(b)) => {
                        let (near, far) = if a <= b { (l, r) } else { (r, l) };
                        stack[sp] = far;
                        sp += 1;
                        node = near;
                        continue;
                    }
                    (Some(_), None) => {
                        node = l;
                        continue;
                    }
                    (None, Some(_)) => {
                        node = r;
                        continue;
                    }
                    (None, None) => {}
                }
            }
            // Pop the next node whose box is still in front of the best hit.
            loop {
                if sp == 0 {
                    return best;
                }
                sp -= 1;
                let cand = stack[sp];
                if ray
                    .hits(&self.nodes[cand as usize].bounds, tmin, tmax)
                    .is_some()
                {
                    node = cand;
                    break;
                }
            }
        }
    }

    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }
}

/// A ray prepared for box tests: inverse direction and which slab face is near.
struct Ray {
    o: [f64; 3],
    inv: [f64; 3],
    neg: [bool; 3],
}

#[inline(always)]
fn fmax(a: f64, b: f64) -> f64 {
    if a > b { a } else { b }
}

#[inline(always)]
fn fmin(a: f64, b: f64) -> f64 {
    if a < b { a } else { b }
}

impl Ray {
    #[inline(always)]
    fn new(o: V3, d: V3) -> Ray {
        let inv = [1.0 / d.x, 1.0 / d.y, 1.0 / d.z];
        Ray {
            o: [o.x, o.y, o.z],
            inv,
            neg: [inv[0] < 0.0, inv[1] < 0.0, inv[2] < 0.0],
        }
    }

    /// Slab test against a box: the entry distance if the ray crosses it within
    /// [tmin, tmax]. The near and far faces are chosen by the direction's signs, so
    /// no per-axis min/max is needed.
    #[inline(always)]
    fn hits(&self, b: &Aabb, tmin: f64, tmax: f64) -> Option<f64> {
        let lo = [b.min.x, b.min.y, b.min.z];
        let hi = [b.max.x, b.max.y, b.max.z];
        let mut t0 = tmin;
        let mut t1 = tmax;
        for k in 0..3 {
            let (near, far) = if self.neg[k] {
                (hi[k], lo[k])
            } else {
                (lo[k], hi[k])
            };
            t0 = fmax(t0, (near - self.o[k]) * self.inv[k]);
            t1 = fmin(t1, (far - self.o[k]) * self.inv[k]);
        }
        (t0 <= t1).then_some(t0)
    }
}

fn build_node(
    boxes: &[Aabb],
    centroids: &[V3],
    order: &mut [u32],
    start: usize,
    end: usize,
    depth: usize,
    nodes: &mut Vec<Node>,
) -> u32 {
    let index = nodes.len() as u32;
    let bounds = order[start..end]
        .iter()
        .fold(Aabb::EMPTY, |b, &i| b.union(&boxes[i as usize]));
    nodes.push(Node {
        bounds,
        first: start as u32,
        count: (end - start) as u32,
        right: 0,
    });
    let n = end - start;
    if n <= LEAF_SIZE || depth >= MAX_DEPTH {
        return index;
    }
    let cbounds = order[start..end]
        .iter()
        .fold(Aabb::EMPTY, |b, &i| b.grow(centroids[i as usize]));
    // Best binned SAH split over the three axes.
    let mut best: Option<(f64, usize, f64)> = None; // (cost, axis, split position)
    for axis in 0..3 {
        let lo = cbounds.min.axis(axis);
        let hi = cbounds.max.axis(axis);
        if hi - lo <= 1e-12 {
            continue;
        }
        let scale = BINS as f64 / (hi - lo);
        let mut bin_box = [Aabb::EMPTY; BINS];
        let mut bin_n = [0usize; BINS];
        for &i in &order[start..end] {
            let b = (((centroids[i as usize].axis(axis) - lo) * scale) as usize).min(BINS - 1);
            bin_n[b] += 1;
            bin_box[b] = bin_box[b].union(&boxes[i as usize]);
        }
        let mut left_area = [0.0; BINS];
        let mut left_n = [0usize; BINS];
        let (mut acc, mut cnt) = (Aabb::EMPTY, 0);
        for k in 0..BINS {
            acc = acc.union(&bin_box[k]);
            cnt += bin_n[k];
            left_area[k] = acc.surface_area();
            left_n[k] = cnt;
        }
        let (mut acc, mut cnt) = (Aabb::EMPTY, 0);
        for k in (1..BINS).rev() {
            acc = acc.union(&bin_box[k]);
            cnt += bin_n[k];
            let cost = left_area[k - 1] * left_n[k - 1] as f64 + acc.surface_area() * cnt as f64;
            if left_n[k - 1] > 0 && cnt > 0 && best.is_none_or(|(c, _, _)| cost < c) {
                best = Some((cost, axis, lo + k as f64 / scale));
            }
        }
    }
    let leaf_cost = bounds.surface_area() * n as f64;
    let mid = match best {
        Some((cost, axis, split)) if cost < leaf_cost || n > 8 => {
            partition(order, start, end, |i| {
                centroids[i as usize].axis(axis) < split
            })
        }
        _ if n > 8 => {
            // Degenerate centroids: split by index to bound leaf size.
            start + n / 2
        }
        _ => return index,
    };
    let mid = if mid == start || mid == end {
        start + n / 2
    } else {
        mid
    };
    let left = build_node(boxes, centroids, order, start, mid, depth + 1, nodes);
    let right = build_node(boxes, centroids, order, mid, end, depth + 1, nodes);
    let node = &mut nodes[index as usize];
    node.count = 0;
    node.first = left;
    node.right = right;
    index
}

/// Stable partition (keeps index order within each side, for determinism).
fn partition(order: &mut [u32], start: usize, end: usize, left: impl Fn(u32) -> bool) -> usize {
    let (l, r): (Vec<u32>, Vec<u32>) = order[start..end].iter().partition(|&&i| left(i));
    let mid = start + l.len();
    order[start..mid].copy_from_slice(&l);
    order[mid..end].copy_from_slice(&r);
    mid
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{M3, v3};
    use crate::primitive::{NO_OWNER, Primitive, Shape, Surface};
    use crate::rng::Sampler;

    fn random_prims(n: usize) -> Vec<Primitive> {
        let mut s = Sampler::new(5);
        (0..n)
            .map(|_| {
                Primitive::new(
                    v3(
                        s.range(-50.0, 50.0),
                        s.range(-50.0, 50.0),
                        s.range(-3.0, 5.0),
                    ),
                    M3::rot_z(s.range(0.0, 6.0)),
                    v3(s.range(0.1, 3.0), s.range(0.1, 3.0), s.range(0.1, 3.0)),
                    [Shape::Box, Shape::Ellipsoid, Shape::Cylinder][s.int(0, 2) as usize],
                    0,
                    Surface::Object,
                    NO_OWNER,
                )
            })
            .collect()
    }

    #[test]
    fn bvh_matches_brute_force() {
        let prims = random_prims(300);
        let items: Vec<(u32, Aabb)> = prims
            .iter()
            .enumerate()
            .map(|(i, p)| (i as u32, p.aabb()))
            .collect();
        let bvh = Bvh::build(&items);
        let mut s = Sampler::new(9);
        for _ in 0..2000 {
            let o = v3(
                s.range(-10.0, 10.0),
                s.range(-10.0, 10.0),
                s.range(0.0, 2.0),
            );
            let d = v3(s.normal(), s.normal(), 0.3 * s.normal()).normalized();
            let brute = prims
                .iter()
                .enumerate()
                .filter_map(|(i, p)| p.intersect(o, d, 1e-9, 200.0).map(|e| (i as u32, e.t)))
                .min_by(|a, b| a.1.total_cmp(&b.1));
            let fast = bvh.closest(o, d, 1e-9, 200.0, |i, tmax| {
                prims[i as usize]
                    .intersect(o, d, 1e-9, tmax)
                    .map(|e| (e.t, e.t))
            });
            match (brute, fast) {
                (None, None) => {}
                (Some((_, tb)), Some((_, tf))) => assert!((tb - tf).abs() < 1e-9),
                other => panic!("mismatch {other:?}"),
            }
        }
    }

    #[test]
    fn empty_and_single() {
        let bvh = Bvh::build(&[]);
        assert!(
            bvh.closest(V3::ZERO, V3::X, 0.0, 10.0, |_, _| Some((1.0, ())))
                .is_none()
        );
        let prims = random_prims(1);
        let bvh = Bvh::build(&[(0, prims[0].aabb())]);
        assert_eq!(bvh.node_count(), 1);
    }
}
