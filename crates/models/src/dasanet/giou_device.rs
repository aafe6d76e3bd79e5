//! The choice of the GIoU loss's polygons ([`super::giou`]) as a CubeCL kernel, for burn's
//! GPU backends (cargo features `wgpu` and `cuda`): one thread a box pair picks, from the
//! pair's 24 candidate points, the corners of the footprints' intersection and of their
//! convex hull, in the host's order (angle about the points' mean) and with the host's
//! tests, and writes them as rows of the candidate points for the areas' gathers.
//!
//! Why: on the host the choice needs the candidate points read back, a wait in the middle
//! of every DASANet training step for the whole forward pass queued before it (the only
//! read-back of stage two's loss). Here the index never leaves the device.
//!
//! Precision: the host decides in f64 from the f32 points, the kernel in f32. The two can
//! decide otherwise only where a point lies on the other box's boundary (within rounding),
//! where taking it or not changes no area; points within 10 µm of each other count as one
//! (the host's 1e-9 m is below f32's resolution at these coordinates, and two copies of one
//! corner, made by different edge crossings, differ by rounding). The angle is a pseudo-angle
//! (`dy / (|dx| + |dy|)` unfolded over (−π, π]), which orders points as the host's `atan2`
//! does without a transcendental.

use burn::backend::tensor::{FloatTensor, IntTensor};
use burn::backend::{Backend, Dispatch, backend_extension};
use burn::prelude::*;
use burn_cubecl::CubeBackend;
use burn_cubecl::tensor::CubeTensor;
use fusiondet_nn::cube::{float_rows, i32_buffer, launch_shape};
use kernels::polygon_vertices;

/// The kernel (see the module's documentation).
#[backend_extension(Cube)]
pub trait GiouVertexOps: Backend {
    /// From candidate points [F, 24, 2] (a pair's 4 + 4 footprint corners, counter-clockwise,
    /// then its 16 edge crossings): the intersection's and the hull's vertices, each [F · 8]
    /// (i32) rows of the points laid out [F · 24, 2], pair f's eight at 8f.. (see
    /// [`super::giou`] for the padding).
    fn giou_vertices(points: FloatTensor<Self>) -> (IntTensor<Self>, IntTensor<Self>);
}

/// [`GiouVertexOps::giou_vertices`] on a burn tensor of a CubeCL device (without autodiff).
pub fn giou_vertices(points: Tensor<3>) -> (Tensor<1, Int>, Tensor<1, Int>) {
    let (inter, hull) = <Dispatch as GiouVertexOps>::giou_vertices(points.into_dispatch());
    (Tensor::from_dispatch(inter), Tensor::from_dispatch(hull))
}

/// The kernel, in CubeCL's language (its prelude names `Tensor` apart from burn's).
mod kernels {
    use cubecl::prelude::*;

    /// Candidate points a pair.
    const CANDIDATES: usize = 24;
    /// Vertices a polygon, padded.
    const VERTICES: usize = 8;

    /// The cross product of (b − a) and (c − a).
    #[cube]
    fn turn(xs: &Array<f32>, ys: &Array<f32>, a: usize, b: usize, c: usize) -> f32 {
        (xs[b] - xs[a]) * (ys[c] - ys[a]) - (ys[b] - ys[a]) * (xs[c] - xs[a])
    }

    /// Whether point k lies in the counter-clockwise quadrilateral of points
    /// first..first + 4 (boundary included), as the host's `inside`.
    #[cube]
    fn inside(xs: &Array<f32>, ys: &Array<f32>, k: usize, first: usize) -> bool {
        let mut all = true;
        for i in 0..4usize {
            if turn(xs, ys, first + i, first + (i + 1) % 4, k) < -1e-9f32 {
                all = false;
            }
        }
        all
    }

