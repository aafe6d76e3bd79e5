//! Scene layout: a street in its own frame (x along the street, y to the left, z up,
//! ground at z = 0) with a road of 2–4 lanes, parking strips, curbs, sidewalks,
//! front yards, building façades, trees, lamp posts, signs, hedges and street
//! furniture; cars parked in rows (sometimes a perpendicular parking lot) and
//! driving in both directions, vans and trucks among them, pedestrians alone and in
//! groups (sometimes crossing), cyclists, and now and then a cross street.
//! Four scene kinds (city, residential, arterial road, campus) set the densities;
//! their weights are tuned so that the labelled class mix and occlusion levels
//! resemble KITTI's.

use crate::material::{Material, Pattern};
use crate::math::{M3, Pose, cos, rad, sin, v3};
use crate::parts;
use crate::primitive::{NO_OWNER, Shape, Surface};
use crate::rng::Sampler;
use crate::scene::{Clutter, ClutterKind, Scene, SceneBuilder};
use fusiondet_kitti::ObjectClass;
use std::f64::consts::{FRAC_PI_2, PI};

/// The kinds of street the simulator draws from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize)]
pub enum SceneKind {
    City,
    Residential,
    Arterial,
    Campus,
}

impl SceneKind {
    pub const ALL: [SceneKind; 4] = [
        SceneKind::City,
        SceneKind::Residential,
        SceneKind::Arterial,
        SceneKind::Campus,
    ];
}

/// Scene-level knobs (the defaults give KITTI-like streets).
#[derive(Debug, Clone, PartialEq)]
pub struct LayoutConfig {
    /// Relative frequency of city, residential, arterial and campus scenes.
    pub kind_weights: [f64; 4],
    /// Height of the LiDAR above the ground (KITTI: 1.73 m).
    pub mount_height: f64,
    /// Multiplies the number of pedestrians/cyclists/driving cars (1 = default).
    pub traffic_scale: f64,
}

impl Default for LayoutConfig {
    fn default() -> Self {
        LayoutConfig {
            kind_weights: [0.35, 0.3, 0.2, 0.15],
            mount_height: 1.73,
            traffic_scale: 1.0,
        }
    }
}

/// What the layout decided, for statistics and debugging.
#[derive(Debug, Clone, PartialEq)]
pub struct LayoutInfo {
    pub kind: SceneKind,
    pub lanes: (usize, usize),
    pub cross_street: Option<f64>,
    /// Street frame → LiDAR frame.
    pub to_lidar: Pose,
}

/// Per-kind densities.
struct KindParams {
    lanes: &'static [(usize, usize)],
    parking_prob: f64,
    sidewalk: (f64, f64),
    yard: (f64, f64),
    building_h: (f64, f64),
    tree_prob: f64,
    tree_spacing: (f64, f64),
    occupancy: (f64, f64),
    headway: f64,
    ped_groups: f64,
    group_extra: f64,
    cyclists: f64,
    buildings_prob: f64,
    lot_prob: f64,
    cross_prob: f64,
    hedge_prob: f64,
}

fn params(kind: SceneKind) -> KindParams {
    match kind {
        SceneKind::City => KindParams {
            lanes: &[(1, 1), (1, 1), (2, 2), (2, 1)],
            parking_prob: 0.7,
            sidewalk: (2.5, 5.0),
            yard: (0.0, 1.5),
            building_h: (10.0, 22.0),
            tree_prob: 0.45,
            tree_spacing: (9.0, 18.0),
            occupancy: (0.25, 0.75),
            headway: 35.0,
            ped_groups: 2.4,
            group_extra: 0.6,
            cyclists: 1.2,
            buildings_prob: 0.95,
            lot_prob: 0.08,
            cross_prob: 0.4,
            hedge_prob: 0.1,
        },
        SceneKind::Residential => KindParams {
            lanes: &[(1, 1)],
            parking_prob: 0.65,
            sidewalk: (1.5, 3.0),
            yard: (2.0, 8.0),
            building_h: (6.0, 12.0),
            tree_prob: 0.85,
            tree_spacing: (8.0, 14.0),
            occupancy: (0.2, 0.65),
            headway: 50.0,
            ped_groups: 1.2,
            group_extra: 0.4,
            cyclists: 0.8,
            buildings_prob: 0.9,
            lot_prob: 0.05,
            cross_prob: 0.35,
            hedge_prob: 0.6,
        },
        SceneKind::Arterial => KindParams {
            lanes: &[(2, 2), (2, 2), (3, 2), (1, 1)],
            parking_prob: 0.3,
            sidewalk: (2.0, 4.0),
            yard: (3.0, 15.0),
            building_h: (6.0, 16.0),
            tree_prob: 0.8,
            tree_spacing: (8.0, 20.0),
            occupancy: (0.2, 0.6),
            headway: 35.0,
            ped_groups: 0.8,
            group_extra: 0.3,
            cyclists: 0.8,
            buildings_prob: 0.6,
            lot_prob: 0.15,
            cross_prob: 0.25,
            hedge_prob: 0.4,
        },
        SceneKind::Campus => KindParams {
            lanes: &[(1, 1), (2, 2)],
            parking_prob: 0.4,
            sidewalk: (4.0, 8.0),
            yard: (2.0, 10.0),
            building_h: (8.0, 20.0),
            tree_prob: 0.9,
            tree_spacing: (6.0, 12.0),
            occupancy: (0.3, 0.7),
            headway: 45.0,
            ped_groups: 5.0,
            group_extra: 0.9,
            cyclists: 3.0,
            buildings_prob: 0.8,
            lot_prob: 0.05,
            cross_prob: 0.5,
            hedge_prob: 0.3,
        },
    }
}

/// A footprint on the ground (oriented rectangle) used to keep things from overlapping.
#[derive(Debug, Clone, Copy)]
struct Footprint {
    c: (f64, f64),
    axis: (f64, f64),
    hl: f64,
    hw: f64,
}

