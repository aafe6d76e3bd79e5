//! Clutter: what real rooms hold besides the ten evaluated classes — books on shelves,
//! monitors, lamps, cups and plants on tops, boxes, bins, plants and cabinets on the floor,
//! pictures on the walls. None of it is labelled; cabinets and boxes are remembered as
//! look-alikes the simulated 2D detector may mistake for an evaluated class.

use super::furniture::Support;
use super::room::{FloorPlan, Rect, Room, wall_panel};
use crate::material::Material;
use crate::math::{M3, Pose, V3, v3};
use crate::primitive::{NO_OWNER, Shape, Surface};
use crate::rng::Sampler;
use crate::scene::SceneBuilder;
use fusiondet_sunrgbd::SunClass;

/// An unlabelled thing that looks like an evaluated class (room frame): its footprint pose
/// (bottom middle, facing +x), size (dx, dy, dz) and the class it resembles.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lookalike {
    pub resembles: SunClass,
    pub pose: Pose,
    pub size: [f64; 3],
}

/// What a support is, for what stands on it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SupportKind {
    Desk,
    Table,
    Shelf,
    Bedside,
}

const COLOURS: [[f64; 3]; 8] = [
    [0.8, 0.2, 0.15],
    [0.15, 0.3, 0.7],
    [0.9, 0.8, 0.2],
    [0.2, 0.55, 0.3],
    [0.9, 0.9, 0.9],
    [0.1, 0.1, 0.1],
    [0.6, 0.45, 0.3],
    [0.5, 0.5, 0.55],
];

fn colour(b: &mut SceneBuilder, s: &mut Sampler) -> u16 {
    let rgb = *s.pick(&COLOURS);
    let k = s.range(0.7, 1.1);
    b.material(Material::solid(rgb.map(|c| (c * k).min(1.0)), 0.5))
}

/// Adds a clutter part in the frame `pose`.
fn part(b: &mut SceneBuilder, pose: &Pose, shape: Shape, c: V3, half: V3, m: u16) {
    b.add(
        pose,
        shape,
        c,
        M3::IDENTITY,
        half,
        m,
        Surface::Clutter,
        NO_OWNER,
    );
}

/// Things standing on a support.
pub fn on_support(b: &mut SceneBuilder, s: &mut Sampler, sup: &Support, kind: SupportKind) {
    let frame = Pose {
        rot: M3::rot_z(sup.yaw),
        t: sup.center,
    };
    let room = sup.clearance - 0.01;
    match kind {
        SupportKind::Shelf => {
            // Rows of books, some gaps, now and then a box.
            let mut y = -sup.hy;
            while y < sup.hy - 0.03 {
                if s.chance(0.2) {
                    y += s.range(0.05, 0.3);
                    continue;
                }
                let run = s.range(0.1, 0.45).min(sup.hy - y);
                let m = colour(b, s);
                let mut yb = y;
                while yb < y + run - 0.015 {
                    let t = s.range(0.015, 0.05).min(y + run - yb);
                    let h = s.range(0.15, 0.3).min(room);
                    let d = s.range(0.12, 0.22).min(2.0 * sup.hx);
                    if h > 0.05 {
                        let book_m = if s.chance(0.3) { colour(b, s) } else { m };
                        part(
                            b,
                            &frame,
                            Shape::Box,
                            v3(sup.hx - d / 2.0, yb + t / 2.0, h / 2.0),
                            v3(d / 2.0, t / 2.0, h / 2.0),
                            book_m,
                        );
                    }
                    yb += t + 0.002;
                }
                y += run + 0.01;
            }
        }
        _ => {
            let n = match kind {
                SupportKind::Desk => s.int(1, 4),
                SupportKind::Table => s.int(0, 4),
                _ => s.int(0, 2),
            };
            if kind == SupportKind::Desk && s.chance(0.7) && sup.hx > 0.25 {
                // A monitor at the back, facing the front.
                let dark = b.material(Material::solid([0.05, 0.05, 0.06], 0.5));
                let w = s.range(0.45, 0.65).min(2.0 * sup.hy - 0.1);
                let x = -sup.hx + 0.15;
                part(
                    b,
                    &frame,
                    Shape::Box,
                    v3(x, 0.0, 0.01),
                    v3(0.08, 0.1, 0.01),
                    dark,
                );
                part(
                    b,
                    &frame,
                    Shape::Box,
                    v3(x, 0.0, 0.12),
                    v3(0.015, 0.03, 0.11),
                    dark,
                );
                part(
                    b,
                    &frame,
                    Shape::Box,
                    v3(x + 0.03, 0.0, 0.35),
                    v3(0.015, w / 2.0, 0.17),
                    dark,
                );
                // And a keyboard.
                part(
                    b,
                    &frame,
                    Shape::Box,
                    v3(sup.hx - 0.2, 0.0, 0.012),
                    v3(0.07, 0.22, 0.012),
                    dark,
                );
            }
            if kind == SupportKind::Bedside && s.chance(0.7) {
                lamp(b, s, &frame, v3(0.0, 0.0, 0.0));
            }
            for _ in 0..n {
                let x = s.range(-sup.hx + 0.08, sup.hx - 0.08);
                let y = s.range(-sup.hy + 0.08, sup.hy - 0.08);
                let m = colour(b, s);
                match s.below(4) {
                    0 => {
                        let (r, h) = (s.range(0.03, 0.05), s.range(0.08, 0.12));
                        part(
                            b,
                            &frame,
                            Shape::Cylinder,
                            v3(x, y, h / 2.0),
                            v3(r, r, h / 2.0),
                            m,
                        );
                    }
                    1 => {
                        let (r, h) = (s.range(0.03, 0.045), s.range(0.2, 0.32));
                        part(
                            b,
                            &frame,
                            Shape::Cylinder,
                            v3(x, y, h / 2.0),
                            v3(r, r, h / 2.0),
                            m,
                        );
                    }
                    2 => {
                        let half = v3(s.range(0.1, 0.17), s.range(0.13, 0.2), s.range(0.005, 0.02));
                        part(b, &frame, Shape::Box, v3(x, y, half.z), half, m);
                    }
                    _ => plant(b, s, &frame, v3(x, y, 0.0), 0.08),
                }
            }
        }
    }
}

