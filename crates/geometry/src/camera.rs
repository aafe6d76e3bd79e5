//! Transforms between the LiDAR frame, the rectified camera frame and the image
//! of the left colour camera (P2): the KITTI chain `y = P2 · R0_rect · Tr_velo_to_cam · x`.

use nalgebra::{Matrix3, Matrix3x4, Matrix4, Vector3, Vector4};

/// The calibration of one frame, prepared for fast transforms.
#[derive(Debug, Clone)]
pub struct CameraModel {
    /// P2, rectified camera → image.
    pub p2: Matrix3x4<f64>,
    /// LiDAR → rectified camera (R0_rect · Tr_velo_to_cam as a 4×4).
    pub velo_to_rect: Matrix4<f64>,
    /// Rectified camera → LiDAR (its inverse).
    pub rect_to_velo: Matrix4<f64>,
}

fn mat34(m: &[[f64; 4]; 3]) -> Matrix3x4<f64> {
    Matrix3x4::from_fn(|r, c| m[r][c])
}

impl CameraModel {
    /// Builds the model from P2 (rectified camera → image), R0_rect and
    /// Tr_velo_to_cam; fails only if the extrinsics are singular.
    pub fn new(
        p2: &[[f64; 4]; 3],
        r0_rect: &[[f64; 3]; 3],
        tr_velo_to_cam: &[[f64; 4]; 3],
    ) -> Result<CameraModel, String> {
        let r0 = Matrix3::from_fn(|r, c| r0_rect[r][c]);
        let mut r0_h = Matrix4::identity();
        r0_h.fixed_view_mut::<3, 3>(0, 0).copy_from(&r0);
        let mut tr = Matrix4::identity();
        tr.fixed_view_mut::<3, 4>(0, 0)
            .copy_from(&mat34(tr_velo_to_cam));
        let velo_to_rect = r0_h * tr;
        let rect_to_velo = velo_to_rect
            .try_inverse()
            .ok_or("R0_rect · Tr_velo_to_cam is not invertible")?;
        Ok(CameraModel {
            p2: mat34(p2),
            velo_to_rect,
            rect_to_velo,
        })
    }

    pub fn fu(&self) -> f64 {
        self.p2[(0, 0)]
    }
    pub fn fv(&self) -> f64 {
        self.p2[(1, 1)]
    }
    /// P2 as plain rows.
    pub fn p2_rows(&self) -> [[f64; 4]; 3] {
        std::array::from_fn(|r| std::array::from_fn(|c| self.p2[(r, c)]))
    }
    pub fn cu(&self) -> f64 {
        self.p2[(0, 2)]
    }
    pub fn cv(&self) -> f64 {
        self.p2[(1, 2)]
    }

    pub fn velo_to_rect(&self, p: [f64; 3]) -> [f64; 3] {
        let v = self.velo_to_rect * Vector4::new(p[0], p[1], p[2], 1.0);
        [v.x, v.y, v.z]
    }

    pub fn rect_to_velo(&self, p: [f64; 3]) -> [f64; 3] {
        let v = self.rect_to_velo * Vector4::new(p[0], p[1], p[2], 1.0);
        [v.x, v.y, v.z]
    }

    /// Projects a rectified-camera point to pixels; returns (u, v, depth).
    /// The pixel is meaningless when depth ≤ 0 (behind the camera).
    pub fn rect_to_image(&self, p: [f64; 3]) -> (f64, f64, f64) {
        let y = self.p2 * Vector4::new(p[0], p[1], p[2], 1.0);
        (y.x / y.z, y.y / y.z, y.z)
    }

