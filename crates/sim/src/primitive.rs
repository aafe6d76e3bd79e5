//! Analytic ray–primitive intersections. Every primitive is a convex solid in its own
//! local frame (centre + rotation), so one transform of the ray covers boxes,
//! ellipsoids, cylinders and "rounded boxes" (a box intersected with an ellipsoid:
//! the cheap way to give car bodies rounded corners instead of plain-box point patterns).

use crate::math::{M3, V3, v3};

/// The solid shape, with `half` its half-extents along the local axes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// Axis-aligned (in the local frame) box.
    Box,
    /// Ellipsoid with semi-axes `half`.
    Ellipsoid,
    /// Elliptic cylinder along local z: semi-axes `half.x`, `half.y`, half-length `half.z`.
    Cylinder,
    /// Box ∩ ellipsoid with semi-axes `radii` (≥ `half` where corners should be kept).
    RoundedBox { radii: V3 },
}

/// What a surface is, for the camera palette, statistics and consistency checks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Surface {
    Road,
    Marking,
    Sidewalk,
    Grass,
    Building,
    Vegetation,
    Trunk,
    Pole,
    Sign,
    Wall,
    /// A part of a labelled object (car body, person, bike...).
    Object,
    /// An unlabelled movable thing: a parked bicycle, a bin, a bench.
    Clutter,
    /// A room's floor and ceiling (the indoor simulator).
    Floor,
    Ceiling,
}

/// Owner value of primitives that belong to no labelled object.
pub const NO_OWNER: u32 = u32::MAX;

/// One solid in the scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Primitive {
    pub center: V3,
    /// Local axes in the world frame.
    pub rot: M3,
    pub half: V3,
    pub shape: Shape,
    /// Index into the scene's materials.
    pub material: u16,
    pub surface: Surface,
    /// Index of the labelled object this is part of, or [`NO_OWNER`].
    pub owner: u32,
    /// Cached 1/half and 1/radii (divisions are the slow part of a ray test) and
    /// the bounding-sphere radius for a cheap early miss.
    inv_half: V3,
    inv_radii: V3,
    radius: f64,
}

fn recip(v: V3) -> V3 {
    v3(1.0 / v.x, 1.0 / v.y, 1.0 / v.z)
}

/// An axis-aligned bounding box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    pub min: V3,
    pub max: V3,
}

impl Aabb {
    pub const EMPTY: Aabb = Aabb {
        min: v3(f64::INFINITY, f64::INFINITY, f64::INFINITY),
        max: v3(f64::NEG_INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY),
    };
    pub fn union(&self, o: &Aabb) -> Aabb {
        Aabb {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }
    pub fn grow(&self, p: V3) -> Aabb {
        Aabb {
            min: self.min.min(p),
            max: self.max.max(p),
        }
    }
    pub fn centroid(&self) -> V3 {
        (self.min + self.max) * 0.5
    }
    pub fn surface_area(&self) -> f64 {
        let d = self.max - self.min;
        if d.x < 0.0 {
            return 0.0;
        }
        2.0 * (d.x * d.y + d.y * d.z + d.z * d.x)
    }
}

/// Where a ray meets a primitive: the first surface distance ≥ tmin, the exit
/// distance, and whether the ray started inside (then `t` is the exit).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Span {
    pub t: f64,
    pub t_exit: f64,
    pub inside: bool,
}

/// Where a ray enters a primitive: distance, exit distance and outward normal (world).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Entry {
    pub t: f64,
    pub t_exit: f64,
    pub normal: V3,
}

impl Primitive {
    pub fn new(
        center: V3,
        rot: M3,
        half: V3,
        shape: Shape,
        material: u16,
        surface: Surface,
        owner: u32,
    ) -> Primitive {
        let radii = match shape {
            Shape::RoundedBox { radii } => radii,
            _ => half,
        };
        let extent = match shape {
            Shape::RoundedBox { radii } => half.min(radii),
            _ => half,
        };
        Primitive {
            center,
            rot,
            half,
            shape,
            material,
            surface,
            owner,
            inv_half: recip(half),
            inv_radii: recip(radii),
            radius: extent.norm() * 1.0001 + 1e-6,
        }
    }

    /// The same solid moved by a rigid transform.
    pub fn transformed(&self, pose: &crate::math::Pose) -> Primitive {
        Primitive {
            center: pose.point(self.center),
            rot: pose.rot.mul(&self.rot),
            ..*self
        }
    }

