//! Training-time augmentation of a [`Scene`], as the published configuration runs it:
//! ground-truth sampling, (optionally) per-object noise, then a random flip across the x
//! axis, a rotation about z and a scaling of the whole scene — LiDAR and pseudo points
//! alike. Every draw comes from the caller's [`Sampler`]
//! (one forked stream per step, so switching one step off leaves the others' draws
//! unchanged).
//!
//! Ground-truth sampling (OpenPCDet's `DataBaseSampler`): for each sample group, `count`
//! distinct database objects of the class are drawn; a candidate is pasted only if its
//! bird's-eye footprint overlaps no box of the scene (of any class), no box pasted for
//! an earlier group and no other candidate of its own group (two overlapping candidates
//! are both rejected). The scene's points (and pseudo points) inside pasted boxes are
//! removed and the objects' added.

use crate::boxes::{GtBox, LidarBox, bev_intersection, in_any_box, rotate_z};
use crate::config::{AugmentConfig, SampleGroup};
use crate::error::{Result, VoxelError};
use crate::gt_database::GtDatabase;
use crate::scene::{PseudoPoint, Scene};
use fusiondet_dataset::rng::Sampler;
use fusiondet_kitti::LidarPoint;

/// Mirrors points across the x axis (y → −y), whatever else they carry.
fn flip_points<const N: usize>(points: &mut [[f32; N]]) {
    for p in points {
        p[1] = -p[1];
    }
}

/// Rotates points about z by `angle`.
fn rotate_points<const N: usize>(points: &mut [[f32; N]], angle: f64) {
    for p in points {
        let [x, y] = rotate_z([p[0] as f64, p[1] as f64], angle);
        p[0] = x as f32;
        p[1] = y as f32;
    }
}

/// Scales point positions about the origin.
fn scale_points<const N: usize>(points: &mut [[f32; N]], factor: f64) {
    for p in points {
        for v in &mut p[..3] {
            *v = (*v as f64 * factor) as f32;
        }
    }
}

/// Mirrors the scene across the x axis: y → −y, heading → −heading.
pub fn flip_x(scene: &mut Scene) {
    flip_points(&mut scene.points);
    flip_points(&mut scene.pseudo);
    for g in &mut scene.gts {
        g.bbox.y = -g.bbox.y;
        g.bbox.heading = -g.bbox.heading;
    }
}

/// Rotates the scene about the LiDAR z axis by `angle` (counter-clockwise from above).
pub fn rotate(scene: &mut Scene, angle: f64) {
    rotate_points(&mut scene.points, angle);
    rotate_points(&mut scene.pseudo, angle);
    for g in &mut scene.gts {
        let [x, y] = rotate_z([g.bbox.x, g.bbox.y], angle);
        g.bbox.x = x;
        g.bbox.y = y;
        g.bbox.heading += angle;
    }
}

/// Scales the scene about the LiDAR origin: positions and box sizes times `factor`.
pub fn scale(scene: &mut Scene, factor: f64) {
    scale_points(&mut scene.points, factor);
    scale_points(&mut scene.pseudo, factor);
    for g in &mut scene.gts {
        let b = &mut g.bbox;
        for v in [
            &mut b.x, &mut b.y, &mut b.z, &mut b.dx, &mut b.dy, &mut b.dz,
        ] {
            *v *= factor;
        }
    }
}

/// Turns and moves points inside `from` as its box goes to `to` (same size): about the
/// old centre by the heading change, then to the new centre.
fn move_object<const N: usize>(points: &mut [[f32; N]], from: &LidarBox, to: &LidarBox) {
    let inside = points_in_box_xyz(from, points);
    let angle = to.heading - from.heading;
    for (p, inside) in points.iter_mut().zip(inside) {
        if inside {
            let [x, y] = rotate_z([p[0] as f64 - from.x, p[1] as f64 - from.y], angle);
            p[0] = (x + to.x) as f32;
            p[1] = (y + to.y) as f32;
            p[2] = (p[2] as f64 - from.z + to.z) as f32;
        }
    }
}

/// Which points (of any width, x, y, z first) lie inside the box.
fn points_in_box_xyz<const N: usize>(b: &LidarBox, points: &[[f32; N]]) -> Vec<bool> {
    points
        .iter()
        .map(|p| b.contains([p[0] as f64, p[1] as f64, p[2] as f64]))
        .collect()
}

