//! Per-sensor acceleration grids. Both sensors cast all their rays from one point,
//! so instead of walking the BVH for every ray we bin the primitives once per frame
//! by the directions in which they can be seen from that point — rings × 1°
//! azimuth for the LiDAR, 8×8-pixel tiles for the camera, and an orthographic grid
//! along the sun direction for shadow rays — and sort each cell's list by the
//! primitives' nearest possible distance. A ray then tests its cell's primitives in
//! order and stops as soon as the next one cannot be nearer than its hit. The bins
//! are conservative (angular bounds of each primitive's box, with a margin), so the
//! result is exactly the nearest hit; the BVH stays for general rays.

use crate::camera::PixelRays;
use crate::math::{V3, atan2, v3};
use crate::primitive::{Aabb, Surface};
use crate::scene::{Hit, Scene};
use fusiondet_geometry::CameraModel;

/// One candidate of a cell: nearest possible hit distance and primitive index.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Candidate {
    pub near: f64,
    pub prim: u32,
}

/// Candidate lists of every cell (compressed rows).
#[derive(Debug, Clone, Default)]
pub struct CellLists {
    offsets: Vec<u32>,
    items: Vec<Candidate>,
}

impl CellLists {
    /// Builds the lists from (cell, candidate) pairs: a counting sort by cell, then
    /// each cell sorted by distance (ties by index, for determinism).
    fn build(cells: usize, entries: &[(u32, Candidate)]) -> CellLists {
        let mut counts = vec![0u32; cells + 1];
        for (c, _) in entries {
            counts[*c as usize + 1] += 1;
        }
        for k in 0..cells {
            counts[k + 1] += counts[k];
        }
        let offsets = counts.clone();
        let mut fill = counts;
        let mut items = vec![Candidate { near: 0.0, prim: 0 }; entries.len()];
        for (c, cand) in entries {
            let slot = &mut fill[*c as usize];
            items[*slot as usize] = *cand;
            *slot += 1;
        }
        for k in 0..cells {
            items[offsets[k] as usize..offsets[k + 1] as usize]
                .sort_by(|a, b| a.near.total_cmp(&b.near).then(a.prim.cmp(&b.prim)));
        }
        CellLists { offsets, items }
    }

    pub fn cell(&self, k: usize) -> &[Candidate] {
        &self.items[self.offsets[k] as usize..self.offsets[k + 1] as usize]
    }

    pub fn len(&self) -> usize {
        self.items.len()
    }

    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }
}

/// Distance from `o` to the box (0 inside).
fn box_distance(b: &Aabb, o: V3) -> f64 {
    let d = (b.min - o).max(o - b.max).max(V3::ZERO);
    d.norm()
}

/// Nearest hit among `cands` (sorted by `near`) and the scene's unbounded primitives.
#[inline]
pub fn cast_candidates(
    scene: &Scene,
    cands: &[Candidate],
    o: V3,
    d: V3,
    tmin: f64,
    tmax: f64,
) -> Option<Hit> {
    let mut best: Option<(u32, crate::primitive::Span)> = None;
    let mut tmax = tmax;
    for &i in scene.unbounded() {
        if let Some(e) = scene.prims[i as usize].hit_interval(o, d, tmin, tmax) {
            tmax = e.t;
            best = Some((i, e));
        }
    }
    for c in cands {
        if c.near > tmax {
            break;
        }
        if let Some(e) = scene.prims[c.prim as usize].hit_interval(o, d, tmin, tmax) {
            tmax = e.t;
            best = Some((c.prim, e));
        }
    }
    best.map(|(prim, e)| scene.hit(prim, o, d, e))
}

/// Margin added to angular bounds (degrees): covers rounding in the bounds.
const MARGIN_DEG: f64 = 0.05;

/// The LiDAR's grid: one row per ring, `cols` azimuth columns over 360°.
#[derive(Debug, Clone)]
pub struct LidarGrid {
    pub cols: usize,
    lists: CellLists,
}

