//! The scene: primitives with their materials, the labelled objects ("actors") they
//! make up, unlabelled clutter the 2D detector may mistake for objects, and the BVH
//! the LiDAR and the camera cast their rays through. Everything is in the LiDAR
//! frame (x forward, y left, z up, sensor at the origin).

use crate::bvh::Bvh;
use crate::material::{Material, SurfaceSample};
use crate::math::{M3, Pose, V3};
use crate::primitive::{Aabb, NO_OWNER, Primitive, Shape, Span, Surface};
use fusiondet_kitti::ObjectClass;
use std::ops::Range;

/// A labelled object: its box (bottom centre, heading, up, dimensions) in the LiDAR
/// frame and the primitives that make it.
#[derive(Debug, Clone, PartialEq)]
pub struct Actor {
    pub class: ObjectClass,
    pub bottom_center: V3,
    /// Unit vector along the object's length (its facing direction).
    pub heading: V3,
    pub up: V3,
    /// Length, width, height in metres (KITTI's l, w, h).
    pub l: f64,
    pub w: f64,
    pub h: f64,
    pub prims: Range<usize>,
    /// Parked (true) or on the move; used by the statistics only.
    pub parked: bool,
}

/// Kinds of unlabelled things a real 2D detector sometimes fires on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ClutterKind {
    /// Tall and thin: poles, trunks, sign posts (pedestrian-like).
    Upright,
    /// Parked bicycles (cyclist-like).
    Bicycle,
    /// Car-sized blobs: bushes, bins, hedges ends (car-like).
    Blob,
}

/// An unlabelled thing with a box, for false positives of the simulated 2D detector.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Clutter {
    pub kind: ClutterKind,
    pub bottom_center: V3,
    pub w: f64,
    pub h: f64,
}

/// A ray hit: distance, exit distance of the primitive, world normal (facing the
/// ray), primitive index, and the hit point and normal in the primitive's frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    pub t: f64,
    pub t_exit: f64,
    pub normal: V3,
    pub prim: u32,
    pub local: V3,
    pub local_normal: V3,
}

/// A finished, immutable scene.
#[derive(Debug, Clone)]
pub struct Scene {
    pub prims: Vec<Primitive>,
    pub materials: Vec<Material>,
    pub actors: Vec<Actor>,
    pub clutter: Vec<Clutter>,
    /// Direction towards the sun (for camera shading), LiDAR frame.
    pub sun: V3,
    /// Primitives too large for the BVH (the terrain), tested by every ray.
    unbounded: Vec<u32>,
    bvh: Bvh,
}

impl Scene {
    /// Nearest hit of the ray `o + t d` with t in [tmin, tmax].
    #[inline]
    pub fn cast(&self, o: V3, d: V3, tmin: f64, tmax: f64) -> Option<Hit> {
        let mut best: Option<(u32, Span)> = None;
        let mut tmax = tmax;
        for &i in &self.unbounded {
            if let Some(e) = self.prims[i as usize].hit_interval(o, d, tmin, tmax) {
                tmax = e.t;
                best = Some((i, e));
            }
        }
        let found = self.bvh.closest(o, d, tmin, tmax, |i, tmax| {
            self.prims[i as usize]
                .hit_interval(o, d, tmin, tmax)
                .map(|e| (e.t, e))
        });
        found.or(best).map(|(prim, e)| self.hit(prim, o, d, e))
    }

    /// Completes a hit on `prim` with its normals.
    #[inline]
    pub fn hit(&self, prim: u32, o: V3, d: V3, span: Span) -> Hit {
        let (local, local_normal, normal) = self.prims[prim as usize].surface_frame(o, d, &span);
        Hit {
            t: span.t,
            t_exit: span.t_exit,
            normal,
            prim,
            local,
            local_normal,
        }
    }

    /// Primitives tested by every ray rather than through the BVH or grids.
    pub fn unbounded(&self) -> &[u32] {
        &self.unbounded
    }

