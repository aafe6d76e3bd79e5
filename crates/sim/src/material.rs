//! Surface materials: what the camera sees (colour, procedural pattern) and what the
//! LiDAR gets back (reflectance, return probability, porosity), evaluated per hit.
//!
//! LiDAR reflectance values are calibrated to KITTI's `reflectance` channel as
//! measured on the real frames: road and pavement ≈ 0.29, façades and vegetation
//! 0.1–0.5, car paint mostly near 0 (two thirds of KITTI's car points read 0.00),
//! licence plates, reflectors and signs close to 1.

use crate::math::V3;
use crate::rng::hash_unit;

/// A procedural pattern modulating a material by position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pattern {
    Plain,
    /// Brightness noise of ±`amount` (reflectance ±2·`amount`) on a 0.5 m grid
    /// (asphalt, dirt, grass).
    Speckle {
        amount: f64,
    },
    /// Paving slabs: darker joints every `size` metres.
    Pavers {
        size: f64,
    },
    /// A building façade with a grid of windows (glass returns few LiDAR points).
    Facade {
        storey: f64,
        spacing: f64,
        window_rgb: [f64; 3],
        ground_floor: f64,
    },
    /// A cabin: painted roof, pillars and sills; glass on the sides from
    /// `glass_from` (in units of the half-length, −1 = the whole length) to the front.
    Cabin {
        glass_rgb: [f64; 3],
        glass_from: f64,
    },
    /// Foliage: strong brightness variation.
    Leaves,
}

/// One material of the scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Material {
    /// Linear RGB albedo in [0, 1].
    pub rgb: [f64; 3],
    /// LiDAR reflectance at normal incidence (KITTI's reflectance channel).
    pub reflectance: f64,
    /// Probability that a beam hitting this surface returns at all (glass < 1).
    pub return_prob: f64,
    /// Mean free path in metres of a beam inside a porous volume (foliage); 0 = solid.
    pub free_path: f64,
    pub pattern: Pattern,
}

impl Material {
    pub const fn solid(rgb: [f64; 3], reflectance: f64) -> Material {
        Material {
            rgb,
            reflectance,
            return_prob: 1.0,
            free_path: 0.0,
            pattern: Pattern::Plain,
        }
    }
    pub const fn with_pattern(mut self, pattern: Pattern) -> Material {
        self.pattern = pattern;
        self
    }
    pub const fn porous(mut self, free_path: f64) -> Material {
        self.free_path = free_path;
        self
    }
    pub const fn glassy(mut self, return_prob: f64) -> Material {
        self.return_prob = return_prob;
        self
    }
}

/// The material as seen at one point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceSample {
    pub rgb: [f64; 3],
    pub reflectance: f64,
    pub return_prob: f64,
}

fn scale(rgb: [f64; 3], s: f64) -> [f64; 3] {
    [rgb[0] * s, rgb[1] * s, rgb[2] * s]
}

/// Glass: dark, specular, and most beams do not come back.
const GLASS_REFLECTANCE: f64 = 0.0;
const GLASS_RETURN: f64 = 0.35;