    /// Whether edge a0→a1 crosses edge b0→b1, as the host's `crossing`.
    #[cube]
    fn crosses(
        xs: &Array<f32>,
        ys: &Array<f32>,
        a0: usize,
        a1: usize,
        b0: usize,
        b1: usize,
    ) -> bool {
        let (dax, day) = (xs[a1] - xs[a0], ys[a1] - ys[a0]);
        let (dbx, dby) = (xs[b1] - xs[b0], ys[b1] - ys[b0]);
        let denom = dax * dby - day * dbx;
        let scale = (dax * dax + day * day).sqrt() * (dbx * dbx + dby * dby).sqrt();
        let mut result = false;
        // The host's floor on the scale (`f64::MIN_POSITIVE`) only keeps a zero-length edge
        // from crossing; any positive floor does that.
        let mut floor = scale;
        if floor < 1e-30f32 {
            floor = 1e-30f32;
        }
        if denom.abs() > 1e-9f32 * floor {
            let (wx, wy) = (xs[b0] - xs[a0], ys[b0] - ys[a0]);
            let t = (wx * dby - wy * dbx) / denom;
            let u = (wx * day - wy * dax) / denom;
            let low = -1e-9f32;
            let high = 1.0f32 + 1e-9f32;
            result = t >= low && t <= high && u >= low && u <= high;
        }
        result
    }

    /// Increasing with the angle of (dx, dy) over (−π, π], as `atan2(dy, dx)` is.
    #[cube]
    fn pseudo_angle(dx: f32, dy: f32) -> f32 {
        let size = dx.abs() + dy.abs();
        let mut angle = 0.0f32;
        if size > 0.0f32 {
            let r = dy / size;
            if dx >= 0.0f32 {
                angle = r;
            } else if dy >= 0.0f32 {
                angle = 2.0f32 - r;
            } else {
                angle = -2.0f32 - r;
            }
        }
        angle
    }

    /// The host's `counter_clockwise`: the `n` chosen points sorted by angle about their mean
    /// (stable), repeats of one position dropped, written as eight rows from `out_at` (the
    /// last repeated; all `first_row`, no area, for fewer than 3 distinct points).
    #[cube]
    #[allow(clippy::too_many_arguments)]
    fn write_polygon(
        xs: &Array<f32>,
        ys: &Array<f32>,
        chosen: &mut Array<u32>,
        n: usize,
        out: &mut Tensor<i32>,
        out_at: usize,
        first_row: i32,
    ) {
        let mut mean_x = 0.0f32;
        let mut mean_y = 0.0f32;
        let count = f32::cast_from(n as u32);
        for i in 0..n {
            let k = chosen[i] as usize;
            mean_x += xs[k] / count;
            mean_y += ys[k] / count;
        }
        let mut keys = Array::<f32>::new(comptime!(CANDIDATES));
        for i in 0..n {
            let k = chosen[i] as usize;
            keys[i] = pseudo_angle(xs[k] - mean_x, ys[k] - mean_y);
        }
        // Insertion sort: stable, as the host's `sort_by`, and at most 24 points.
        for i in 1..n {
            let key = keys[i];
            let item = chosen[i];
            let mut j = i;
            let mut moving = true;
            while moving {
                if j == 0 {
                    moving = false;
                } else if keys[j - 1] > key {
                    keys[j] = keys[j - 1];
                    chosen[j] = chosen[j - 1];
                    j -= 1;
                } else {
                    moving = false;
                }
            }
            keys[j] = key;
            chosen[j] = item;
        }
        // Repeats of the last kept position dropped, as `dedup_by`.
        let mut kept = 0usize;
        for i in 0..n {
            let k = chosen[i] as usize;
            let mut keep = true;
            if kept > 0 {
                let last = chosen[kept - 1] as usize;
                if (xs[k] - xs[last]).abs() < 1e-5f32 && (ys[k] - ys[last]).abs() < 1e-5f32 {
                    keep = false;
                }
            }
            if keep {
                chosen[kept] = chosen[i];
                kept += 1;
            }
        }
        if kept < 3 {
            for s in 0..VERTICES {
                out[out_at + s] = first_row;
            }
        } else {
            let mut used = kept;
            if used > VERTICES {
                used = VERTICES;
            }
            for s in 0..VERTICES {
                let mut slot = s;
                if slot >= used {
                    slot = used - 1;
                }
                out[out_at + s] = first_row + i32::cast_from(chosen[slot]);
            }
        }
    }