impl Footprint {
    fn new(x: f64, y: f64, heading: f64, l: f64, w: f64) -> Footprint {
        Footprint {
            c: (x, y),
            axis: (cos(heading), sin(heading)),
            hl: l / 2.0,
            hw: w / 2.0,
        }
    }
    /// Separating-axis test of two oriented rectangles.
    fn overlaps(&self, o: &Footprint) -> bool {
        let d = (o.c.0 - self.c.0, o.c.1 - self.c.1);
        let r_a = (self.hl * self.hl + self.hw * self.hw).sqrt();
        let r_b = (o.hl * o.hl + o.hw * o.hw).sqrt();
        if d.0 * d.0 + d.1 * d.1 > (r_a + r_b) * (r_a + r_b) {
            return false;
        }
        let axes = [
            self.axis,
            (-self.axis.1, self.axis.0),
            o.axis,
            (-o.axis.1, o.axis.0),
        ];
        for a in axes {
            let proj = |f: &Footprint| {
                let u = f.axis;
                let v = (-u.1, u.0);
                f.hl * (u.0 * a.0 + u.1 * a.1).abs() + f.hw * (v.0 * a.0 + v.1 * a.1).abs()
            };
            let dist = (d.0 * a.0 + d.1 * a.1).abs();
            if dist > proj(self) + proj(o) {
                return false;
            }
        }
        true
    }
}

/// The street's cross-section and what has been placed so far.
struct Street {
    p: KindParams,
    lane_w: f64,
    lanes_right: usize,
    lanes_left: usize,
    /// y of the road's outer edges (right edge negative).
    edge_r: f64,
    edge_l: f64,
    park_r: Option<f64>,
    park_l: Option<f64>,
    curb: f64,
    sidewalk_r: f64,
    sidewalk_l: f64,
    yard_r: f64,
    yard_l: f64,
    /// Cross street: centre x and road width.
    cross: Option<(f64, f64)>,
    x_min: f64,
    x_max: f64,
    taken: Vec<Footprint>,
}

impl Street {
    fn free(&self, f: &Footprint) -> bool {
        !self.taken.iter().any(|t| t.overlaps(f))
    }
    /// Is x inside the cross street (plus `margin`)?
    fn in_cross(&self, x: f64, margin: f64) -> bool {
        self.cross
            .is_some_and(|(xc, wc)| (x - xc).abs() < wc / 2.0 + margin)
    }
    /// The x-intervals of [x_min, x_max] outside the cross street widened by `margin`.
    fn spans(&self, margin: f64) -> Vec<(f64, f64)> {
        match self.cross {
            Some((xc, wc)) => vec![
                (self.x_min, xc - wc / 2.0 - margin),
                (xc + wc / 2.0 + margin, self.x_max),
            ],
            None => vec![(self.x_min, self.x_max)],
        }
    }
    /// y of the outer edge of the sidewalk on `side` (+1 left, −1 right).
    fn sidewalk_outer(&self, side: f64) -> f64 {
        if side > 0.0 {
            self.edge_l + self.sidewalk_l
        } else {
            self.edge_r - self.sidewalk_r
        }
    }
    fn edge(&self, side: f64) -> f64 {
        if side > 0.0 { self.edge_l } else { self.edge_r }
    }
    fn sidewalk_w(&self, side: f64) -> f64 {
        if side > 0.0 {
            self.sidewalk_l
        } else {
            self.sidewalk_r
        }
    }
    fn yard(&self, side: f64) -> f64 {
        if side > 0.0 { self.yard_l } else { self.yard_r }
    }
    fn parking(&self, side: f64) -> Option<f64> {
        if side > 0.0 { self.park_l } else { self.park_r }
    }
}

/// Shared static materials of one scene.
struct Palette {
    road: u16,
    marking: u16,
    sidewalk: u16,
    curb: u16,
    grass: u16,
    terrain: u16,
    trunk: u16,
    leaves: [u16; 3],
    hedge: u16,
    pole: u16,
    sign: u16,
    wall: u16,
    bin: u16,
}

fn palette(b: &mut SceneBuilder, s: &mut Sampler) -> Palette {
    let asphalt = s.range(0.28, 0.4);
    Palette {
        road: b.material(
            Material::solid([asphalt, asphalt, asphalt * 1.03], s.range(0.3, 0.38))
                .with_pattern(Pattern::Speckle { amount: 0.05 }),
        ),
        marking: b.material(Material::solid([0.9, 0.9, 0.88], s.range(0.6, 0.85))),
        sidewalk: b.material(
            Material::solid([0.58, 0.55, 0.52], s.range(0.3, 0.4))
                .with_pattern(Pattern::Pavers { size: 0.6 }),
        ),
        curb: b.material(Material::solid([0.65, 0.64, 0.62], 0.3)),
        grass: b.material(
            Material::solid([0.2, 0.38, 0.12], s.range(0.35, 0.5))
                .with_pattern(Pattern::Speckle { amount: 0.2 }),
        ),
        terrain: b.material(
            Material::solid([0.35, 0.36, 0.22], 0.3).with_pattern(Pattern::Speckle { amount: 0.2 }),
        ),
        trunk: b.material(Material::solid([0.3, 0.22, 0.15], 0.35)),
        leaves: [
            b.material(
                Material::solid([0.14, 0.3, 0.1], s.range(0.3, 0.5))
                    .with_pattern(Pattern::Leaves)
                    .porous(s.range(0.6, 1.2)),
            ),
            b.material(
                Material::solid([0.22, 0.36, 0.12], s.range(0.3, 0.5))
                    .with_pattern(Pattern::Leaves)
                    .porous(s.range(0.6, 1.2)),
            ),
            b.material(
                Material::solid([0.1, 0.22, 0.08], s.range(0.3, 0.5))
                    .with_pattern(Pattern::Leaves)
                    .porous(s.range(0.8, 1.5)),
            ),
        ],
        hedge: b.material(
            Material::solid([0.12, 0.28, 0.1], 0.4)
                .with_pattern(Pattern::Leaves)
                .porous(0.3),
        ),
        pole: b.material(Material::solid([0.4, 0.42, 0.42], 0.3)),
        sign: b.material(Material::solid([0.85, 0.85, 0.9], 0.95)),
        wall: b.material(Material::solid([0.6, 0.57, 0.52], 0.3)),
        bin: b.material(Material::solid([0.25, 0.3, 0.28], 0.15)),
    }
}