/// A table lamp standing at `at` (frame `frame`).
fn lamp(b: &mut SceneBuilder, s: &mut Sampler, frame: &Pose, at: V3) {
    let base = colour(b, s);
    let shade = b.material(Material::solid([0.95, 0.9, 0.75], 0.5));
    let h = s.range(0.3, 0.45);
    part(
        b,
        frame,
        Shape::Cylinder,
        at + v3(0.0, 0.0, 0.015),
        v3(0.07, 0.07, 0.015),
        base,
    );
    part(
        b,
        frame,
        Shape::Cylinder,
        at + v3(0.0, 0.0, h / 2.0),
        v3(0.012, 0.012, h / 2.0),
        base,
    );
    let r = s.range(0.1, 0.16);
    part(
        b,
        frame,
        Shape::Cylinder,
        at + v3(0.0, 0.0, h),
        v3(r, r, 0.1),
        shade,
    );
}

/// A potted plant of pot radius `r` at `at`.
fn plant(b: &mut SceneBuilder, s: &mut Sampler, frame: &Pose, at: V3, r: f64) {
    let pot = b.material(Material::solid([0.6, 0.35, 0.25], 0.5));
    let leaves = b.material(
        Material::solid([0.15, 0.4, 0.15], 0.5).with_pattern(crate::material::Pattern::Leaves),
    );
    let ph = r * 1.6;
    part(
        b,
        frame,
        Shape::Cylinder,
        at + v3(0.0, 0.0, ph / 2.0),
        v3(r, r, ph / 2.0),
        pot,
    );
    let fh = r * s.range(1.5, 4.0);
    part(
        b,
        frame,
        Shape::Ellipsoid,
        at + v3(0.0, 0.0, ph + fh * 0.8),
        v3(r * 1.8, r * 1.8, fh),
        leaves,
    );
}

