//! The ten evaluated classes built from parts (legs, tops, back-rests, frames, mattresses,
//! drawer fronts, shelves...). Each piece is built in its own frame: origin at the middle of
//! its footprint on the floor, +x its front (the way it faces), +y its left, +z up. Its
//! amodal box is `[-dx/2, dx/2] × [-dy/2, dy/2] × [0, dz]` in that frame, which is SUN RGB-D's
//! convention too: `dx` runs along the heading (a sofa's depth, a bed's length), `dy` across.
//! Every part stays inside that box, so the label is the tight box of the parts.

use crate::material::{Material, Pattern};
use crate::math::{M3, Pose, V3, v3};
use crate::primitive::{Shape, Surface};
use crate::rng::Sampler;
use crate::scene::SceneBuilder;
use fusiondet_sunrgbd::SunClass;

/// A flat surface things can stand on (a table top, a shelf), in the room frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Support {
    /// Middle of the surface, z its height.
    pub center: V3,
    pub yaw: f64,
    /// Half extents along the surface's own x and y.
    pub hx: f64,
    pub hy: f64,
    /// Free height above it (the next shelf, or open).
    pub clearance: f64,
}

/// Draws a piece's size: the class mean scaled per dimension (σ 12%, kept within
/// −25%…+30%), beds by mattress width (single, double, queen, king; weighted so that their
/// mean width is SUN RGB-D's 1.6 m).
pub fn sample_size(class: SunClass, s: &mut Sampler) -> [f64; 3] {
    let m = class.mean_size();
    let mut size = m.map(|v| v * s.normal_clamped(1.0, 0.12, 0.75, 1.3));
    match class {
        SunClass::Bed => {
            size[1] =
                [0.95, 1.45, 1.65, 1.85][s.weighted(&[0.1, 0.35, 0.35, 0.2])] + s.range(0.0, 0.1);
            size[0] = s.range(1.95, 2.25);
            size[2] = size[2].max(0.8);
        }
        SunClass::Chair => {
            size[2] = size[2].max(0.7);
        }
        SunClass::Bathtub => {
            size[1] = s.range(1.5, 1.75);
            size[0] = s.range(0.68, 0.8);
        }
        _ => {}
    }
    size
}

/// A coffee table's size (a low `table`).
pub fn coffee_table_size(s: &mut Sampler) -> [f64; 3] {
    [s.range(0.5, 0.7), s.range(0.9, 1.3), s.range(0.38, 0.5)]
}

/// Colour palettes (linear RGB albedo).
const WOODS: [[f64; 3]; 5] = [
    [0.55, 0.38, 0.22],
    [0.72, 0.56, 0.38],
    [0.35, 0.22, 0.13],
    [0.82, 0.72, 0.58],
    [0.25, 0.16, 0.1],
];
const FABRICS: [[f64; 3]; 7] = [
    [0.55, 0.55, 0.58],
    [0.3, 0.35, 0.5],
    [0.6, 0.25, 0.22],
    [0.75, 0.7, 0.6],
    [0.2, 0.2, 0.22],
    [0.4, 0.5, 0.35],
    [0.85, 0.85, 0.82],
];
const METALS: [[f64; 3]; 3] = [[0.2, 0.2, 0.22], [0.6, 0.6, 0.62], [0.08, 0.08, 0.08]];
const WHITES: [[f64; 3]; 2] = [[0.92, 0.92, 0.9], [0.85, 0.86, 0.88]];
const LAMINATES: [[f64; 3]; 4] = [
    [0.9, 0.9, 0.88],
    [0.7, 0.6, 0.48],
    [0.45, 0.45, 0.47],
    [0.8, 0.78, 0.7],
];

fn tint(rgb: [f64; 3], s: &mut Sampler) -> [f64; 3] {
    let k = s.range(0.85, 1.12);
    rgb.map(|c| (c * k).clamp(0.0, 1.0))
}

fn mat(palette: &[[f64; 3]], b: &mut SceneBuilder, s: &mut Sampler) -> u16 {
    let rgb = tint(*s.pick(palette), s);
    b.material(Material::solid(rgb, 0.5))
}