/// Per-object noise (SECOND's `noise_per_object`, as DASANet's "local rotation" and
/// "local noising"): each box, in turn, turned about its centre and moved by a normal
/// offset with the points in it (both clouds); a box whose moved footprint would overlap
/// another box keeps its place. Returns how many moved.
pub fn local_noise(scene: &mut Scene, config: &AugmentConfig, sampler: &mut Sampler) -> usize {
    let [r0, r1] = config.local_rotation;
    let std = config.local_translation_std;
    let mut moved = 0;
    for i in 0..scene.gts.len() {
        // Every object draws, moved or not, so one object's fate leaves the others' draws.
        let angle = if r1 > r0 { sampler.range(r0, r1) } else { r0 };
        let offset: [f64; 3] = std::array::from_fn(|a| sampler.normal() * std[a]);
        let from = scene.gts[i].bbox;
        let to = LidarBox {
            x: from.x + offset[0],
            y: from.y + offset[1],
            z: from.z + offset[2],
            heading: from.heading + angle,
            ..from
        };
        let collides = scene
            .gts
            .iter()
            .enumerate()
            .any(|(j, g)| j != i && bev_intersection(&to, &g.bbox) > 0.0);
        if collides {
            continue;
        }
        move_object(&mut scene.points, &from, &to);
        move_object(&mut scene.pseudo, &from, &to);
        scene.gts[i].bbox = to;
        moved += 1;
    }
    moved
}

/// The database objects each sample group may paste, filtered once.
#[derive(Debug, Clone)]
pub struct GtSampler {
    database: GtDatabase,
    /// Per group: the group and its eligible objects (indices into the database).
    pools: Vec<(SampleGroup, Vec<usize>)>,
    limit_whole_scene: bool,
}

impl GtSampler {
    /// Keeps, per group of `config`, the objects of its class with at least
    /// `min_points` points and a difficulty not in `removed_difficulties`. A group
    /// that would paste objects but finds none is an error.
    pub fn new(database: GtDatabase, config: &AugmentConfig) -> Result<GtSampler> {
        config.validate()?;
        let mut pools = Vec::new();
        for group in &config.sample_groups {
            let pool: Vec<usize> = database
                .objects()
                .iter()
                .enumerate()
                .filter(|(_, o)| {
                    o.class == group.class
                        && o.num_points >= group.min_points
                        && !config.removed_difficulties.contains(&o.difficulty)
                })
                .map(|(i, _)| i)
                .collect();
            if pool.is_empty() && group.count > 0 {
                return Err(VoxelError::Input(format!(
                    "the ground-truth database has no {} with at least {} points and an \
                     allowed difficulty; build it from frames with such objects, or drop the \
                     class from `sample_groups`",
                    group.class, group.min_points
                )));
            }
            pools.push((group.clone(), pool));
        }
        Ok(GtSampler {
            database,
            pools,
            limit_whole_scene: config.limit_whole_scene,
        })
    }

    /// Whether pasted objects bring pseudo points (the database was built with them).
    pub fn has_pseudo(&self) -> bool {
        self.database.has_pseudo()
    }

    /// Objects eligible for pasting, per group.
    pub fn pool_sizes(&self) -> Vec<usize> {
        self.pools.iter().map(|(_, p)| p.len()).collect()
    }

