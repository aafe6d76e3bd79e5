//! The 3D GIoU loss of DASANet's detection head (Section 3.4.2; Rezatofighi et al.,
//! CVPR 2019, extended to boxes that turn about z as Zhou et al., 3DV 2019 do): from the
//! eight vertices of a predicted box and of its ground truth,
//!
//! IoU = V(A ∩ B) / V(A ∪ B),  GIoU = IoU − (V(C) − V(A ∪ B)) / V(C),  loss = 1 − GIoU,
//!
//! where V(A ∩ B) is the bird's-eye intersection polygon's area times the overlap of the
//! height ranges, and C is the convex hull of both footprints times the height range
//! spanning both.
//!
//! Differentiable the way autodiff differentiates any polygon clipping: which points
//! bound the intersection and the hull (corners inside the other box, edge crossings,
//! hull corners) and in which order is decided from the current values, on the host or,
//! where the network runs on a CubeCL device, by a kernel there ([`super::giou_device`]:
//! no read-back in the step); the points themselves are tensor functions of the corners,
//! so gradients flow to every vertex that shapes the areas, through gathers whose backward
//! pass on a GPU adds each point's readers (`RowGather`) rather than walking every vertex
//! on one thread a column (burn's `select`). Written here because burn has no rotated-box
//! IoU.

use burn::prelude::*;
use fusiondet_nn::gather::RowGather;

/// Bird's-eye footprint corners, counter-clockwise, of boxes from [`box_corners`]
/// (corner k has x sign +/− for bit 0, y for bit 1, z for bit 2): indices 0, 1, 3, 2.
///
/// [`box_corners`]: crate::voxel_rcnn::loss::box_corners
const FOOTPRINT: [usize; 4] = [0, 1, 3, 2];
/// Candidate points per pair: 4 + 4 corners, then the 16 edge crossings (P edge i, G
/// edge j at 8 + 4i + j).
pub(super) const CANDIDATES: usize = 24;
/// The intersection of two convex quadrilaterals, and their hull, have at most 8 corners.
const MAX_VERTICES: usize = 8;
/// Edges closer to parallel than this (cross product of unit directions) do not cross.
const PARALLEL: f64 = 1e-9;

pub(super) type P2 = [f64; 2];

fn cross(a: P2, b: P2) -> f64 {
    a[0] * b[1] - a[1] * b[0]
}

fn sub(a: P2, b: P2) -> P2 {
    [a[0] - b[0], a[1] - b[1]]
}

/// Whether `p` lies in the counter-clockwise convex polygon `quad` (boundary included).
fn inside(p: P2, quad: &[P2; 4]) -> bool {
    (0..4).all(|i| cross(sub(quad[(i + 1) % 4], quad[i]), sub(p, quad[i])) >= -1e-9)
}

/// Where edge a0→a1 crosses edge b0→b1, as the parameter along a, if they cross.
fn crossing(a0: P2, a1: P2, b0: P2, b1: P2) -> Option<f64> {
    let (da, db) = (sub(a1, a0), sub(b1, b0));
    let denom = cross(da, db);
    let scale = (da[0].hypot(da[1]) * db[0].hypot(db[1])).max(f64::MIN_POSITIVE);
    if denom.abs() <= PARALLEL * scale {
        return None;
    }
    let w = sub(b0, a0);
    let t = cross(w, db) / denom;
    let u = cross(w, da) / denom;
    ((-1e-9..=1.0 + 1e-9).contains(&t) && (-1e-9..=1.0 + 1e-9).contains(&u)).then_some(t)
}

/// Indices into the candidates that bound the intersection, counter-clockwise, padded
/// by repeating the last (a repeated point adds no area); all zero when the footprints
/// do not overlap in an area.
pub(super) fn intersection_vertices(
    p: &[P2; 4],
    g: &[P2; 4],
    points: &[P2; CANDIDATES],
) -> Vec<usize> {
    let mut chosen: Vec<usize> = Vec::with_capacity(MAX_VERTICES * 2);
    chosen.extend((0..4).filter(|&i| inside(p[i], g)));
    chosen.extend((0..4).filter(|&j| inside(g[j], p)).map(|j| 4 + j));
    for i in 0..4 {
        for j in 0..4 {
            if crossing(p[i], p[(i + 1) % 4], g[j], g[(j + 1) % 4]).is_some() {
                chosen.push(8 + 4 * i + j);
            }
        }
    }
    counter_clockwise(chosen, points)
}