/// Adds parts in one object's frame.
struct Parts<'a> {
    b: &'a mut SceneBuilder,
    pose: Pose,
    owner: u32,
}

impl Parts<'_> {
    /// An axis-aligned box from `min` to `max` (object frame).
    fn cuboid(&mut self, min: V3, max: V3, m: u16) {
        self.b.add(
            &self.pose,
            Shape::Box,
            (min + max) * 0.5,
            M3::IDENTITY,
            (max - min) * 0.5,
            m,
            Surface::Object,
            self.owner,
        );
    }

    /// A box with rounded edges (cushions, mattresses).
    fn soft(&mut self, min: V3, max: V3, m: u16) {
        let half = (max - min) * 0.5;
        self.b.add(
            &self.pose,
            Shape::RoundedBox { radii: half * 1.25 },
            (min + max) * 0.5,
            M3::IDENTITY,
            half,
            m,
            Surface::Object,
            self.owner,
        );
    }

    /// A vertical (elliptic) cylinder standing on z0 up to z1.
    #[allow(clippy::too_many_arguments)]
    fn post(&mut self, x: f64, y: f64, rx: f64, ry: f64, z0: f64, z1: f64, m: u16) {
        self.b.add(
            &self.pose,
            Shape::Cylinder,
            v3(x, y, 0.5 * (z0 + z1)),
            M3::IDENTITY,
            v3(rx, ry, 0.5 * (z1 - z0)),
            m,
            Surface::Object,
            self.owner,
        );
    }

    fn blob(&mut self, c: V3, half: V3, m: u16) {
        self.b.add(
            &self.pose,
            Shape::Ellipsoid,
            c,
            M3::IDENTITY,
            half,
            m,
            Surface::Object,
            self.owner,
        );
    }

    /// Four legs of square section `t` inset by `inset` from the footprint's corners.
    #[allow(clippy::too_many_arguments)]
    fn legs(&mut self, hx: f64, hy: f64, t: f64, inset: f64, z1: f64, m: u16, round: bool) {
        for (sx, sy) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
            let (x, y) = (sx * (hx - inset - t / 2.0), sy * (hy - inset - t / 2.0));
            if round {
                self.post(x, y, t / 2.0, t / 2.0, 0.0, z1, m);
            } else {
                self.cuboid(
                    v3(x - t / 2.0, y - t / 2.0, 0.0),
                    v3(x + t / 2.0, y + t / 2.0, z1),
                    m,
                );
            }
        }
    }

    /// The surface on top of the object at height z (room frame).
    fn support(&self, hx: f64, hy: f64, z: f64, clearance: f64) -> Support {
        let c = self.pose.point(v3(0.0, 0.0, z));
        Support {
            center: c,
            yaw: crate::math::atan2(self.pose.rot.cols[0].y, self.pose.rot.cols[0].x),
            hx,
            hy,
            clearance,
        }
    }
}

