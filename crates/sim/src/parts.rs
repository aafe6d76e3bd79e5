//! Object part models. Each labelled object is built from several solids in its own
//! frame (origin at the bottom centre, x forward, y left, z up) so that its point
//! pattern is not a plain box: a car's rounded lower body, glass cabin and wheels
//! under the body line; a person's legs, torso, arms and head; a cyclist's bike and
//! rider. Dimensions follow KITTI's label statistics (mean ± std of h, w, l).

use crate::material::{Material, Pattern};
use crate::math::{M3, Pose, V3, rad, v3};
use crate::primitive::{Shape, Surface};
use crate::rng::Sampler;
use crate::scene::SceneBuilder;
use fusiondet_kitti::ObjectClass;
use std::f64::consts::FRAC_PI_2;

/// Label dimensions (l, w, h) drawn from KITTI's per-class statistics, with one shared
/// size factor so that long cars are also a little wider and taller.
pub fn sample_dims(class: ObjectClass, s: &mut Sampler) -> (f64, f64, f64) {
    // (mean, std, min, max) of h, w, l as in KITTI's training labels.
    let stats: [(f64, f64, f64, f64); 3] = match class {
        ObjectClass::Car => [
            (1.53, 0.14, 1.25, 2.0),
            (1.63, 0.10, 1.38, 2.0),
            (3.88, 0.43, 2.9, 5.2),
        ],
        ObjectClass::Van => [
            (2.21, 0.30, 1.75, 2.9),
            (1.90, 0.16, 1.6, 2.3),
            (5.08, 0.70, 3.9, 6.6),
        ],
        ObjectClass::Truck => [
            (3.25, 0.45, 2.5, 4.0),
            (2.59, 0.22, 2.2, 3.0),
            (10.1, 2.8, 5.5, 16.5),
        ],
        ObjectClass::Cyclist => [
            (1.74, 0.09, 1.5, 1.95),
            (0.60, 0.12, 0.4, 0.9),
            (1.76, 0.17, 1.4, 2.1),
        ],
        _ => [
            (1.76, 0.11, 1.45, 2.0),
            (0.66, 0.14, 0.4, 1.0),
            (0.84, 0.23, 0.4, 1.3),
        ],
    };
    let common = s.normal();
    let mut draw = |(m, sd, lo, hi): (f64, f64, f64, f64)| {
        let z = 0.6 * common + 0.8 * s.normal();
        (m + sd * z).clamp(lo, hi)
    };
    let h = draw(stats[0]);
    let w = draw(stats[1]);
    let l = draw(stats[2]);
    (l, w, h)
}

/// A paint: camera colour and LiDAR reflectance. Most car paints read close to 0 in
/// KITTI's reflectance channel; silver and white ones somewhat higher.
pub fn car_paint(s: &mut Sampler) -> ([f64; 3], f64) {
    const COLOURS: [([f64; 3], f64); 8] = [
        ([0.55, 0.56, 0.58], 0.22), // silver
        ([0.32, 0.33, 0.35], 0.14), // grey
        ([0.05, 0.05, 0.06], 0.22), // black
        ([0.85, 0.85, 0.83], 0.14), // white
        ([0.10, 0.16, 0.38], 0.10), // blue
        ([0.55, 0.08, 0.07], 0.08), // red
        ([0.12, 0.25, 0.15], 0.04), // green
        ([0.60, 0.50, 0.30], 0.06), // beige
    ];
    let weights: Vec<f64> = COLOURS.iter().map(|c| c.1).collect();
    let (rgb, _) = COLOURS[s.weighted(&weights)];
    let jitter = s.range(0.9, 1.1);
    let rgb = [rgb[0] * jitter, rgb[1] * jitter, rgb[2] * jitter];
    let reflectance = if s.chance(0.6) {
        s.range(0.0, 0.004)
    } else {
        let u = s.unit();
        0.01 + 0.3 * u * u
    };
    (rgb, reflectance)
}