/// Builds one random street scene (in the LiDAR frame) from the frame's layout stream.
pub fn build_scene(s: &mut Sampler, cfg: &LayoutConfig) -> (Scene, LayoutInfo) {
    let kind = SceneKind::ALL[s.weighted(&cfg.kind_weights)];
    let p = params(kind);
    let mut b = SceneBuilder::new();
    let pal = palette(&mut b, s);

    // Cross-section.
    let lane_w = s.range(3.0, 3.5);
    let (lanes_right, lanes_left) = *s.pick(p.lanes);
    let park_r = s.chance(p.parking_prob).then(|| s.range(2.0, 2.4));
    let park_l = s.chance(p.parking_prob).then(|| s.range(2.0, 2.4));
    let edge_r = -(lanes_right as f64 * lane_w + park_r.unwrap_or(0.3));
    let edge_l = lanes_left as f64 * lane_w + park_l.unwrap_or(0.3);
    let cross = s
        .chance(p.cross_prob)
        .then(|| (s.range(14.0, 60.0), s.range(8.0, 14.0)));
    let mut street = Street {
        lane_w,
        lanes_right,
        lanes_left,
        edge_r,
        edge_l,
        park_r,
        park_l,
        curb: s.range(0.1, 0.16),
        sidewalk_r: s.range(p.sidewalk.0, p.sidewalk.1),
        sidewalk_l: s.range(p.sidewalk.0, p.sidewalk.1),
        yard_r: s.range(p.yard.0, p.yard.1),
        yard_l: s.range(p.yard.0, p.yard.1),
        cross,
        x_min: -90.0,
        x_max: 150.0,
        taken: Vec::new(),
        p,
    };
    // The ego car: in a right-hand lane, facing along +x.
    let ego_lane = s.int(0, lanes_right as i64 - 1) as f64;
    let y_ego = -(ego_lane + 0.5) * lane_w + s.range(-0.3, 0.3);
    street
        .taken
        .push(Footprint::new(-0.8, y_ego, 0.0, 5.0, 2.2));

    ground(&mut b, &street, &pal);
    markings(&mut b, s, &street, &pal);
    roadside(&mut b, s, &mut street, &pal);
    parked_cars(&mut b, s, &mut street);
    traffic(&mut b, s, &mut street, y_ego, cfg.traffic_scale);
    people(&mut b, s, &mut street, cfg.traffic_scale);

    // Street frame → LiDAR frame: sensor above the ego position, small yaw of the ego
    // relative to the street and a small roll/pitch of the car body.
    let yaw = s.normal_clamped(0.0, rad(2.5), rad(-7.0), rad(7.0));
    let roll = s.normal_clamped(0.0, rad(0.4), rad(-1.0), rad(1.0));
    let pitch = s.normal_clamped(0.0, rad(0.4), rad(-1.0), rad(1.0));
    let tilt = M3::rot_x(roll).mul(&M3::rot_y(pitch));
    let rot = tilt.mul(&M3::rot_z(-yaw));
    let sensor = v3(0.0, y_ego, cfg.mount_height);
    let to_lidar = Pose {
        rot,
        t: rot.apply(-sensor),
    };
    let sun_az = s.range(-PI, PI);
    let sun_el = rad(s.range(20.0, 60.0));
    let sun = v3(
        cos(sun_el) * cos(sun_az),
        cos(sun_el) * sin(sun_az),
        sin(sun_el),
    );
    let info = LayoutInfo {
        kind,
        lanes: (lanes_right, lanes_left),
        cross_street: street.cross.map(|c| c.0),
        to_lidar,
    };
    (b.finish(&to_lidar, sun), info)
}

/// Terrain, road slab, sidewalks with curbs, yards, and the cross street.
fn ground(b: &mut SceneBuilder, st: &Street, pal: &Palette) {
    let id = Pose::IDENTITY;
    b.add_unbounded_box(
        &id,
        v3(-250.0, -250.0, -1.0),
        v3(300.0, 250.0, -0.03),
        pal.terrain,
        Surface::Grass,
    );
    b.add_box(
        &id,
        v3(st.x_min - 60.0, st.edge_r, -0.5),
        v3(st.x_max + 60.0, st.edge_l, 0.0),
        pal.road,
        Surface::Road,
    );
    for side in [1.0, -1.0] {
        let e = st.edge(side);
        let o = st.sidewalk_outer(side);
        let y_far = o + side * st.yard(side);
        for (x0, x1) in st.spans(0.0) {
            let (a, c) = (e.min(o), e.max(o));
            b.add_box(
                &id,
                v3(x0, a, -0.5),
                v3(x1, c, st.curb),
                pal.sidewalk,
                Surface::Sidewalk,
            );
            // The curb stone: a lighter strip on the road edge.
            let (ca, cc) = (e.min(e + side * 0.15), e.max(e + side * 0.15));
            b.add_box(
                &id,
                v3(x0, ca, -0.5),
                v3(x1, cc, st.curb + 0.002),
                pal.curb,
                Surface::Sidewalk,
            );
        }
        for (x0, x1) in st.spans(st.sidewalk_w(side)) {
            if st.yard(side) > 0.3 {
                let (a, c) = (o.min(y_far), o.max(y_far));
                b.add_box(
                    &id,
                    v3(x0, a, -0.5),
                    v3(x1, c, st.curb - 0.02),
                    pal.grass,
                    Surface::Grass,
                );
            }
        }
    }
    if let Some((xc, wc)) = st.cross {
        b.add_box(
            &id,
            v3(xc - wc / 2.0, -200.0, -0.5),
            v3(xc + wc / 2.0, 200.0, -0.001),
            pal.road,
            Surface::Road,
        );
        for side in [1.0, -1.0] {
            let sw = st.sidewalk_w(side);
            for (x0, x1) in [
                (xc - wc / 2.0 - sw, xc - wc / 2.0),
                (xc + wc / 2.0, xc + wc / 2.0 + sw),
            ] {
                let (a, c) = if side > 0.0 {
                    (st.edge_l, 200.0)
                } else {
                    (-200.0, st.edge_r)
                };
                b.add_box(
                    &id,
                    v3(x0, a, -0.5),
                    v3(x1, c, st.curb),
                    pal.sidewalk,
                    Surface::Sidewalk,
                );
            }
        }
    }
}