    /// Pastes sampled objects into the scene; returns how many.
    pub fn paste(&self, scene: &mut Scene, sampler: &mut Sampler) -> usize {
        let mut existing: Vec<LidarBox> = scene.boxes();
        let mut pasted: Vec<usize> = Vec::new();
        for (group, pool) in &self.pools {
            let mut count = group.count;
            if self.limit_whole_scene {
                let present = scene.gts.iter().filter(|g| g.class == group.class).count();
                count = count.saturating_sub(present);
            }
            let count = count.min(pool.len());
            if count == 0 {
                continue;
            }
            // The first `count` of a partial Fisher–Yates shuffle: distinct objects.
            let mut order = pool.clone();
            for i in 0..count {
                let j = i + sampler.below(order.len() - i);
                order.swap(i, j);
            }
            let candidates = &order[..count];
            let boxes: Vec<LidarBox> = candidates
                .iter()
                .map(|&i| self.database.objects()[i].bbox)
                .collect();
            let overlaps = |a: &LidarBox, b: &LidarBox| bev_intersection(a, b) > 0.0;
            let mut accepted = Vec::new();
            for (k, b) in boxes.iter().enumerate() {
                let free = !existing.iter().any(|e| overlaps(b, e))
                    && !boxes
                        .iter()
                        .enumerate()
                        .any(|(m, c)| m != k && overlaps(b, c));
                if free {
                    accepted.push(k);
                }
            }
            for k in accepted {
                existing.push(boxes[k]);
                pasted.push(candidates[k]);
            }
        }
        if pasted.is_empty() {
            return 0;
        }
        let new_boxes: Vec<LidarBox> = pasted
            .iter()
            .map(|&i| self.database.objects()[i].bbox)
            .collect();
        let shifted = |p: &[f32], b: &LidarBox| -> [f32; 3] {
            [
                (p[0] as f64 + b.x) as f32,
                (p[1] as f64 + b.y) as f32,
                (p[2] as f64 + b.z) as f32,
            ]
        };
        let outside = |p: &[f32]| !in_any_box(&new_boxes, [p[0] as f64, p[1] as f64, p[2] as f64]);
        let mut points: Vec<LidarPoint> = Vec::new();
        let mut pseudo: Vec<PseudoPoint> = Vec::new();
        for &i in &pasted {
            let b = &self.database.objects()[i].bbox;
            points.extend(self.database.points_of(i).iter().map(|p| {
                let [x, y, z] = shifted(p, b);
                [x, y, z, p[3]]
            }));
            pseudo.extend(self.database.pseudo_of(i).iter().map(|p| {
                let [x, y, z] = shifted(p, b);
                [x, y, z, p[3], p[4], p[5]]
            }));
        }
        // Pasted objects' points first, then the scene's outside the pasted boxes.
        points.extend(scene.points.iter().copied().filter(|p| outside(p)));
        pseudo.extend(scene.pseudo.iter().copied().filter(|p| outside(p)));
        scene.points = points;
        scene.pseudo = pseudo;
        scene.gts.extend(pasted.iter().map(|&i| {
            let o = &self.database.objects()[i];
            GtBox {
                bbox: o.bbox,
                class: o.class,
            }
        }));
        pasted.len()
    }
}

/// What one call of [`augment`] did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct AugmentReport {
    pub pasted: usize,
    /// Objects the per-object noise moved.
    pub moved: usize,
    pub flipped: bool,
    pub rotation: f64,
    pub scale: f64,
}

