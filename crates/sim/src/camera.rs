//! The camera: ray casts the same scene through every pixel of the left colour
//! camera (P2, R0_rect, Tr_velo_to_cam), so image and point cloud agree by
//! construction. Lambertian shading with a sun, sky light and sun shadows, distance
//! haze and a sky gradient. Alongside the colours it keeps, per pixel, the primitive
//! seen there — the z-buffer/object-id image the occlusion labels are computed from.

use crate::math::{V3, v3};
use crate::primitive::Surface;
use crate::scene::Scene;
use crate::viewgrid::{CameraGrid, Candidate, ShadowGrid, cast_candidates};
use fusiondet_geometry::CameraModel;
use image::RgbImage;
use rayon::prelude::*;

/// Pixel value of the id image where only sky is seen.
pub const SKY: u32 = u32::MAX;

/// Rendering options.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraSpec {
    pub width: u32,
    pub height: u32,
    /// Cast a shadow ray towards the sun for every lit pixel.
    pub shadows: bool,
    pub max_range: f64,
}

impl Default for CameraSpec {
    fn default() -> Self {
        CameraSpec {
            width: 1242,
            height: 375,
            shadows: true,
            max_range: 400.0,
        }
    }
}

/// The rendered frame.
#[derive(Debug, Clone)]
pub struct Render {
    pub image: RgbImage,
    /// Primitive index seen at each pixel (row-major), or [`SKY`].
    pub prim: Vec<u32>,
    /// Depth of the surface seen at each pixel (row-major): its rectified-camera z in
    /// metres, 0 for sky. The ground truth of depth completion.
    pub depth: Vec<f32>,
    pub width: u32,
    pub height: u32,
}

impl Render {
    pub fn prim_at(&self, u: u32, v: u32) -> u32 {
        self.prim[(v * self.width + u) as usize]
    }
}

/// Pixel rays: the camera centre and the direction of pixel (u, v) in the LiDAR frame.
#[derive(Debug, Clone, Copy)]
pub struct PixelRays {
    pub origin: V3,
    a_u: V3,
    a_v: V3,
    a_1: V3,
}

impl PixelRays {
    pub fn new(cam: &CameraModel) -> PixelRays {
        // Centre: P2 · [C; 1] = 0, i.e. the back-projection at depth 0.
        let c_rect = cam.image_to_rect(0.0, 0.0, 0.0);
        let origin = V3::from_array(cam.rect_to_velo(c_rect));
        // Directions: the back-projection at depth 1 minus the centre, rotated to LiDAR.
        let dir = |u: f64, v: f64| {
            let p = cam.image_to_rect(u, v, 1.0);
            let d_rect = [p[0] - c_rect[0], p[1] - c_rect[1], p[2] - c_rect[2]];
            let m = &cam.rect_to_velo;
            v3(
                m[(0, 0)] * d_rect[0] + m[(0, 1)] * d_rect[1] + m[(0, 2)] * d_rect[2],
                m[(1, 0)] * d_rect[0] + m[(1, 1)] * d_rect[1] + m[(1, 2)] * d_rect[2],
                m[(2, 0)] * d_rect[0] + m[(2, 1)] * d_rect[1] + m[(2, 2)] * d_rect[2],
            )
        };
        let a_1 = dir(0.0, 0.0);
        PixelRays {
            origin,
            a_u: dir(1.0, 0.0) - a_1,
            a_v: dir(0.0, 1.0) - a_1,
            a_1,
        }
    }

    /// Direction (not normalised) through pixel centre (u, v).
    #[inline]
    pub fn dir(&self, u: f64, v: f64) -> V3 {
        self.a_1 + self.a_u * u + self.a_v * v
    }
}

const SKY_ZENITH: [f64; 3] = [0.35, 0.55, 0.85];
const SKY_HORIZON: [f64; 3] = [0.85, 0.9, 0.95];

fn sky(d: V3) -> [f64; 3] {
    let t = (d.z / d.norm()).clamp(0.0, 1.0).sqrt();
    [
        SKY_HORIZON[0] + (SKY_ZENITH[0] - SKY_HORIZON[0]) * t,
        SKY_HORIZON[1] + (SKY_ZENITH[1] - SKY_HORIZON[1]) * t,
        SKY_HORIZON[2] + (SKY_ZENITH[2] - SKY_HORIZON[2]) * t,
    ]
}

fn to_u8(c: f64) -> u8 {
    (c.clamp(0.0, 1.0) * 255.0 + 0.5) as u8
}