const GLASS_RGB: [f64; 3] = [0.07, 0.09, 0.11];

struct Parts<'a> {
    b: &'a mut SceneBuilder,
    pose: Pose,
    owner: u32,
    surface: Surface,
}

impl Parts<'_> {
    fn add(&mut self, shape: Shape, center: V3, rot: M3, half: V3, material: u16) {
        let (pose, owner, surface) = (self.pose, self.owner, self.surface);
        self.b
            .add(&pose, shape, center, rot, half, material, surface, owner);
    }
    /// A solid between two points (an ellipsoid or a cylinder of `radius` along the segment).
    fn limb(&mut self, shape: Shape, a: V3, b: V3, radius: V3, material: u16) {
        let d = b - a;
        let len = d.norm();
        let rot = along(d);
        self.add(
            shape,
            (a + b) * 0.5,
            rot,
            v3(radius.x, radius.y, len * 0.5),
            material,
        );
    }
}

/// A rotation whose local z axis points along `d`.
fn along(d: V3) -> M3 {
    let z = d.normalized();
    let helper = if z.z.abs() < 0.9 { V3::Z } else { V3::X };
    let x = helper.cross(z).normalized();
    let y = z.cross(x);
    M3 { cols: [x, y, z] }
}

/// A wheel: a short cylinder whose axis is the object's y axis.
fn wheel_rot() -> M3 {
    M3::rot_x(FRAC_PI_2)
}

/// Car: rounded lower body, cabin (glass sides, painted roof and pillars), four
/// wheels reaching below the body, licence plates (bright in LiDAR reflectance).
pub fn car(
    b: &mut SceneBuilder,
    s: &mut Sampler,
    pose: &Pose,
    dims: (f64, f64, f64),
    parked: bool,
) {
    let (l, w, h) = dims;
    let first = b.prims.len();
    let owner = b.begin_actor();
    let (rgb, refl) = car_paint(s);
    let paint = b.material(Material::solid(rgb, refl));
    let cabin = b.material(Material::solid(rgb, refl).with_pattern(Pattern::Cabin {
        glass_rgb: GLASS_RGB,
        glass_from: -1.0,
    }));
    let tyre = b.material(Material::solid([0.04, 0.04, 0.04], 0.0));
    let plate = b.material(Material::solid([0.9, 0.9, 0.85], 0.9));
    let mut p = Parts {
        b,
        pose: *pose,
        owner,
        surface: Surface::Object,
    };
    let clear = s.range(0.16, 0.24);
    let r_wheel = (0.31 + 0.08 * (h - 1.5)).clamp(0.28, 0.37);
    let belt = h * s.range(0.55, 0.62);
    let lower = v3(l / 2.0, w / 2.0, (belt - clear) / 2.0);
    p.add(
        Shape::RoundedBox {
            radii: v3(lower.x * 1.12, lower.y * 1.3, lower.z * 2.4),
        },
        v3(0.0, 0.0, (belt + clear) / 2.0),
        M3::IDENTITY,
        lower,
        paint,
    );
    let lc = l * s.range(0.46, 0.56);
    let xc = -l * s.range(0.02, 0.08);
    let top = v3(lc / 2.0, w * 0.43, (h - belt + 0.03) / 2.0);
    p.add(
        Shape::RoundedBox {
            radii: v3(top.x * 1.08, top.y * 1.4, top.z * 1.7),
        },
        v3(xc, 0.0, belt - 0.03 + top.z),
        M3::IDENTITY,
        top,
        cabin,
    );
    let (front, rear) = (s.range(0.78, 0.95), s.range(0.7, 0.9));
    for (x, y) in [
        (l / 2.0 - front, 1.0),
        (l / 2.0 - front, -1.0),
        (-l / 2.0 + rear, 1.0),
        (-l / 2.0 + rear, -1.0),
    ] {
        p.add(
            Shape::Cylinder,
            v3(x, y * (w / 2.0 - 0.13), r_wheel),
            wheel_rot(),
            v3(r_wheel, r_wheel, 0.11),
            tyre,
        );
    }
    for x in [l / 2.0 - 0.01, -l / 2.0 + 0.01] {
        p.add(
            Shape::Box,
            v3(x, 0.0, clear + 0.25),
            M3::IDENTITY,
            v3(0.02, 0.26, 0.06),
            plate,
        );
    }
    p.b.end_actor(ObjectClass::Car, pose, l, w, h, first, parked);
}