/// Lane markings: dashed lane dividers and centre line, solid edge lines where there
/// is no parking strip, a zebra crossing before a cross street. Bright in reflectance.
fn markings(b: &mut SceneBuilder, s: &mut Sampler, st: &Street, pal: &Palette) {
    let id = Pose::IDENTITY;
    let z = 0.004;
    let phase = s.range(0.0, 9.0);
    let mut dividers = Vec::new();
    for k in 1..st.lanes_right {
        dividers.push(-(k as f64) * st.lane_w);
    }
    for k in 1..st.lanes_left {
        dividers.push(k as f64 * st.lane_w);
    }
    let centre_solid = st.lanes_right + st.lanes_left >= 4;
    for (x0, x1) in st.spans(2.0) {
        if centre_solid {
            b.add_box(
                &id,
                v3(x0, -0.08, -0.1),
                v3(x1, 0.08, z),
                pal.marking,
                Surface::Marking,
            );
        } else {
            dividers.push(0.0);
        }
        for &y in &dividers {
            let mut x = x0 + phase % 9.0;
            while x + 3.0 < x1 {
                if x > -60.0 && x < 110.0 {
                    b.add_box(
                        &id,
                        v3(x, y - 0.06, -0.1),
                        v3(x + 3.0, y + 0.06, z),
                        pal.marking,
                        Surface::Marking,
                    );
                }
                x += 9.0;
            }
        }
        if !centre_solid {
            dividers.pop();
        }
        for (side, park) in [(1.0, st.park_l), (-1.0, st.park_r)] {
            let y = st.edge(side) - side * park.unwrap_or(0.0) - side * 0.35;
            b.add_box(
                &id,
                v3(x0, y - 0.075, -0.1),
                v3(x1, y + 0.075, z),
                pal.marking,
                Surface::Marking,
            );
        }
    }
    if let Some((xc, wc)) = st.cross {
        let x1 = xc - wc / 2.0 - 1.0;
        let mut y = st.edge_r + 0.5;
        while y + 0.5 < st.edge_l - 0.3 {
            b.add_box(
                &id,
                v3(x1 - 3.5, y, -0.1),
                v3(x1, y + 0.5, z),
                pal.marking,
                Surface::Marking,
            );
            y += 1.0;
        }
    }
}

