//! The RGB-D camera: a Kinect-like sensor held 1–1.6 m above the floor and pitched down,
//! ray cast through every pixel into a colour image and a depth image with the sensor's
//! faults, then back-projected into upright-depth points exactly as the SUN RGB-D toolbox
//! does it with a raw depth PNG ([`fusiondet_sunrgbd::depth_to_points`]).
//!
//! Pixel convention: the toolbox's (MATLAB's) — pixel column c, row r (from 0) is the image
//! point u = c + 1, v = r + 1 — so the written `calib` matrix projects a point onto
//! (c + 1, r + 1) of the pixel it came from, as the real prepared files do.
//!
//! Depth faults, per pixel (stateless hashes of the frame key and pixel index, so rows can
//! be cast on any number of threads):
//! * axial noise σ(z) = 1.2 mm + 1.9 mm · (z − 0.4 m)² (Nguyen, Izadi & Lovell 2012, Kinect);
//! * quantisation of the disparity to 1/8 px with focal length × baseline 580 px · 7.5 cm,
//!   so depth steps grow as z²: 3 mm at 1 m, 4.6 cm at 4 m, 14 cm at 7 m; then millimetres;
//! * holes: glancing surfaces (cos incidence below 0.25), dark ones (albedo luminance below
//!   0.1, the projected pattern is not seen), glass (the material's return probability),
//!   far ones (rising from 4.5 m), a 0.5% floor; nothing nearer than 0.4 m or beyond 8 m;
//! * the projector's shadow: the pattern comes from a projector [`PROJECTOR_BASELINE`] to the
//!   camera's right, so surfaces it cannot see (beside the right edges of nearer things, as
//!   the camera sees them) get no depth — a second ray per pixel, from the projector.

use crate::math::{M3, V3, rad, v3};
use crate::primitive::NO_OWNER;
use crate::rng::{Sampler, hash_normal, hash_unit};
use crate::scene::Scene;
use fusiondet_sunrgbd::{Calib, Mat33, RawDepth};
use image::RgbImage;
use rayon::prelude::*;

/// The sensor's parameters and the ranges its pose is drawn from.
#[derive(Debug, Clone, PartialEq)]
pub struct RgbdSpec {
    pub width: u32,
    pub height: u32,
    /// Focal length range in pixels for a 640-pixel-wide image (scaled with the width).
    pub focal: (f64, f64),
    /// Camera height above the floor, metres.
    pub camera_height: (f64, f64),
    /// Downward pitch, degrees.
    pub pitch_deg: (f64, f64),
    /// Roll deviation (uniform ±), degrees.
    pub roll_deg: f64,
    pub min_range: f64,
    pub max_range: f64,
}

impl Default for RgbdSpec {
    fn default() -> Self {
        RgbdSpec {
            width: 640,
            height: 480,
            focal: (518.0, 532.0),
            camera_height: (1.0, 1.6),
            pitch_deg: (5.0, 25.0),
            roll_deg: 2.0,
            min_range: 0.4,
            max_range: 8.0,
        }
    }
}

/// The projector's offset along the camera's x axis, metres (Kinect v1: 7.5 cm).
pub const PROJECTOR_BASELINE: f64 = 0.075;
/// Focal length × baseline of the structured-light pair, pixel·metres.
const FOCAL_BASELINE: f64 = 580.0 * 0.075;
/// Disparity resolution, pixels.
const DISPARITY_STEP: f64 = 1.0 / 8.0;

/// One frame's camera: intrinsics, tilt and height.
#[derive(Debug, Clone, PartialEq)]
pub struct RgbdCamera {
    /// [fx 0 cx; 0 fy cy; 0 0 1] in the toolbox's 1-based pixel coordinates.
    pub k: Mat33,
    /// Upright = Rtilt · tilted depth frame (x right, y forward, z up of the camera).
    pub rtilt: Mat33,
    pub width: u32,
    pub height: u32,
    pub camera_height: f64,
    pub pitch: f64,
    pub roll: f64,
}

