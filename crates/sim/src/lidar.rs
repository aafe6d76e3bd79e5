//! The LiDAR scan: one ray per laser and firing, cast through the scene in parallel
//! (one task per ring, results concatenated in ring order, so the output order is
//! KITTI's — ring by ring from the top, azimuth anticlockwise from straight ahead —
//! and independent of the thread count).
//!
//! Per beam: foliage is a porous volume (the beam stops after an exponentially
//! distributed free path or passes through); glass returns only sometimes; whether
//! a solid surface returns depends on its reflectance, the incidence angle and the
//! range (`1 / (1 + (r / r50)^k)`, `r50 ∝ √(reflectance · cos θ)`), which is what
//! makes dark cars fade faster with distance than the plain 1/r² of beam geometry,
//! as in KITTI; range noise is Gaussian; the reflectance channel is the surface's
//! reflectance, weakly shaded by the incidence angle, plus noise, on KITTI's 0.01 grid.

use crate::math::{V3, cos, ipow, ln, rad, sin, v3};
use crate::rng::{hash_normal, hash_unit};
use crate::scene::Scene;
use crate::sensors::LidarSpec;
use crate::viewgrid::{Candidate, LidarGrid, cast_candidates};
use fusiondet_kitti::LidarPoint;
use rayon::prelude::*;

/// What a point hit, for labels, statistics and tests.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PointInfo {
    /// Index of the primitive hit.
    pub prim: u32,
    pub ring: u8,
    /// The beam went through foliage before this return.
    pub through_foliage: bool,
}

/// One revolution.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LidarScan {
    pub points: Vec<LidarPoint>,
    pub info: Vec<PointInfo>,
    /// Rays cast (after the ego-car mask).
    pub rays: usize,
}

// Salts of the per-ray random numbers.
const SALT_DROP: u64 = 0;
const SALT_DETECT: u64 = 1;
const SALT_GLASS: u64 = 2;
const SALT_NOISE: u64 = 10;
const SALT_REFL: u64 = 11;
const SALT_FOLIAGE: u64 = 32;

/// Casts every beam of one revolution. `key` seeds the per-ray noise.
pub fn scan(scene: &Scene, spec: &LidarSpec, key: u64) -> LidarScan {
    let phase = hash_unit(key, u64::MAX, 0);
    let step = 360.0 / spec.firings as f64;
    let q = spec.azimuth_quantum_deg;
    let grid = LidarGrid::new(scene, &spec.elevations_deg, 360);
    // Firing azimuths (snapped to the encoder grid) and their sines and cosines,
    // shared by all lasers.
    let azimuths: Vec<(f64, f64, f64)> = (0..spec.firings)
        .map(|k| {
            let az_deg = (((k as f64 + phase) * step) / q).round() * q;
            let az = rad(az_deg);
            (az_deg, cos(az), sin(az))
        })
        .collect();
    let rings: Vec<(Vec<LidarPoint>, Vec<PointInfo>, usize)> = spec
        .elevations_deg
        .par_iter()
        .enumerate()
        .map(|(ring, &el_deg)| {
            let el = rad(el_deg);
            let (se, ce) = (sin(el), cos(el));
            let mut pts = Vec::with_capacity(spec.firings);
            let mut info = Vec::with_capacity(spec.firings);
            let mut rays = 0;
            for (k, &(az_deg, ca, sa)) in azimuths.iter().enumerate() {
                if az_deg >= 360.0 || spec.masked(ring, az_deg) {
                    continue;
                }
                rays += 1;
                let d = v3(ce * ca, ce * sa, se);
                let ray = (ring * spec.firings + k) as u64;
                let cands = grid.candidates(ring, az_deg);
                if let Some((p, i)) = beam(scene, cands, spec, key, ray, d) {
                    pts.push(p);
                    info.push(PointInfo {
                        ring: ring as u8,
                        ..i
                    });
                }
            }
            (pts, info, rays)
        })
        .collect();
    let mut out = LidarScan::default();
    for (p, i, r) in rings {
        out.points.extend(p);
        out.info.extend(i);
        out.rays += r;
    }
    out
}

