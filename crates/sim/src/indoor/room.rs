//! Rooms: their kinds and sizes, the shell (floor, walls, an optional ceiling, door, window,
//! skirting) and the floor plan bookkeeping that keeps furniture from overlapping. The room
//! frame has its origin in a floor corner, x and y along the walls, z up; the room spans
//! `[0, width] × [0, depth] × [0, height]`.

use crate::material::Material;
use crate::math::{Pose, V3, atan2, cos, sin, v3};
use crate::primitive::Surface;
use crate::rng::Sampler;
use crate::scene::SceneBuilder;

/// The room kinds SUN RGB-D's scenes mostly are.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize)]
pub enum RoomKind {
    Bedroom,
    Office,
    Bathroom,
    LivingRoom,
    Classroom,
}

impl RoomKind {
    pub const ALL: [RoomKind; 5] = [
        RoomKind::Bedroom,
        RoomKind::Office,
        RoomKind::Bathroom,
        RoomKind::LivingRoom,
        RoomKind::Classroom,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            RoomKind::Bedroom => "bedroom",
            RoomKind::Office => "office",
            RoomKind::Bathroom => "bathroom",
            RoomKind::LivingRoom => "living room",
            RoomKind::Classroom => "classroom",
        }
    }

    /// Draws a kind: bedrooms and offices are SUN RGB-D's commonest scenes.
    pub fn sample(s: &mut Sampler) -> RoomKind {
        RoomKind::ALL[s.weighted(&[0.3, 0.25, 0.12, 0.18, 0.15])]
    }

    /// Floor size ranges (width, depth) in metres.
    fn size_range(self) -> ((f64, f64), (f64, f64)) {
        match self {
            RoomKind::Bedroom => ((3.0, 4.5), (3.2, 5.0)),
            RoomKind::Office => ((3.0, 6.0), (3.5, 6.5)),
            RoomKind::Bathroom => ((1.9, 3.0), (2.2, 3.5)),
            RoomKind::LivingRoom => ((3.8, 6.0), (4.0, 7.0)),
            RoomKind::Classroom => ((6.0, 8.5), (6.5, 9.5)),
        }
    }
}

/// A room's dimensions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Room {
    pub kind: RoomKind,
    pub width: f64,
    pub depth: f64,
    pub height: f64,
    pub ceiling: bool,
}

impl Room {
    pub fn sample(kind: RoomKind, s: &mut Sampler) -> Room {
        let ((w0, w1), (d0, d1)) = kind.size_range();
        Room {
            kind,
            width: s.range(w0, w1),
            depth: s.range(d0, d1),
            height: s.range(2.4, 3.0),
            // Real frames often look down enough to miss the ceiling; an open top also
            // stands for rooms seen from a doorway into a larger space.
            ceiling: s.chance(0.85),
        }
    }

    /// Wall `k` (0 south y = 0, 1 east x = width, 2 north y = depth, 3 west x = 0): its
    /// start corner, direction along it (counter-clockwise seen from above), inward normal
    /// and length.
    pub fn wall(&self, k: usize) -> Wall {
        let (w, d) = (self.width, self.depth);
        let (origin, along, length) = match k % 4 {
            0 => (v3(0.0, 0.0, 0.0), v3(1.0, 0.0, 0.0), w),
            1 => (v3(w, 0.0, 0.0), v3(0.0, 1.0, 0.0), d),
            2 => (v3(w, d, 0.0), v3(-1.0, 0.0, 0.0), w),
            _ => (v3(0.0, d, 0.0), v3(0.0, -1.0, 0.0), d),
        };
        Wall {
            origin,
            along,
            normal: v3(-along.y, along.x, 0.0),
            length,
        }
    }
}

/// One wall's line on the floor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Wall {
    pub origin: V3,
    pub along: V3,
    pub normal: V3,
    pub length: f64,
}

impl Wall {
    /// The pose of a piece `dx` deep standing with its back `gap` from the wall, its middle
    /// `at` metres along it, facing into the room.
    pub fn pose_against(&self, at: f64, dx: f64, gap: f64) -> Pose {
        let c = self.origin + self.along * at + self.normal * (gap + dx / 2.0);
        Pose {
            rot: crate::math::M3::rot_z(atan2(self.normal.y, self.normal.x)),
            t: c,
        }
    }
}

/// An oriented rectangle on the floor (a footprint).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rect {
    pub cx: f64,
    pub cy: f64,
    pub yaw: f64,
    pub hx: f64,
    pub hy: f64,
}