/// Buildings, yards with hedges and walls, trees, lamp posts, signs and furniture.
fn roadside(b: &mut SceneBuilder, s: &mut Sampler, st: &mut Street, pal: &Palette) {
    let id = Pose::IDENTITY;
    for side in [1.0, -1.0] {
        let outer = st.sidewalk_outer(side);
        let yard = st.yard(side);
        let front = outer + side * yard;
        let lot = s.chance(st.p.lot_prob);
        // Parking lot instead of buildings along a stretch.
        let lot_span = lot.then(|| {
            let x0 = s.range(-10.0, 40.0);
            (x0, x0 + s.range(25.0, 45.0))
        });
        if let Some((x0, x1)) = lot_span {
            parking_lot(b, s, st, side, front, x0, x1, pal);
        }
        // Building façades.
        if s.chance(st.p.buildings_prob) {
            for (x0, x1) in st.spans(st.sidewalk_w(side) + 1.0) {
                let mut x = x0;
                while x < x1 {
                    let w = s.range(8.0, 26.0).min(x1 - x);
                    if w < 3.0 {
                        break;
                    }
                    let in_lot = lot_span.is_some_and(|(a, c)| x + w > a - 2.0 && x < c + 2.0);
                    if !in_lot && !s.chance(0.08) {
                        let setback = s.range(0.0, 1.2);
                        building(b, s, st, side, front + side * setback, x, x + w);
                    }
                    x += w + if s.chance(0.2) {
                        s.range(2.0, 8.0)
                    } else {
                        0.0
                    };
                }
            }
            if let Some((xc, wc)) = st.cross {
                // Façades along the cross street.
                for (xa, xb) in [
                    (
                        xc - wc / 2.0 - 40.0,
                        xc - wc / 2.0 - st.sidewalk_w(side) - 1.0,
                    ),
                    (
                        xc + wc / 2.0 + st.sidewalk_w(side) + 1.0,
                        xc + wc / 2.0 + 40.0,
                    ),
                ] {
                    let ya = front + side * 15.0;
                    building(b, s, st, side, ya, xa, xb);
                }
            }
        }
        // Hedges or low walls at the property line.
        if yard > 1.5 && s.chance(st.p.hedge_prob) {
            let hedge = s.chance(0.7);
            let h = if hedge {
                s.range(0.8, 1.8)
            } else {
                s.range(0.5, 1.2)
            };
            let t = if hedge { s.range(0.5, 1.0) } else { 0.25 };
            for (x0, x1) in st.spans(st.sidewalk_w(side) + 1.0) {
                let mut x = x0;
                while x < x1 {
                    let len = s.range(6.0, 20.0).min(x1 - x);
                    let y = front - side * s.range(0.3, 1.0);
                    let in_lot = lot_span.is_some_and(|(a, c)| x + len > a && x < c);
                    if !in_lot {
                        let (m, surf) = if hedge {
                            (pal.hedge, Surface::Vegetation)
                        } else {
                            (pal.wall, Surface::Wall)
                        };
                        b.add_box(
                            &id,
                            v3(x, y.min(y + side * t), st.curb - 0.05),
                            v3(x + len, y.max(y + side * t), st.curb + h),
                            m,
                            surf,
                        );
                        if hedge {
                            b.clutter.push(Clutter {
                                kind: ClutterKind::Blob,
                                bottom_center: v3(x + len / 2.0, y, st.curb),
                                w: len.min(4.0),
                                h,
                            });
                        }
                    }
                    x += len + s.range(1.0, 4.0);
                }
            }
        }
        // Trees along the sidewalk (in tree pits near the curb or at its outer edge).
        if s.chance(st.p.tree_prob) {
            let (lo, hi) = st.p.tree_spacing;
            let near_curb = s.chance(0.6);
            for (x0, x1) in st.spans(3.0) {
                let mut x = x0 + s.range(0.0, hi);
                while x < x1 {
                    let y = if near_curb {
                        st.edge(side) + side * s.range(0.6, 1.0)
                    } else {
                        outer + side * s.range(0.5, (yard - 0.5).max(0.6))
                    };
                    tree(b, s, st, pal, x, y);
                    x += s.range(lo, hi);
                }
            }
        }
        // Lamp posts at the curb.
        let spacing = s.range(22.0, 38.0);
        for (x0, x1) in st.spans(2.0) {
            let mut x = x0 + s.range(0.0, spacing);
            while x < x1 {
                let y = st.edge(side) + side * 0.45;
                if st.free(&Footprint::new(x, y, 0.0, 0.4, 0.4)) {
                    lamp(b, s, st, pal, x, y, side);
                }
                x += spacing;
            }
        }
        // Signs, bins, bollards, parked bicycles on the sidewalk.
        let n_items = s.poisson(6.0);
        for _ in 0..n_items {
            let x = s.range(-40.0, 90.0);
            if st.in_cross(x, 1.0) {
                continue;
            }
            let y = st.edge(side) + side * s.range(0.3, st.sidewalk_w(side) - 0.3).max(0.35);
            furniture(b, s, st, pal, x, y);
        }
    }
    if let Some((xc, wc)) = st.cross {
        // Traffic lights at the corners.
        for (dx, side) in [(-1.0, 1.0), (-1.0, -1.0), (1.0, 1.0), (1.0, -1.0)] {
            let x = xc + dx * (wc / 2.0 + 0.6);
            let y = st.edge(side) + side * 0.6;
            let mut pose = Pose::IDENTITY;
            pose.t = v3(x, y, st.curb);
            pole(b, &pose, pal.pole, 0.07, 3.2);
            b.add_box(
                &pose,
                v3(-0.15, -0.15, 2.3),
                v3(0.15, 0.15, 3.2),
                pal.bin,
                Surface::Sign,
            );
            b.clutter.push(Clutter {
                kind: ClutterKind::Upright,
                bottom_center: pose.t,
                w: 0.4,
                h: 3.2,
            });
            st.taken.push(Footprint::new(x, y, 0.0, 0.5, 0.5));
        }
    }
}

/// A building: a box with a façade pattern, its front face at `y_front`.
fn building(
    b: &mut SceneBuilder,
    s: &mut Sampler,
    st: &Street,
    side: f64,
    y_front: f64,
    x0: f64,
    x1: f64,
) {
    let colours = [
        [0.78, 0.72, 0.62],
        [0.85, 0.83, 0.78],
        [0.6, 0.35, 0.28],
        [0.55, 0.55, 0.55],
        [0.75, 0.65, 0.45],
        [0.7, 0.75, 0.72],
    ];
    let rgb = *s.pick(&colours);
    let storey = s.range(2.8, 3.6);
    let m = b.material(
        Material::solid(rgb, s.range(0.15, 0.45)).with_pattern(Pattern::Facade {
            storey,
            spacing: s.range(2.5, 4.5),
            window_rgb: [0.12, 0.14, 0.18],
            ground_floor: s.range(0.5, 4.0),
        }),
    );
    let h = s.range(st.p.building_h.0, st.p.building_h.1);
    let depth = s.range(8.0, 16.0);
    let (a, c) = (
        y_front.min(y_front + side * depth),
        y_front.max(y_front + side * depth),
    );
    b.add_box(
        &Pose::IDENTITY,
        v3(x0, a, -0.5),
        v3(x1, c, h),
        m,
        Surface::Building,
    );
    if s.chance(0.3) && h > 8.0 {
        // A balcony row or shop awning sticking out of the façade.
        let z = s.range(2.8, 4.0);
        let (a2, c2) = (
            y_front.min(y_front - side * 1.2),
            y_front.max(y_front - side * 1.2),
        );
        b.add_box(
            &Pose::IDENTITY,
            v3(x0 + 0.5, a2, z),
            v3(x1 - 0.5, c2, z + 0.25),
            m,
            Surface::Building,
        );
    }
}