    pub fn is_unbounded(&self, prim: u32) -> bool {
        self.unbounded.contains(&prim)
    }

    /// Does the ray hit any part of one actor (its unoccluded silhouette)?
    pub fn hits_actor(&self, actor: usize, o: V3, d: V3, tmax: f64) -> bool {
        self.prims[self.actors[actor].prims.clone()]
            .iter()
            .any(|p| p.hit_interval(o, d, 0.0, tmax).is_some())
    }

    /// The material at a hit (`p` is the hit point in the scene frame).
    pub fn surface_at(&self, hit: &Hit, p: V3) -> SurfaceSample {
        let pr = &self.prims[hit.prim as usize];
        self.materials[pr.material as usize].sample(hit.local, hit.local_normal, pr.half, p)
    }

    /// The labelled object a primitive belongs to.
    pub fn owner(&self, prim: u32) -> Option<usize> {
        let o = self.prims[prim as usize].owner;
        (o != NO_OWNER).then_some(o as usize)
    }
}

/// Collects primitives in a local frame (the street's ground frame) and finishes
/// into a [`Scene`] in the LiDAR frame.
#[derive(Debug, Clone, Default)]
pub struct SceneBuilder {
    pub prims: Vec<Primitive>,
    pub materials: Vec<Material>,
    pub actors: Vec<Actor>,
    pub clutter: Vec<Clutter>,
    unbounded: Vec<u32>,
}

/// Boxes longer than this are cut into pieces of at most [`CHUNK`] metres: long
/// thin slabs (road, sidewalks, curbs) would otherwise make every BVH node span the
/// whole street and every ray visit most of the tree.
const SPLIT_ABOVE: f64 = 30.0;
const CHUNK: f64 = 10.0;

fn pieces(lo: f64, hi: f64) -> Vec<(f64, f64)> {
    let len = hi - lo;
    if len <= SPLIT_ABOVE {
        return vec![(lo, hi)];
    }
    let n = (len / CHUNK).ceil() as usize;
    (0..n)
        .map(|k| {
            (
                lo + len * k as f64 / n as f64,
                lo + len * (k + 1) as f64 / n as f64,
            )
        })
        .collect()
}

impl SceneBuilder {
    pub fn new() -> SceneBuilder {
        SceneBuilder::default()
    }

    pub fn material(&mut self, m: Material) -> u16 {
        self.materials.push(m);
        (self.materials.len() - 1) as u16
    }

    /// Adds a primitive given in the frame `pose` (e.g. an object's own frame).
    #[allow(clippy::too_many_arguments)]
    pub fn add(
        &mut self,
        pose: &Pose,
        shape: Shape,
        center: V3,
        rot: M3,
        half: V3,
        material: u16,
        surface: Surface,
        owner: u32,
    ) {
        self.prims.push(Primitive::new(
            pose.point(center),
            pose.rot.mul(&rot),
            half,
            shape,
            material,
            surface,
            owner,
        ));
    }

    /// Adds an axis-aligned (in `pose`) box spanning `min`..`max`, in pieces if long.
    pub fn add_box(&mut self, pose: &Pose, min: V3, max: V3, material: u16, surface: Surface) {
        for (x0, x1) in pieces(min.x, max.x) {
            for (y0, y1) in pieces(min.y, max.y) {
                let (a, b) = (
                    V3 {
                        x: x0,
                        y: y0,
                        z: min.z,
                    },
                    V3 {
                        x: x1,
                        y: y1,
                        z: max.z,
                    },
                );
                self.add(
                    pose,
                    Shape::Box,
                    (a + b) * 0.5,
                    M3::IDENTITY,
                    (b - a) * 0.5,
                    material,
                    surface,
                    NO_OWNER,
                );
            }
        }
    }