    /// One box pair a thread: its intersection's and its hull's vertices (the host's
    /// `intersection_vertices` and `hull_vertices`).
    #[cube(launch_unchecked)]
    pub fn polygon_vertices(points: &Tensor<f32>, inter: &mut Tensor<i32>, hull: &mut Tensor<i32>) {
        let f = ABSOLUTE_POS;
        if f >= points.shape(0) {
            terminate!();
        }
        let at = f * points.stride(0);
        let mut xs = Array::<f32>::new(comptime!(CANDIDATES));
        let mut ys = Array::<f32>::new(comptime!(CANDIDATES));
        for k in 0..CANDIDATES {
            xs[k] = points[at + k * points.stride(1)];
            ys[k] = points[at + k * points.stride(1) + points.stride(2)];
        }
        let first_row = i32::cast_from(f * CANDIDATES);
        let out_at = f * VERTICES;

        // The intersection: corners inside the other box, then the edge crossings.
        let mut chosen = Array::<u32>::new(comptime!(CANDIDATES));
        let mut n = 0usize;
        for i in 0..4usize {
            if inside(&xs, &ys, i, 4) {
                chosen[n] = i as u32;
                n += 1;
            }
        }
        for j in 0..4usize {
            if inside(&xs, &ys, 4 + j, 0) {
                chosen[n] = (4 + j) as u32;
                n += 1;
            }
        }
        for i in 0..4usize {
            for j in 0..4usize {
                if crosses(&xs, &ys, i, (i + 1) % 4, 4 + j, 4 + (j + 1) % 4) {
                    chosen[n] = (8 + 4 * i + j) as u32;
                    n += 1;
                }
            }
        }
        write_polygon(&xs, &ys, &mut chosen, n, inter, out_at, first_row);

        // The hull of the eight corners: Andrew's monotone chain over them sorted by (x, y).
        let mut order = Array::<u32>::new(8usize);
        for k in 0..8usize {
            let mut j = k;
            let mut moving = true;
            while moving {
                if j == 0 {
                    moving = false;
                } else {
                    let prev = order[j - 1] as usize;
                    if xs[prev] > xs[k] || (xs[prev] == xs[k] && ys[prev] > ys[k]) {
                        order[j] = order[j - 1];
                        j -= 1;
                    } else {
                        moving = false;
                    }
                }
            }
            order[j] = k as u32;
        }
        let mut chain = Array::<u32>::new(comptime!(CANDIDATES));
        let mut h = 0usize;
        for pass in 0..2usize {
            let start = h;
            for step in 0..8usize {
                let mut k = order[step] as usize;
                if pass == 1 {
                    k = order[7 - step] as usize;
                }
                let mut popping = true;
                while popping {
                    if h < start + 2 {
                        popping = false;
                    } else if turn(&xs, &ys, chain[h - 2] as usize, chain[h - 1] as usize, k)
                        <= 1e-12f32
                    {
                        h -= 1;
                    } else {
                        popping = false;
                    }
                }
                chain[h] = k as u32;
                h += 1;
            }
            h -= 1;
        }
        write_polygon(&xs, &ys, &mut chain, h, hull, out_at, first_row);
    }
}

impl GiouVertexOps for CubeBackend {
    fn giou_vertices(points: CubeTensor) -> (CubeTensor, CubeTensor) {
        let points = float_rows(points);
        let pairs = points.meta.shape()[0];
        let client = points.client.clone();
        let (inter, hull) = (
            i32_buffer(&points, pairs * 8),
            i32_buffer(&points, pairs * 8),
        );
        if pairs > 0 {
            let (count, dim) = launch_shape(&client, pairs);
            // SAFETY: threads past the last pair return first; a pair reads its own 24
            // points through the tensor's strides and writes its own 8 entries of each
            // one-dimensional output; the local arrays hold 24 entries, and a pair chooses at
            // most 24 candidates (8 corners + 16 crossings) and its hull chain at most 16.
            unsafe {
                polygon_vertices::launch_unchecked(
                    &client,
                    count,
                    dim,
                    points.into_tensor_arg(),
                    inter.clone().into_tensor_arg(),
                    hull.clone().into_tensor_arg(),
                );
            }
        }
        (inter, hull)
    }
}

