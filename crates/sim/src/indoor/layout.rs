//! Furnishing a room: what each kind of room holds and where (beds with their heads to a wall
//! and night stands beside them, desks against walls with a chair in front, classroom desks
//! in rows, sofas facing a coffee table), placed on the floor plan without overlap, then the
//! clutter. The camera's standpoint is chosen first, near one wall looking into the room,
//! and kept free.

use super::clutter::{self, Lookalike, SupportKind};
use super::furniture::{self, Support, sample_size};
use super::room::{FloorPlan, Rect, Room, RoomKind, build_shell};
use crate::math::{M3, Pose, V3, atan2, v3};
use crate::rng::Sampler;
use crate::scene::SceneBuilder;
use fusiondet_sunrgbd::SunClass;
use std::ops::Range;

/// One placed piece of furniture (room frame until the scene is moved to the camera).
#[derive(Debug, Clone, PartialEq)]
pub struct Placed {
    pub class: SunClass,
    /// Its frame: origin at the middle of its footprint on the floor, +x its front.
    pub pose: Pose,
    /// (dx, dy, dz): along its front, across, up.
    pub size: [f64; 3],
    /// Its primitives in the scene.
    pub prims: Range<usize>,
}

/// A furnished room before it is seen.
#[derive(Debug, Clone)]
pub struct RoomLayout {
    pub room: Room,
    pub builder: SceneBuilder,
    pub furniture: Vec<Placed>,
    pub lookalikes: Vec<Lookalike>,
    /// The camera's place on the floor and the direction it looks (angle from +x).
    pub camera_at: V3,
    pub camera_yaw: f64,
    /// The ceiling light.
    pub light: V3,
}

/// Margin kept between footprints (and to the camera's place).
const MARGIN: f64 = 0.04;
/// The smallest gap between two pieces placed side by side: both margins and a little.
const CLEAR: f64 = 2.0 * MARGIN + 0.01;

struct Furnisher<'a> {
    room: Room,
    s: &'a mut Sampler,
    b: SceneBuilder,
    plan: FloorPlan,
    furniture: Vec<Placed>,
    lookalikes: Vec<Lookalike>,
    /// Walls in view, the one opposite the camera listed twice (more often chosen).
    walls: Vec<usize>,
    /// Supports and what stands on them, dressed at the end.
    supports: Vec<(Support, SupportKind)>,
}