impl Rect {
    /// The footprint of a piece of size (dx, dy) at `pose`.
    pub fn of(pose: &Pose, dx: f64, dy: f64) -> Rect {
        let f = pose.rot.cols[0];
        Rect {
            cx: pose.t.x,
            cy: pose.t.y,
            yaw: atan2(f.y, f.x),
            hx: dx / 2.0,
            hy: dy / 2.0,
        }
    }

    fn axes(&self) -> [[f64; 2]; 2] {
        let (s, c) = (sin(self.yaw), cos(self.yaw));
        [[c, s], [-s, c]]
    }

    pub fn corners(&self) -> [[f64; 2]; 4] {
        let [a, b] = self.axes();
        [(1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)].map(|(i, j)| {
            [
                self.cx + a[0] * i * self.hx + b[0] * j * self.hy,
                self.cy + a[1] * i * self.hx + b[1] * j * self.hy,
            ]
        })
    }

    /// Half the rectangle's extent along a unit axis.
    fn radius_along(&self, axis: [f64; 2]) -> f64 {
        let [a, b] = self.axes();
        self.hx * (a[0] * axis[0] + a[1] * axis[1]).abs()
            + self.hy * (b[0] * axis[0] + b[1] * axis[1]).abs()
    }

    /// Whether the two rectangles, each grown by `margin` on every side, overlap
    /// (separating axes: the four edge directions).
    pub fn overlaps(&self, o: &Rect, margin: f64) -> bool {
        let d = [o.cx - self.cx, o.cy - self.cy];
        self.axes().into_iter().chain(o.axes()).all(|axis| {
            let dist = (d[0] * axis[0] + d[1] * axis[1]).abs();
            dist < self.radius_along(axis) + o.radius_along(axis) + 2.0 * margin
        })
    }
}

/// The floor plan: footprints placed so far, including areas kept free (the camera's place,
/// the door's swing).
#[derive(Debug, Clone, Default)]
pub struct FloorPlan {
    pub width: f64,
    pub depth: f64,
    pub taken: Vec<Rect>,
}

impl FloorPlan {
    pub fn new(room: &Room) -> FloorPlan {
        FloorPlan {
            width: room.width,
            depth: room.depth,
            taken: Vec::new(),
        }
    }

    /// Whether `r` lies in the room and clear (by `margin`) of everything placed.
    pub fn fits(&self, r: &Rect, margin: f64) -> bool {
        let inside = r.corners().iter().all(|c| {
            c[0] >= -1e-9 && c[0] <= self.width + 1e-9 && c[1] >= -1e-9 && c[1] <= self.depth + 1e-9
        });
        inside && !self.taken.iter().any(|t| t.overlaps(r, margin))
    }

    /// Takes `r` if it fits.
    pub fn take(&mut self, r: Rect, margin: f64) -> bool {
        let ok = self.fits(&r, margin);
        if ok {
            self.taken.push(r);
        }
        ok
    }
}

/// Where the door is: wall and the distance of its middle along the wall.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Door {
    pub wall: usize,
    pub at: f64,
    pub width: f64,
}