/// Sorts points by angle about their mean and drops repeats of one position, then pads
/// to [`MAX_VERTICES`]. Fewer than 3 distinct points: no area (all index 0).
fn counter_clockwise(mut chosen: Vec<usize>, points: &[P2; CANDIDATES]) -> Vec<usize> {
    let n = chosen.len().max(1) as f64;
    let mean = chosen.iter().fold([0.0, 0.0], |m, &k| {
        [m[0] + points[k][0] / n, m[1] + points[k][1] / n]
    });
    let angle = |k: usize| (points[k][1] - mean[1]).atan2(points[k][0] - mean[0]);
    chosen.sort_by(|&a, &b| angle(a).total_cmp(&angle(b)));
    chosen.dedup_by(|a, b| {
        let d = sub(points[*a], points[*b]);
        d[0].abs() < 1e-9 && d[1].abs() < 1e-9
    });
    if chosen.len() < 3 {
        return vec![0; MAX_VERTICES];
    }
    // Two footprints cross in at most 8 points; more means repeats within the tolerance.
    chosen.truncate(MAX_VERTICES);
    let last = *chosen.last().expect("at least 3");
    chosen.resize(MAX_VERTICES, last);
    chosen
}

/// The convex hull of the 8 footprint corners (candidates 0–7), counter-clockwise,
/// padded (Andrew's monotone chain).
pub(super) fn hull_vertices(points: &[P2; CANDIDATES]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..8).collect();
    order.sort_by(|&a, &b| {
        points[a][0]
            .total_cmp(&points[b][0])
            .then(points[a][1].total_cmp(&points[b][1]))
    });
    let turn =
        |o: usize, a: usize, b: usize| cross(sub(points[a], points[o]), sub(points[b], points[o]));
    let mut hull: Vec<usize> = Vec::with_capacity(16);
    for pass in [order.clone(), order.into_iter().rev().collect()] {
        let start = hull.len();
        for k in pass {
            while hull.len() >= start + 2
                && turn(hull[hull.len() - 2], hull[hull.len() - 1], k) <= 1e-12
            {
                hull.pop();
            }
            hull.push(k);
        }
        hull.pop();
    }
    counter_clockwise(hull, points)
}

/// Footprint corners [F, 4, 2] of corner sets [F, 8, 3].
pub(super) fn footprint(corners: &Tensor<3>) -> Tensor<3> {
    let device = corners.device();
    let index = Tensor::<1, Int>::from_data(
        TensorData::new(FOOTPRINT.map(|k| k as i64).to_vec(), [4]),
        &device,
    );
    corners.clone().select(1, index).slice_dim(2, 0..2)
}

/// All 24 candidate points [F, 24, 2]: the 8 corners, then every edge crossing (the
/// crossing of the lines through the edges; only real crossings are ever gathered).
pub(super) fn candidate_points(p: Tensor<3>, g: Tensor<3>) -> Tensor<3> {
    let [f, _, _] = p.dims();
    let device = p.device();
    let next = Tensor::<1, Int>::from_data(TensorData::new(vec![1i64, 2, 3, 0], [4]), &device);
    let dp = p.clone().select(1, next.clone()) - p.clone(); // [F, 4, 2]
    let dg = g.clone().select(1, next) - g.clone();
    // Pair (i, j) → [F, 4, 4, 2].
    let p0 = p.clone().reshape([f, 4, 1, 2]).expand([f, 4, 4, 2]);
    let dpe = dp.reshape([f, 4, 1, 2]).expand([f, 4, 4, 2]);
    let g0 = g.clone().reshape([f, 1, 4, 2]).expand([f, 4, 4, 2]);
    let dge = dg.reshape([f, 1, 4, 2]).expand([f, 4, 4, 2]);
    let x = |t: &Tensor<4>| t.clone().slice_dim(3, 0..1);
    let y = |t: &Tensor<4>| t.clone().slice_dim(3, 1..2);
    let cross4 = |a: &Tensor<4>, b: &Tensor<4>| x(a) * y(b) - y(a) * x(b);
    let denom = cross4(&dpe, &dge);
    // Parallel pairs are never gathered; a safe denominator keeps their (unused)
    // values and gradients finite.
    let safe = denom.clone().abs().lower_elem(1e-12);
    let denom = denom.mask_fill(safe, 1.0);
    let w = g0 - p0.clone();
    let t = cross4(&w, &dge) / denom;
    let crossings = (p0 + dpe * t).reshape([f, 16, 2]);
    Tensor::cat(vec![p, g, crossings], 1)
}

/// Each pair's polygon as two gathers of rows of its points laid out [F · n, 2]: its
/// eight (padded) vertices, and each one's successor, the last's being the first.
struct Polygons {
    vertices: RowGather,
    successors: RowGather,
}