/// Builds one piece of furniture of `size` at `pose` (its frame in the room), its primitives
/// owned by `owner`; returns the surfaces clutter may stand on.
pub fn build(
    class: SunClass,
    size: [f64; 3],
    s: &mut Sampler,
    b: &mut SceneBuilder,
    pose: &Pose,
    owner: u32,
) -> Vec<Support> {
    let [dx, dy, dz] = size;
    let (hx, hy) = (dx / 2.0, dy / 2.0);
    let mut p = Parts {
        b,
        pose: *pose,
        owner,
    };
    match class {
        SunClass::Bed => {
            let wood = mat(&WOODS, p.b, s);
            let linen = mat(&FABRICS, p.b, s);
            let sheet = mat(&WHITES, p.b, s);
            let frame_top = s.range(0.25, 0.35);
            let mattress_top = (frame_top + s.range(0.18, 0.26)).min(dz - 0.15);
            p.legs(hx, hy, 0.06, 0.04, 0.1, wood, false);
            p.cuboid(v3(-hx + 0.06, -hy, 0.1), v3(hx, hy, frame_top), wood);
            p.soft(
                v3(-hx + 0.08, -hy + 0.03, frame_top),
                v3(hx - 0.02, hy - 0.03, mattress_top),
                sheet,
            );
            // Headboard at the back, the full box height.
            p.cuboid(v3(-hx, -hy, 0.0), v3(-hx + 0.06, hy, dz), wood);
            // Duvet over the foot end, a little proud of the mattress.
            let duvet_from = -hx + s.range(0.45, 0.7);
            p.soft(
                v3(duvet_from, -hy + 0.01, mattress_top - 0.08),
                v3(hx - 0.01, hy - 0.01, mattress_top + 0.04),
                linen,
            );
            let pillows = if dy > 1.3 { 2 } else { 1 };
            for k in 0..pillows {
                let yc = if pillows == 1 {
                    0.0
                } else {
                    (k as f64 - 0.5) * dy / 2.0
                };
                let py = (dy / (2.0 * pillows as f64) - 0.06).min(0.35);
                p.blob(
                    v3(-hx + 0.3, yc, mattress_top + 0.05),
                    v3(0.2, py, 0.08),
                    sheet,
                );
            }
            Vec::new()
        }
        SunClass::Table | SunClass::Desk => {
            let top_m = mat(if s.chance(0.5) { &WOODS } else { &LAMINATES }, p.b, s);
            let leg_m = if s.chance(0.5) {
                top_m
            } else {
                mat(&METALS, p.b, s)
            };
            let t = s.range(0.025, 0.05);
            p.cuboid(v3(-hx, -hy, dz - t), v3(hx, hy, dz), top_m);
            if class == SunClass::Desk {
                if s.chance(0.5) {
                    // Side panels.
                    for sy in [-1.0, 1.0] {
                        let y = sy * (hy - 0.012);
                        p.cuboid(v3(-hx, y - 0.012, 0.0), v3(hx, y + 0.012, dz - t), leg_m);
                    }
                } else {
                    p.legs(hx, hy, 0.04, 0.02, dz - t, leg_m, false);
                }
                // Modesty panel at the back.
                p.cuboid(v3(-hx, -hy, 0.35), v3(-hx + 0.02, hy, dz - t), leg_m);
                if s.chance(0.6) {
                    // A drawer pedestal on one side.
                    let side = if s.chance(0.5) { 1.0 } else { -1.0 };
                    let w = 0.4f64.min(dy / 3.0);
                    let (y0, y1) = if side > 0.0 {
                        (hy - 0.03 - w, hy - 0.03)
                    } else {
                        (-hy + 0.03, -hy + 0.03 + w)
                    };
                    p.cuboid(v3(-hx + 0.05, y0, 0.02), v3(hx - 0.02, y1, dz - t), top_m);
                }
            } else if dx.min(dy) < 0.8 && s.chance(0.3) {
                // A pedestal table.
                p.post(0.0, 0.0, 0.05, 0.05, 0.03, dz - t, leg_m);
                p.post(0.0, 0.0, hx * 0.7, hy * 0.7, 0.0, 0.03, leg_m);
            } else {
                p.legs(
                    hx,
                    hy,
                    s.range(0.035, 0.07),
                    0.03,
                    dz - t,
                    leg_m,
                    s.chance(0.4),
                );
                // Apron under the top.
                p.cuboid(
                    v3(-hx + 0.04, -hy + 0.04, dz - t - 0.08),
                    v3(hx - 0.04, hy - 0.04, dz - t),
                    top_m,
                );
            }
            vec![p.support(hx, hy, dz, 2.0)]
        }
        SunClass::Sofa => {
            let fabric = mat(&FABRICS, p.b, s);
            let cushion = if s.chance(0.6) {
                fabric
            } else {
                mat(&FABRICS, p.b, s)
            };
            let feet = mat(&METALS, p.b, s);
            let seat = s.range(0.38, 0.46);
            let arm = s.range(0.12, 0.22).min(dy / 6.0);
            let back = s.range(0.16, 0.25).min(dx / 3.0);
            p.legs(hx, hy, 0.05, 0.05, 0.08, feet, false);
            p.soft(
                v3(-hx + back, -hy + arm, 0.08),
                v3(hx, hy - arm, seat - 0.1),
                fabric,
            );
            p.soft(v3(-hx, -hy, 0.08), v3(-hx + back, hy, dz), fabric);
            for sy in [-1.0, 1.0] {
                let (y0, y1) = if sy > 0.0 {
                    (hy - arm, hy)
                } else {
                    (-hy, -hy + arm)
                };
                p.soft(
                    v3(-hx, y0, 0.08),
                    v3(hx, y1, (seat + s.range(0.1, 0.22)).min(dz)),
                    fabric,
                );
            }
            let n = if dy > 1.6 { 3 } else { 2 };
            let inner = dy - 2.0 * arm;
            for k in 0..n {
                let y0 = -hy + arm + inner * k as f64 / n as f64;
                p.soft(
                    v3(-hx + back, y0 + 0.01, seat - 0.1),
                    v3(hx - 0.02, y0 + inner / n as f64 - 0.01, seat),
                    cushion,
                );
            }
            Vec::new()
        }
        SunClass::Chair => {
            let seat_h = s.range(0.42, 0.48).min(dz - 0.2);
            if s.chance(0.4) {
                // Office chair: star base, gas column, padded seat and back.
                let metal = mat(&METALS, p.b, s);
                let pad = mat(&FABRICS, p.b, s);
                let r = hx.min(hy) - 0.02;
                for k in 0..5 {
                    let a = k as f64 * std::f64::consts::TAU / 5.0;
                    let (sa, ca) = (crate::math::sin(a), crate::math::cos(a));
                    p.b.add(
                        &p.pose,
                        Shape::Box,
                        v3(ca * r / 2.0, sa * r / 2.0, 0.05),
                        M3::rot_z(a),
                        v3(r / 2.0, 0.02, 0.02),
                        metal,
                        Surface::Object,
                        owner,
                    );
                }
                p.post(0.0, 0.0, 0.03, 0.03, 0.07, seat_h - 0.06, metal);
                p.soft(
                    v3(-hx + 0.05, -hy + 0.04, seat_h - 0.08),
                    v3(hx - 0.03, hy - 0.04, seat_h),
                    pad,
                );
                p.soft(
                    v3(-hx, -hy + 0.06, seat_h + 0.08),
                    v3(-hx + 0.07, hy - 0.06, dz),
                    pad,
                );
                p.cuboid(
                    v3(-hx + 0.02, -0.03, seat_h),
                    v3(-hx + 0.05, 0.03, seat_h + 0.1),
                    metal,
                );
            } else {
                let wood = mat(if s.chance(0.6) { &WOODS } else { &METALS }, p.b, s);
                let seat_m = if s.chance(0.5) {
                    wood
                } else {
                    mat(&FABRICS, p.b, s)
                };
                p.legs(hx, hy, 0.035, 0.01, seat_h - 0.04, wood, s.chance(0.4));
                p.cuboid(v3(-hx, -hy, seat_h - 0.04), v3(hx, hy, seat_h), seat_m);
                // Back posts and back-rest.
                for sy in [-1.0, 1.0] {
                    let y = sy * (hy - 0.03);
                    p.cuboid(
                        v3(-hx, y - 0.017, seat_h),
                        v3(-hx + 0.035, y + 0.017, dz),
                        wood,
                    );
                }
                let rest_from = seat_h + s.range(0.15, 0.3);
                p.cuboid(
                    v3(-hx + 0.005, -hy + 0.04, rest_from.min(dz - 0.08)),
                    v3(-hx + 0.03, hy - 0.04, dz - 0.01),
                    seat_m,
                );
            }
            Vec::new()
        }
        SunClass::Toilet => {
            let white = mat(&WHITES, p.b, s);
            let tank_d = 0.18f64.min(dx * 0.3);
            let seat_h = s.range(0.38, 0.43).min(dz - 0.2);
            // Tank against the wall, the full width.
            p.cuboid(v3(-hx, -hy, seat_h), v3(-hx + tank_d, hy, dz), white);
            let bowl_len = dx - tank_d;
            let bowl_x = -hx + tank_d + bowl_len / 2.0;
            p.post(
                -hx + tank_d + 0.12,
                0.0,
                0.12,
                (hy - 0.08).max(0.08),
                0.0,
                seat_h - 0.12,
                white,
            );
            p.blob(
                v3(bowl_x, 0.0, seat_h - 0.12),
                v3(bowl_len / 2.0, hy - 0.02, 0.12),
                white,
            );
            p.post(
                bowl_x,
                0.0,
                bowl_len / 2.0 - 0.01,
                hy - 0.03,
                seat_h - 0.03,
                seat_h,
                white,
            );
            Vec::new()
        }
        SunClass::Dresser | SunClass::NightStand => {
            let body = mat(if s.chance(0.7) { &WOODS } else { &LAMINATES }, p.b, s);
            let front = if s.chance(0.6) {
                body
            } else {
                mat(&LAMINATES, p.b, s)
            };
            let knob = mat(&METALS, p.b, s);
            let plinth = if s.chance(0.5) { 0.08 } else { 0.0 };
            if plinth > 0.0 {
                if s.chance(0.5) {
                    p.legs(hx, hy, 0.04, 0.02, plinth, body, true);
                } else {
                    p.cuboid(
                        v3(-hx + 0.03, -hy + 0.03, 0.0),
                        v3(hx - 0.05, hy - 0.03, plinth),
                        body,
                    );
                }
            }
            p.cuboid(v3(-hx, -hy, plinth), v3(hx - 0.02, hy, dz), body);
            let rows = if class == SunClass::Dresser {
                s.int(3, 5) as usize
            } else {
                s.int(1, 3) as usize
            };
            let cols = if class == SunClass::Dresser && dy > 0.9 && s.chance(0.5) {
                2
            } else {
                1
            };
            let (z0, z1) = (plinth + 0.02, dz - 0.03);
            for r in 0..rows {
                let (a, c) = (
                    z0 + (z1 - z0) * r as f64 / rows as f64,
                    z0 + (z1 - z0) * (r + 1) as f64 / rows as f64,
                );
                for k in 0..cols {
                    let y0 = -hy + 0.02 + (dy - 0.04) * k as f64 / cols as f64;
                    let y1 = -hy + 0.02 + (dy - 0.04) * (k + 1) as f64 / cols as f64;
                    p.cuboid(
                        v3(hx - 0.02, y0 + 0.005, a + 0.005),
                        v3(hx, y1 - 0.005, c - 0.005),
                        front,
                    );
                    let (ym, zm) = (0.5 * (y0 + y1), 0.5 * (a + c));
                    p.cuboid(
                        v3(hx - 0.02, ym - 0.05, zm - 0.01),
                        v3(hx, ym + 0.05, zm + 0.01),
                        knob,
                    );
                }
            }
            vec![p.support(hx, hy, dz, 2.0)]
        }
        SunClass::Bookshelf => {
            let wood = mat(if s.chance(0.6) { &WOODS } else { &LAMINATES }, p.b, s);
            let t = 0.02;
            p.cuboid(v3(-hx, -hy, 0.0), v3(-hx + 0.01, hy, dz), wood);
            for sy in [-1.0, 1.0] {
                let y = sy * (hy - t / 2.0);
                p.cuboid(v3(-hx, y - t / 2.0, 0.0), v3(hx, y + t / 2.0, dz), wood);
            }
            p.cuboid(v3(-hx, -hy, dz - t), v3(hx, hy, dz), wood);
            let shelves = ((dz / 0.35).round() as usize).clamp(2, 7);
            let step = (dz - 0.06 - t) / shelves as f64;
            let mut supports = Vec::new();
            for k in 0..shelves {
                let z = 0.06 + step * k as f64;
                p.cuboid(v3(-hx + 0.01, -hy + t, z - t), v3(hx, hy - t, z), wood);
                supports.push(p.support(hx - 0.03, hy - t - 0.01, z, step - t - 0.01));
            }
            supports
        }
        SunClass::Bathtub => {
            let white = mat(&WHITES, p.b, s);
            let w = 0.07;
            p.cuboid(v3(-hx, -hy, 0.0), v3(hx, hy, 0.08), white);
            for sx in [-1.0, 1.0] {
                let x = sx * (hx - w / 2.0);
                p.cuboid(v3(x - w / 2.0, -hy, 0.0), v3(x + w / 2.0, hy, dz), white);
            }
            for sy in [-1.0, 1.0] {
                let y = sy * (hy - w / 2.0);
                p.cuboid(
                    v3(-hx + w, y - w / 2.0, 0.0),
                    v3(hx - w, y + w / 2.0, dz),
                    white,
                );
            }
            Vec::new()
        }
    }
}