/// Applies the configured augmentation to a training scene. `gt_sampler` is required
/// when the configuration has sample groups.
pub fn augment(
    scene: &mut Scene,
    config: &AugmentConfig,
    gt_sampler: Option<&GtSampler>,
    sampler: &mut Sampler,
) -> Result<AugmentReport> {
    let mut report = AugmentReport {
        scale: 1.0,
        ..Default::default()
    };
    let mut paste_stream = sampler.fork();
    let mut flip_stream = sampler.fork();
    let mut rotation_stream = sampler.fork();
    let mut scale_stream = sampler.fork();
    // Forked only when on, so that scenes without it draw exactly as before.
    let mut local_stream = config.local_noise().then(|| sampler.fork());
    if config.sample_groups.iter().any(|g| g.count > 0) {
        let gs = gt_sampler.ok_or_else(|| {
            VoxelError::Input(
                "augmentation samples ground truth (`sample_groups`) but no ground-truth \
                 database was given"
                    .into(),
            )
        })?;
        report.pasted = gs.paste(scene, &mut paste_stream);
    }
    if let Some(stream) = local_stream.as_mut() {
        report.moved = local_noise(scene, config, stream);
    }
    if config.flip_x && flip_stream.chance(0.5) {
        flip_x(scene);
        report.flipped = true;
    }
    let [r0, r1] = config.rotation;
    if r1 > r0 {
        report.rotation = rotation_stream.range(r0, r1);
        rotate(scene, report.rotation);
    } else if r0 != 0.0 {
        report.rotation = r0;
        rotate(scene, r0);
    }
    let [s0, s1] = config.scaling;
    if s1 > s0 {
        report.scale = scale_stream.range(s0, s1);
        scale(scene, report.scale);
    } else if s0 != 1.0 {
        report.scale = s0;
        scale(scene, s0);
    }
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::boxes::points_in_box;
    use crate::gt_database::DbObject;
    use fusiondet_kitti::ObjectClass;
    use std::f64::consts::FRAC_PI_2;

    fn car(x: f64, y: f64, heading: f64) -> LidarBox {
        LidarBox {
            x,
            y,
            z: -1.0,
            dx: 4.0,
            dy: 2.0,
            dz: 1.5,
            heading,
        }
    }

    fn scene() -> Scene {
        Scene {
            points: vec![[10.0, 2.0, -1.0, 0.5], [30.0, -5.0, 0.0, 0.25]],
            pseudo: vec![
                [10.0, 2.0, -1.0, 0.1, 0.2, 0.3],
                [30.0, -5.0, 0.0, 0.4, 0.5, 0.6],
            ],
            gts: vec![GtBox {
                bbox: car(10.0, 2.0, 0.3),
                class: ObjectClass::Car,
            }],
        }
    }

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-6
    }

    #[test]
    fn flip_rotation_and_scaling_by_hand() {
        let mut s = scene();
        flip_x(&mut s);
        assert_eq!(s.points[0], [10.0, -2.0, -1.0, 0.5]);
        assert_eq!(s.pseudo[0], [10.0, -2.0, -1.0, 0.1, 0.2, 0.3]);
        assert_eq!((s.gts[0].bbox.y, s.gts[0].bbox.heading), (-2.0, -0.3));

        let mut s = scene();
        rotate(&mut s, FRAC_PI_2);
        // (10, 2) → (−2, 10); the heading turns with it.
        assert!(close(s.points[0][0] as f64, -2.0) && close(s.points[0][1] as f64, 10.0));
        let q = s.pseudo[0];
        assert!(
            close(q[0] as f64, -2.0) && close(q[1] as f64, 10.0) && q[2..] == [-1.0, 0.1, 0.2, 0.3]
        );
        let b = s.gts[0].bbox;
        assert!(close(b.x, -2.0) && close(b.y, 10.0) && close(b.heading, 0.3 + FRAC_PI_2));
        // A point inside the box stays inside after the rotation.
        assert!(points_in_box(&b, &s.points[..1])[0]);

        let mut s = scene();
        scale(&mut s, 2.0);
        assert_eq!(s.points[1], [60.0, -10.0, 0.0, 0.25]);
        assert_eq!(s.pseudo[1], [60.0, -10.0, 0.0, 0.4, 0.5, 0.6]);
        let b = s.gts[0].bbox;
        assert_eq!(
            [b.x, b.y, b.z, b.dx, b.dy, b.dz, b.heading],
            [20.0, 4.0, -2.0, 8.0, 4.0, 3.0, 0.3]
        );
    }

    #[test]
    fn augmentation_is_seeded_and_none_changes_nothing() {
        let config = AugmentConfig {
            sample_groups: Vec::new(),
            ..Default::default()
        };
        let run = |seed| {
            let mut s = scene();
            let r = augment(&mut s, &config, None, &mut Sampler::new(seed)).unwrap();
            (s, r)
        };
        assert_eq!(run(3), run(3));
        let reports: Vec<AugmentReport> = (0..16).map(|k| run(k).1).collect();
        assert!(reports.iter().any(|r| r.flipped) && reports.iter().any(|r| !r.flipped));
        assert!(
            reports
                .iter()
                .all(|r| r.rotation.abs() <= std::f64::consts::FRAC_PI_4)
        );
        assert!(reports.iter().all(|r| (0.95..=1.05).contains(&r.scale)));

        let mut s = scene();
        let r = augment(&mut s, &AugmentConfig::none(), None, &mut Sampler::new(1)).unwrap();
        assert_eq!((s, r.pasted, r.flipped), (scene(), 0, false));
        // Sample groups without a database are an error.
        let err = augment(
            &mut scene(),
            &AugmentConfig::default(),
            None,
            &mut Sampler::new(1),
        )
        .unwrap_err();
        assert!(err.to_string().contains("database"), "{err}");
    }

    fn db_object(bbox: LidarBox, difficulty: i8) -> DbObject {
        DbObject {
            frame: "000000".into(),
            index: 0,
            class: ObjectClass::Car,
            bbox,
            difficulty,
            bbox_2d: [0.0; 4],
            offset: 0,
            num_points: 0,
            pseudo_offset: 0,
            num_pseudo: 0,
        }
    }

    /// Objects: 0 collides with the scene's car at (10, 2); 1 and 2 are free and far
    /// apart; 3 and 4 overlap each other; 5 has too few points; 6 has difficulty −1.
    fn database() -> GtDatabase {
        let mut db = GtDatabase::new();
        let pts = |n: usize| -> Vec<LidarPoint> {
            (0..n).map(|k| [0.1 * k as f32, 0.0, 0.0, 0.9]).collect()
        };
        for (b, n, d) in [
            (car(11.0, 2.5, 0.0), 6, 0),
            (car(20.0, 10.0, 0.0), 6, 1),
            (car(40.0, -10.0, 1.0), 7, 0),
            (car(50.0, 10.0, 0.0), 6, 2),
            (car(51.0, 10.5, 0.5), 6, 0),
            (car(60.0, 0.0, 0.0), 4, 0),
            (car(60.0, 20.0, 0.0), 9, -1),
        ] {
            db.push(db_object(b, d), &pts(n));
        }
        db
    }

    #[test]
    fn ground_truth_sampling_pastes_only_free_objects() {
        let config = AugmentConfig {
            sample_groups: vec![SampleGroup {
                class: ObjectClass::Car,
                count: 15,
                min_points: 5,
            }],
            removed_difficulties: vec![-1],
            ..AugmentConfig::none()
        };
        let gs = GtSampler::new(database(), &config).unwrap();
        assert_eq!(gs.pool_sizes(), [5]);
        let mut s = scene();
        // A scene point inside the box that object 1 will occupy is removed.
        s.points.push([20.5, 10.0, -1.0, 0.1]);
        // 15 wanted, 5 eligible: all drawn; 0 collides with the scene, 3 and 4 with
        // each other, so exactly 1 and 2 are pasted, whatever the seed.
        for seed in 0..5 {
            let mut t = s.clone();
            assert_eq!(gs.paste(&mut t, &mut Sampler::new(seed)), 2);
            let mut pasted: Vec<(f64, f64)> =
                t.gts[1..].iter().map(|g| (g.bbox.x, g.bbox.y)).collect();
            pasted.sort_by(|a, b| a.partial_cmp(b).unwrap());
            assert_eq!(pasted, [(20.0, 10.0), (40.0, -10.0)]);
            // 6 + 7 object points, then the scene's two points outside the pasted boxes.
            assert_eq!(t.points.len(), 13 + 2);
            assert!(t.points.contains(&[20.0, 10.0, -1.0, 0.9]));
            assert!(!t.points.contains(&[20.5, 10.0, -1.0, 0.1]));
            assert_eq!(&t.points[13..], &s.points[..2]);
        }
        // With the whole scene limited to 2 cars, one is sampled (2 − 1 present).
        let limited = GtSampler::new(
            database(),
            &AugmentConfig {
                limit_whole_scene: true,
                sample_groups: vec![SampleGroup {
                    class: ObjectClass::Car,
                    count: 2,
                    min_points: 5,
                }],
                ..config.clone()
            },
        )
        .unwrap();
        let pasted: usize = (0..20)
            .map(|seed| limited.paste(&mut scene(), &mut Sampler::new(seed)))
            .max()
            .unwrap();
        assert_eq!(pasted, 1);
        // A class with no eligible object is an error.
        let err = GtSampler::new(
            database(),
            &AugmentConfig {
                sample_groups: vec![SampleGroup {
                    class: ObjectClass::Cyclist,
                    count: 5,
                    min_points: 5,
                }],
                ..config
            },
        )
        .unwrap_err();
        assert!(err.to_string().contains("Cyclist"), "{err}");
    }

    /// With a database built with pseudo points, pasted objects bring theirs (shifted to
    /// the box) and the scene's pseudo points inside pasted boxes go; without, the
    /// scene's inside pasted boxes still go.
    #[test]
    fn pasting_carries_pseudo_points() {
        let config = AugmentConfig {
            sample_groups: vec![SampleGroup {
                class: ObjectClass::Car,
                count: 15,
                min_points: 5,
            }],
            removed_difficulties: vec![-1],
            ..AugmentConfig::none()
        };
        let plain = database();
        let mut with_pseudo = GtDatabase::new();
        with_pseudo.mark_pseudo();
        for (i, o) in plain.objects().iter().enumerate() {
            let pseudo: Vec<PseudoPoint> = (0..3)
                .map(|k| [0.0, 0.1 * k as f32, 0.0, 0.5, 0.5, i as f32])
                .collect();
            with_pseudo.push_with_pseudo(
                db_object(o.bbox, o.difficulty),
                plain.points_of(i),
                &pseudo,
            );
        }
        let gs = GtSampler::new(with_pseudo, &config).unwrap();
        assert!(gs.has_pseudo());
        let mut s = scene();
        s.pseudo.push([20.5, 10.0, -1.0, 0.0, 0.0, 0.0]);
        assert_eq!(gs.paste(&mut s, &mut Sampler::new(0)), 2);
        // Objects 1 and 2 with 3 pseudo points each, then the scene's two outside.
        assert_eq!(s.pseudo.len(), 6 + 2);
        assert!(s.pseudo.contains(&[20.0, 10.2, -1.0, 0.5, 0.5, 1.0]));
        assert!(s.pseudo.contains(&[40.0, -9.9, -1.0, 0.5, 0.5, 2.0]));
        assert!(!s.pseudo.contains(&[20.5, 10.0, -1.0, 0.0, 0.0, 0.0]));

        let gs = GtSampler::new(database(), &config).unwrap();
        assert!(!gs.has_pseudo());
        let mut s = scene();
        s.pseudo.push([20.5, 10.0, -1.0, 0.0, 0.0, 0.0]);
        gs.paste(&mut s, &mut Sampler::new(0));
        assert_eq!(s.pseudo, scene().pseudo);
    }

    /// Per-object noise turns and moves each object with its points (both clouds), leaves
    /// an object in place when its moved box would hit another, and is seeded.
    #[test]
    fn local_noise_moves_objects_with_their_points() {
        let config = AugmentConfig {
            local_rotation: [FRAC_PI_2, FRAC_PI_2],
            local_translation_std: [0.0; 3],
            ..AugmentConfig::none()
        };
        let mut s = scene();
        // A point 1 m ahead of the car's centre (heading 0.3) along its axis.
        let (sin, cos) = 0.3f64.sin_cos();
        s.points
            .push([(10.0 + cos) as f32, (2.0 + sin) as f32, -1.0, 0.7]);
        s.pseudo
            .push([(10.0 + cos) as f32, (2.0 + sin) as f32, -1.0, 0.1, 0.1, 0.1]);
        assert_eq!(local_noise(&mut s, &config, &mut Sampler::new(1)), 1);
        let b = s.gts[0].bbox;
        assert!(close(b.heading, 0.3 + FRAC_PI_2) && close(b.x, 10.0) && close(b.y, 2.0));
        // Turned a quarter about the centre: now 1 m along the new heading.
        let (sin, cos) = (0.3 + FRAC_PI_2).sin_cos();
        for p in [&s.points[2][..3], &s.pseudo[2][..3]] {
            assert!(
                close(p[0] as f64, 10.0 + cos) && close(p[1] as f64, 2.0 + sin),
                "{p:?}"
            );
        }
        // Points outside the box stay.
        assert_eq!(s.points[1], scene().points[1]);

        // A second car right beside: turning the first would hit it, so neither moves
        // (the second's turn would hit the first).
        let mut s = scene();
        s.gts.push(GtBox {
            bbox: car(10.0, 4.5, 0.3),
            class: ObjectClass::Car,
        });
        let before = s.clone();
        assert_eq!(local_noise(&mut s, &config, &mut Sampler::new(1)), 0);
        assert_eq!(s, before);

        // Through `augment`, seeded and reported.
        let noisy = AugmentConfig {
            local_rotation: [-0.5, 0.5],
            local_translation_std: [0.25, 0.25, 0.0],
            ..AugmentConfig::none()
        };
        let run = |seed| {
            let mut s = scene();
            let r = augment(&mut s, &noisy, None, &mut Sampler::new(seed)).unwrap();
            (s, r.moved)
        };
        assert_eq!(run(5), run(5));
        assert_eq!(run(5).1, 1);
        assert_ne!(run(5).0.gts[0].bbox, scene().gts[0].bbox);
    }
}