impl Polygons {
    /// From vertices chosen on the host (F × 8 indices into each pair's `n` points).
    fn from_host(vertices: &[Vec<usize>], n: usize, device: &Device) -> Self {
        let rows = vertices.len() * n;
        let gather = |shift: usize| {
            let index: Vec<u32> = vertices
                .iter()
                .enumerate()
                .flat_map(|(row, v)| {
                    (0..MAX_VERTICES).map(move |k| (row * n + v[(k + shift) % MAX_VERTICES]) as u32)
                })
                .collect();
            RowGather::new(&index, rows, device)
        };
        Polygons {
            vertices: gather(0),
            successors: gather(1),
        }
    }

    /// From vertices chosen on a CubeCL device ([`super::giou_device`]): `vertices` [F · 8]
    /// rows of the [F · 24] candidate points, for values on `values_device`.
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    fn from_device(vertices: Tensor<1, Int>, values_device: &Device) -> Self {
        let [len] = vertices.dims();
        let f = len / MAX_VERTICES;
        let table = vertices.clone().reshape([f, MAX_VERTICES]);
        let successors = Tensor::cat(
            vec![
                table.clone().slice_dim(1, 1..MAX_VERTICES),
                table.slice_dim(1, 0..1),
            ],
            1,
        )
        .reshape([len]);
        let rows = f * CANDIDATES;
        Polygons {
            vertices: RowGather::from_device_index(vertices, rows, values_device),
            successors: RowGather::from_device_index(successors, rows, values_device),
        }
    }
}

/// The intersections' and the hulls' polygons of the pairs' candidate points [F, 24, 2]:
/// chosen on the device that holds them where that is a CubeCL device, else on the host
/// from the points read back (see the module's documentation).
fn intersections_and_hulls(points: &Tensor<3>) -> (Polygons, Polygons) {
    let device = points.device();
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    if fusiondet_nn::cube::cube_runtime(&device).is_some() {
        let (inter, hull) = super::giou_device::giou_vertices(points.clone().inner());
        return (
            Polygons::from_device(inter, &device),
            Polygons::from_device(hull, &device),
        );
    }
    let [f, _, _] = points.dims();
    let values: Vec<f64> = points
        .clone()
        .into_data()
        .convert::<f64>()
        .try_into_vec::<f64>()
        .expect("candidate points read back");
    let (inter_v, hull_v): (Vec<Vec<usize>>, Vec<Vec<usize>>) = (0..f)
        .map(|row| {
            let pt: [P2; CANDIDATES] = std::array::from_fn(|k| {
                [
                    values[(row * CANDIDATES + k) * 2],
                    values[(row * CANDIDATES + k) * 2 + 1],
                ]
            });
            let quad = |base: usize| -> [P2; 4] { std::array::from_fn(|k| pt[base + k]) };
            (
                intersection_vertices(&quad(0), &quad(4), &pt),
                hull_vertices(&pt),
            )
        })
        .unzip();
    (
        Polygons::from_host(&inter_v, CANDIDATES, &device),
        Polygons::from_host(&hull_v, CANDIDATES, &device),
    )
}

/// Shoelace areas [F] of `polygons` over the pairs' `points` [F, n, 2].
fn polygon_areas(points: &Tensor<3>, polygons: &Polygons) -> Tensor<1> {
    let [f, n, _] = points.dims();
    let flat = points.clone().reshape([f * n, 2]);
    let a = polygons
        .vertices
        .gather(flat.clone())
        .reshape([f, MAX_VERTICES, 2]);
    let b = polygons
        .successors
        .gather(flat)
        .reshape([f, MAX_VERTICES, 2]);
    let terms = a.clone().slice_dim(2, 0..1) * b.clone().slice_dim(2, 1..2)
        - a.slice_dim(2, 1..2) * b.slice_dim(2, 0..1);
    terms.sum_dim(1).reshape([f]).mul_scalar(0.5).abs()
}