impl LidarGrid {
    /// Bins the scene's bounded primitives for rays from the origin at the given
    /// ring elevations (degrees).
    pub fn new(scene: &Scene, elevations_deg: &[f64], cols: usize) -> LidarGrid {
        let rows = elevations_deg.len();
        let col_deg = 360.0 / cols as f64;
        let mut entries = Vec::new();
        for (i, p) in scene.prims.iter().enumerate() {
            if scene.is_unbounded(i as u32) {
                continue;
            }
            let b = p.aabb();
            let (el_lo, el_hi, az) = angular_bounds(&b, V3::ZERO);
            let near = box_distance(&b, V3::ZERO);
            let cand = Candidate {
                near,
                prim: i as u32,
            };
            let ring_range: Vec<usize> = (0..rows)
                .filter(|&r| {
                    elevations_deg[r] >= el_lo - MARGIN_DEG
                        && elevations_deg[r] <= el_hi + MARGIN_DEG
                })
                .collect();
            if ring_range.is_empty() {
                continue;
            }
            let col_range: Vec<usize> = match az {
                None => (0..cols).collect(),
                Some((lo, hi)) => {
                    let c0 = ((lo - MARGIN_DEG) / col_deg).floor() as i64;
                    let c1 = ((hi + MARGIN_DEG) / col_deg).floor() as i64;
                    (c0..=c1)
                        .map(|c| c.rem_euclid(cols as i64) as usize)
                        .collect()
                }
            };
            for &r in &ring_range {
                for &c in &col_range {
                    entries.push(((r * cols + c) as u32, cand));
                }
            }
        }
        LidarGrid {
            cols,
            lists: CellLists::build(rows * cols, &entries),
        }
    }

    /// Candidates of a ray of `ring` at azimuth `az_deg` in [0, 360).
    #[inline]
    pub fn candidates(&self, ring: usize, az_deg: f64) -> &[Candidate] {
        let c = ((az_deg / 360.0 * self.cols as f64) as usize).min(self.cols - 1);
        self.lists.cell(ring * self.cols + c)
    }

    pub fn entries(&self) -> usize {
        self.lists.len()
    }
}

/// Elevation bounds (degrees) of a box seen from `o`, and its azimuth interval
/// (degrees, `lo` may be negative) or `None` when it surrounds the vertical through `o`.
fn angular_bounds(b: &Aabb, o: V3) -> (f64, f64, Option<(f64, f64)>) {
    let (x0, x1, y0, y1) = (b.min.x - o.x, b.max.x - o.x, b.min.y - o.y, b.max.y - o.y);
    let dx = if x0 > 0.0 {
        x0
    } else if x1 < 0.0 {
        -x1
    } else {
        0.0
    };
    let dy = if y0 > 0.0 {
        y0
    } else if y1 < 0.0 {
        -y1
    } else {
        0.0
    };
    let dmin = (dx * dx + dy * dy).sqrt();
    let (mx, my) = (x0.abs().max(x1.abs()), y0.abs().max(y1.abs()));
    let dmax = (mx * mx + my * my).sqrt();
    let (zlo, zhi) = (b.min.z - o.z, b.max.z - o.z);
    let deg = 180.0 / std::f64::consts::PI;
    let el_hi = if zhi >= 0.0 {
        atan2(zhi, dmin)
    } else {
        atan2(zhi, dmax)
    } * deg;
    let el_lo = if zlo <= 0.0 {
        atan2(zlo, dmin)
    } else {
        atan2(zlo, dmax)
    } * deg;
    if dmin == 0.0 {
        return (el_lo, el_hi, None);
    }
    let corners = [(x0, y0), (x1, y0), (x0, y1), (x1, y1)];
    let a0 = atan2(corners[0].1, corners[0].0) * deg;
    let (mut lo, mut hi) = (0.0f64, 0.0f64);
    for (x, y) in corners {
        let mut delta = atan2(y, x) * deg - a0;
        if delta > 180.0 {
            delta -= 360.0;
        } else if delta <= -180.0 {
            delta += 360.0;
        }
        lo = lo.min(delta);
        hi = hi.max(delta);
    }
    (el_lo, el_hi, Some((a0 + lo, a0 + hi)))
}

/// The camera's grid: `tile`×`tile` pixel tiles.
#[derive(Debug, Clone)]
pub struct CameraGrid {
    pub tile: u32,
    pub cols: u32,
    lists: CellLists,
}

impl CameraGrid {
    pub fn new(
        scene: &Scene,
        cam: &CameraModel,
        rays: &PixelRays,
        width: u32,
        height: u32,
        tile: u32,
    ) -> CameraGrid {
        let cols = width.div_ceil(tile);
        let rows = height.div_ceil(tile);
        let mut entries = Vec::new();
        for (i, p) in scene.prims.iter().enumerate() {
            if scene.is_unbounded(i as u32) {
                continue;
            }
            let b = p.aabb();
            let Some((u0, v0, u1, v1)) = project_box(&b, cam) else {
                continue;
            };
            // One pixel of margin: pixel centres sit at integer coordinates.
            let (u0, u1) = ((u0 - 1.0).max(0.0), (u1 + 1.0).min(width as f64 - 1.0));
            let (v0, v1) = ((v0 - 1.0).max(0.0), (v1 + 1.0).min(height as f64 - 1.0));
            if u0 > u1 || v0 > v1 {
                continue;
            }
            let cand = Candidate {
                near: box_distance(&b, rays.origin),
                prim: i as u32,
            };
            let (c0, c1) = (u0 as u32 / tile, u1 as u32 / tile);
            let (r0, r1) = (v0 as u32 / tile, v1 as u32 / tile);
            for r in r0..=r1 {
                for c in c0..=c1 {
                    entries.push((r * cols + c, cand));
                }
            }
        }
        CameraGrid {
            tile,
            cols,
            lists: CellLists::build((rows * cols) as usize, &entries),
        }
    }