/// A tree: trunk and one to three porous crowns.
fn tree(b: &mut SceneBuilder, s: &mut Sampler, st: &mut Street, pal: &Palette, x: f64, y: f64) {
    let r = s.range(0.1, 0.3);
    let fp = Footprint::new(x, y, 0.0, 2.0 * r + 0.3, 2.0 * r + 0.3);
    if !st.free(&fp) {
        return;
    }
    st.taken.push(fp);
    let trunk_h = s.range(1.8, 3.5);
    let mut pose = Pose::IDENTITY;
    pose.t = v3(x, y, st.curb - 0.05);
    b.add(
        &pose,
        Shape::Cylinder,
        v3(0.0, 0.0, trunk_h / 2.0 + 0.5),
        M3::IDENTITY,
        v3(r, r, trunk_h / 2.0 + 0.5),
        pal.trunk,
        Surface::Trunk,
        NO_OWNER,
    );
    let crown_r = s.range(1.5, 3.5) * (0.6 + r * 1.5);
    let leaves = pal.leaves[s.int(0, 2) as usize];
    let n = s.int(1, 3);
    for _ in 0..n {
        let rz = crown_r * s.range(0.8, 1.3);
        let c = v3(
            s.range(-0.5, 0.5),
            s.range(-0.5, 0.5),
            trunk_h + rz * s.range(0.6, 0.9),
        );
        b.add(
            &pose,
            Shape::Ellipsoid,
            c,
            M3::rot_z(s.range(0.0, PI)),
            v3(crown_r * s.range(0.8, 1.1), crown_r * s.range(0.8, 1.1), rz),
            leaves,
            Surface::Vegetation,
            NO_OWNER,
        );
    }
    b.clutter.push(Clutter {
        kind: ClutterKind::Upright,
        bottom_center: pose.t,
        w: 2.0 * r + 0.2,
        h: trunk_h,
    });
}

fn pole(b: &mut SceneBuilder, pose: &Pose, material: u16, r: f64, h: f64) {
    b.add(
        pose,
        Shape::Cylinder,
        v3(0.0, 0.0, h / 2.0),
        M3::IDENTITY,
        v3(r, r, h / 2.0),
        material,
        Surface::Pole,
        NO_OWNER,
    );
}

/// A street lamp: tall pole, arm over the road, lamp head.
fn lamp(
    b: &mut SceneBuilder,
    s: &mut Sampler,
    st: &mut Street,
    pal: &Palette,
    x: f64,
    y: f64,
    side: f64,
) {
    let h = s.range(6.0, 9.0);
    let mut pose = Pose::IDENTITY;
    pose.t = v3(x, y, st.curb);
    pole(b, &pose, pal.pole, s.range(0.07, 0.12), h);
    let arm = s.range(0.8, 2.0);
    let (a, c) = (0.0f64.min(-side * arm), 0.0f64.max(-side * arm));
    b.add_box(
        &pose,
        v3(-0.04, a, h - 0.1),
        v3(0.04, c, h),
        pal.pole,
        Surface::Pole,
    );
    b.add_box(
        &pose,
        v3(-0.25, -side * arm - 0.15, h - 0.25),
        v3(0.25, -side * arm + 0.15, h - 0.05),
        pal.pole,
        Surface::Pole,
    );
    st.taken.push(Footprint::new(x, y, 0.0, 0.4, 0.4));
    b.clutter.push(Clutter {
        kind: ClutterKind::Upright,
        bottom_center: pose.t,
        w: 0.3,
        h: 2.5,
    });
}

/// Sidewalk furniture: a sign, a bin, bollards or a parked bicycle.
fn furniture(
    b: &mut SceneBuilder,
    s: &mut Sampler,
    st: &mut Street,
    pal: &Palette,
    x: f64,
    y: f64,
) {
    let choice = s.weighted(&[0.3, 0.25, 0.2, 0.25]);
    let (l, w) = [(0.5, 0.5), (0.7, 0.7), (0.3, 0.3), (1.8, 0.6)][choice];
    let heading = if choice == 3 {
        s.range(0.0, 2.0 * PI)
    } else {
        0.0
    };
    let fp = Footprint::new(x, y, heading, l + 0.2, w + 0.2);
    if !st.free(&fp) {
        return;
    }
    st.taken.push(fp);
    let pose = Pose {
        rot: M3::rot_z(heading),
        t: v3(x, y, st.curb),
    };
    match choice {
        0 => {
            let h = s.range(2.2, 2.9);
            pole(b, &pose, pal.pole, 0.035, h);
            // The plate faces the road.
            b.add_box(
                &pose,
                v3(-0.3, -0.02, h - 0.65),
                v3(0.3, 0.02, h),
                pal.sign,
                Surface::Sign,
            );
            b.clutter.push(Clutter {
                kind: ClutterKind::Upright,
                bottom_center: pose.t,
                w: 0.6,
                h,
            });
        }
        1 => {
            let h = s.range(0.9, 1.2);
            b.add_box(
                &pose,
                v3(-0.3, -0.3, 0.0),
                v3(0.3, 0.3, h),
                pal.bin,
                Surface::Clutter,
            );
            b.clutter.push(Clutter {
                kind: ClutterKind::Blob,
                bottom_center: pose.t,
                w: 0.6,
                h,
            });
        }
        2 => {
            for k in 0..s.int(2, 4) {
                let mut p = pose;
                p.t = pose.t + v3(k as f64 * 1.5, 0.0, 0.0);
                pole(b, &p, pal.pole, 0.08, 0.9);
            }
        }
        _ => {
            parts::parked_bicycle(b, s, &pose);
            b.clutter.push(Clutter {
                kind: ClutterKind::Bicycle,
                bottom_center: pose.t,
                w: 1.7,
                h: 1.05,
            });
        }
    }
}

/// Places an actor of `class` with the given street pose if its footprint is free;
/// returns its length when placed.
#[allow(clippy::too_many_arguments)]
fn place(
    b: &mut SceneBuilder,
    s: &mut Sampler,
    st: &mut Street,
    class: ObjectClass,
    x: f64,
    y: f64,
    z: f64,
    heading: f64,
    moving: bool,
) -> Option<f64> {
    let dims = parts::sample_dims(class, s);
    place_sized(b, s, st, class, dims, x, y, z, heading, moving).then_some(dims.0)
}

