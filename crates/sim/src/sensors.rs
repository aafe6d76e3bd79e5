//! Sensor models: the Velodyne HDL-64E as mounted on the KITTI car, and the left
//! colour camera's calibration (P2, R0_rect, Tr_velo_to_cam).
//!
//! # How the beam pattern was chosen
//!
//! Measured on KITTI's full scans 000000–000005 (points are stored ring by ring,
//! each ring sweeping azimuth from 0° anticlockwise):
//!
//! * 64 rings; median elevation of each ring (seen from the velodyne origin) from
//!   +2.7° down to −23.6°, about 0.34° apart in the upper block (rings 0–31) and
//!   0.5° apart in the lower block. The spec sheet's "+2.0° to −24.9°" differs by
//!   the per-laser origin offsets; we use the measured table so that our rings land
//!   where KITTI's do (e.g. the lowest ring meets the ground 4.0 m away).
//! * A ring holds at most 2,150–2,157 points, so each laser fires about 2,160 times
//!   per revolution: one firing every 1/6° (0.167°) on average. The
//!   "0.08–0.09°" of the spec sheet is the *encoder* resolution (and the laser step
//!   at 5 Hz): consecutive azimuths in KITTI differ by 0.18° (82% of steps) or 0.09°
//!   (14%), exactly what a 0.167° firing step read on a 0.09° encoder gives. We
//!   reproduce both: 2,160 firings per laser, azimuths snapped to the 0.09° grid.
//! * So a revolution has 64 × 2,160 = 138,240 rays, and KITTI's frames keep
//!   113k–127k of them (82–92%). The rest are sky and beyond-range rays (the upper
//!   rings, 0° to +2.7°, see only what is tall and close), rays blocked by the ego
//!   car (the lowest rings lose ≈ 25–40% of their azimuths, front and back; we use
//!   the measured azimuth sectors), weak returns from dark or grazing surfaces, and
//!   ~0.3% random dropouts.

use crate::math::{M3, rad};
use crate::rng::Sampler;
use fusiondet_kitti::{Calib, Mat33, Mat34};

/// Elevation of each ring in degrees, top (ring 0) to bottom, as measured on KITTI.
pub const HDL64_ELEVATIONS_DEG: [f64; 64] = [
    2.72, 2.36, 2.09, 1.65, 1.38, 0.97, 0.68, 0.31, -0.03, -0.44, -0.72, -1.03, -1.42, -1.80,
    -2.14, -2.49, -2.81, -3.17, -3.49, -3.85, -4.13, -4.47, -4.78, -5.10, -5.45, -5.75, -6.06,
    -6.33, -6.76, -7.06, -7.27, -7.65, -8.32, -8.85, -9.32, -9.71, -10.17, -10.77, -11.27, -11.70,
    -12.15, -12.57, -13.10, -13.62, -14.19, -14.63, -15.13, -15.50, -16.11, -16.63, -17.19, -17.64,
    -18.14, -18.54, -19.00, -19.54, -20.06, -20.65, -21.14, -21.54, -21.99, -22.63, -23.15, -23.63,
];

/// Azimuth sectors (first ring affected, from°, to°) where KITTI's scans have no
/// points because the ego car's roof rack and body block the beams (measured).
pub const EGO_MASK: [(usize, f64, f64); 17] = [
    (42, 156.0, 166.0),
    (42, 196.0, 206.0),
    (47, 282.0, 298.0),
    (53, 158.0, 204.0),
    (56, 128.0, 136.0),
    (56, 228.0, 236.0),
    (57, 152.0, 208.0),
    (57, 350.0, 360.0),
    (57, 0.0, 10.0),
    (59, 0.0, 16.0),
    (59, 344.0, 360.0),
    (61, 0.0, 20.0),
    (61, 340.0, 360.0),
    (61, 126.0, 142.0),
    (61, 146.0, 212.0),
    (62, 216.0, 234.0),
    (62, 320.0, 332.0),
];