/// Traces one beam; returns the point (LiDAR frame, f32) if it comes back.
fn beam(
    scene: &Scene,
    cands: &[Candidate],
    spec: &LidarSpec,
    key: u64,
    ray: u64,
    d: V3,
) -> Option<(LidarPoint, PointInfo)> {
    if hash_unit(key, ray, SALT_DROP) < spec.dropout {
        return None;
    }
    let mut t0 = 0.0;
    let mut through_foliage = false;
    for segment in 0..6 {
        let hit = cast_candidates(scene, cands, V3::ZERO, d, t0, spec.max_range)?;
        let prim = &scene.prims[hit.prim as usize];
        let material = &scene.materials[prim.material as usize];
        let (t, cos_i, surface) = if material.free_path > 0.0 {
            // Porous volume: stop after a free path, or leave it.
            let u = hash_unit(key, ray, SALT_FOLIAGE + segment);
            let depth = -material.free_path * ln(1.0 - u);
            if hit.t + depth < hit.t_exit {
                let t = hit.t + depth;
                (t, 0.6, scene.surface_at(&hit, d * hit.t))
            } else {
                through_foliage = true;
                t0 = hit.t_exit + 1e-4;
                continue;
            }
        } else {
            let sample = scene.surface_at(&hit, d * hit.t);
            if sample.return_prob < 1.0 && hash_unit(key, ray, SALT_GLASS) >= sample.return_prob {
                return None;
            }
            (hit.t, hit.normal.dot(d).abs(), sample)
        };
        if t < spec.min_range || t > spec.max_range {
            return None;
        }
        // Weak returns: dark, grazing or far surfaces come back less often.
        let strength = (surface.reflectance + spec.reflectance_floor) * cos_i.max(0.05);
        let r50 = spec.reference_range * (strength / spec.reference_reflectance).sqrt();
        let p_detect = 1.0 / (1.0 + ipow(t / r50, spec.falloff_exponent));
        if hash_unit(key, ray, SALT_DETECT) >= p_detect {
            return None;
        }
        let range = t + spec.range_noise * hash_normal(key, ray, SALT_NOISE);
        let p = d * range;
        // KITTI's ground reads ≈ 0.29 even at grazing incidence: a weak angle dependence.
        let refl = surface.reflectance * (0.75 + 0.25 * cos_i)
            + spec.reflectance_noise * hash_normal(key, ray, SALT_REFL);
        let refl = (refl.clamp(0.0, 1.0) * 100.0).round() / 100.0;
        return Some((
            [p.x as f32, p.y as f32, p.z as f32, refl as f32],
            PointInfo {
                prim: hit.prim,
                ring: 0,
                through_foliage,
            },
        ));
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::{LayoutConfig, build_scene};
    use crate::rng::Sampler;

    #[test]
    fn scan_is_deterministic_and_kitti_sized() {
        let (scene, _) = build_scene(&mut Sampler::new(12), &LayoutConfig::default());
        let spec = LidarSpec::default();
        let a = scan(&scene, &spec, 99);
        let b = scan(&scene, &spec, 99);
        assert_eq!(a, b);
        assert!(
            a.points.len() > 80_000 && a.points.len() < 138_240,
            "{}",
            a.points.len()
        );
        // Ring order: ring indices never decrease.
        assert!(a.info.windows(2).all(|w| w[0].ring <= w[1].ring));
        // Reflectance on KITTI's grid, in [0, 1].
        assert!(a.points.iter().all(|p| (0.0..=1.0).contains(&p[3])));
        assert!(
            a.points
                .iter()
                .all(|p| ((p[3] * 100.0).round() - p[3] * 100.0).abs() < 1e-3)
        );
        // Ground hits of the lowest ring are about 4 m away, 1.73 m below.
        let low: Vec<_> = a
            .points
            .iter()
            .zip(&a.info)
            .filter(|(_, i)| i.ring == 63)
            .map(|(p, _)| p)
            .collect();
        let med_z = {
            let mut z: Vec<f32> = low.iter().map(|p| p[2]).collect();
            z.sort_by(f32::total_cmp);
            z[z.len() / 2]
        };
        assert!((med_z + 1.73).abs() < 0.1, "{med_z}");
    }

    #[test]
    fn azimuth_steps_are_on_the_encoder_grid() {
        let (scene, _) = build_scene(&mut Sampler::new(5), &LayoutConfig::default());
        let a = scan(&scene, &LidarSpec::default(), 1);
        let ring: Vec<f64> = a
            .points
            .iter()
            .zip(&a.info)
            .filter(|(_, i)| i.ring == 40)
            .map(|(p, _)| {
                (p[1] as f64)
                    .atan2(p[0] as f64)
                    .to_degrees()
                    .rem_euclid(360.0)
            })
            .collect();
        let mut small = 0;
        let mut mid = 0;
        for w in ring.windows(2) {
            let g = w[1] - w[0];
            if (0.07..0.11).contains(&g) {
                small += 1;
            } else if (0.16..0.2).contains(&g) {
                mid += 1;
            }
        }
        let total = (ring.len() - 1) as f64;
        assert!(mid as f64 / total > 0.7, "{mid} of {total}");
        assert!(small as f64 / total > 0.08, "{small} of {total}");
    }
}