impl Furnisher<'_> {
    /// Places `class` of `size` at `pose` if its footprint is free; returns its supports.
    fn place(&mut self, class: SunClass, size: [f64; 3], pose: Pose) -> Option<Vec<Support>> {
        if !self.plan.take(Rect::of(&pose, size[0], size[1]), MARGIN) {
            return None;
        }
        let first = self.b.prims.len();
        let owner = self.furniture.len() as u32;
        let sup = furniture::build(class, size, self.s, &mut self.b, &pose, owner);
        self.furniture.push(Placed {
            class,
            pose,
            size,
            prims: first..self.b.prims.len(),
        });
        Some(sup)
    }

    /// Against one of `walls` (back to it), a few tries.
    fn against_wall(
        &mut self,
        class: SunClass,
        size: [f64; 3],
        walls: &[usize],
    ) -> Option<(Pose, Vec<Support>)> {
        self.against_wall_within(class, size, walls, 1.0)
    }

    /// Against one of `walls`, its middle within `spread` (a share of the free length) of
    /// the wall's middle.
    fn against_wall_within(
        &mut self,
        class: SunClass,
        size: [f64; 3],
        walls: &[usize],
        spread: f64,
    ) -> Option<(Pose, Vec<Support>)> {
        for _ in 0..12 {
            let wall = self.room.wall(*self.s.pick(walls));
            let (lo, hi) = (size[1] / 2.0 + 0.03, wall.length - size[1] / 2.0 - 0.03);
            if hi < lo {
                continue;
            }
            let (mid, half) = (0.5 * (lo + hi), 0.5 * (hi - lo) * spread);
            let at = self.s.range(mid - half, mid + half);
            let mut pose = wall.pose_against(at, size[0], self.s.range(0.02, 0.06));
            pose.rot = pose.rot.mul(&M3::rot_z(self.s.range(-0.03, 0.03)));
            if let Some(sup) = self.place(class, size, pose) {
                return Some((pose, sup));
            }
        }
        None
    }

    /// Anywhere on the floor, turned to the walls' grid (± a little).
    fn free_standing(&mut self, class: SunClass, size: [f64; 3]) -> Option<(Pose, Vec<Support>)> {
        for _ in 0..12 {
            let yaw =
                self.s.below(4) as f64 * std::f64::consts::FRAC_PI_2 + self.s.range(-0.15, 0.15);
            let r = 0.5 * (size[0] * size[0] + size[1] * size[1]).sqrt();
            let (w, d) = (self.room.width, self.room.depth);
            if w < 2.0 * r || d < 2.0 * r {
                return None;
            }
            let pose = Pose {
                rot: M3::rot_z(yaw),
                t: v3(self.s.range(r, w - r), self.s.range(r, d - r), 0.0),
            };
            if let Some(sup) = self.place(class, size, pose) {
                return Some((pose, sup));
            }
        }
        None
    }

    /// A piece in front of `host` (at `host` frame's x = `ahead`, y = `y`), facing `facing`
    /// radians relative to the host.
    fn relative(
        &mut self,
        class: SunClass,
        size: [f64; 3],
        host: &Pose,
        ahead: f64,
        y: f64,
        facing: f64,
    ) -> Option<Vec<Support>> {
        let pose = Pose {
            rot: host.rot.mul(&M3::rot_z(facing + self.s.range(-0.2, 0.2))),
            t: host.point(v3(ahead, y, 0.0)),
        };
        self.place(class, size, pose)
    }

    /// A chair facing a desk or table whose front is its +x, at lateral offset `y`.
    fn chair_at(&mut self, host: &Pose, host_dx: f64, y: f64) {
        let size = sample_size(SunClass::Chair, self.s);
        let ahead = host_dx / 2.0 + size[0] / 2.0 + self.s.range(CLEAR, 0.3);
        self.relative(SunClass::Chair, size, host, ahead, y, std::f64::consts::PI);
    }

    fn supports(&mut self, sup: Vec<Support>, kind: SupportKind) {
        self.supports.extend(sup.into_iter().map(|s| (s, kind)));
    }

    fn bedroom(&mut self) {
        let walls = self.walls.clone();
        let size = sample_size(SunClass::Bed, self.s);
        // Beds mostly stand in the middle of a wall, with room for night stands.
        let spread = if self.s.chance(0.7) { 0.3 } else { 1.0 };
        if let Some((bed, _)) = self.against_wall_within(SunClass::Bed, size, &walls, spread) {
            // Night stands beside the head end.
            for side in [1.0, -1.0] {
                if self.s.chance(0.7) {
                    let ns = sample_size(SunClass::NightStand, self.s);
                    let y = side * (size[1] / 2.0 + ns[1] / 2.0 + self.s.range(CLEAR, 0.16));
                    let x = -size[0] / 2.0 + ns[0] / 2.0 + 0.01;
                    let pose = Pose {
                        rot: bed.rot,
                        t: bed.point(v3(x, y, 0.0)),
                    };
                    if let Some(sup) = self.place(SunClass::NightStand, ns, pose) {
                        self.supports(sup, SupportKind::Bedside);
                    }
                }
            }
        }
        if self.s.chance(0.55) {
            let size = sample_size(SunClass::Dresser, self.s);
            if let Some((_, sup)) = self.against_wall(SunClass::Dresser, size, &walls) {
                self.supports(sup, SupportKind::Table);
            }
        }
        if self.s.chance(0.35) {
            self.desk_with_chair(&walls);
        }
        if self.s.chance(0.3) {
            self.bookshelf(&walls);
        }
        if self.s.chance(0.2) {
            let size = sample_size(SunClass::Chair, self.s);
            self.free_standing(SunClass::Chair, size);
        }
    }

    fn desk_with_chair(&mut self, walls: &[usize]) {
        let size = sample_size(SunClass::Desk, self.s);
        if let Some((desk, sup)) = self.against_wall(SunClass::Desk, size, walls) {
            self.supports(sup, SupportKind::Desk);
            if self.s.chance(0.85) {
                let y = self.s.range(-0.2, 0.2) * size[1];
                self.chair_at(&desk, size[0], y);
            }
        }
    }

    fn bookshelf(&mut self, walls: &[usize]) {
        let size = sample_size(SunClass::Bookshelf, self.s);
        if let Some((_, sup)) = self.against_wall(SunClass::Bookshelf, size, walls) {
            self.supports(sup, SupportKind::Shelf);
        }
    }

    /// A table with chairs along its long sides.
    fn dining_table(&mut self) {
        let size = sample_size(SunClass::Table, self.s);
        if let Some((table, sup)) = self.free_standing(SunClass::Table, size) {
            self.supports(sup, SupportKind::Table);
            // Its long sides (dy is the longer) are at ±x: chairs there face it.
            let per_side = if size[1] > 1.1 { 2 } else { 1 };
            for side in [1.0, -1.0] {
                for k in 0..per_side {
                    if self.s.chance(0.75) {
                        let along = ((k as f64 + 0.5) / per_side as f64 - 0.5) * size[1];
                        let cs = sample_size(SunClass::Chair, self.s);
                        let off = size[0] / 2.0 + cs[0] / 2.0 + self.s.range(CLEAR, 0.25);
                        // Facing the table: the chair at +x looks along −x.
                        let turn = if side > 0.0 {
                            std::f64::consts::PI
                        } else {
                            0.0
                        } + self.s.range(-0.2, 0.2);
                        let pose = Pose {
                            rot: table.rot.mul(&M3::rot_z(turn)),
                            t: table.point(v3(side * off, along, 0.0)),
                        };
                        self.place(SunClass::Chair, cs, pose);
                    }
                }
            }
        }
    }

    fn office(&mut self) {
        let walls = self.walls.clone();
        for _ in 0..self.s.int(1, 3) {
            self.desk_with_chair(&walls);
        }
        for _ in 0..self.s.int(0, 2) {
            self.bookshelf(&walls);
        }
        if self.s.chance(0.3) {
            self.dining_table();
        }
        if self.s.chance(0.2) {
            let size = sample_size(SunClass::Sofa, self.s);
            self.against_wall(SunClass::Sofa, size, &walls);
        }
        if self.s.chance(0.4) {
            let w = *self.s.pick(&walls);
            let size = [0.45, self.s.range(0.4, 0.9), self.s.range(0.6, 1.3)];
            if let Some(sup) = clutter::cabinet(
                &mut self.b,
                self.s,
                &self.room,
                &mut self.plan,
                w,
                size,
                &mut self.lookalikes,
            ) {
                self.supports.push((sup, SupportKind::Table));
            }
        }
    }

    fn bathroom(&mut self) {
        let walls = self.walls.clone();
        if self.s.chance(0.6) {
            let size = sample_size(SunClass::Bathtub, self.s);
            self.against_wall(SunClass::Bathtub, size, &walls);
        }
        if self.s.chance(0.95) {
            let size = sample_size(SunClass::Toilet, self.s);
            self.against_wall(SunClass::Toilet, size, &walls);
        }
        // A vanity with its basin.
        let w = *self.s.pick(&walls);
        let size = [0.5, self.s.range(0.6, 1.2), 0.85];
        if let Some(sup) = clutter::cabinet(
            &mut self.b,
            self.s,
            &self.room,
            &mut self.plan,
            w,
            size,
            &mut self.lookalikes,
        ) {
            self.supports.push((sup, SupportKind::Bedside));
        }
    }

    fn living_room(&mut self) {
        let walls = self.walls.clone();
        let size = sample_size(SunClass::Sofa, self.s);
        if let Some((sofa, _)) = self.against_wall(SunClass::Sofa, size, &walls)
            && self.s.chance(0.8)
        {
            let t = furniture::coffee_table_size(self.s);
            // A coffee table in front, its long side along the sofa.
            let ahead = size[0] / 2.0 + t[0] / 2.0 + self.s.range(0.3, 0.5);
            if let Some(sup) = self.relative(SunClass::Table, t, &sofa, ahead, 0.0, 0.0) {
                self.supports(sup, SupportKind::Table);
            }
        }
        if self.s.chance(0.35) {
            let size = sample_size(SunClass::Sofa, self.s);
            self.against_wall(SunClass::Sofa, size, &walls);
        }
        for _ in 0..self.s.int(0, 2) {
            let size = sample_size(SunClass::Chair, self.s);
            self.free_standing(SunClass::Chair, size);
        }
        if self.s.chance(0.5) {
            self.bookshelf(&walls);
        }
        if self.s.chance(0.3) {
            self.dining_table();
        }
        if self.s.chance(0.2) {
            let size = sample_size(SunClass::Dresser, self.s);
            self.against_wall(SunClass::Dresser, size, &walls);
        }
        if self.s.chance(0.6) {
            // A TV stand.
            let w = *self.s.pick(&walls);
            let size = [0.45, self.s.range(1.0, 1.8), self.s.range(0.4, 0.6)];
            if let Some(sup) = clutter::cabinet(
                &mut self.b,
                self.s,
                &self.room,
                &mut self.plan,
                w,
                size,
                &mut self.lookalikes,
            ) {
                self.supports.push((sup, SupportKind::Desk));
            }
        }
    }

    /// Rows of desks (or tables) with a chair each, all facing the front wall (away from
    /// the camera, which stands at the back), a teacher's desk at the front.
    fn classroom(&mut self, cam_wall: usize) {
        let back = self.room.wall(cam_wall);
        let facing = atan2(back.normal.y, back.normal.x);
        let rot = M3::rot_z(facing);
        let class = if self.s.chance(0.7) {
            SunClass::Desk
        } else {
            SunClass::Table
        };
        let size = {
            let m = sample_size(class, self.s);
            [m[0].min(0.75), m[1].min(1.4), m[2].clamp(0.7, 0.78)]
        };
        // Room between rows for a chair (up to 0.77 m deep), its gaps and the margins.
        let row_pitch = size[0] + self.s.range(1.05, 1.25);
        let col_pitch = size[1] + self.s.range(0.3, 0.7);
        let depth = back.length.max(0.0);
        let room_depth = if cam_wall.is_multiple_of(2) {
            self.room.depth
        } else {
            self.room.width
        };
        let cols = ((depth - 0.6) / col_pitch).floor().max(1.0) as usize;
        let rows = ((room_depth - 2.5) / row_pitch).floor().clamp(1.0, 6.0) as usize;
        let x0 = (depth - cols as f64 * col_pitch) / 2.0 + col_pitch / 2.0;
        for r in 0..rows {
            for c in 0..cols {
                if self.s.chance(0.1) {
                    continue;
                }
                let d = 1.6 + r as f64 * row_pitch;
                let t = back.origin + back.along * (x0 + c as f64 * col_pitch) + back.normal * d;
                let desk = Pose { rot, t };
                let dsize = size.map(|v| v * self.s.range(0.98, 1.02));
                if let Some(sup) = self.place(class, dsize, desk) {
                    self.supports(sup, SupportKind::Table);
                    if self.s.chance(0.85) {
                        // The chair behind its desk, facing the same way.
                        let cs = sample_size(SunClass::Chair, self.s);
                        let ahead = -(dsize[0] / 2.0 + cs[0] / 2.0 + self.s.range(CLEAR, 0.14));
                        let pose = Pose {
                            rot: rot.mul(&M3::rot_z(self.s.range(-0.06, 0.06))),
                            t: desk.point(v3(ahead, self.s.range(-0.1, 0.1), 0.0)),
                        };
                        self.place(SunClass::Chair, cs, pose);
                    }
                }
            }
        }
        let front = (cam_wall + 2) % 4;
        self.desk_with_chair(&[front]);
        if self.s.chance(0.5) {
            let walls = self.walls.clone();
            self.bookshelf(&walls);
        }
    }
}

