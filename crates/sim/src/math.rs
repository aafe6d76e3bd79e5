//! Small f64 vector/rotation types for the ray caster, and transcendental functions
//! from the pure-Rust `libm`, so that every machine computes bit-identical worlds
//! (the platform libm behind `f64::sin` and friends may differ in the last bit).

use std::ops::{Add, AddAssign, Div, Mul, Neg, Sub};

pub fn sin(x: f64) -> f64 {
    libm::sin(x)
}
pub fn cos(x: f64) -> f64 {
    libm::cos(x)
}
pub fn atan2(y: f64, x: f64) -> f64 {
    libm::atan2(y, x)
}
pub fn exp(x: f64) -> f64 {
    libm::exp(x)
}
pub fn ln(x: f64) -> f64 {
    libm::log(x)
}
pub fn tan(x: f64) -> f64 {
    libm::tan(x)
}
pub fn powf(x: f64, y: f64) -> f64 {
    libm::pow(x, y)
}
/// `x^n` by repeated multiplication in a fixed order (`powi`'s order is up to the
/// compiler and its runtime library).
pub fn ipow(x: f64, n: u32) -> f64 {
    let mut r = 1.0;
    for _ in 0..n {
        r *= x;
    }
    r
}
/// Degrees to radians.
pub fn rad(deg: f64) -> f64 {
    deg * (std::f64::consts::PI / 180.0)
}

/// A 3-vector (points, directions, normals) in metres.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct V3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

pub const fn v3(x: f64, y: f64, z: f64) -> V3 {
    V3 { x, y, z }
}

impl V3 {
    pub const ZERO: V3 = v3(0.0, 0.0, 0.0);
    pub const X: V3 = v3(1.0, 0.0, 0.0);
    pub const Y: V3 = v3(0.0, 1.0, 0.0);
    pub const Z: V3 = v3(0.0, 0.0, 1.0);

    pub fn dot(self, o: V3) -> f64 {
        self.x * o.x + self.y * o.y + self.z * o.z
    }
    pub fn cross(self, o: V3) -> V3 {
        v3(
            self.y * o.z - self.z * o.y,
            self.z * o.x - self.x * o.z,
            self.x * o.y - self.y * o.x,
        )
    }
    pub fn norm(self) -> f64 {
        self.dot(self).sqrt()
    }
    pub fn normalized(self) -> V3 {
        let n = self.norm();
        if n > 0.0 { self / n } else { self }
    }
    pub fn mul_elem(self, o: V3) -> V3 {
        v3(self.x * o.x, self.y * o.y, self.z * o.z)
    }
    pub fn div_elem(self, o: V3) -> V3 {
        v3(self.x / o.x, self.y / o.y, self.z / o.z)
    }
    pub fn min(self, o: V3) -> V3 {
        v3(self.x.min(o.x), self.y.min(o.y), self.z.min(o.z))
    }
    pub fn max(self, o: V3) -> V3 {
        v3(self.x.max(o.x), self.y.max(o.y), self.z.max(o.z))
    }
    pub fn abs(self) -> V3 {
        v3(self.x.abs(), self.y.abs(), self.z.abs())
    }
    pub fn axis(self, k: usize) -> f64 {
        match k {
            0 => self.x,
            1 => self.y,
            _ => self.z,
        }
    }
    pub fn to_array(self) -> [f64; 3] {
        [self.x, self.y, self.z]
    }
    pub fn from_array(a: [f64; 3]) -> V3 {
        v3(a[0], a[1], a[2])
    }
}

impl Add for V3 {
    type Output = V3;
    fn add(self, o: V3) -> V3 {
        v3(self.x + o.x, self.y + o.y, self.z + o.z)
    }
}
impl AddAssign for V3 {
    fn add_assign(&mut self, o: V3) {
        *self = *self + o;
    }
}
impl Sub for V3 {
    type Output = V3;
    fn sub(self, o: V3) -> V3 {
        v3(self.x - o.x, self.y - o.y, self.z - o.z)
    }
}
impl Mul<f64> for V3 {
    type Output = V3;
    fn mul(self, s: f64) -> V3 {
        v3(self.x * s, self.y * s, self.z * s)
    }
}
impl Div<f64> for V3 {
    type Output = V3;
    fn div(self, s: f64) -> V3 {
        v3(self.x / s, self.y / s, self.z / s)
    }
}
impl Neg for V3 {
    type Output = V3;
    fn neg(self) -> V3 {
        v3(-self.x, -self.y, -self.z)
    }
}