/// Builds the shell: floor, four walls, skirting, a door and maybe a window and a ceiling.
/// Returns the door (its swing is kept free in `plan`).
pub fn build_shell(
    room: &Room,
    s: &mut Sampler,
    b: &mut SceneBuilder,
    plan: &mut FloorPlan,
    camera_wall: usize,
) -> Door {
    let (w, d, h) = (room.width, room.depth, room.height);
    let id = Pose::IDENTITY;
    let tiles = room.kind == RoomKind::Bathroom || s.chance(0.15);
    let floor = super::furniture::floor_material(b, s, tiles);
    b.add_box(
        &id,
        v3(-0.2, -0.2, -0.1),
        v3(w + 0.2, d + 0.2, 0.0),
        floor,
        Surface::Floor,
    );
    let paint = super::furniture::wall_material(b, s);
    let t = 0.1;
    b.add_box(
        &id,
        v3(-t, -t, 0.0),
        v3(w + t, 0.0, h),
        paint,
        Surface::Wall,
    );
    b.add_box(
        &id,
        v3(-t, d, 0.0),
        v3(w + t, d + t, h),
        paint,
        Surface::Wall,
    );
    b.add_box(&id, v3(-t, 0.0, 0.0), v3(0.0, d, h), paint, Surface::Wall);
    b.add_box(&id, v3(w, 0.0, 0.0), v3(w + t, d, h), paint, Surface::Wall);
    if room.ceiling {
        let white = b.material(Material::solid([0.92, 0.92, 0.9], 0.5));
        b.add_box(
            &id,
            v3(-t, -t, h),
            v3(w + t, d + t, h + t),
            white,
            Surface::Ceiling,
        );
    }
    let skirting = b.material(Material::solid([0.8, 0.78, 0.74], 0.5));
    for k in 0..4 {
        let wall = room.wall(k);
        let a = wall.origin;
        let e = wall.origin + wall.along * wall.length + wall.normal * 0.012;
        let (lo, hi) = (a.min(e), a.max(e));
        b.add_box(
            &id,
            v3(lo.x, lo.y, 0.0),
            v3(hi.x, hi.y, 0.08),
            skirting,
            Surface::Wall,
        );
    }
    // The door, not on the camera's wall (a frame is rarely taken standing in a doorway).
    let door_wall = (camera_wall + 1 + s.below(3)) % 4;
    let wall = room.wall(door_wall);
    let width = 0.85f64.min(wall.length - 0.3);
    let at = s.range(width / 2.0 + 0.1, wall.length - width / 2.0 - 0.1);
    let door_m = b.material(Material::solid(
        [[0.55, 0.38, 0.22], [0.9, 0.9, 0.88], [0.4, 0.28, 0.18]][s.below(3)],
        0.5,
    ));
    wall_panel(b, &wall, at, width, 0.0, 2.05, 0.02, door_m, Surface::Wall);
    // Its swing stays free.
    plan.taken
        .push(Rect::of(&wall.pose_against(at, width, 0.0), width, width));
    if s.chance(0.6) {
        // A window (glass: the depth sensor's pattern mostly passes through).
        let k = (door_wall + 1 + s.below(3)) % 4;
        let wall = room.wall(k);
        let ww = s.range(0.9, 1.8).min(wall.length - 0.6);
        if ww > 0.5 {
            let at = s.range(ww / 2.0 + 0.3, wall.length - ww / 2.0 - 0.3);
            let glass = b.material(Material::solid([0.82, 0.88, 0.95], 0.5).glassy(0.15));
            wall_panel(b, &wall, at, ww, 0.9, 2.1, 0.01, glass, Surface::Wall);
        }
    }
    Door {
        wall: door_wall,
        at,
        width,
    }
}

/// A flat panel on a wall: `width` wide around `at`, from z0 to z1, `proud` out of the wall.
#[allow(clippy::too_many_arguments)]
pub fn wall_panel(
    b: &mut SceneBuilder,
    wall: &Wall,
    at: f64,
    width: f64,
    z0: f64,
    z1: f64,
    proud: f64,
    m: u16,
    surface: Surface,
) {
    let a = wall.origin + wall.along * (at - width / 2.0);
    let e = wall.origin + wall.along * (at + width / 2.0) + wall.normal * proud;
    let (lo, hi) = (a.min(e), a.max(e));
    b.add_box(
        &Pose::IDENTITY,
        v3(lo.x, lo.y, z0),
        v3(hi.x, hi.y, z1),
        m,
        surface,
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rectangles_overlap_exactly_when_they_should() {
        let a = Rect {
            cx: 0.0,
            cy: 0.0,
            yaw: 0.0,
            hx: 1.0,
            hy: 0.5,
        };
        let mut b = Rect {
            cx: 2.05,
            cy: 0.0,
            yaw: 0.0,
            hx: 1.0,
            hy: 0.5,
        };
        assert!(!a.overlaps(&b, 0.0));
        assert!(a.overlaps(&b, 0.03));
        // Turned by 45°, its corner reaches 1.06 m towards a: overlap.
        b.yaw = std::f64::consts::FRAC_PI_4;
        b.cx = 1.9;
        assert!(a.overlaps(&b, 0.0));
        b.cx = 2.1;
        assert!(!a.overlaps(&b, 0.0));
    }

    #[test]
    fn a_piece_against_a_wall_faces_into_the_room_and_touches_nothing_outside() {
        let room = Room {
            kind: RoomKind::Bedroom,
            width: 4.0,
            depth: 5.0,
            height: 2.6,
            ceiling: true,
        };
        let plan = FloorPlan::new(&room);
        for k in 0..4 {
            let wall = room.wall(k);
            let pose = wall.pose_against(1.0, 0.6, 0.02);
            // Facing = the inward normal; the back 2 cm from the wall.
            assert!((pose.rot.cols[0] - wall.normal).norm() < 1e-12);
            let back = pose.point(v3(-0.3, 0.0, 0.0));
            let dist = (back - wall.origin).dot(wall.normal);
            assert!((dist - 0.02).abs() < 1e-12);
            assert!(plan.fits(&Rect::of(&pose, 0.6, 1.0), 0.0));
        }
    }
}