    /// Adds a box that every ray tests directly instead of through the BVH (the terrain).
    pub fn add_unbounded_box(
        &mut self,
        pose: &Pose,
        min: V3,
        max: V3,
        material: u16,
        surface: Surface,
    ) {
        self.unbounded.push(self.prims.len() as u32);
        self.add(
            pose,
            Shape::Box,
            (min + max) * 0.5,
            M3::IDENTITY,
            (max - min) * 0.5,
            material,
            surface,
            NO_OWNER,
        );
    }

    /// Starts a labelled object; its primitives are those added until [`Self::end_actor`].
    pub fn begin_actor(&mut self) -> u32 {
        self.actors.len() as u32
    }

    /// Registers the object whose primitives were added since `first_prim`.
    #[allow(clippy::too_many_arguments)]
    pub fn end_actor(
        &mut self,
        class: ObjectClass,
        pose: &Pose,
        l: f64,
        w: f64,
        h: f64,
        first_prim: usize,
        parked: bool,
    ) {
        self.actors.push(Actor {
            class,
            bottom_center: pose.t,
            heading: pose.rot.cols[0],
            up: pose.rot.cols[2],
            l,
            w,
            h,
            prims: first_prim..self.prims.len(),
            parked,
        });
    }

    /// Moves everything by `to_lidar` (street frame → LiDAR frame) and builds the BVH.
    pub fn finish(mut self, to_lidar: &Pose, sun_street: V3) -> Scene {
        for p in &mut self.prims {
            *p = p.transformed(to_lidar);
        }
        for a in &mut self.actors {
            a.bottom_center = to_lidar.point(a.bottom_center);
            a.heading = to_lidar.dir(a.heading);
            a.up = to_lidar.dir(a.up);
        }
        for c in &mut self.clutter {
            c.bottom_center = to_lidar.point(c.bottom_center);
        }
        let items: Vec<(u32, Aabb)> = self
            .prims
            .iter()
            .enumerate()
            .filter(|(i, _)| !self.unbounded.contains(&(*i as u32)))
            .map(|(i, p)| (i as u32, p.aabb()))
            .collect();
        let bvh = Bvh::build(&items);
        Scene {
            prims: self.prims,
            materials: self.materials,
            actors: self.actors,
            clutter: self.clutter,
            sun: to_lidar.dir(sun_street).normalized(),
            unbounded: self.unbounded,
            bvh,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::v3;

    #[test]
    fn cast_finds_nearest_and_actor_silhouette_ignores_occluders() {
        let mut b = SceneBuilder::new();
        let m = b.material(Material::solid([0.5; 3], 0.3));
        b.add_box(
            &Pose::IDENTITY,
            v3(5.0, -1.0, -1.0),
            v3(6.0, 1.0, 1.0),
            m,
            Surface::Wall,
        );
        let first = b.prims.len();
        let pose = Pose {
            rot: M3::IDENTITY,
            t: v3(10.0, 0.0, -1.0),
        };
        b.add(
            &pose,
            Shape::Box,
            v3(0.0, 0.0, 0.75),
            M3::IDENTITY,
            v3(2.0, 0.8, 0.75),
            m,
            Surface::Object,
            0,
        );
        b.end_actor(ObjectClass::Car, &pose, 4.0, 1.6, 1.5, first, true);
        let s = b.finish(&Pose::IDENTITY, V3::Z);
        let hit = s.cast(V3::ZERO, V3::X, 0.0, 100.0).unwrap();
        assert!((hit.t - 5.0).abs() < 1e-12);
        assert_eq!(s.owner(hit.prim), None);
        assert!(s.hits_actor(0, V3::ZERO, V3::X, 100.0));
        assert!(!s.hits_actor(0, V3::ZERO, V3::Y, 100.0));
        let behind = s.cast(
            v3(0.0, 0.0, 0.0),
            v3(1.0, 0.0, -0.1).normalized(),
            0.0,
            100.0,
        );
        assert!(behind.is_some());
    }
}