/// A rotation stored by its columns: the local x, y, z axes expressed in the parent frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct M3 {
    pub cols: [V3; 3],
}

impl M3 {
    pub const IDENTITY: M3 = M3 {
        cols: [V3::X, V3::Y, V3::Z],
    };

    /// Rotation by `a` about the z (up) axis.
    pub fn rot_z(a: f64) -> M3 {
        let (s, c) = (sin(a), cos(a));
        M3 {
            cols: [v3(c, s, 0.0), v3(-s, c, 0.0), V3::Z],
        }
    }
    /// Rotation by `a` about the x axis.
    pub fn rot_x(a: f64) -> M3 {
        let (s, c) = (sin(a), cos(a));
        M3 {
            cols: [V3::X, v3(0.0, c, s), v3(0.0, -s, c)],
        }
    }
    /// Rotation by `a` about the y axis.
    pub fn rot_y(a: f64) -> M3 {
        let (s, c) = (sin(a), cos(a));
        M3 {
            cols: [v3(c, 0.0, -s), V3::Y, v3(s, 0.0, c)],
        }
    }
    /// Local → parent.
    pub fn apply(&self, v: V3) -> V3 {
        self.cols[0] * v.x + self.cols[1] * v.y + self.cols[2] * v.z
    }
    /// Parent → local (the transpose, since the matrix is orthonormal).
    pub fn apply_t(&self, v: V3) -> V3 {
        v3(
            self.cols[0].dot(v),
            self.cols[1].dot(v),
            self.cols[2].dot(v),
        )
    }
    pub fn mul(&self, o: &M3) -> M3 {
        M3 {
            cols: [
                self.apply(o.cols[0]),
                self.apply(o.cols[1]),
                self.apply(o.cols[2]),
            ],
        }
    }
}

/// A rigid transform (rotation then translation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    pub rot: M3,
    pub t: V3,
}

impl Pose {
    pub const IDENTITY: Pose = Pose {
        rot: M3::IDENTITY,
        t: V3::ZERO,
    };
    pub fn point(&self, p: V3) -> V3 {
        self.rot.apply(p) + self.t
    }
    pub fn dir(&self, d: V3) -> V3 {
        self.rot.apply(d)
    }
    /// `self ∘ inner`: first `inner`, then `self`.
    pub fn compose(&self, inner: &Pose) -> Pose {
        Pose {
            rot: self.rot.mul(&inner.rot),
            t: self.point(inner.t),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotations_are_orthonormal_and_invert() {
        let r = M3::rot_z(0.7).mul(&M3::rot_x(-0.2)).mul(&M3::rot_y(1.1));
        let v = v3(1.0, -2.0, 0.5);
        let back = r.apply_t(r.apply(v));
        assert!((back - v).norm() < 1e-12);
        assert!((r.apply(v).norm() - v.norm()).abs() < 1e-12);
        // rot_z turns x towards y.
        let q = M3::rot_z(std::f64::consts::FRAC_PI_2).apply(V3::X);
        assert!((q - V3::Y).norm() < 1e-12);
    }

    #[test]
    fn pose_composition_applies_inner_first() {
        let a = Pose {
            rot: M3::rot_z(0.3),
            t: v3(1.0, 2.0, 3.0),
        };
        let b = Pose {
            rot: M3::rot_x(0.5),
            t: v3(-1.0, 0.0, 0.4),
        };
        let p = v3(0.3, 0.2, 0.1);
        let lhs = a.compose(&b).point(p);
        let rhs = a.point(b.point(p));
        assert!((lhs - rhs).norm() < 1e-12);
    }
}