    /// Back-projects pixel (u, v) at depth `depth` (the third homogeneous coordinate
    /// of P2's output) to the rectified camera frame: the exact inverse of
    /// [`CameraModel::rect_to_image`].
    pub fn image_to_rect(&self, u: f64, v: f64, depth: f64) -> [f64; 3] {
        let m = self.p2.fixed_view::<3, 3>(0, 0).into_owned();
        let t = self.p2.column(3).into_owned();
        let rhs = Vector3::new(u * depth, v * depth, depth) - t;
        let x = m.try_inverse().map(|inv| inv * rhs).unwrap_or(rhs);
        [x.x, x.y, x.z]
    }

    /// Back-projects pixel (u, v) to the rectified-camera point whose z (the depth a
    /// depth map stores) is `z`: solves P2 · [x, y, z, 1] = w · [u, v, 1] for x, y and w.
    /// `None` when the ray through (u, v) runs parallel to the z = const plane.
    pub fn image_to_rect_at_z(&self, u: f64, v: f64, z: f64) -> Option<[f64; 3]> {
        let p = &self.p2;
        // Unknowns (x, y, w): row r of P2 gives p_r0 x + p_r1 y − s_r w = −(p_r2 z + p_r3),
        // with s = (u, v, 1).
        let s = [u, v, 1.0];
        let a = Matrix3::from_fn(|r, c| match c {
            0 => p[(r, 0)],
            1 => p[(r, 1)],
            _ => -s[r],
        });
        let b = Vector3::from_fn(|r, _| -(p[(r, 2)] * z + p[(r, 3)]));
        let x = a.try_inverse()? * b;
        Some([x.x, x.y, z])
    }

    pub fn velo_to_image(&self, p: [f64; 3]) -> (f64, f64, f64) {
        self.rect_to_image(self.velo_to_rect(p))
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Frame 000000's P2, R0_rect and Tr_velo_to_cam (KITTI, CC BY-NC-SA 3.0).
    pub(crate) fn sample_camera() -> CameraModel {
        CameraModel::new(
            &[
                [707.0493, 0.0, 604.0814, 45.75831],
                [0.0, 707.0493, 180.5066, -0.3454157],
                [0.0, 0.0, 1.0, 0.004981016],
            ],
            &[
                [0.9999128, 0.01009263, -0.008511932],
                [-0.01012729, 0.9999406, -0.004037671],
                [0.008470675, 0.004123522, 0.9999556],
            ],
            &[
                [0.006927964, -0.9999722, -0.002757829, -0.02457729],
                [-0.001162982, 0.002749836, -0.9999955, -0.06127237],
                [0.9999753, 0.006931141, -0.001143899, -0.3321029],
            ],
        )
        .unwrap()
    }

    #[test]
    fn velo_rect_round_trip() {
        let cam = sample_camera();
        let p = [12.3, -4.5, -1.2];
        let back = cam.rect_to_velo(cam.velo_to_rect(p));
        for k in 0..3 {
            assert!((back[k] - p[k]).abs() < 1e-9);
        }
        // LiDAR forward is camera depth.
        let r = cam.velo_to_rect([10.0, 0.0, 0.0]);
        assert!((r[2] - 10.0).abs() < 0.5 && r[0].abs() < 0.5);
    }

    #[test]
    fn back_projection_at_a_given_z_returns_the_point() {
        let cam = sample_camera();
        for p in [[2.0, 1.5, 20.0], [-7.5, 0.3, 4.2], [0.0, -1.0, 60.0]] {
            let (u, v, _) = cam.rect_to_image(p);
            let back = cam.image_to_rect_at_z(u, v, p[2]).unwrap();
            for k in 0..3 {
                assert!((back[k] - p[k]).abs() < 1e-9, "{p:?} -> {back:?}");
            }
        }
    }

    #[test]
    fn image_round_trip() {
        let cam = sample_camera();
        let p = [2.0, 1.5, 20.0];
        let (u, v, d) = cam.rect_to_image(p);
        let back = cam.image_to_rect(u, v, d);
        for k in 0..3 {
            assert!((back[k] - p[k]).abs() < 1e-9, "{back:?}");
        }
    }
}