/// Floor clutter: `n` boxes, bins and plants where the floor plan has room, mostly near the
/// walls. Cardboard boxes are remembered as night-stand look-alikes.
pub fn floor_items(
    b: &mut SceneBuilder,
    s: &mut Sampler,
    room: &Room,
    plan: &mut FloorPlan,
    n: usize,
    lookalikes: &mut Vec<Lookalike>,
) {
    for _ in 0..n {
        for _try in 0..10 {
            let wall = room.wall(s.below(4));
            let kind = s.below(3);
            let (dx, dy, dz) = match kind {
                0 => (s.range(0.3, 0.6), s.range(0.3, 0.7), s.range(0.2, 0.6)),
                1 => (0.3, 0.3, s.range(0.3, 0.45)),
                _ => (0.4, 0.4, 0.0),
            };
            let at = s.range(dy / 2.0, (wall.length - dy / 2.0).max(dy / 2.0));
            let mut pose = wall.pose_against(at, dx, s.range(0.02, 0.4));
            pose.rot = pose.rot.mul(&M3::rot_z(s.range(-0.3, 0.3)));
            if !plan.take(Rect::of(&pose, dx, dy), 0.03) {
                continue;
            }
            match kind {
                0 => {
                    let card = b.material(Material::solid([0.62, 0.48, 0.32], 0.5));
                    part(
                        b,
                        &pose,
                        Shape::Box,
                        v3(0.0, 0.0, dz / 2.0),
                        v3(dx / 2.0, dy / 2.0, dz / 2.0),
                        card,
                    );
                    lookalikes.push(Lookalike {
                        resembles: SunClass::NightStand,
                        pose,
                        size: [dx, dy, dz],
                    });
                }
                1 => {
                    let m = colour(b, s);
                    part(
                        b,
                        &pose,
                        Shape::Cylinder,
                        v3(0.0, 0.0, dz / 2.0),
                        v3(0.14, 0.14, dz / 2.0),
                        m,
                    );
                }
                _ => {
                    let r = s.range(0.1, 0.16);
                    plant(b, s, &pose, V3::ZERO, r)
                }
            }
            break;
        }
    }
}

/// A cabinet (a vanity, a TV stand, a filing cabinet) against `wall`: not one of the ten
/// classes, but a dresser look-alike.
#[allow(clippy::too_many_arguments)]
pub fn cabinet(
    b: &mut SceneBuilder,
    s: &mut Sampler,
    room: &Room,
    plan: &mut FloorPlan,
    wall: usize,
    size: [f64; 3],
    lookalikes: &mut Vec<Lookalike>,
) -> Option<Support> {
    let wall = room.wall(wall);
    let [dx, dy, dz] = size;
    for _ in 0..10 {
        let at = s.range(
            dy / 2.0 + 0.05,
            (wall.length - dy / 2.0 - 0.05).max(dy / 2.0 + 0.05),
        );
        let pose = wall.pose_against(at, dx, 0.02);
        if !plan.take(Rect::of(&pose, dx, dy), 0.05) {
            continue;
        }
        let m = colour(b, s);
        let front = b.material(Material::solid([0.85, 0.84, 0.8], 0.5));
        part(
            b,
            &pose,
            Shape::Box,
            v3(-0.01, 0.0, dz / 2.0),
            v3(dx / 2.0 - 0.01, dy / 2.0, dz / 2.0),
            m,
        );
        part(
            b,
            &pose,
            Shape::Box,
            v3(dx / 2.0 - 0.01, 0.0, dz / 2.0),
            v3(0.01, dy / 2.0 - 0.02, dz / 2.0 - 0.03),
            front,
        );
        lookalikes.push(Lookalike {
            resembles: SunClass::Dresser,
            pose,
            size,
        });
        return Some(Support {
            center: pose.point(v3(0.0, 0.0, dz)),
            yaw: crate::math::atan2(pose.rot.cols[0].y, pose.rot.cols[0].x),
            hx: dx / 2.0,
            hy: dy / 2.0,
            clearance: 2.0,
        });
    }
    None
}

/// Pictures, boards and shelves' worth of flat things on the walls.
pub fn wall_items(b: &mut SceneBuilder, s: &mut Sampler, room: &Room, n: usize) {
    for _ in 0..n {
        let wall = room.wall(s.below(4));
        let w = s.range(0.3, 1.2).min(wall.length - 0.4);
        if w < 0.2 {
            continue;
        }
        let at = s.range(w / 2.0 + 0.2, wall.length - w / 2.0 - 0.2);
        let z0 = s.range(1.1, 1.6);
        let h = s.range(0.3, 0.8).min(room.height - z0 - 0.1);
        let m = colour(b, s);
        wall_panel(b, &wall, at, w, z0, z0 + h, 0.025, m, Surface::Clutter);
    }
}