/// Van: tall body with glass only in the front cabin, short bonnet, four wheels.
pub fn van(
    b: &mut SceneBuilder,
    s: &mut Sampler,
    pose: &Pose,
    dims: (f64, f64, f64),
    parked: bool,
) {
    let (l, w, h) = dims;
    let first = b.prims.len();
    let owner = b.begin_actor();
    let (rgb, refl) = if s.chance(0.5) {
        ([0.85, 0.85, 0.84], s.range(0.05, 0.3))
    } else {
        car_paint(s)
    };
    let paint = b.material(Material::solid(rgb, refl));
    let cabin = b.material(Material::solid(rgb, refl).with_pattern(Pattern::Cabin {
        glass_rgb: GLASS_RGB,
        glass_from: 0.45,
    }));
    let tyre = b.material(Material::solid([0.04, 0.04, 0.04], 0.0));
    let plate = b.material(Material::solid([0.9, 0.9, 0.85], 0.9));
    let mut p = Parts {
        b,
        pose: *pose,
        owner,
        surface: Surface::Object,
    };
    let clear = 0.22;
    let r_wheel = 0.34;
    let hood = s.range(0.5, 0.9);
    let belt = 0.5 * h;
    let lower = v3(l / 2.0, w / 2.0, (belt - clear) / 2.0);
    p.add(
        Shape::RoundedBox {
            radii: v3(lower.x * 1.06, lower.y * 1.3, lower.z * 2.5),
        },
        v3(0.0, 0.0, (belt + clear) / 2.0),
        M3::IDENTITY,
        lower,
        paint,
    );
    let upper = v3((l - hood) / 2.0, w / 2.0 - 0.02, (h - belt + 0.02) / 2.0);
    p.add(
        Shape::RoundedBox {
            radii: v3(upper.x * 1.08, upper.y * 1.25, upper.z * 2.0),
        },
        v3(-hood / 2.0, 0.0, belt - 0.02 + upper.z),
        M3::IDENTITY,
        upper,
        cabin,
    );
    for (x, y) in [
        (l / 2.0 - 0.9, 1.0),
        (l / 2.0 - 0.9, -1.0),
        (-l / 2.0 + 1.0, 1.0),
        (-l / 2.0 + 1.0, -1.0),
    ] {
        p.add(
            Shape::Cylinder,
            v3(x, y * (w / 2.0 - 0.14), r_wheel),
            wheel_rot(),
            v3(r_wheel, r_wheel, 0.12),
            tyre,
        );
    }
    p.add(
        Shape::Box,
        v3(-l / 2.0 + 0.01, 0.0, 0.5),
        M3::IDENTITY,
        v3(0.02, 0.26, 0.06),
        plate,
    );
    p.b.end_actor(ObjectClass::Van, pose, l, w, h, first, parked);
}