    #[inline]
    pub fn candidates(&self, u: u32, v: u32) -> &[Candidate] {
        self.lists
            .cell(((v / self.tile) * self.cols + u / self.tile) as usize)
    }
}

/// Image bounds of a LiDAR-frame box: corners in the rectified frame, edges cut at
/// the near plane, projected. `None` if wholly behind the camera.
fn project_box(b: &Aabb, cam: &CameraModel) -> Option<(f64, f64, f64, f64)> {
    const NEAR: f64 = 0.05;
    let mut c = [[0.0; 3]; 8];
    for (k, slot) in c.iter_mut().enumerate() {
        let p = v3(
            if k & 1 == 0 { b.min.x } else { b.max.x },
            if k & 2 == 0 { b.min.y } else { b.max.y },
            if k & 4 == 0 { b.min.z } else { b.max.z },
        );
        *slot = cam.velo_to_rect(p.to_array());
    }
    let mut pts: Vec<[f64; 3]> = c.iter().copied().filter(|p| p[2] >= NEAR).collect();
    for i in 0..8 {
        for bit in [1, 2, 4] {
            let j = i | bit;
            if j == i {
                continue;
            }
            let (a, e) = (c[i], c[j]);
            if (a[2] - NEAR) * (e[2] - NEAR) < 0.0 {
                let t = (NEAR - a[2]) / (e[2] - a[2]);
                pts.push([a[0] + t * (e[0] - a[0]), a[1] + t * (e[1] - a[1]), NEAR]);
            }
        }
    }
    if pts.is_empty() {
        return None;
    }
    let (mut u0, mut v0, mut u1, mut v1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for p in pts {
        let (u, v, _) = cam.rect_to_image(p);
        u0 = u0.min(u);
        v0 = v0.min(v);
        u1 = u1.max(u);
        v1 = v1.max(v);
    }
    Some((u0, v0, u1, v1))
}

/// An orthographic grid along the sun direction for shadow rays: a primitive that
/// can shade a point lies in the cell of the point's projection. Ground-level
/// surfaces (road, markings, sidewalks, grass) cast no shadows worth a ray and are
/// left out.
#[derive(Debug, Clone)]
pub struct ShadowGrid {
    sun: V3,
    u: V3,
    w: V3,
    origin: (f64, f64),
    cell: f64,
    cols: usize,
    rows: usize,
    lists: CellLists,
}

impl ShadowGrid {
    pub fn new(scene: &Scene, cell: f64, half_extent: f64) -> ShadowGrid {
        let sun = scene.sun;
        let helper = if sun.z.abs() < 0.9 { V3::Z } else { V3::X };
        let u = helper.cross(sun).normalized();
        let w = sun.cross(u);
        let cols = (2.0 * half_extent / cell).ceil() as usize;
        let rows = cols;
        let origin = (-half_extent, -half_extent);
        let mut entries = Vec::new();
        for (i, p) in scene.prims.iter().enumerate() {
            if scene.is_unbounded(i as u32)
                || matches!(
                    p.surface,
                    Surface::Road | Surface::Marking | Surface::Sidewalk | Surface::Grass
                )
            {
                continue;
            }
            let b = p.aabb();
            let (mut a0, mut a1, mut b0, mut b1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
            for k in 0..8 {
                let q = v3(
                    if k & 1 == 0 { b.min.x } else { b.max.x },
                    if k & 2 == 0 { b.min.y } else { b.max.y },
                    if k & 4 == 0 { b.min.z } else { b.max.z },
                );
                let (pu, pw) = (q.dot(u), q.dot(w));
                a0 = a0.min(pu);
                a1 = a1.max(pu);
                b0 = b0.min(pw);
                b1 = b1.max(pw);
            }
            let c0 = ((a0 - origin.0) / cell).floor().max(0.0) as usize;
            let c1 = ((a1 - origin.0) / cell).floor().min(cols as f64 - 1.0);
            let r0 = ((b0 - origin.1) / cell).floor().max(0.0) as usize;
            let r1 = ((b1 - origin.1) / cell).floor().min(rows as f64 - 1.0);
            if c1 < 0.0 || r1 < 0.0 {
                continue;
            }
            for r in r0..=r1 as usize {
                for c in c0..=c1 as usize {
                    entries.push((
                        (r * cols + c) as u32,
                        Candidate {
                            near: 0.0,
                            prim: i as u32,
                        },
                    ));
                }
            }
        }
        ShadowGrid {
            sun,
            u,
            w,
            origin,
            cell,
            cols,
            rows,
            lists: CellLists::build(rows * cols, &entries),
        }
    }

    /// Is the sun blocked as seen from `p`?
    #[inline]
    pub fn in_shadow(&self, scene: &Scene, p: V3) -> bool {
        let c = ((p.dot(self.u) - self.origin.0) / self.cell).floor();
        let r = ((p.dot(self.w) - self.origin.1) / self.cell).floor();
        if c < 0.0 || r < 0.0 || c >= self.cols as f64 || r >= self.rows as f64 {
            return false;
        }
        let cands = self.lists.cell(r as usize * self.cols + c as usize);
        cands.iter().any(|cand| {
            scene.prims[cand.prim as usize]
                .hit_interval(p, self.sun, 0.0, 300.0)
                .is_some()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::{LayoutConfig, build_scene};
    use crate::math::{cos, rad, sin};
    use crate::rng::Sampler;
    use crate::sensors::{HDL64_ELEVATIONS_DEG, sample_calib};

    #[test]
    fn lidar_grid_gives_the_bvh_answer() {
        let (scene, _) = build_scene(&mut Sampler::new(21), &LayoutConfig::default());
        let grid = LidarGrid::new(&scene, &HDL64_ELEVATIONS_DEG, 360);
        let mut s = Sampler::new(3);
        for _ in 0..20_000 {
            let ring = s.int(0, 63) as usize;
            let az = s.range(0.0, 360.0);
            let el = rad(HDL64_ELEVATIONS_DEG[ring]);
            let d = v3(cos(el) * cos(rad(az)), cos(el) * sin(rad(az)), sin(el));
            let a = scene.cast(V3::ZERO, d, 0.0, 120.0);
            let b = cast_candidates(&scene, grid.candidates(ring, az), V3::ZERO, d, 0.0, 120.0);
            assert_eq!(a.map(|h| h.t), b.map(|h| h.t), "ring {ring} az {az}");
        }
    }

    #[test]
    fn camera_grid_gives_the_bvh_answer() {
        let (scene, _) = build_scene(&mut Sampler::new(22), &LayoutConfig::default());
        let cam = sample_calib(&mut Sampler::new(22)).camera_model().unwrap();
        let rays = PixelRays::new(&cam);
        let grid = CameraGrid::new(&scene, &cam, &rays, 1242, 375, 8);
        let mut s = Sampler::new(4);
        for _ in 0..20_000 {
            let (u, v) = (s.int(0, 1241) as u32, s.int(0, 374) as u32);
            let d = rays.dir(u as f64, v as f64).normalized();
            let a = scene.cast(rays.origin, d, 0.05, 400.0);
            let b = cast_candidates(&scene, grid.candidates(u, v), rays.origin, d, 0.05, 400.0);
            assert_eq!(a.map(|h| h.t), b.map(|h| h.t), "pixel {u} {v}");
        }
    }

    #[test]
    fn shadow_grid_agrees_with_shadow_rays() {
        let (scene, _) = build_scene(&mut Sampler::new(23), &LayoutConfig::default());
        let grid = ShadowGrid::new(&scene, 1.0, 200.0);
        let mut s = Sampler::new(5);
        let mut shadowed = 0;
        for _ in 0..5_000 {
            // Points on the road and sidewalks around the sensor.
            let p = v3(s.range(-30.0, 60.0), s.range(-15.0, 15.0), -1.7);
            let lifted = p + V3::Z * 0.05;
            let bvh = scene.cast(lifted, scene.sun, 0.0, 300.0).is_some_and(|h| {
                !matches!(
                    scene.prims[h.prim as usize].surface,
                    Surface::Road | Surface::Marking | Surface::Sidewalk | Surface::Grass
                )
            });
            let fast = grid.in_shadow(&scene, lifted);
            if bvh {
                shadowed += 1;
                assert!(fast, "{p:?}");
            }
        }
        assert!(shadowed > 0);
    }
}