    /// The world-space bounding box (tight for boxes; the box of the local extents otherwise).
    pub fn aabb(&self) -> Aabb {
        let h = match self.shape {
            Shape::RoundedBox { radii } => self.half.min(radii),
            _ => self.half,
        };
        // Extent of a rotated box along each world axis: Σ |R_ij| h_j.
        let c = &self.rot.cols;
        let e = c[0].abs() * h.x + c[1].abs() * h.y + c[2].abs() * h.z;
        Aabb {
            min: self.center - e,
            max: self.center + e,
        }
    }

    /// Where the ray `o + t d` is inside the solid, clipped to [tmin, tmax]: the
    /// first distance ≥ `tmin` on its surface (the entry, or the exit for a ray that
    /// starts inside) and the exit. No normal: callers compute it for the winner only.
    #[inline]
    pub fn hit_interval(&self, o: V3, d: V3, tmin: f64, tmax: f64) -> Option<Span> {
        // Bounding sphere: reject rays passing farther than `radius` from the centre
        // (`d` need not be unit length).
        let oc = self.center - o;
        let dd = d.dot(d);
        let proj = oc.dot(d);
        // Squared distance of the centre from the ray's line, times |d|² (no division).
        if oc.dot(oc) * dd - proj * proj > self.radius * self.radius * dd {
            return None;
        }
        let lo = self.rot.apply_t(-oc);
        let ld = self.rot.apply_t(d);
        let (t0, t1) = match self.shape {
            Shape::Box => slab(lo, ld, self.half)?,
            Shape::Ellipsoid => ellipsoid(lo, ld, self.inv_half)?,
            Shape::Cylinder => cylinder(lo, ld, self.half, self.inv_half)?,
            Shape::RoundedBox { .. } => {
                let (a0, a1) = slab(lo, ld, self.half)?;
                let (b0, b1) = ellipsoid(lo, ld, self.inv_radii)?;
                let (t0, t1) = (a0.max(b0), a1.min(b1));
                if t0 > t1 {
                    return None;
                }
                (t0, t1)
            }
        };
        let (t, inside) = if t0 >= tmin {
            (t0, false)
        } else if t1 >= tmin {
            (t1, true)
        } else {
            return None;
        };
        (t <= tmax).then_some(Span {
            t,
            t_exit: t1,
            inside,
        })
    }

    /// The hit point and unit normal in the local frame, and the normal in the world
    /// frame turned to face the ray; a ray that started inside gets the normal facing it.
    pub fn surface_frame(&self, o: V3, d: V3, span: &Span) -> (V3, V3, V3) {
        let l = self.rot.apply_t(o + d * span.t - self.center);
        let mut n_local = if span.inside {
            -self.rot.apply_t(d)
        } else {
            self.local_normal(l)
        }
        .normalized();
        let mut n = self.rot.apply(n_local);
        if n.dot(d) > 0.0 {
            n = -n;
            n_local = -n_local;
        }
        (l, n_local, n)
    }

    /// The outward normal in the local frame at a local surface point. Where two
    /// surfaces meet (box face vs rounding ellipsoid, cylinder side vs cap) the point
    /// belongs to the one it lies closer to, so the choice does not flicker with
    /// rounding noise.
    pub fn local_normal(&self, l: V3) -> V3 {
        let q = l.mul_elem(self.inv_half).abs();
        let box_measure = q.x.max(q.y).max(q.z);
        let box_normal = || {
            if q.x >= q.y && q.x >= q.z {
                V3::X * l.x.signum()
            } else if q.y >= q.z {
                V3::Y * l.y.signum()
            } else {
                V3::Z * l.z.signum()
            }
        };
        match self.shape {
            Shape::Box => box_normal(),
            Shape::Ellipsoid => l.mul_elem(self.inv_half).mul_elem(self.inv_half),
            Shape::Cylinder => {
                let side = (q.x * q.x + q.y * q.y).sqrt();
                if (1.0 - q.z).abs() < (1.0 - side).abs() {
                    V3::Z * l.z.signum()
                } else {
                    v3(
                        l.x * self.inv_half.x * self.inv_half.x,
                        l.y * self.inv_half.y * self.inv_half.y,
                        0.0,
                    )
                }
            }
            Shape::RoundedBox { .. } => {
                let e = l.mul_elem(self.inv_radii);
                let ell_measure = e.dot(e).sqrt();
                if (1.0 - ell_measure).abs() < (1.0 - box_measure).abs() {
                    l.mul_elem(self.inv_radii).mul_elem(self.inv_radii)
                } else {
                    box_normal()
                }
            }
        }
    }