/// Truck: cab with windscreen, box body, chassis and three axles.
pub fn truck(
    b: &mut SceneBuilder,
    s: &mut Sampler,
    pose: &Pose,
    dims: (f64, f64, f64),
    parked: bool,
) {
    let (l, w, h) = dims;
    let first = b.prims.len();
    let owner = b.begin_actor();
    let (cab_rgb, cab_refl) = car_paint(s);
    let body_rgb = *s.pick(&[
        [0.8, 0.8, 0.78],
        [0.6, 0.1, 0.1],
        [0.2, 0.3, 0.5],
        [0.75, 0.7, 0.6],
    ]);
    let cab = b.material(
        Material::solid(cab_rgb, cab_refl).with_pattern(Pattern::Cabin {
            glass_rgb: GLASS_RGB,
            glass_from: 0.3,
        }),
    );
    let cab_low = b.material(Material::solid(cab_rgb, cab_refl));
    let body = b.material(Material::solid(body_rgb, s.range(0.1, 0.4)));
    let dark = b.material(Material::solid([0.05, 0.05, 0.05], 0.03));
    let mut p = Parts {
        b,
        pose: *pose,
        owner,
        surface: Surface::Object,
    };
    let cab_len = s.range(1.9, 2.4);
    let cab_h = (h * 0.85).min(3.0);
    let r = 0.5;
    let xf = l / 2.0 - cab_len / 2.0;
    p.add(
        Shape::Box,
        v3(xf, 0.0, (0.4 + 1.5) / 2.0),
        M3::IDENTITY,
        v3(cab_len / 2.0, w / 2.0 - 0.05, (1.5 - 0.4) / 2.0),
        cab_low,
    );
    let upper = v3(cab_len / 2.0, w / 2.0 - 0.08, (cab_h - 1.5) / 2.0);
    p.add(
        Shape::RoundedBox {
            radii: v3(upper.x * 1.15, upper.y * 1.3, upper.z * 1.8),
        },
        v3(xf, 0.0, 1.5 + upper.z),
        M3::IDENTITY,
        upper,
        cab,
    );
    let body_len = l - cab_len - 0.25;
    p.add(
        Shape::Box,
        v3(-l / 2.0 + body_len / 2.0, 0.0, (1.1 + h) / 2.0),
        M3::IDENTITY,
        v3(body_len / 2.0, w / 2.0, (h - 1.1) / 2.0),
        body,
    );
    p.add(
        Shape::Box,
        v3(-cab_len / 2.0, 0.0, 0.8),
        M3::IDENTITY,
        v3((l - cab_len) / 2.0, w / 2.0 - 0.4, 0.3),
        dark,
    );
    for x in [l / 2.0 - cab_len / 2.0, -l / 2.0 + 2.2, -l / 2.0 + 1.0] {
        for y in [1.0, -1.0] {
            p.add(
                Shape::Cylinder,
                v3(x, y * (w / 2.0 - 0.2), r),
                wheel_rot(),
                v3(r, r, 0.18),
                dark,
            );
        }
    }
    p.b.end_actor(ObjectClass::Truck, pose, l, w, h, first, parked);
}

/// Clothing: camera colour and LiDAR reflectance (fabric is brighter than car paint).
fn clothes(s: &mut Sampler) -> ([f64; 3], f64) {
    let rgb = *s.pick(&[
        [0.08, 0.08, 0.1],
        [0.15, 0.2, 0.35],
        [0.5, 0.5, 0.5],
        [0.75, 0.72, 0.65],
        [0.55, 0.15, 0.12],
        [0.2, 0.35, 0.2],
        [0.85, 0.85, 0.85],
        [0.35, 0.25, 0.18],
    ]);
    (rgb, s.range(0.15, 0.5))
}