fn to_rows(m: &M3) -> Mat33 {
    std::array::from_fn(|i| std::array::from_fn(|j| m.cols[j].axis(i)))
}

impl RgbdCamera {
    /// Draws a camera (the calibration stream).
    pub fn sample(spec: &RgbdSpec, s: &mut Sampler) -> RgbdCamera {
        let scale = spec.width as f64 / 640.0;
        let f = s.range(spec.focal.0, spec.focal.1) * scale;
        let fy = f * s.range(0.998, 1.002);
        let cx = (spec.width as f64 + 1.0) / 2.0 + s.range(-8.0, 8.0) * scale;
        let cy = (spec.height as f64 + 1.0) / 2.0 + s.range(-8.0, 8.0) * scale;
        let pitch = rad(s.range(spec.pitch_deg.0, spec.pitch_deg.1));
        let roll = rad(s.range(-spec.roll_deg, spec.roll_deg));
        let rtilt = M3::rot_x(-pitch).mul(&M3::rot_y(roll));
        RgbdCamera {
            k: [[f, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]],
            rtilt: to_rows(&rtilt),
            width: spec.width,
            height: spec.height,
            camera_height: s.range(spec.camera_height.0, spec.camera_height.1),
            pitch,
            roll,
        }
    }

    /// The data set's depth-to-image matrix.
    pub fn calib(&self) -> Calib {
        Calib::from_camera(&self.k, &self.rtilt)
    }

    /// The upright direction through pixel (col, row), scaled so that one unit along it is
    /// one metre of camera depth.
    pub fn ray(&self, col: u32, row: u32) -> V3 {
        let (u, v) = (col as f64 + 1.0, row as f64 + 1.0);
        let d = [
            (u - self.k[0][2]) / self.k[0][0],
            1.0,
            -(v - self.k[1][2]) / self.k[1][1],
        ];
        let r = &self.rtilt;
        v3(
            r[0][0] * d[0] + r[0][1] * d[1] + r[0][2] * d[2],
            r[1][0] * d[0] + r[1][1] * d[1] + r[1][2] * d[2],
            r[2][0] * d[0] + r[2][1] * d[1] + r[2][2] * d[2],
        )
    }
}

/// What the camera recorded, row-major.
#[derive(Debug, Clone)]
pub struct Capture {
    pub image: RgbImage,
    pub depth: RawDepth,
    /// The furniture index seen at each pixel, or [`NO_OWNER`].
    pub owner: Vec<u32>,
    /// The true camera depth at each pixel (0 where nothing is within range).
    pub true_depth: Vec<f32>,
}

/// Why a pixel holds no depth, for the statistics.
fn hole_probability(z: f64, cos_incidence: f64, albedo: [f64; 3], return_prob: f64) -> f64 {
    let glance = ((0.25 - cos_incidence) / 0.2).clamp(0.0, 1.0) * 0.85;
    let lum = 0.3 * albedo[0] + 0.59 * albedo[1] + 0.11 * albedo[2];
    let dark = ((0.1 - lum) / 0.08).clamp(0.0, 1.0) * 0.85;
    let glass = 1.0 - return_prob;
    let far = ((z - 4.5) / 3.5).clamp(0.0, 1.0) * 0.4;
    let floor = 0.005;
    1.0 - (1.0 - glance) * (1.0 - dark) * (1.0 - glass) * (1.0 - far) * (1.0 - floor)
}

/// Whether the projector at `projector` cannot light the surface point `p`.
fn in_projector_shadow(scene: &Scene, projector: V3, p: V3) -> bool {
    let to_p = p - projector;
    let dist = to_p.norm();
    scene
        .cast(projector, to_p / dist, 0.01, dist - 0.01)
        .is_some()
}