#[allow(clippy::too_many_arguments)]
fn place_sized(
    b: &mut SceneBuilder,
    s: &mut Sampler,
    st: &mut Street,
    class: ObjectClass,
    dims: (f64, f64, f64),
    x: f64,
    y: f64,
    z: f64,
    heading: f64,
    moving: bool,
) -> bool {
    let (l, w, _) = dims;
    let margin = if matches!(class, ObjectClass::Pedestrian) {
        0.05
    } else {
        0.15
    };
    let fp = Footprint::new(x, y, heading, l + margin, w + margin);
    if !st.free(&fp) {
        return false;
    }
    st.taken.push(fp);
    let pose = Pose {
        rot: M3::rot_z(heading),
        t: v3(x, y, z),
    };
    let mut os = s.fork();
    match class {
        ObjectClass::Car => parts::car(b, &mut os, &pose, dims, !moving),
        ObjectClass::Van => parts::van(b, &mut os, &pose, dims, !moving),
        ObjectClass::Truck => parts::truck(b, &mut os, &pose, dims, !moving),
        ObjectClass::Cyclist => parts::cyclist(b, &mut os, &pose, dims, moving),
        _ => parts::pedestrian(b, &mut os, &pose, dims, moving),
    }
    true
}

fn vehicle_class(s: &mut Sampler, van: f64, truck: f64) -> ObjectClass {
    match s.weighted(&[1.0 - van - truck, van, truck]) {
        0 => ObjectClass::Car,
        1 => ObjectClass::Van,
        _ => ObjectClass::Truck,
    }
}

/// Rows of parallel-parked cars in the parking strips, with gaps and empty slots.
fn parked_cars(b: &mut SceneBuilder, s: &mut Sampler, st: &mut Street) {
    for side in [1.0, -1.0] {
        let Some(width) = st.parking(side) else {
            continue;
        };
        let occupancy = s.range(st.p.occupancy.0, st.p.occupancy.1);
        let y = st.edge(side) - side * width / 2.0;
        // Cars park in the direction of traffic on their side.
        let heading = if side > 0.0 { PI } else { 0.0 };
        for (x0, x1) in st.spans(5.0) {
            let mut x = x0.max(-75.0) + s.range(0.0, 4.0);
            while x < x1.min(120.0) {
                if s.chance(occupancy) {
                    let class = vehicle_class(s, 0.08, 0.015);
                    let dims = parts::sample_dims(class, s);
                    let yj = y
                        + s.range(-0.2, 0.2)
                        + if class == ObjectClass::Car {
                            0.0
                        } else {
                            -side * 0.15
                        };
                    let hj = heading + rad(s.normal_clamped(0.0, 2.0, -6.0, 6.0));
                    let centre = x + dims.0 / 2.0;
                    if place_sized(b, s, st, class, dims, centre, yj, 0.0, hj, false) {
                        x = centre + dims.0 / 2.0 + s.range(0.5, 2.2);
                    } else {
                        x += 1.0;
                    }
                } else {
                    x += s.range(4.5, 8.0);
                }
            }
        }
    }
}

/// A parking lot: rows of cars perpendicular to the street beyond the sidewalk.
#[allow(clippy::too_many_arguments)]
fn parking_lot(
    b: &mut SceneBuilder,
    s: &mut Sampler,
    st: &mut Street,
    side: f64,
    front: f64,
    x0: f64,
    x1: f64,
    pal: &Palette,
) {
    let id = Pose::IDENTITY;
    let depth = s.range(12.0, 26.0);
    let (a, c) = (
        front.min(front + side * depth),
        front.max(front + side * depth),
    );
    b.add_box(
        &id,
        v3(x0, a, -0.5),
        v3(x1, c, 0.02),
        pal.road,
        Surface::Road,
    );
    let rows = ((depth - 1.0) / 6.0).floor().max(1.0) as usize;
    let occupancy = s.range(0.5, 0.9);
    for r in 0..rows {
        let y = front + side * (3.0 + 6.0 * r as f64);
        let heading = if (r % 2 == 0) == (side > 0.0) {
            FRAC_PI_2
        } else {
            -FRAC_PI_2
        };
        let mut x = x0 + 1.5;
        while x < x1 - 1.5 {
            if s.chance(occupancy) {
                let class = vehicle_class(s, 0.07, 0.0);
                let hj = heading + rad(s.normal_clamped(0.0, 3.0, -10.0, 10.0));
                let (dx, dy) = (s.range(-0.2, 0.2), s.range(-0.3, 0.3));
                place(b, s, st, class, x + dx, y + dy, 0.02, hj, false);
            }
            x += s.range(2.4, 2.9);
        }
    }
}

/// Driving cars, vans and trucks in every lane in both directions, and on the cross street.
fn traffic(b: &mut SceneBuilder, s: &mut Sampler, st: &mut Street, y_ego: f64, scale: f64) {
    let mut lanes = Vec::new();
    for k in 0..st.lanes_right {
        lanes.push((-(k as f64 + 0.5) * st.lane_w, 0.0));
    }
    for k in 0..st.lanes_left {
        lanes.push(((k as f64 + 0.5) * st.lane_w, PI));
    }
    let headway = st.p.headway / scale.max(0.05);
    for (y, heading) in lanes {
        let ego_lane = (y - y_ego).abs() < st.lane_w / 2.0;
        let mut x = -80.0 + s.range(0.0, headway);
        while x < 130.0 {
            let class = vehicle_class(s, 0.09, 0.05);
            let in_cross = st.in_cross(x, 3.0);
            let behind_ego_gap = ego_lane && x > -9.0 && x < 9.0;
            if !in_cross && !behind_ego_gap {
                let yj = y + s.normal_clamped(0.0, 0.2, -0.5, 0.5);
                let hj = heading + rad(s.normal_clamped(0.0, 1.5, -5.0, 5.0));
                place(b, s, st, class, x, yj, 0.0, hj, true);
            }
            x += 6.0 + s.range(0.0, 1.0) * headway * 2.0;
        }
    }
    if let Some((xc, wc)) = st.cross {
        for _ in 0..s.poisson(1.5 * scale) {
            let dir = if s.chance(0.5) { 1.0 } else { -1.0 };
            let lane_x = xc - dir * wc / 4.0;
            let y = s.range(-40.0, 40.0);
            let class = vehicle_class(s, 0.1, 0.05);
            place(b, s, st, class, lane_x, y, 0.0, dir * FRAC_PI_2, true);
        }
    }
}