/// A person in walking (or standing) pose. `phase` in [-1, 1] sets the stride.
fn person(
    p: &mut Parts<'_>,
    s: &mut Sampler,
    h: f64,
    w: f64,
    l: f64,
    phase: f64,
    seat: Option<V3>,
) {
    let (top_rgb, top_refl) = clothes(s);
    let (leg_rgb, leg_refl) = clothes(s);
    let top = p.b.material(Material::solid(top_rgb, top_refl));
    let legs = p.b.material(Material::solid(leg_rgb, leg_refl));
    let skin = p.b.material(Material::solid([0.75, 0.58, 0.48], 0.35));
    let hip_z = 0.53 * h;
    let head_r = 0.105 * h / 1.76;
    let hip_w = 0.1 * w / 0.66 + 0.02;
    let shoulder_w = (w / 2.0 - 0.07).max(0.14);
    // The neck sits so that the top of the head is at `h`.
    let neck_z = h - 2.2 * head_r - 0.02;
    let (hip, lean) = match seat {
        Some(seat) => (seat, rad(s.range(15.0, 35.0))),
        None => (v3(0.0, 0.0, hip_z), rad(s.range(0.0, 6.0))),
    };
    let (ls, lc) = (crate::math::sin(lean), crate::math::cos(lean));
    let torso_len = (neck_z - hip.z) / lc;
    let neck = hip + v3(torso_len * ls, 0.0, torso_len * lc);
    p.limb(
        Shape::Ellipsoid,
        hip,
        neck + v3(0.0, 0.0, 0.04),
        v3(0.12 + 0.05 * (l - 0.84).max(0.0), shoulder_w * 0.95, 0.0),
        top,
    );
    p.add(
        Shape::Ellipsoid,
        neck + v3(0.02, 0.0, 1.1 * head_r + 0.02),
        M3::IDENTITY,
        v3(head_r * 0.95, head_r * 0.85, head_r * 1.1),
        skin,
    );
    if seat.is_none() {
        // Legs: feet apart along x by the stride.
        let stride = (l - 0.28).max(0.05) * phase;
        for (side, sign) in [(1.0, 1.0), (-1.0, -1.0)] {
            let foot = v3(sign * stride / 2.0, side * hip_w, 0.04);
            let hip_j = v3(0.0, side * hip_w, hip_z + 0.02);
            p.limb(Shape::Ellipsoid, hip_j, foot, v3(0.085, 0.08, 0.0), legs);
            // Arms swing opposite to the legs.
            let shoulder = neck + v3(0.0, side * shoulder_w, -0.06);
            let hand = shoulder + v3(-sign * stride * 0.35, side * 0.04, -0.62 * h / 1.76);
            p.limb(Shape::Ellipsoid, shoulder, hand, v3(0.05, 0.05, 0.0), top);
        }
    }
}

/// Pedestrian: legs, torso, arms, head; sometimes a bag.
pub fn pedestrian(
    b: &mut SceneBuilder,
    s: &mut Sampler,
    pose: &Pose,
    dims: (f64, f64, f64),
    walking: bool,
) {
    let (l, w, h) = dims;
    let first = b.prims.len();
    let owner = b.begin_actor();
    let mut p = Parts {
        b,
        pose: *pose,
        owner,
        surface: Surface::Object,
    };
    let phase = if walking {
        s.range(-1.0, 1.0)
    } else {
        s.range(-0.2, 0.2)
    };
    person(&mut p, s, h, w, l, phase, None);
    if s.chance(0.3) {
        let bag = p.b.material(Material::solid([0.1, 0.1, 0.1], 0.1));
        p.add(
            Shape::Box,
            v3(-0.16, 0.0, 0.68 * h),
            M3::IDENTITY,
            v3(0.08, 0.15, 0.18),
            bag,
        );
    }
    p.b.end_actor(ObjectClass::Pedestrian, pose, l, w, h, first, !walking);
}