/// The axial noise deviation at depth z (metres).
pub fn noise_sigma(z: f64) -> f64 {
    0.0012 + 0.0019 * (z - 0.4) * (z - 0.4)
}

/// The depth the sensor reports for a (noisy) depth: disparity quantised, then millimetres.
pub fn quantise(z: f64) -> f64 {
    let disparity = FOCAL_BASELINE / z;
    let q = (disparity / DISPARITY_STEP).round() * DISPARITY_STEP;
    if q <= 0.0 {
        return f64::INFINITY;
    }
    ((FOCAL_BASELINE / q) * 1000.0).round() / 1000.0
}

fn to_u8(c: f64) -> u8 {
    (c.clamp(0.0, 1.0) * 255.0 + 0.5) as u8
}

/// Casts every pixel: colour under a ceiling light `light` (upright frame), depth with the
/// sensor's faults (per-pixel randomness keyed by `key`).
pub fn capture(scene: &Scene, cam: &RgbdCamera, spec: &RgbdSpec, light: V3, key: u64) -> Capture {
    let (w, h) = (cam.width, cam.height);
    let r = &cam.rtilt;
    let projector = v3(r[0][0], r[1][0], r[2][0]) * PROJECTOR_BASELINE;
    // Per row: colours, millimetres, owners, true depths.
    type Row = (Vec<u8>, Vec<u16>, Vec<u32>, Vec<f32>);
    let rows: Vec<Row> = (0..h)
        .into_par_iter()
        .map(|row| {
            let mut rgb = Vec::with_capacity(3 * w as usize);
            let mut mm = Vec::with_capacity(w as usize);
            let mut owner = Vec::with_capacity(w as usize);
            let mut truth = Vec::with_capacity(w as usize);
            for col in 0..w {
                let pixel = (row * w + col) as u64;
                let ray = cam.ray(col, row);
                let len = ray.norm();
                let d = ray / len;
                let hit = scene.cast(V3::ZERO, d, 0.01, spec.max_range * len + 1.0);
                let Some(hit) = hit else {
                    rgb.extend([0, 0, 0]);
                    mm.push(0);
                    owner.push(NO_OWNER);
                    truth.push(0.0);
                    continue;
                };
                let p = d * hit.t;
                let sample = scene.surface_at(&hit, p);
                let n = hit.normal;
                let to_light = light - p;
                let r2 = to_light.dot(to_light);
                let lambert = (n.dot(to_light) / r2.sqrt()).max(0.0);
                let shade = 0.32 + 0.85 * lambert / (1.0 + 0.06 * r2);
                for (k, c) in sample.rgb.iter().enumerate() {
                    let grain = 0.012 * hash_normal(key ^ 0x1A6E, pixel, k as u64);
                    rgb.push(to_u8(c * shade + grain));
                }
                owner.push(scene.prims[hit.prim as usize].owner);
                let z = hit.t / len;
                let in_range = (spec.min_range..=spec.max_range).contains(&z);
                truth.push(if in_range { z as f32 } else { 0.0 });
                let p_hole = hole_probability(z, n.dot(d).abs(), sample.rgb, sample.return_prob);
                if !in_range
                    || hash_unit(key, pixel, 1) < p_hole
                    || in_projector_shadow(scene, projector, p)
                {
                    mm.push(0);
                    continue;
                }
                let noisy = z + noise_sigma(z) * hash_normal(key, pixel, 2);
                let reported = quantise(noisy);
                if (spec.min_range..=spec.max_range).contains(&reported) {
                    mm.push((reported * 1000.0).round() as u16);
                } else {
                    mm.push(0);
                }
            }
            (rgb, mm, owner, truth)
        })
        .collect();
    let n = (w * h) as usize;
    let (mut pixels, mut millimetres, mut owner, mut true_depth) = (
        Vec::with_capacity(3 * n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    );
    for (r, m, o, t) in rows {
        pixels.extend(r);
        millimetres.extend(m);
        owner.extend(o);
        true_depth.extend(t);
    }
    Capture {
        image: RgbImage::from_raw(w, h, pixels).expect("buffer has the image size"),
        depth: RawDepth {
            width: w as usize,
            height: h as usize,
            millimetres,
        },
        owner,
        true_depth,
    }
}

/// The upright position of the camera's optical axis, for the statistics: (pitch, roll) of
/// Rtilt's forward axis.
pub fn forward_axis(cam: &RgbdCamera) -> V3 {
    v3(cam.rtilt[0][1], cam.rtilt[1][1], cam.rtilt[2][1])
}

/// A camera looking level along +y (tests).
#[cfg(test)]
pub(crate) fn level_camera(width: u32, height: u32, f: f64) -> RgbdCamera {
    RgbdCamera {
        k: [
            [f, 0.0, (width as f64 + 1.0) / 2.0],
            [0.0, f, (height as f64 + 1.0) / 2.0],
            [0.0, 0.0, 1.0],
        ],
        rtilt: to_rows(&M3::IDENTITY),
        width,
        height,
        camera_height: 1.3,
        pitch: 0.0,
        roll: 0.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::material::Material;
    use crate::math::Pose;
    use crate::primitive::Surface;
    use crate::scene::SceneBuilder;

    #[test]
    fn rays_project_back_onto_their_pixels() {
        let cam = RgbdCamera::sample(&RgbdSpec::default(), &mut Sampler::new(4));
        let calib = cam.calib();
        for (c, r) in [(0, 0), (639, 479), (320, 10), (17, 400)] {
            let p = cam.ray(c, r) * 3.7;
            let [u, v] = calib.project(p.to_array()).unwrap();
            assert!((u - (c as f64 + 1.0)).abs() < 1e-9, "{u} vs {c}");
            assert!((v - (r as f64 + 1.0)).abs() < 1e-9, "{v} vs {r}");
            // The camera-frame depth along the ray is its scale: Rtilt's forward axis.
            assert!((p.dot(forward_axis(&cam)) - 3.7).abs() < 1e-9);
        }
        // Pitched down: the image centre looks below the horizon.
        assert!(forward_axis(&cam).z < -0.08);
    }

    /// A post 1.5 m ahead of a wall at 3 m casts the projector's shadow on the wall: holes on
    /// the post's left (away from the projector, which sits to the camera's right), none on its
    /// right, and hardly any far from it.
    #[test]
    fn the_projector_shadows_the_wall_beside_a_nearer_object() {
        let mut b = SceneBuilder::new();
        let grey = b.material(Material::solid([0.6, 0.6, 0.6], 0.5));
        let id = Pose::IDENTITY;
        b.add_box(
            &id,
            v3(-5.0, 3.0, -5.0),
            v3(5.0, 3.2, 5.0),
            grey,
            Surface::Wall,
        );
        b.add_box(
            &id,
            v3(-0.1, 1.45, -2.0),
            v3(0.1, 1.55, 2.0),
            grey,
            Surface::Wall,
        );
        let scene = b.finish(&Pose::IDENTITY, V3::Z);
        let cam = level_camera(160, 120, 130.0);
        let cap = capture(&scene, &cam, &RgbdSpec::default(), v3(0.0, 1.5, 1.0), 3);
        let row = 60u32;
        let hole = |col: u32| cap.depth.millimetres[(row * 160 + col) as usize] == 0;
        let wall = |col: u32| (cap.true_depth[(row * 160 + col) as usize] - 3.0).abs() < 1e-4;
        // The post spans columns around the centre; the wall beside it on each side.
        let post: Vec<u32> = (0..160).filter(|&c| !wall(c)).collect();
        let (first, last) = (post[0], *post.last().unwrap());
        // Shadow width on the wall: baseline · (3 − 1.45) / 1.45 ≈ 8 cm ≈ 3.5 px at 3 m.
        let left: usize = (first - 6..first).filter(|&c| hole(c)).count();
        let right: usize = (last + 1..last + 7).filter(|&c| hole(c)).count();
        assert!(left >= 2 && right == 0, "left {left}, right {right}");
        assert!((0..40).filter(|&c| hole(c)).count() <= 2);
    }

    #[test]
    fn noise_and_quantisation_grow_with_range() {
        assert!(noise_sigma(1.0) < 0.002 && noise_sigma(4.0) > 0.02);
        let step = |z: f64| {
            // The smallest change the quantised depth can show near z.
            let a = quantise(z);
            let mut b = a;
            let mut x = z;
            while b == a {
                x += 0.0005;
                b = quantise(x);
            }
            b - a
        };
        let (near, far) = (step(1.0), step(4.0));
        assert!(near > 0.001 && near < 0.006, "{near}");
        assert!(far > 0.03 && far < 0.07, "{far}");
    }

    /// A wall 3 m ahead: its depth is right on average, its spread matches σ(3 m) within the
    /// quantisation, and a dark patch and a glass patch are mostly holes.
    #[test]
    fn depth_statistics_on_a_flat_wall() {
        let mut b = SceneBuilder::new();
        let grey = b.material(Material::solid([0.6, 0.6, 0.6], 0.5));
        let black = b.material(Material::solid([0.02, 0.02, 0.02], 0.5));
        let glass = b.material(Material::solid([0.8, 0.8, 0.9], 0.5).glassy(0.1));
        let id = Pose::IDENTITY;
        b.add_box(
            &id,
            v3(-5.0, 3.0, -5.0),
            v3(5.0, 3.2, 5.0),
            grey,
            Surface::Wall,
        );
        b.add_box(
            &id,
            v3(-2.0, 2.9, -0.5),
            v3(-1.0, 3.0, 0.5),
            black,
            Surface::Wall,
        );
        b.add_box(
            &id,
            v3(1.0, 2.9, -0.5),
            v3(2.0, 3.0, 0.5),
            glass,
            Surface::Wall,
        );
        let scene = b.finish(&Pose::IDENTITY, V3::Z);
        let cam = level_camera(160, 120, 130.0);
        let cap = capture(&scene, &cam, &RgbdSpec::default(), v3(0.0, 1.5, 1.0), 9);
        let (mut n, mut sum, mut sq, mut dark, mut dark_holes, mut glassy, mut glass_holes) =
            (0.0, 0.0, 0.0, 0, 0, 0, 0);
        for row in 0..120u32 {
            for col in 0..160u32 {
                let i = (row * 160 + col) as usize;
                let truth = cap.true_depth[i] as f64;
                let mm = cap.depth.millimetres[i];
                let x = (cam.ray(col, row) * truth).x;
                if (truth - 2.9).abs() < 1e-6 && x < -1.0 {
                    dark += 1;
                    dark_holes += usize::from(mm == 0);
                } else if (truth - 2.9).abs() < 1e-6 {
                    glassy += 1;
                    glass_holes += usize::from(mm == 0);
                } else if mm > 0 {
                    let e = f64::from(mm) / 1000.0 - truth;
                    n += 1.0;
                    sum += e;
                    sq += e * e;
                }
            }
        }
        let (mean, sd) = (sum / n, (sq / n - (sum / n) * (sum / n)).sqrt());
        assert!(mean.abs() < 0.003, "bias {mean}");
        assert!(
            sd > 0.6 * noise_sigma(3.0) && sd < 1.6 * noise_sigma(3.0),
            "σ {sd}"
        );
        assert!(
            dark > 100 && dark_holes as f64 > 0.7 * dark as f64,
            "{dark_holes}/{dark}"
        );
        assert!(
            glassy > 100 && glass_holes as f64 > 0.8 * glassy as f64,
            "{glass_holes}/{glassy}"
        );
    }
}