/// Per pair: IoU and GIoU [F] of the boxes with corners `pred` and `gt`, both [F, 8, 3]
/// (upright boxes: corners 0–3 on top, 4–7 at the bottom, as [`box_corners`] orders them).
///
/// [`box_corners`]: crate::voxel_rcnn::loss::box_corners
pub fn iou_giou_3d(pred: Tensor<3>, gt: Tensor<3>) -> (Tensor<1>, Tensor<1>) {
    let [f, _, _] = pred.dims();
    let (p, g) = (footprint(&pred), footprint(&gt));
    let points = candidate_points(p.clone(), g.clone());
    let (inter, hull) = intersections_and_hulls(&points);
    let inter_area = polygon_areas(&points, &inter);
    let hull_area = polygon_areas(&points, &hull);
    // Each footprint is its own polygon: corners 0–3, the last repeated (one gather for both).
    let footprints = Polygons::from_host(&vec![(0..4).chain([3; 4]).collect(); f], 4, &p.device());
    let (area_p, area_g) = (
        polygon_areas(&p, &footprints),
        polygon_areas(&g, &footprints),
    );
    let z = |c: &Tensor<3>, k: usize| {
        c.clone()
            .slice_dim(1, k..k + 1)
            .slice_dim(2, 2..3)
            .reshape([f])
    };
    let (top_p, bottom_p, top_g, bottom_g) = (z(&pred, 0), z(&pred, 4), z(&gt, 0), z(&gt, 4));
    let overlap = (top_p.clone().min_pair(top_g.clone())
        - bottom_p.clone().max_pair(bottom_g.clone()))
    .clamp_min(0.0);
    let span = top_p.clone().max_pair(top_g.clone()) - bottom_p.clone().min_pair(bottom_g.clone());
    let inter = inter_area * overlap;
    let union = area_p * (top_p - bottom_p) + area_g * (top_g - bottom_g) - inter.clone();
    let hull = hull_area * span;
    let union = union.clamp_min(1e-9);
    let iou = inter / union.clone();
    let giou = iou.clone() - (hull.clone() - union) / hull.clamp_min(1e-9);
    (iou, giou)
}