/// A bicycle in the frame of `p`: two thin wheels, frame tubes, handlebar. Returns
/// (saddle, handlebar) positions for a rider.
fn bicycle(p: &mut Parts<'_>, s: &mut Sampler, l: f64, w: f64) -> (V3, V3) {
    let frame = p.b.material(Material::solid(
        *s.pick(&[
            [0.1, 0.1, 0.1],
            [0.6, 0.1, 0.1],
            [0.2, 0.3, 0.6],
            [0.7, 0.7, 0.7],
        ]),
        s.range(0.05, 0.4),
    ));
    let tyre = p.b.material(Material::solid([0.05, 0.05, 0.05], 0.05));
    let r = s.range(0.32, 0.36);
    let xr = -l / 2.0 + r;
    let xf = l / 2.0 - r;
    for x in [xr, xf] {
        p.add(
            Shape::Cylinder,
            v3(x, 0.0, r),
            wheel_rot(),
            v3(r, r, 0.025),
            tyre,
        );
    }
    let bb = v3(xr + 0.42, 0.0, 0.3);
    let saddle = v3(xr + 0.3, 0.0, 0.95);
    let head = v3(xf - 0.12, 0.0, 0.98);
    let tube = v3(0.025, 0.025, 0.0);
    p.limb(Shape::Cylinder, v3(xr, 0.0, r), bb, tube, frame);
    p.limb(Shape::Cylinder, bb, saddle, tube, frame);
    p.limb(Shape::Cylinder, bb, head, tube, frame);
    p.limb(Shape::Cylinder, saddle, head, tube, frame);
    p.limb(Shape::Cylinder, head, v3(xf, 0.0, r), tube, frame);
    let bar = v3(xf - 0.15, 0.0, 1.05);
    p.add(
        Shape::Cylinder,
        bar,
        wheel_rot(),
        v3(0.02, 0.02, (w / 2.0 - 0.02).max(0.2)),
        frame,
    );
    (saddle, bar)
}

/// Cyclist: bicycle plus a rider leaning towards the handlebar.
pub fn cyclist(
    b: &mut SceneBuilder,
    s: &mut Sampler,
    pose: &Pose,
    dims: (f64, f64, f64),
    moving: bool,
) {
    let (l, w, h) = dims;
    let first = b.prims.len();
    let owner = b.begin_actor();
    let mut p = Parts {
        b,
        pose: *pose,
        owner,
        surface: Surface::Object,
    };
    let (saddle, bar) = bicycle(&mut p, s, l, w);
    let (leg_rgb, leg_refl) = clothes(s);
    let legs = p.b.material(Material::solid(leg_rgb, leg_refl));
    // Rider: torso from the saddle towards the handlebar, head on top.
    person(
        &mut p,
        s,
        h,
        w.max(0.5),
        0.84,
        0.0,
        Some(saddle + v3(0.0, 0.0, 0.05)),
    );
    // Legs from the hip to the pedals, arms to the bar.
    let pedal = saddle + v3(0.15, 0.0, -0.62);
    for side in [1.0, -1.0] {
        let crank = pedal + v3(side * 0.12, side * 0.12, side * 0.08);
        p.limb(
            Shape::Ellipsoid,
            saddle + v3(0.05, side * 0.11, 0.05),
            crank,
            v3(0.08, 0.075, 0.0),
            legs,
        );
    }
    let arm_mat = legs;
    let shoulder = saddle + v3(0.28, 0.0, 0.5);
    for side in [1.0, -1.0] {
        p.limb(
            Shape::Ellipsoid,
            shoulder + v3(0.0, side * 0.18, 0.0),
            bar + v3(0.0, side * (w / 2.0 - 0.08).max(0.18), 0.0),
            v3(0.045, 0.045, 0.0),
            arm_mat,
        );
    }
    p.b.end_actor(ObjectClass::Cyclist, pose, l, w, h, first, !moving);
}