impl Material {
    /// Evaluates the material at a hit: `local` is the hit point and `local_n` the
    /// normal in the primitive's frame, `half` its half-extents, `world` the point
    /// in the scene frame (for patterns that must continue across primitives).
    pub fn sample(&self, local: V3, local_n: V3, half: V3, world: V3) -> SurfaceSample {
        let base = SurfaceSample {
            rgb: self.rgb,
            reflectance: self.reflectance,
            return_prob: self.return_prob,
        };
        match self.pattern {
            Pattern::Plain => base,
            Pattern::Speckle { amount } => {
                let cell = hash_unit(
                    0x51EC,
                    (world.x * 2.0).floor() as i64 as u64,
                    (world.y * 2.0).floor() as i64 as u64,
                );
                let s = 1.0 + amount * (cell - 0.5) * 2.0;
                SurfaceSample {
                    rgb: scale(self.rgb, s),
                    reflectance: self.reflectance * (1.0 + 2.0 * amount * (cell - 0.5)),
                    ..base
                }
            }
            Pattern::Pavers { size } => {
                let fx = (world.x / size).fract().abs();
                let fy = (world.y / size).fract().abs();
                let joint = fx < 0.04 || fy < 0.04;
                SurfaceSample {
                    rgb: if joint {
                        scale(self.rgb, 0.8)
                    } else {
                        self.rgb
                    },
                    ..base
                }
            }
            Pattern::Facade {
                storey,
                spacing,
                window_rgb,
                ground_floor,
            } => {
                if local_n.z.abs() > 0.5 {
                    return SurfaceSample {
                        rgb: scale(self.rgb, 0.7),
                        ..base
                    };
                }
                // Horizontal coordinate along the face, height above the ground.
                let along = if local_n.x.abs() > local_n.y.abs() {
                    local.y + half.y
                } else {
                    local.x + half.x
                };
                let z = local.z + half.z;
                if z < ground_floor {
                    return SurfaceSample {
                        rgb: scale(self.rgb, 0.8),
                        ..base
                    };
                }
                let fa = (along / spacing).fract();
                let fz = ((z - ground_floor) / storey).fract();
                let window = (0.25..0.75).contains(&fa) && (0.3..0.85).contains(&fz);
                if window {
                    SurfaceSample {
                        rgb: window_rgb,
                        reflectance: GLASS_REFLECTANCE,
                        return_prob: GLASS_RETURN,
                    }
                } else {
                    base
                }
            }
            Pattern::Cabin {
                glass_rgb,
                glass_from,
            } => {
                // Roof (faces up), the pillars at the ends and the sills stay painted.
                let roof = local_n.z > 0.55;
                let pillar = local.x.abs() > 0.88 * half.x && local_n.x.abs() < 0.5;
                let sill = local.z < -0.75 * half.z;
                let painted_part = glass_from > -1.0 && local.x < glass_from * half.x;
                if roof || pillar || sill || painted_part {
                    base
                } else {
                    SurfaceSample {
                        rgb: glass_rgb,
                        reflectance: GLASS_REFLECTANCE,
                        return_prob: GLASS_RETURN,
                    }
                }
            }
            Pattern::Leaves => {
                let cell = hash_unit(
                    0x1EAF,
                    (world.x * 3.0).floor() as i64 as u64,
                    ((world.y * 3.0).floor() as i64 as u64)
                        ^ (((world.z * 3.0).floor() as i64 as u64) << 20),
                );
                SurfaceSample {
                    rgb: scale(self.rgb, 0.65 + 0.7 * cell),
                    reflectance: self.reflectance * (0.6 + 0.8 * cell),
                    ..base
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::v3;

    #[test]
    fn facade_has_windows_and_walls() {
        let m = Material::solid([0.8, 0.7, 0.6], 0.3).with_pattern(Pattern::Facade {
            storey: 3.0,
            spacing: 3.0,
            window_rgb: [0.1, 0.1, 0.2],
            ground_floor: 3.5,
        });
        let half = v3(10.0, 5.0, 8.0);
        let n = v3(0.0, -1.0, 0.0);
        // Middle of a window bay on the second storey.
        let win = m.sample(v3(1.5 - 10.0, -5.0, 3.5 + 1.7 - 8.0), n, half, V3::ZERO);
        assert!(win.return_prob < 1.0);
        let wall = m.sample(v3(0.1 - 10.0, -5.0, 3.5 + 1.7 - 8.0), n, half, V3::ZERO);
        assert_eq!(wall.return_prob, 1.0);
        let ground = m.sample(v3(1.5 - 10.0, -5.0, 1.0 - 8.0), n, half, V3::ZERO);
        assert_eq!(ground.return_prob, 1.0);
    }

    #[test]
    fn cabin_roof_is_paint_sides_are_glass() {
        let m = Material::solid([0.5, 0.0, 0.0], 0.05).with_pattern(Pattern::Cabin {
            glass_rgb: [0.1, 0.1, 0.1],
            glass_from: -1.0,
        });
        let half = v3(1.0, 0.7, 0.3);
        let roof = m.sample(v3(0.0, 0.0, 0.3), V3::Z, half, V3::ZERO);
        assert_eq!(roof.rgb, [0.5, 0.0, 0.0]);
        let side = m.sample(v3(0.0, 0.7, 0.0), V3::Y, half, V3::ZERO);
        assert!(side.return_prob < 1.0);
    }
}