/// The LiDAR model.
#[derive(Debug, Clone, PartialEq)]
pub struct LidarSpec {
    pub elevations_deg: Vec<f64>,
    /// Firings per laser per revolution.
    pub firings: usize,
    /// Encoder resolution the azimuths are reported on (degrees).
    pub azimuth_quantum_deg: f64,
    pub max_range: f64,
    /// Returns closer than this are dropped (the sensor's blind zone / the ego car).
    pub min_range: f64,
    /// Range noise standard deviation (m).
    pub range_noise: f64,
    /// Reflectance noise standard deviation.
    pub reflectance_noise: f64,
    /// Probability that any beam is lost at random.
    pub dropout: f64,
    /// Range (m) at which a surface of reflectance [`Self::reference_reflectance`] seen
    /// head-on returns half of the time; the return probability falls off as
    /// `1 / (1 + (r / r50)^k)` with `r50` scaling with √(reflectance · cos incidence).
    pub reference_range: f64,
    pub reference_reflectance: f64,
    pub falloff_exponent: u32,
    /// Added to the reflectance when deciding returns: even black paint returns close up.
    pub reflectance_floor: f64,
    pub ego_mask: Vec<(usize, f64, f64)>,
}

impl Default for LidarSpec {
    fn default() -> Self {
        LidarSpec {
            elevations_deg: HDL64_ELEVATIONS_DEG.to_vec(),
            firings: 2160,
            azimuth_quantum_deg: 0.09,
            max_range: 120.0,
            min_range: 2.5,
            range_noise: 0.02,
            reflectance_noise: 0.05,
            dropout: 0.003,
            reference_range: 140.0,
            reference_reflectance: 0.3,
            falloff_exponent: 4,
            reflectance_floor: 0.05,
            ego_mask: EGO_MASK.to_vec(),
        }
    }
}

impl LidarSpec {
    pub fn rays(&self) -> usize {
        self.elevations_deg.len() * self.firings
    }

    /// Is the beam of `ring` at azimuth `az_deg` (0..360) blocked by the ego car?
    pub fn masked(&self, ring: usize, az_deg: f64) -> bool {
        self.ego_mask
            .iter()
            .any(|&(r, a, b)| ring >= r && az_deg >= a && az_deg < b)
    }
}

/// The two real KITTI camera calibrations (recording days 2011-09-26 and 2011-09-28)
/// the simulated rigs are perturbed from.
struct Rig {
    f: f64,
    cu: f64,
    cv: f64,
    /// P2's fourth column (the colour camera's offset from camera 0).
    p2_t: [f64; 3],
    r0: Mat33,
    tr: Mat34,
}

const RIGS: [Rig; 2] = [
    Rig {
        f: 721.5377,
        cu: 609.5593,
        cv: 172.854,
        p2_t: [44.85728, 0.2163791, 0.002745884],
        r0: [
            [0.9999239, 0.00983776, -0.007445048],
            [-0.009869795, 0.9999421, -0.004278459],
            [0.007402527, 0.004351614, 0.9999631],
        ],
        tr: [
            [0.007533745, -0.9999714, -0.000616602, -0.004069766],
            [0.01480249, 0.0007280733, -0.9998902, -0.07631618],
            [0.9998621, 0.00752379, 0.01480755, -0.2717806],
        ],
    },
    Rig {
        f: 707.0493,
        cu: 604.0814,
        cv: 180.5066,
        p2_t: [45.75831, -0.3454157, 0.004981016],
        r0: [
            [0.9999128, 0.01009263, -0.008511932],
            [-0.01012729, 0.9999406, -0.004037671],
            [0.008470675, 0.004123522, 0.9999556],
        ],
        tr: [
            [0.006927964, -0.9999722, -0.002757829, -0.02457729],
            [-0.001162982, 0.002749836, -0.9999955, -0.06127237],
            [0.9999753, 0.006931141, -0.001143899, -0.3321029],
        ],
    },
];

fn round_to(x: f64, digits: u32) -> f64 {
    // Calibration files carry 7 significant digits, like KITTI's.
    let s = crate::math::ipow(10.0, digits);
    (x * s).round() / s
}