#[cfg(all(test, feature = "wgpu"))]
mod tests {
    use super::super::giou::tests::corners;
    use super::super::giou::{
        CANDIDATES, P2, candidate_points, footprint, giou_3d_loss, hull_vertices,
        intersection_vertices, iou_giou_3d,
    };
    use super::*;
    use crate::voxel_rcnn::loss::box_corners;
    use crate::voxel_rcnn::synthetic::unit;

    fn wgpu_device() -> Option<Device> {
        fusiondet_nn::cube::working_wgpu_device("the GIoU loss's polygons on the device")
    }

    /// Box pairs (x, y, z, dx, dy, dz, heading): ground truths at random, predictions
    /// around them (overlapping, turned, shifted apart), and the degenerate kinds: the
    /// same box, a nested one, one turned by a right angle, one far away.
    fn pairs(count: usize) -> (Vec<[f32; 7]>, Vec<[f32; 7]>) {
        let mut state = 29u64;
        let mut preds = Vec::new();
        let mut gts = Vec::new();
        for k in 0..count {
            let s = &mut state;
            let gt = [
                (unit(s) * 60.0) as f32,
                (unit(s) * 60.0 - 30.0) as f32,
                (unit(s) * 2.0 - 1.0) as f32,
                (3.0 + unit(s) * 2.0) as f32,
                (1.4 + unit(s) * 0.6) as f32,
                (1.3 + unit(s) * 0.5) as f32,
                (unit(s) * 6.0 - 3.0) as f32,
            ];
            let mut pred = gt;
            match k % 8 {
                0 => {}
                1 => pred[3..6].iter_mut().for_each(|v| *v *= 0.5),
                2 => pred[6] += std::f32::consts::FRAC_PI_2,
                3 => pred[0] += 30.0,
                _ => {
                    for v in &mut pred[0..3] {
                        *v += (unit(s) * 3.0 - 1.5) as f32;
                    }
                    for v in &mut pred[3..6] {
                        *v *= (0.7 + unit(s) * 0.6) as f32;
                    }
                    pred[6] += (unit(s) * 2.0 - 1.0) as f32;
                }
            }
            preds.push(pred);
            gts.push(gt);
        }
        (preds, gts)
    }

    fn values(t: Tensor<1>) -> Vec<f32> {
        t.into_data()
            .convert::<f32>()
            .try_into_vec::<f32>()
            .unwrap()
    }

    /// A polygon's area from its padded vertex list (shoelace, f64).
    fn area(points: &[P2], vertices: &[usize]) -> f64 {
        let n = vertices.len();
        (0..n)
            .map(|k| {
                let (a, b) = (points[vertices[k]], points[vertices[(k + 1) % n]]);
                a[0] * b[1] - a[1] * b[0]
            })
            .sum::<f64>()
            .abs()
            / 2.0
    }