/// Pedestrian groups on the sidewalks (some crossing the road) and cyclists.
fn people(b: &mut SceneBuilder, s: &mut Sampler, st: &mut Street, scale: f64) {
    let groups = s.poisson(st.p.ped_groups * scale);
    for _ in 0..groups {
        let side = if s.chance(0.5) { 1.0 } else { -1.0 };
        let crossing = s.chance(0.12);
        let x = s.range(-15.0, 50.0);
        let (gx, gy, heading, z) = if crossing {
            let xz = st.cross.map_or(x, |(xc, wc)| xc - wc / 2.0 - 2.5);
            (
                xz,
                s.range(st.edge_r + 1.0, st.edge_l - 1.0),
                side * FRAC_PI_2,
                0.0,
            )
        } else {
            let y = st.edge(side) + side * s.range(0.5, (st.sidewalk_w(side) - 0.4).max(0.6));
            let heading = if s.chance(0.85) {
                if s.chance(0.5) { 0.0 } else { PI }
            } else {
                s.range(-PI, PI)
            };
            (x, y, heading, st.curb)
        };
        let size = 1 + s.poisson(st.p.group_extra).min(4);
        let walking = s.chance(0.75);
        for k in 0..size {
            let (dx, dy) = if k == 0 {
                (0.0, 0.0)
            } else {
                (s.range(-1.2, 1.2), s.range(-0.8, 0.8))
            };
            let hj =
                heading + rad(s.normal_clamped(0.0, if walking { 8.0 } else { 40.0 }, -90.0, 90.0));
            let (c, sn) = (cos(heading), sin(heading));
            let (px, py) = (gx + c * dx - sn * dy, gy + sn * dx + c * dy);
            place(b, s, st, ObjectClass::Pedestrian, px, py, z, hj, walking);
        }
    }
    let cyclists = s.poisson(st.p.cyclists * scale);
    for _ in 0..cyclists {
        let on_road = s.chance(0.75);
        let dir_right = s.chance(0.6);
        let x = s.range(-10.0, 60.0);
        let (y, heading, z) = if on_road {
            if dir_right {
                (
                    st.edge_r + st.park_r.unwrap_or(0.0) + s.range(0.6, 1.2),
                    0.0,
                    0.0,
                )
            } else {
                (
                    st.edge_l - st.park_l.unwrap_or(0.0) - s.range(0.6, 1.2),
                    PI,
                    0.0,
                )
            }
        } else {
            let side = if dir_right { -1.0 } else { 1.0 };
            let y = st.edge(side) + side * s.range(0.6, (st.sidewalk_w(side) - 0.5).max(0.7));
            (y, if s.chance(0.5) { 0.0 } else { PI }, st.curb)
        };
        if st.in_cross(x, 2.0) && z > 0.0 {
            continue;
        }
        let hj = heading + rad(s.normal_clamped(0.0, 4.0, -15.0, 15.0));
        place(b, s, st, ObjectClass::Cyclist, x, y, z, hj, true);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn footprints_overlap_test() {
        let a = Footprint::new(0.0, 0.0, 0.0, 4.0, 2.0);
        assert!(a.overlaps(&Footprint::new(3.9, 0.0, 0.0, 4.0, 2.0)));
        assert!(!a.overlaps(&Footprint::new(4.1, 0.0, 0.0, 4.0, 2.0)));
        // Rotated by 90° a 4×2 box reaches 1 m along x.
        assert!(!a.overlaps(&Footprint::new(3.1, 0.0, FRAC_PI_2, 4.0, 2.0)));
        assert!(a.overlaps(&Footprint::new(2.9, 0.0, FRAC_PI_2, 4.0, 2.0)));
    }

    #[test]
    fn scenes_are_deterministic_and_populated() {
        let cfg = LayoutConfig::default();
        let (a, ia) = build_scene(&mut Sampler::new(77), &cfg);
        let (b, ib) = build_scene(&mut Sampler::new(77), &cfg);
        assert_eq!(a.prims, b.prims);
        assert_eq!(ia, ib);
        assert!(a.actors.iter().any(|x| x.class == ObjectClass::Car));
        assert!(a.prims.len() > 100);
        let (c, _) = build_scene(&mut Sampler::new(78), &cfg);
        assert_ne!(a.prims.len(), c.prims.len());
    }

    #[test]
    fn actors_do_not_overlap_each_other() {
        for seed in 0..8 {
            let (scene, _) = build_scene(&mut Sampler::new(seed), &LayoutConfig::default());
            let fps: Vec<Footprint> = scene
                .actors
                .iter()
                .map(|a| {
                    let heading = crate::math::atan2(a.heading.y, a.heading.x);
                    Footprint::new(a.bottom_center.x, a.bottom_center.y, heading, a.l, a.w)
                })
                .collect();
            for i in 0..fps.len() {
                for j in i + 1..fps.len() {
                    assert!(
                        !fps[i].overlaps(&fps[j]),
                        "seed {seed}: actors {i} and {j} overlap"
                    );
                }
            }
        }
    }

    #[test]
    fn sensor_is_at_mount_height_above_the_road() {
        let (scene, _) = build_scene(&mut Sampler::new(3), &LayoutConfig::default());
        let hit = scene
            .cast(
                crate::math::V3::ZERO,
                v3(0.3, 0.0, -1.0).normalized(),
                0.0,
                10.0,
            )
            .unwrap();
        let p = v3(0.3, 0.0, -1.0).normalized() * hit.t;
        assert!((p.z + 1.73).abs() < 0.05, "{p:?}");
    }
}