/// A KITTI-like calibration: one of the real rigs with small per-frame changes
/// (focal length ±0.3%, principal point ±2 px, extrinsic rotation ±0.15°,
/// translation ±1 cm), so models cannot memorise one matrix.
pub fn sample_calib(s: &mut Sampler) -> Calib {
    let rig = &RIGS[s.int(0, RIGS.len() as i64 - 1) as usize];
    let f = rig.f * (1.0 + s.normal_clamped(0.0, 0.001, -0.003, 0.003));
    let cu = rig.cu + s.normal_clamped(0.0, 0.7, -2.0, 2.0);
    let cv = rig.cv + s.normal_clamped(0.0, 0.7, -2.0, 2.0);
    let p_of = |t: [f64; 3]| -> Mat34 {
        [
            [round_to(f, 4), 0.0, round_to(cu, 4), t[0]],
            [0.0, round_to(f, 4), round_to(cv, 4), t[1]],
            [0.0, 0.0, 1.0, t[2]],
        ]
    };
    // Cameras 0, 1, 3 keep the rig's baselines scaled by the focal length.
    let scale = f / rig.f;
    let p0 = p_of([0.0, 0.0, 0.0]);
    let p1 = p_of([round_to(-0.537150 * rig.f * scale, 4), 0.0, 0.0]);
    let p2 = p_of([
        round_to(rig.p2_t[0] * scale, 5),
        round_to(rig.p2_t[1] * scale, 7),
        rig.p2_t[2],
    ]);
    let p3 = p_of([
        round_to(-0.4732 * rig.f * scale, 4),
        round_to(2.33 * scale, 5),
        0.003201153,
    ]);
    // Extrinsics: a small extra rotation (roll, pitch, yaw) and translation.
    let d = |s: &mut Sampler, deg: f64| rad(s.normal_clamped(0.0, deg / 2.0, -deg, deg));
    let extra = M3::rot_x(d(s, 0.15))
        .mul(&M3::rot_y(d(s, 0.15)))
        .mul(&M3::rot_z(d(s, 0.15)));
    let mut tr = rig.tr;
    // R' = R · extra: the perturbation acts in the LiDAR frame.
    for (r, row) in tr.iter_mut().enumerate() {
        let base = [rig.tr[r][0], rig.tr[r][1], rig.tr[r][2]];
        for (c, v) in row.iter_mut().take(3).enumerate() {
            let e = extra.cols[c];
            *v = round_to(base[0] * e.x + base[1] * e.y + base[2] * e.z, 9);
        }
        row[3] = round_to(rig.tr[r][3] + s.normal_clamped(0.0, 0.005, -0.01, 0.01), 8);
    }
    Calib {
        p: [p0, p1, p2, p3],
        r0_rect: rig.r0,
        tr_velo_to_cam: tr,
        tr_imu_to_velo: [
            [0.9999976, 0.0007553071, -0.002035826, -0.8086759],
            [-0.0007854027, 0.9998898, -0.01482298, 0.3195559],
            [0.002024406, 0.01482454, 0.9998881, -0.7997231],
        ],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn elevation_table_is_monotone_and_spans_the_sensor() {
        let e = HDL64_ELEVATIONS_DEG;
        assert!(e.windows(2).all(|w| w[0] > w[1]));
        assert!(e[0] > 2.0 && e[0] < 3.0);
        assert!(e[63] < -23.0 && e[63] > -25.0);
        // Upper block denser than the lower block.
        let upper = (e[0] - e[31]) / 31.0;
        let lower = (e[32] - e[63]) / 31.0;
        assert!(upper < 0.4 && lower > 0.45, "{upper} {lower}");
    }

    #[test]
    fn mask_blocks_the_low_rings_front_and_back_only() {
        let l = LidarSpec::default();
        assert!(l.masked(63, 180.0) && l.masked(63, 5.0));
        assert!(!l.masked(63, 90.0));
        assert!(!l.masked(20, 180.0));
    }

    #[test]
    fn sampled_calibrations_are_kitti_like() {
        let mut s = Sampler::new(1);
        for _ in 0..20 {
            let c = sample_calib(&mut s);
            let cam = c.camera_model().unwrap();
            assert!(cam.fu() > 700.0 && cam.fu() < 725.0);
            // LiDAR forward is camera depth, the LiDAR origin is ~0.27–0.33 m behind the camera.
            let r = cam.velo_to_rect([10.0, 0.0, 0.0]);
            assert!((r[2] - 10.0).abs() < 0.5 && r[0].abs() < 0.1, "{r:?}");
            let o = cam.velo_to_rect([0.0, 0.0, 0.0]);
            assert!(o[2] < -0.2 && o[2] > -0.4, "{o:?}");
            // The rotation part stays orthonormal to the printed precision.
            let t = c.tr_velo_to_cam;
            for row in &t {
                let n: f64 = row[..3].iter().map(|x| x * x).sum();
                assert!((n - 1.0).abs() < 1e-6);
            }
        }
    }
}
