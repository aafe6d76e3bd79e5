//! Host-side box corners in the conventions the loss uses (the heading and size
//! coding is the frustum crate's `BoxCoder`) (frustum frame: x right, y down,
//! z forward; heading is a rotation about y as in KITTI's `rotation_y`).

/// The eight corners of a box given by its *geometric* centre, heading and (l, w, h), in
/// the order of `fusiondet_geometry::corners`: 0–3 the bottom face (y = centre + h/2),
/// 4–7 the top face, both counter-clockwise seen from above; corner k of the local box is
/// (±l/2, ±h/2, ±w/2) rotated by x' = c·x + s·z, z' = −s·x + c·z.
pub fn box_corners(center: [f32; 3], heading: f32, size: [f32; 3]) -> [[f32; 3]; 8] {
    let (s, c) = heading.sin_cos();
    let [l, w, h] = size;
    let mut out = [[0.0; 3]; 8];
    for k in 0..8 {
        let (x, y, z) = (
            CORNER_SIGNS[0][k] * l / 2.0,
            CORNER_SIGNS[1][k] * h / 2.0,
            CORNER_SIGNS[2][k] * w / 2.0,
        );
        out[k] = [
            c * x + s * z + center[0],
            y + center[1],
            -s * x + c * z + center[2],
        ];
    }
    out
}

/// Signs of the local (x ~ l, y ~ h, z ~ w) corner offsets, in corner order.
pub(crate) const CORNER_SIGNS: [[f32; 8]; 3] = [
    [1.0, 1.0, -1.0, -1.0, 1.0, 1.0, -1.0, -1.0],
    [1.0, 1.0, 1.0, 1.0, -1.0, -1.0, -1.0, -1.0],
    [1.0, -1.0, -1.0, 1.0, 1.0, -1.0, -1.0, 1.0],
];

/// The corners of the same box turned by π about its vertical axis: (2cx − x, y, 2cz − z),
/// corner by corner (what `box_corners(center, heading + π, size)` gives).
pub fn flip_corners(corners: &[[f32; 3]; 8], center: [f32; 3]) -> [[f32; 3]; 8] {
    corners.map(|[x, y, z]| [2.0 * center[0] - x, y, 2.0 * center[2] - z])
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f32::consts::PI;

    #[test]
    fn flipped_corners_are_the_box_turned_by_pi() {
        let (c, h, s) = ([1.0, 1.5, 20.0], 0.7, [3.9, 1.6, 1.5]);
        let a = flip_corners(&box_corners(c, h, s), c);
        let b = box_corners(c, h + PI, s);
        for k in 0..8 {
            for d in 0..3 {
                assert!((a[k][d] - b[k][d]).abs() < 1e-5);
            }
        }
    }
}