    /// The nearest intersection of the ray `o + t d` with `t` in [tmin, tmax], with
    /// its normal. A ray starting inside reports the exit (normal facing the ray).
    #[inline]
    pub fn intersect(&self, o: V3, d: V3, tmin: f64, tmax: f64) -> Option<Entry> {
        let span = self.hit_interval(o, d, tmin, tmax)?;
        Some(Entry {
            t: span.t,
            t_exit: span.t_exit,
            normal: self.surface_frame(o, d, &span).2,
        })
    }

    /// True when the world point lies inside (or on) the solid.
    pub fn contains(&self, p: V3) -> bool {
        let l = self.rot.apply_t(p - self.center);
        let in_box =
            l.x.abs() <= self.half.x && l.y.abs() <= self.half.y && l.z.abs() <= self.half.z;
        let in_ell = |inv: V3| {
            let q = l.mul_elem(inv);
            q.dot(q) <= 1.0
        };
        match self.shape {
            Shape::Box => in_box,
            Shape::Ellipsoid => in_ell(self.inv_half),
            Shape::Cylinder => {
                let q = v3(l.x * self.inv_half.x, l.y * self.inv_half.y, 0.0);
                q.dot(q) <= 1.0 && l.z.abs() <= self.half.z
            }
            Shape::RoundedBox { .. } => in_box && in_ell(self.inv_radii),
        }
    }
}

/// Slab test against the box [-h, h]: (t_enter, t_exit).
#[inline]
fn slab(o: V3, d: V3, h: V3) -> Option<(f64, f64)> {
    let mut t0 = f64::NEG_INFINITY;
    let mut t1 = f64::INFINITY;
    for k in 0..3 {
        let (ok, dk, hk) = (o.axis(k), d.axis(k), h.axis(k));
        if dk == 0.0 {
            if ok.abs() > hk {
                return None;
            }
            continue;
        }
        let inv = 1.0 / dk;
        let (a, b) = ((-hk - ok) * inv, (hk - ok) * inv);
        let (a, b) = if a > b { (b, a) } else { (a, b) };
        t0 = t0.max(a);
        t1 = t1.min(b);
        if t0 > t1 {
            return None;
        }
    }
    Some((t0, t1))
}

/// Ray against the ellipsoid with reciprocal semi-axes `inv`.
#[inline]
fn ellipsoid(o: V3, d: V3, inv: V3) -> Option<(f64, f64)> {
    let os = o.mul_elem(inv);
    let ds = d.mul_elem(inv);
    let a = ds.dot(ds);
    let b = os.dot(ds);
    let c = os.dot(os) - 1.0;
    let disc = b * b - a * c;
    if disc < 0.0 || a == 0.0 {
        return None;
    }
    let sq = disc.sqrt();
    let inv_a = 1.0 / a;
    Some(((-b - sq) * inv_a, (-b + sq) * inv_a))
}