/// The floor patterns and wall colours of rooms (here because they share the palettes).
pub fn floor_material(b: &mut SceneBuilder, s: &mut Sampler, tiles: bool) -> u16 {
    let rgb = if tiles {
        tint(
            *s.pick(&[[0.8, 0.8, 0.78], [0.6, 0.6, 0.62], [0.75, 0.7, 0.62]]),
            s,
        )
    } else if s.chance(0.6) {
        tint(*s.pick(&WOODS), s)
    } else {
        tint(*s.pick(&FABRICS), s)
    };
    let pattern = if tiles {
        Pattern::Pavers {
            size: s.range(0.3, 0.6),
        }
    } else {
        Pattern::Speckle { amount: 0.08 }
    };
    b.material(Material::solid(rgb, 0.5).with_pattern(pattern))
}

/// A wall paint.
pub fn wall_material(b: &mut SceneBuilder, s: &mut Sampler) -> u16 {
    let rgb = *s.pick(&[
        [0.9, 0.88, 0.82],
        [0.85, 0.85, 0.85],
        [0.8, 0.82, 0.7],
        [0.75, 0.8, 0.85],
        [0.88, 0.78, 0.68],
    ]);
    let rgb = tint(rgb, s);
    b.material(Material::solid(rgb, 0.5))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every part of every class stays inside the piece's amodal box, so the label is the
    /// parts' box.
    #[test]
    fn parts_stay_inside_the_box() {
        let mut s = Sampler::new(3);
        for class in SunClass::ALL {
            for _ in 0..20 {
                let size = sample_size(class, &mut s);
                let mut b = SceneBuilder::new();
                let yaw = s.range(-3.0, 3.0);
                let pose = Pose {
                    rot: M3::rot_z(yaw),
                    t: v3(2.0, 3.0, 0.0),
                };
                build(class, size, &mut s, &mut b, &pose, 0);
                assert!(!b.prims.is_empty());
                let inv = |p: V3| pose.rot.apply_t(p - pose.t);
                for prim in &b.prims {
                    // The local box's corners (a bound on every shape used).
                    let bb = prim.aabb();
                    let h = prim.half;
                    for k in 0..8 {
                        let l = v3(
                            if k & 1 == 0 { -h.x } else { h.x },
                            if k & 2 == 0 { -h.y } else { h.y },
                            if k & 4 == 0 { -h.z } else { h.z },
                        );
                        let q = inv(prim.center + prim.rot.apply(l));
                        let tol = 1e-9;
                        assert!(
                            q.x.abs() <= size[0] / 2.0 + tol
                                && q.y.abs() <= size[1] / 2.0 + tol
                                && q.z >= -tol
                                && q.z <= size[2] + tol,
                            "{class}: part corner {q:?} outside {size:?} ({bb:?})"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn sizes_scatter_around_the_class_means() {
        let mut s = Sampler::new(1);
        for class in SunClass::ALL {
            let n = 400;
            let mut mean = [0.0; 3];
            for _ in 0..n {
                let sz = sample_size(class, &mut s);
                for k in 0..3 {
                    mean[k] += sz[k] / n as f64;
                }
            }
            let m = class.mean_size();
            for k in 0..3 {
                assert!(
                    (mean[k] / m[k] - 1.0).abs() < 0.2,
                    "{class} dim {k}: {} vs {}",
                    mean[k],
                    m[k]
                );
            }
        }
    }
}