/// Furnishes a random room of a random kind (the layout stream `s`).
pub fn build_room(s: &mut Sampler) -> RoomLayout {
    let kind = RoomKind::sample(s);
    build_room_of(kind, s)
}

/// Furnishes a room of `kind`.
pub fn build_room_of(kind: RoomKind, s: &mut Sampler) -> RoomLayout {
    let room = Room::sample(kind, s);
    let mut plan = FloorPlan::new(&room);
    let mut b = SceneBuilder::new();
    // The camera: 0.3–0.9 m from a wall, somewhere in its middle half, looking into the room
    // (± 30°); classrooms are seen from the back, along the rows.
    let cam_wall = s.below(4);
    let wall = room.wall(cam_wall);
    let at = s.range(0.3, 0.7) * wall.length;
    let camera_at = wall.origin + wall.along * at + wall.normal * s.range(0.3, 0.9);
    let turn = if kind == RoomKind::Classroom {
        0.25
    } else {
        0.5
    };
    let camera_yaw = atan2(wall.normal.y, wall.normal.x) + s.range(-turn, turn);
    plan.taken.push(Rect {
        cx: camera_at.x,
        cy: camera_at.y,
        yaw: camera_yaw,
        hx: 0.45,
        hy: 0.45,
    });
    build_shell(&room, s, &mut b, &mut plan, cam_wall);
    let opposite = (cam_wall + 2) % 4;
    let walls = vec![opposite, opposite, (cam_wall + 1) % 4, (cam_wall + 3) % 4];
    let mut f = Furnisher {
        room,
        s,
        b,
        plan,
        furniture: Vec::new(),
        lookalikes: Vec::new(),
        walls,
        supports: Vec::new(),
    };
    match kind {
        RoomKind::Bedroom => f.bedroom(),
        RoomKind::Office => f.office(),
        RoomKind::Bathroom => f.bathroom(),
        RoomKind::LivingRoom => f.living_room(),
        RoomKind::Classroom => f.classroom(cam_wall),
    }
    let supports = std::mem::take(&mut f.supports);
    for (sup, kind) in &supports {
        clutter::on_support(&mut f.b, f.s, sup, *kind);
    }
    let n_floor = f.s.int(1, 5) as usize;
    clutter::floor_items(
        &mut f.b,
        f.s,
        &f.room,
        &mut f.plan,
        n_floor,
        &mut f.lookalikes,
    );
    let n_wall = f.s.int(0, 4) as usize;
    clutter::wall_items(&mut f.b, f.s, &f.room, n_wall);
    let light = v3(f.room.width / 2.0, f.room.depth / 2.0, f.room.height - 0.15);
    RoomLayout {
        room: f.room,
        builder: f.b,
        furniture: f.furniture,
        lookalikes: f.lookalikes,
        camera_at,
        camera_yaw,
        light,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// No two pieces overlap (footprints, which the parts stay within), none leaves the
    /// room, and the camera's place stays free; every kind of room gets furniture.
    #[test]
    fn furniture_never_overlaps_and_stays_in_the_room() {
        let mut s = Sampler::new(11);
        for kind in RoomKind::ALL {
            let mut pieces = 0;
            for _ in 0..25 {
                let l = build_room_of(kind, &mut s);
                let rects: Vec<Rect> = l
                    .furniture
                    .iter()
                    .map(|p| Rect::of(&p.pose, p.size[0], p.size[1]))
                    .collect();
                let plan = FloorPlan::new(&l.room);
                for (i, a) in rects.iter().enumerate() {
                    assert!(plan.fits(a, 0.0), "{kind:?}: {a:?} leaves the room");
                    for b in &rects[i + 1..] {
                        assert!(!a.overlaps(b, 0.0), "{kind:?}: {a:?} overlaps {b:?}");
                    }
                    let cam = Rect {
                        cx: l.camera_at.x,
                        cy: l.camera_at.y,
                        yaw: l.camera_yaw,
                        hx: 0.45,
                        hy: 0.45,
                    };
                    assert!(!a.overlaps(&cam, 0.0));
                }
                pieces += l.furniture.len();
            }
            assert!(pieces >= 25, "{kind:?}: {pieces} pieces in 25 rooms");
        }
    }

    /// Pieces that come in pairs find room: most classroom desks get their chair, most
    /// beds a night stand (the gaps between them clear both margins).
    #[test]
    fn companions_fit_beside_their_hosts() {
        let mut s = Sampler::new(2);
        let count =
            |l: &RoomLayout, c: SunClass| l.furniture.iter().filter(|p| p.class == c).count();
        let (mut desks, mut chairs, mut beds, mut stands) = (0, 0, 0, 0);
        for _ in 0..20 {
            let l = build_room_of(RoomKind::Classroom, &mut s);
            desks += count(&l, SunClass::Desk) + count(&l, SunClass::Table);
            chairs += count(&l, SunClass::Chair);
            let l = build_room_of(RoomKind::Bedroom, &mut s);
            beds += count(&l, SunClass::Bed);
            stands += count(&l, SunClass::NightStand);
        }
        assert!(
            chairs * 10 >= desks * 6,
            "{chairs} chairs for {desks} desks"
        );
        assert!(stands >= beds, "{stands} night stands for {beds} beds");
    }
}