/// Ray against the capped elliptic cylinder along z.
#[inline]
fn cylinder(o: V3, d: V3, h: V3, inv: V3) -> Option<(f64, f64)> {
    // Side: (x/hx)² + (y/hy)² = 1.
    let (ox, oy, dx, dy) = (o.x * inv.x, o.y * inv.y, d.x * inv.x, d.y * inv.y);
    let a = dx * dx + dy * dy;
    let b = ox * dx + oy * dy;
    let c = ox * ox + oy * oy - 1.0;
    let (mut s0, mut s1) = if a == 0.0 {
        if c > 0.0 {
            return None;
        }
        (f64::NEG_INFINITY, f64::INFINITY)
    } else {
        let disc = b * b - a * c;
        if disc < 0.0 {
            return None;
        }
        let sq = disc.sqrt();
        let inv_a = 1.0 / a;
        ((-b - sq) * inv_a, (-b + sq) * inv_a)
    };
    // Caps: |z| ≤ hz.
    if d.z == 0.0 {
        if o.z.abs() > h.z {
            return None;
        }
    } else {
        let inv_z = 1.0 / d.z;
        let (a, b) = ((-h.z - o.z) * inv_z, (h.z - o.z) * inv_z);
        let (a, b) = if a > b { (b, a) } else { (a, b) };
        s0 = s0.max(a);
        s1 = s1.min(b);
    }
    (s0 <= s1).then_some((s0, s1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::M3;

    fn prim(shape: Shape, half: V3, rot: M3) -> Primitive {
        Primitive::new(
            v3(10.0, 0.0, 0.0),
            rot,
            half,
            shape,
            0,
            Surface::Object,
            NO_OWNER,
        )
    }

    #[test]
    fn box_hit_distance_and_normal() {
        let p = prim(Shape::Box, v3(1.0, 2.0, 3.0), M3::IDENTITY);
        let e = p.intersect(V3::ZERO, V3::X, 0.0, 100.0).unwrap();
        assert!((e.t - 9.0).abs() < 1e-12 && (e.t_exit - 11.0).abs() < 1e-12);
        assert!((e.normal - v3(-1.0, 0.0, 0.0)).norm() < 1e-12);
        // Rotated by 90° about z the box is 4 m deep along x.
        let r = prim(
            Shape::Box,
            v3(1.0, 2.0, 3.0),
            M3::rot_z(std::f64::consts::FRAC_PI_2),
        );
        let e = r.intersect(V3::ZERO, V3::X, 0.0, 100.0).unwrap();
        assert!((e.t - 8.0).abs() < 1e-12, "{e:?}");
        assert!(p.intersect(V3::ZERO, V3::Y, 0.0, 100.0).is_none());
        assert!(p.intersect(V3::ZERO, V3::X, 0.0, 5.0).is_none());
    }

    #[test]
    fn sphere_cylinder_and_rounded_box() {
        let s = prim(Shape::Ellipsoid, v3(2.0, 2.0, 2.0), M3::IDENTITY);
        let e = s.intersect(V3::ZERO, V3::X, 0.0, 100.0).unwrap();
        assert!((e.t - 8.0).abs() < 1e-12);
        // Grazing above the sphere misses.
        assert!(s.intersect(v3(0.0, 0.0, 2.01), V3::X, 0.0, 100.0).is_none());
        // Cylinder along z: side hit along x, cap hit from above.
        let c = prim(Shape::Cylinder, v3(0.5, 0.5, 1.0), M3::IDENTITY);
        let e = c.intersect(V3::ZERO, V3::X, 0.0, 100.0).unwrap();
        assert!((e.t - 9.5).abs() < 1e-12);
        let e = c.intersect(v3(10.0, 0.0, 5.0), -V3::Z, 0.0, 100.0).unwrap();
        assert!((e.t - 4.0).abs() < 1e-12 && (e.normal - V3::Z).norm() < 1e-12);
        assert!(c.intersect(v3(0.0, 0.0, 1.2), V3::X, 0.0, 100.0).is_none());
        // Rounded box: a ray at the corner misses where the plain box would hit.
        let half = v3(2.0, 1.0, 0.5);
        let rb = prim(Shape::RoundedBox { radii: half * 1.2 }, half, M3::IDENTITY);
        let corner = v3(0.0, 0.97, 0.47);
        assert!(
            prim(Shape::Box, half, M3::IDENTITY)
                .intersect(corner, V3::X, 0.0, 100.0)
                .is_some()
        );
        assert!(rb.intersect(corner, V3::X, 0.0, 100.0).is_none());
        // Centre ray hits the flat face.
        let e = rb.intersect(V3::ZERO, V3::X, 0.0, 100.0).unwrap();
        assert!((e.t - 8.0).abs() < 1e-12);
    }

    #[test]
    fn hits_lie_on_the_surface_and_aabb_contains_them() {
        let shapes = [
            Shape::Box,
            Shape::Ellipsoid,
            Shape::Cylinder,
            Shape::RoundedBox {
                radii: v3(2.2, 1.3, 0.9),
            },
        ];
        let rot = M3::rot_z(0.4).mul(&M3::rot_x(0.3));
        for shape in shapes {
            let p = prim(shape, v3(1.8, 1.0, 0.7), rot);
            let bb = p.aabb();
            let mut hits = 0;
            for i in 0..400 {
                let a = i as f64 * 0.0123;
                let d = v3(1.0, 0.2 * (a * 7.0).sin(), 0.15 * (a * 3.0).cos()).normalized();
                if let Some(e) = p.intersect(V3::ZERO, d, 0.0, 100.0) {
                    hits += 1;
                    let q = d * e.t;
                    // Just outside along the ray is outside, just inside is inside.
                    assert!(!p.contains(d * (e.t - 1e-6)), "{shape:?}");
                    assert!(p.contains(d * (e.t + 1e-6)), "{shape:?}");
                    assert!(q.x >= bb.min.x - 1e-9 && q.x <= bb.max.x + 1e-9);
                    assert!(q.z >= bb.min.z - 1e-9 && q.z <= bb.max.z + 1e-9);
                    assert!(e.normal.dot(d) <= 0.0);
                }
            }
            assert!(hits > 20, "{shape:?} {hits}");
        }
    }

    #[test]
    fn ray_from_inside_reports_the_exit() {
        let p = prim(Shape::Ellipsoid, v3(2.0, 2.0, 2.0), M3::IDENTITY);
        let e = p.intersect(v3(10.0, 0.0, 0.0), V3::X, 0.0, 100.0).unwrap();
        assert!((e.t - 2.0).abs() < 1e-12);
    }
}