/// Renders the scene as seen by `cam`.
pub fn render(scene: &Scene, cam: &CameraModel, spec: &CameraSpec) -> Render {
    let rays = PixelRays::new(cam);
    let (w, h) = (spec.width, spec.height);
    let (grid, shadows) = rayon::join(
        || CameraGrid::new(scene, cam, &rays, w, h, 8),
        || spec.shadows.then(|| ShadowGrid::new(scene, 1.0, 250.0)),
    );
    // The rectified-camera z of a LiDAR-frame point: the third row of velo_to_rect.
    let z_row: [f64; 4] = std::array::from_fn(|c| cam.velo_to_rect[(2, c)]);
    let rect_z = |p: V3| z_row[0] * p.x + z_row[1] * p.y + z_row[2] * p.z + z_row[3];
    let rows: Vec<(Vec<u8>, Vec<u32>, Vec<f32>)> = (0..h)
        .into_par_iter()
        .map(|v| {
            let mut rgb = Vec::with_capacity(3 * w as usize);
            let mut ids = Vec::with_capacity(w as usize);
            let mut depths = Vec::with_capacity(w as usize);
            for u in 0..w {
                let d = rays.dir(u as f64, v as f64).normalized();
                let cands = grid.candidates(u, v);
                let (c, id, t) = shade(scene, cands, shadows.as_ref(), rays.origin, d, spec);
                rgb.extend(c.iter().map(|&x| to_u8(x)));
                ids.push(id);
                depths.push(t.map_or(0.0, |t| rect_z(rays.origin + d * t) as f32));
            }
            (rgb, ids, depths)
        })
        .collect();
    let mut pixels = Vec::with_capacity((3 * w * h) as usize);
    let mut prim = Vec::with_capacity((w * h) as usize);
    let mut depth = Vec::with_capacity((w * h) as usize);
    for (r, i, z) in rows {
        pixels.extend(r);
        prim.extend(i);
        depth.extend(z);
    }
    Render {
        image: RgbImage::from_raw(w, h, pixels).expect("buffer has the image size"),
        prim,
        depth,
        width: w,
        height: h,
    }
}

/// The colour seen along one ray, the primitive hit and the distance to it.
fn shade(
    scene: &Scene,
    cands: &[Candidate],
    shadows: Option<&ShadowGrid>,
    o: V3,
    d: V3,
    spec: &CameraSpec,
) -> ([f64; 3], u32, Option<f64>) {
    let Some(hit) = cast_candidates(scene, cands, o, d, 0.05, spec.max_range) else {
        return (sky(d), SKY, None);
    };
    let p = o + d * hit.t;
    let sample = scene.surface_at(&hit, p);
    let n = hit.normal;
    let mut sun = n.dot(scene.sun).max(0.0);
    if let Some(grid) = shadows
        && sun > 0.0
        && grid.in_shadow(scene, p + n * 0.02)
    {
        sun = 0.0;
    }
    let surface = scene.prims[hit.prim as usize].surface;
    // Glassy and painted surfaces get a little specular sky reflection.
    let ambient = 0.42 + 0.18 * n.z.max(0.0);
    let light = ambient + 0.75 * sun;
    let mut c = [
        sample.rgb[0] * light,
        sample.rgb[1] * light,
        sample.rgb[2] * light,
    ];
    if surface == Surface::Object && sample.return_prob < 1.0 {
        // Glass mirrors the sky a little.
        let r = 0.15 * (1.0 - n.dot(-d).abs());
        c = [
            c[0] + r * SKY_HORIZON[0],
            c[1] + r * SKY_HORIZON[1],
            c[2] + r * SKY_HORIZON[2],
        ];
    }
    // Distance haze (a rational stand-in for 1 − e^(−t/350), cheaper per pixel).
    let haze = hit.t / (hit.t + 350.0);
    for k in 0..3 {
        c[k] += (SKY_HORIZON[k] - c[k]) * haze;
    }
    (c, hit.prim, Some(hit.t))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::{LayoutConfig, build_scene};
    use crate::rng::Sampler;
    use crate::sensors::sample_calib;

    #[test]
    fn pixel_rays_reproject_to_their_pixels() {
        let calib = sample_calib(&mut Sampler::new(2));
        let cam = calib.camera_model().unwrap();
        let rays = PixelRays::new(&cam);
        for (u, v) in [(0.0, 0.0), (600.0, 180.0), (1241.0, 374.0), (100.0, 300.0)] {
            let p = rays.origin + rays.dir(u, v).normalized() * 23.0;
            let (pu, pv, depth) = cam.velo_to_image(p.to_array());
            assert!(depth > 0.0);
            assert!(
                (pu - u).abs() < 1e-6 && (pv - v).abs() < 1e-6,
                "{u} {v} -> {pu} {pv}"
            );
        }
    }

    #[test]
    fn render_shows_sky_on_top_and_ground_at_the_bottom() {
        let (scene, _) = build_scene(&mut Sampler::new(4), &LayoutConfig::default());
        // A 1/6-scale camera keeps the test fast.
        let mut calib = sample_calib(&mut Sampler::new(4));
        for row in 0..2 {
            for c in 0..4 {
                calib.p[2][row][c] /= 6.0;
            }
        }
        let cam = calib.camera_model().unwrap();
        let spec = CameraSpec {
            width: 207,
            height: 62,
            ..CameraSpec::default()
        };
        let r = render(&scene, &cam, &spec);
        assert_eq!(r.image.dimensions(), (207, 62));
        // The bottom row (looking down ~10° onto the road) always hits something, and
        // the top row (looking up ~12°) sees sky somewhere.
        assert!((0..207).all(|u| r.prim_at(u, 61) != SKY));
        assert!((0..207).any(|u| r.prim_at(u, 0) == SKY));
    }
}