/// Mean 1 − GIoU over the pairs (a scalar [1]).
pub fn giou_3d_loss(pred: Tensor<3>, gt: Tensor<3>) -> Tensor<1> {
    let (_, giou) = iou_giou_3d(pred, gt);
    giou.neg().add_scalar(1.0).mean()
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::voxel_rcnn::loss::box_corners;
    use std::f64::consts::{FRAC_PI_4, SQRT_2};

    /// Corners [N, 8, 3] of boxes (x, y, z, dx, dy, dz, heading) on `d`.
    pub(in crate::dasanet) fn corners(boxes: &[[f32; 7]], d: &Device) -> Tensor<3> {
        let n = boxes.len();
        let col = |a: usize, b: usize| {
            let v: Vec<f32> = boxes.iter().flat_map(|x| x[a..b].to_vec()).collect();
            Tensor::<2>::from_data(TensorData::new(v, [n, b - a]), d)
        };
        box_corners(col(0, 3), col(3, 6), col(6, 7))
    }

    fn vec1(t: Tensor<1>) -> Vec<f64> {
        t.into_data()
            .convert::<f64>()
            .try_into_vec::<f64>()
            .unwrap()
    }

    /// Identical, disjoint, nested and turned boxes against their hand-computed values.
    #[test]
    fn hand_made_pairs() {
        let d = Device::flex();
        let q = FRAC_PI_4 as f32;
        let pred = corners(
            &[
                [1.0, 2.0, 0.5, 3.9, 1.6, 1.5, 0.3], // identical to its gt
                [0.0, 0.0, 0.0, 2.0, 2.0, 1.0, 0.0], // disjoint: 4 m away in x
                [0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0], // nested in a 2 × 2 × 2 box
                [0.0, 0.0, 0.0, 2.0, 2.0, 1.0, q],   // the same square turned 45°
                [0.0, 0.0, 0.0, 2.0, 2.0, 2.0, 0.0], // half the height overlaps
            ],
            &d,
        );
        let gt = corners(
            &[
                [1.0, 2.0, 0.5, 3.9, 1.6, 1.5, 0.3],
                [4.0, 0.0, 0.0, 2.0, 2.0, 1.0, 0.0],
                [0.0, 0.0, 0.0, 2.0, 2.0, 2.0, 0.0],
                [0.0, 0.0, 0.0, 2.0, 2.0, 1.0, 0.0],
                [0.0, 0.0, 1.0, 2.0, 2.0, 2.0, 0.0],
            ],
            &d,
        );
        let (iou, giou) = iou_giou_3d(pred, gt);
        let (iou, giou) = (vec1(iou), vec1(giou));
        let octagon = 8.0 * (std::f64::consts::PI / 8.0).tan(); // inradius 1
        let hull = 2.0 * SQRT_2 * 2.0; // regular octagon of circumradius √2
        let union = 8.0 - octagon;
        let expected = [
            (1.0, 1.0),
            // Disjoint: hull 6 × 2 × 1 = 12, union 8.
            (0.0, -(12.0 - 8.0) / 12.0),
            // Nested: the hull is the outer box, so GIoU = IoU = 1/8.
            (0.125, 0.125),
            (octagon / union, octagon / union - (hull - union) / hull),
            // Height overlap 1 of a 3 m span: inter 4, union 12, hull 12.
            (4.0 / 12.0, 4.0 / 12.0),
        ];
        for (k, (e_iou, e_giou)) in expected.iter().enumerate() {
            assert!(
                (iou[k] - e_iou).abs() < 1e-4,
                "pair {k}: IoU {} vs {e_iou}",
                iou[k]
            );
            assert!(
                (giou[k] - e_giou).abs() < 1e-4,
                "pair {k}: GIoU {} vs {e_giou}",
                giou[k]
            );
        }
    }

    /// The gradient of the loss along the predicted centre's x matches a finite
    /// difference, for a turned, partly overlapping pair.
    #[test]
    fn gradient_matches_finite_differences() {
        let ad = Device::flex().autodiff();
        let gt_box = [0.3f32, -0.2, 0.1, 3.9, 1.6, 1.5, 0.4];
        let loss_at = |x: f32| -> f64 {
            let d = Device::flex();
            let l = giou_3d_loss(
                corners(&[[x, 0.0, 0.0, 4.2, 1.7, 1.4, 0.1]], &d),
                corners(&[gt_box], &d),
            );
            l.into_scalar::<f32>() as f64
        };
        let centre = Tensor::<2>::from_data(TensorData::new(vec![0.5f32, 0.0, 0.0], [1, 3]), &ad)
            .require_grad();
        let sizes = Tensor::<2>::from_data(TensorData::new(vec![4.2f32, 1.7, 1.4], [1, 3]), &ad);
        let heading = Tensor::<2>::from_data(TensorData::new(vec![0.1f32], [1, 1]), &ad);
        let pred = box_corners(centre.clone(), sizes, heading);
        let loss = giou_3d_loss(pred, corners(&[gt_box], &ad));
        let grads = loss.backward();
        let g: Vec<f32> = centre
            .grad(&grads)
            .unwrap()
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        let h = 1e-2f32;
        let numeric = (loss_at(0.5 + h) - loss_at(0.5 - h)) / (2.0 * h as f64);
        assert!(g.iter().all(|v| v.is_finite()));
        assert!(
            (g[0] as f64 - numeric).abs() < 2e-3,
            "autodiff {} vs numeric {numeric}",
            g[0]
        );
        assert!(g[0] > 0.0, "moving away from the ground truth costs");
    }

    /// On a GPU the polygons are chosen there and gathered by their readers (not by burn's
    /// `select`, whose backward pass walks every vertex on one thread a column).
    #[cfg(feature = "wgpu")]
    #[test]
    fn on_wgpu_the_polygons_are_chosen_and_gathered_on_the_device() {
        let Some(gpu) = fusiondet_nn::cube::working_wgpu_device("the GIoU loss's gathers") else {
            return;
        };
        let d = gpu.autodiff();
        let pred = corners(&[[0.0, 0.0, 0.0, 4.0, 2.0, 1.5, 0.3]], &d);
        let gt = corners(&[[0.5, 0.2, 0.0, 4.0, 2.0, 1.5, 0.0]], &d);
        let points = candidate_points(footprint(&pred), footprint(&gt));
        let (inter, hull) = intersections_and_hulls(&points);
        for polygons in [&inter, &hull] {
            assert!(polygons.vertices.sums_readers_on_device());
            assert!(polygons.successors.sums_readers_on_device());
        }
    }

    /// Identical and axis-parallel boxes (parallel edges everywhere) still give finite
    /// gradients.
    #[test]
    fn parallel_edges_keep_gradients_finite() {
        let ad = Device::flex().autodiff();
        let centre = Tensor::<2>::from_data(
            TensorData::new(vec![0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0], [2, 3]),
            &ad,
        )
        .require_grad();
        let sizes = Tensor::<2>::from_data(
            TensorData::new(vec![2.0f32, 2.0, 1.0, 2.0, 2.0, 1.0], [2, 3]),
            &ad,
        );
        let heading = Tensor::<2>::zeros([2, 1], &ad);
        let gt = corners(&[[0.0, 0.0, 0.0, 2.0, 2.0, 1.0, 0.0]; 2], &ad);
        let loss = giou_3d_loss(box_corners(centre.clone(), sizes, heading), gt);
        let g: Vec<f32> = centre
            .grad(&loss.backward())
            .unwrap()
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        assert!(g.iter().all(|v| v.is_finite()), "{g:?}");
        assert!(g[3] > 0.0, "the shifted box is pulled back");
    }
}