    /// The kernel's intersection and hull of each pair bound the same areas as the host's
    /// choice of the same candidate points, and each pair's vertices are its own points.
    #[test]
    fn the_kernel_chooses_the_hosts_polygons() {
        let Some(gpu) = wgpu_device() else { return };
        let (preds, gts) = pairs(400);
        let cpu = Device::flex();
        let points = candidate_points(
            footprint(&corners(&preds, &cpu)),
            footprint(&corners(&gts, &cpu)),
        );
        let flat: Vec<f64> = points
            .clone()
            .into_data()
            .convert::<f64>()
            .try_into_vec::<f64>()
            .unwrap();
        let on_gpu = Tensor::<3>::from_data(points.into_data(), &gpu);
        let (inter, hull) = giou_vertices(on_gpu);
        let rows = |t: Tensor<1, Int>| -> Vec<i64> {
            t.into_data()
                .convert::<i64>()
                .try_into_vec::<i64>()
                .unwrap()
        };
        let (inter, hull) = (rows(inter), rows(hull));
        assert_eq!(inter.len(), preds.len() * 8);
        for f in 0..preds.len() {
            let pt: Vec<P2> = (0..CANDIDATES)
                .map(|k| {
                    [
                        flat[(f * CANDIDATES + k) * 2],
                        flat[(f * CANDIDATES + k) * 2 + 1],
                    ]
                })
                .collect();
            let own = |list: &[i64]| -> Vec<usize> {
                list[f * 8..f * 8 + 8]
                    .iter()
                    .map(|&r| {
                        let r = r as usize;
                        assert_eq!(r / CANDIDATES, f, "pair {f} reads another pair's point");
                        r % CANDIDATES
                    })
                    .collect()
            };
            let arr: [P2; CANDIDATES] = std::array::from_fn(|k| pt[k]);
            let quad = |base: usize| -> [P2; 4] { std::array::from_fn(|k| arr[base + k]) };
            let host_inter = intersection_vertices(&quad(0), &quad(4), &arr);
            let host_hull = hull_vertices(&arr);
            for (what, device, host) in [
                ("intersection", own(&inter), host_inter),
                ("hull", own(&hull), host_hull),
            ] {
                let (a, b) = (area(&pt, &device), area(&pt, &host));
                assert!(
                    (a - b).abs() <= 1e-4 * b.max(1.0),
                    "pair {f} {what}: kernel {device:?} area {a}, host {host:?} area {b}"
                );
            }
        }
    }

    /// IoU, GIoU and the loss's gradients on wgpu (polygons chosen by the kernel, gathered
    /// by `RowGather`) agree with the CPU's (chosen on the host, burn's `select`).
    #[test]
    fn iou_giou_and_gradients_match_the_cpu() {
        let Some(gpu) = wgpu_device() else { return };
        let (preds, gts) = pairs(160);
        let run = |device: &Device| {
            let n = preds.len();
            let col = |boxes: &[[f32; 7]], a: usize, b: usize| {
                let v: Vec<f32> = boxes.iter().flat_map(|x| x[a..b].to_vec()).collect();
                Tensor::<2>::from_data(TensorData::new(v, [n, b - a]), device)
            };
            let centres = col(&preds, 0, 3).require_grad();
            let sizes = col(&preds, 3, 6).require_grad();
            let headings = col(&preds, 6, 7).require_grad();
            let pred = box_corners(centres.clone(), sizes.clone(), headings.clone());
            let gt = corners(&gts, device);
            let (iou, giou) = iou_giou_3d(pred.clone(), gt.clone());
            let grads = giou_3d_loss(pred, gt).backward();
            let grad = |t: &Tensor<2>| -> Vec<f32> {
                t.grad(&grads)
                    .unwrap()
                    .into_data()
                    .convert::<f32>()
                    .try_into_vec::<f32>()
                    .unwrap()
            };
            (
                values(iou.inner()),
                values(giou.inner()),
                [grad(&centres), grad(&sizes), grad(&headings)],
            )
        };
        let (iou_c, giou_c, grads_c) = run(&Device::flex().autodiff());
        let (iou_g, giou_g, grads_g) = run(&gpu.autodiff());
        for k in 0..preds.len() {
            assert!(
                (iou_c[k] - iou_g[k]).abs() < 1e-4 && (giou_c[k] - giou_g[k]).abs() < 1e-4,
                "pair {k}: IoU {} / {}, GIoU {} / {}",
                iou_c[k],
                iou_g[k],
                giou_c[k],
                giou_g[k]
            );
        }
        for (what, (c, g)) in ["centres", "sizes", "headings"]
            .iter()
            .zip(grads_c.iter().zip(&grads_g))
        {
            let scale = c.iter().fold(0f32, |m, v| m.max(v.abs()));
            let worst = c
                .iter()
                .zip(g)
                .map(|(a, b)| (a - b).abs())
                .fold(0f32, f32::max);
            assert!(
                worst <= 1e-3 * scale.max(1e-6),
                "{what}: gradients differ by {worst} (largest {scale})"
            );
        }
    }
}