/// An unlabelled parked bicycle (clutter).
pub fn parked_bicycle(b: &mut SceneBuilder, s: &mut Sampler, pose: &Pose) {
    let mut p = Parts {
        b,
        pose: *pose,
        owner: crate::primitive::NO_OWNER,
        surface: Surface::Clutter,
    };
    let l = s.range(1.6, 1.8);
    bicycle(&mut p, s, l, 0.55);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::V3;

    fn build(f: impl Fn(&mut SceneBuilder, &mut Sampler, &Pose)) -> crate::scene::Scene {
        let mut b = SceneBuilder::new();
        let mut s = Sampler::new(3);
        let pose = Pose {
            rot: M3::rot_z(0.4),
            t: v3(10.0, 2.0, -1.73),
        };
        f(&mut b, &mut s, &pose);
        b.finish(&Pose::IDENTITY, V3::Z)
    }

    /// All parts stay inside the label box (with a small tolerance), as KITTI's tight boxes.
    fn assert_inside_box(scene: &crate::scene::Scene, tol: f64) {
        let a = &scene.actors[0];
        let side = a.up.cross(a.heading);
        for p in &scene.prims[a.prims.clone()] {
            let bb = p.aabb();
            // Sample the box corners of each part's local extents, transformed.
            for sx in [-1.0, 1.0] {
                for sy in [-1.0, 1.0] {
                    for sz in [-1.0, 1.0] {
                        let half = match p.shape {
                            Shape::RoundedBox { radii } => p.half.min(radii),
                            _ => p.half,
                        };
                        let q =
                            p.center + p.rot.apply(v3(sx * half.x, sy * half.y, sz * half.z) * 0.7);
                        let d = q - a.bottom_center;
                        let (x, y, z) = (d.dot(a.heading), d.dot(side), d.dot(a.up));
                        assert!(x.abs() <= a.l / 2.0 + tol, "x {x} l {} {bb:?}", a.l);
                        assert!(y.abs() <= a.w / 2.0 + tol, "y {y} w {}", a.w);
                        assert!(z >= -tol && z <= a.h + tol, "z {z} h {}", a.h);
                    }
                }
            }
        }
    }

    #[test]
    fn objects_fit_their_label_boxes() {
        let mut s = Sampler::new(11);
        for _ in 0..20 {
            let d = sample_dims(ObjectClass::Car, &mut s);
            assert_inside_box(&build(|b, s, p| car(b, s, p, d, true)), 0.05);
            let d = sample_dims(ObjectClass::Van, &mut s);
            assert_inside_box(&build(|b, s, p| van(b, s, p, d, true)), 0.05);
            let d = sample_dims(ObjectClass::Truck, &mut s);
            assert_inside_box(&build(|b, s, p| truck(b, s, p, d, true)), 0.05);
            let d = sample_dims(ObjectClass::Pedestrian, &mut s);
            assert_inside_box(&build(|b, s, p| pedestrian(b, s, p, d, true)), 0.12);
            let d = sample_dims(ObjectClass::Cyclist, &mut s);
            assert_inside_box(&build(|b, s, p| cyclist(b, s, p, d, true)), 0.15);
        }
    }

    #[test]
    fn dims_follow_kitti_means() {
        let mut s = Sampler::new(5);
        let n = 4000;
        let mut mean = |class| {
            let mut acc = (0.0, 0.0, 0.0);
            for _ in 0..n {
                let (l, w, h) = sample_dims(class, &mut s);
                acc = (acc.0 + l, acc.1 + w, acc.2 + h);
            }
            (acc.0 / n as f64, acc.1 / n as f64, acc.2 / n as f64)
        };
        let (l, w, h) = mean(ObjectClass::Car);
        assert!((l - 3.88).abs() < 0.05 && (w - 1.63).abs() < 0.02 && (h - 1.53).abs() < 0.02);
        let (l, w, h) = mean(ObjectClass::Pedestrian);
        assert!((l - 0.84).abs() < 0.04 && (w - 0.66).abs() < 0.03 && (h - 1.76).abs() < 0.02);
        let (l, w, h) = mean(ObjectClass::Cyclist);
        assert!((l - 1.76).abs() < 0.03 && (w - 0.60).abs() < 0.03 && (h - 1.74).abs() < 0.02);
    }

    #[test]
    fn a_car_is_several_parts_and_has_glass() {
        let scene = build(|b, s, p| car(b, s, p, (3.9, 1.6, 1.5), true));
        let a = &scene.actors[0];
        assert!(a.prims.len() >= 7);
        let glassy = scene.prims[a.prims.clone()].iter().any(|p| {
            matches!(
                scene.materials[p.material as usize].pattern,
                Pattern::Cabin { .. }
            )
        });
        assert!(glassy);
    }
}
