//! The ground-truth database that augmentation pastes objects from (OpenPCDet's
//! `gt_database` and `kitti_dbinfos_train.pkl`): for every labelled object of the
//! training frames (DontCare excepted), its box in the LiDAR frame, its class, KITTI
//! difficulty and 2D box, and the points of the full scan inside its box, stored
//! relative to the box centre.
//!
//! A database built for DASANet also keeps each object's pseudo points (the camera's
//! back-projected pixels inside its box), so a pasted object brings them along.
//!
//! On disk, a directory of two or three files, each written atomically:
//! - `points.bin`: every object's points one after another, float32 little-endian
//!   (x, y, z, intensity) as KITTI's velodyne files;
//! - `pseudo.bin` (with pseudo points only): every object's pseudo points, float32
//!   little-endian (x, y, z, r, g, b);
//! - `index.json`: `{"format": "fusiondet-gt-database", "version": 1, "total_points": N,
//!   "pseudo": bool, "total_pseudo": M, "objects": [...]}` (the last two absent in
//!   databases without pseudo points), each object with `frame`, `index` (its line among
//!   the frame's labels), `class` (KITTI's spelling), `bbox` (the [`LidarBox`] fields),
//!   `difficulty` (0 easy, 1 moderate, 2 hard, −1 none), `bbox_2d` [x1, y1, x2, y2],
//!   `offset` (its first point in `points.bin`), `num_points`, and `pseudo_offset`,
//!   `num_pseudo` likewise into `pseudo.bin`.
//!
//! The index is written last, so a directory whose index reads is complete. Numbers in
//! the index are decimal: a box reads back to within an ulp or so of what was written.

use crate::boxes::{LidarBox, points_in_box};
use crate::error::{Result, VoxelError};
use crate::scene::PseudoPoint;
use fusiondet_dataset::SensorFrame;
use fusiondet_kitti::velodyne::{encode_velodyne, parse_velodyne};
use fusiondet_kitti::{LidarPoint, Object, ObjectClass, write_atomic};
use serde::{Deserialize, Serialize};
use std::path::Path;

const FORMAT: &str = "fusiondet-gt-database";
const VERSION: u32 = 1;
pub const INDEX_FILE: &str = "index.json";
pub const POINTS_FILE: &str = "points.bin";
pub const PSEUDO_FILE: &str = "pseudo.bin";

/// OpenPCDet's KITTI difficulty of a label: 0 easy (2D box ≥ 40 px high counting both
/// edge pixels, truncation ≤ 0.15, fully visible), 1 moderate (≥ 25 px, ≤ 0.3, at most
/// partly occluded), 2 hard (≥ 25 px, ≤ 0.5, at most largely occluded), −1 otherwise.
pub fn kitti_difficulty(object: &Object) -> i8 {
    let height = object.bbox.y2 - object.bbox.y1 + 1.0;
    let (t, o) = (object.truncation, object.occlusion);
    if height >= 40.0 && t <= 0.15 && o <= 0 {
        0
    } else if height >= 25.0 && t <= 0.3 && o <= 1 {
        1
    } else if height >= 25.0 && t <= 0.5 && o <= 2 {
        2
    } else {
        -1
    }
}

/// One object of the database.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DbObject {
    pub frame: String,
    /// The object's line among its frame's labels.
    pub index: usize,
    #[serde(with = "crate::config::class_name")]
    pub class: ObjectClass,
    pub bbox: LidarBox,
    pub difficulty: i8,
    pub bbox_2d: [f64; 4],
    /// Its first point in the database's point array.
    pub offset: usize,
    pub num_points: usize,
    /// Its first pseudo point and how many (0 in databases without pseudo points).
    #[serde(default)]
    pub pseudo_offset: usize,
    #[serde(default)]
    pub num_pseudo: usize,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct IndexFile {
    format: String,
    version: u32,
    total_points: usize,
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pseudo: bool,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    total_pseudo: Option<usize>,
    objects: Vec<DbObject>,
}

/// The database in memory.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct GtDatabase {
    objects: Vec<DbObject>,
    points: Vec<LidarPoint>,
    /// Built with pseudo points (even if no object happened to hold one).
    with_pseudo: bool,
    pseudo: Vec<PseudoPoint>,
}

impl GtDatabase {
    pub fn new() -> GtDatabase {
        GtDatabase::default()
    }

    /// The objects of one frame (so that frames can be read and cut in parallel and
    /// the pieces joined with [`GtDatabase::extend`] in frame order).
    pub fn of_frame(frame: &SensorFrame) -> GtDatabase {
        Self::cut(frame, None)
    }

    /// The objects of one frame with the pseudo points of its camera inside their boxes.
    pub fn of_frame_with_pseudo(frame: &SensorFrame, pseudo: &[PseudoPoint]) -> GtDatabase {
        Self::cut(frame, Some(pseudo))
    }

    fn cut(frame: &SensorFrame, pseudo: Option<&[PseudoPoint]>) -> GtDatabase {
        let mut db = GtDatabase::new();
        if pseudo.is_some() {
            db.mark_pseudo();
        }
        // The pseudo points' positions, for the box test.
        let pseudo_xyz: Vec<LidarPoint> = pseudo
            .unwrap_or_default()
            .iter()
            .map(|p| [p[0], p[1], p[2], 0.0])
            .collect();
        for (index, object) in frame.objects.iter().enumerate() {
            if object.class == ObjectClass::DontCare {
                continue;
            }
            let bbox = LidarBox::from_camera(&object.box3d, &frame.camera);
            let inside = points_in_box(&bbox, &frame.lidar);
            let points: Vec<LidarPoint> = frame
                .lidar
                .iter()
                .zip(inside)
                .filter(|(_, i)| *i)
                .map(|(p, _)| relative(p, &bbox))
                .collect();
            let object_pseudo: Vec<PseudoPoint> = match pseudo {
                Some(cloud) => cloud
                    .iter()
                    .zip(points_in_box(&bbox, &pseudo_xyz))
                    .filter(|(_, i)| *i)
                    .map(|(p, _)| relative(p, &bbox))
                    .collect(),
                None => Vec::new(),
            };
            let b = &object.bbox;
            db.push_with_pseudo(
                DbObject {
                    frame: frame.id.clone(),
                    index,
                    class: object.class,
                    bbox,
                    difficulty: kitti_difficulty(object),
                    bbox_2d: [b.x1, b.y1, b.x2, b.y2],
                    offset: 0,
                    num_points: 0,
                    pseudo_offset: 0,
                    num_pseudo: 0,
                },
                &points,
                &object_pseudo,
            );
        }
        db
    }

    /// The database of several frames, in their order.
    pub fn from_frames<'a>(frames: impl IntoIterator<Item = &'a SensorFrame>) -> GtDatabase {
        let mut db = GtDatabase::new();
        for frame in frames {
            db.extend(GtDatabase::of_frame(frame));
        }
        db
    }

    /// Adds an object with its points (relative to its box centre); `offset` and
    /// `num_points` are set here.
    pub fn push(&mut self, object: DbObject, points: &[LidarPoint]) {
        self.push_with_pseudo(object, points, &[]);
    }

    /// Adds an object with its points and pseudo points, both relative to its box centre.
    pub fn push_with_pseudo(
        &mut self,
        mut object: DbObject,
        points: &[LidarPoint],
        pseudo: &[PseudoPoint],
    ) {
        object.offset = self.points.len();
        object.num_points = points.len();
        object.pseudo_offset = self.pseudo.len();
        object.num_pseudo = pseudo.len();
        self.points.extend_from_slice(points);
        self.pseudo.extend_from_slice(pseudo);
        self.objects.push(object);
    }

    /// Records that the database is built with pseudo points.
    pub fn mark_pseudo(&mut self) {
        self.with_pseudo = true;
    }

    /// Whether the database was built with pseudo points.
    pub fn has_pseudo(&self) -> bool {
        self.with_pseudo
    }

    /// Appends another database's objects (the result has pseudo points if either has).
    pub fn extend(&mut self, other: GtDatabase) {
        let shift = self.points.len();
        let pseudo_shift = self.pseudo.len();
        self.with_pseudo |= other.with_pseudo;
        self.points.extend(other.points);
        self.pseudo.extend(other.pseudo);
        self.objects.extend(other.objects.into_iter().map(|mut o| {
            o.offset += shift;
            o.pseudo_offset += pseudo_shift;
            o
        }));
    }

    /// The objects of the frames `keep` says yes to, in their order, with their points:
    /// a training on part of a split pastes only what those frames hold, whatever frames
    /// the database was built from.
    pub fn restricted_to_frames(&self, keep: impl Fn(&str) -> bool) -> GtDatabase {
        let mut db = GtDatabase {
            with_pseudo: self.with_pseudo,
            ..GtDatabase::default()
        };
        for (i, o) in self.objects.iter().enumerate() {
            if keep(&o.frame) {
                db.push_with_pseudo(o.clone(), self.points_of(i), self.pseudo_of(i));
            }
        }
        db
    }

    pub fn objects(&self) -> &[DbObject] {
        &self.objects
    }

    pub fn len(&self) -> usize {
        self.objects.len()
    }

    pub fn is_empty(&self) -> bool {
        self.objects.is_empty()
    }

    /// The points of object `i`, relative to its box centre.
    pub fn points_of(&self, i: usize) -> &[LidarPoint] {
        let o = &self.objects[i];
        &self.points[o.offset..o.offset + o.num_points]
    }

    /// The pseudo points of object `i`, relative to its box centre.
    pub fn pseudo_of(&self, i: usize) -> &[PseudoPoint] {
        let o = &self.objects[i];
        &self.pseudo[o.pseudo_offset..o.pseudo_offset + o.num_pseudo]
    }

    /// Writes the directory (created if missing): points first, then the index.
    pub fn save(&self, dir: &Path) -> Result<()> {
        std::fs::create_dir_all(dir).map_err(|e| db_error(dir, format!("cannot create: {e}")))?;
        write_atomic(&dir.join(POINTS_FILE), &encode_velodyne(&self.points))?;
        if self.with_pseudo {
            let bytes: Vec<u8> = self
                .pseudo
                .iter()
                .flatten()
                .flat_map(|v| v.to_le_bytes())
                .collect();
            write_atomic(&dir.join(PSEUDO_FILE), &bytes)?;
        }
        let index = IndexFile {
            format: FORMAT.into(),
            version: VERSION,
            total_points: self.points.len(),
            pseudo: self.with_pseudo,
            total_pseudo: self.with_pseudo.then_some(self.pseudo.len()),
            objects: self.objects.clone(),
        };
        let text = serde_json::to_string_pretty(&index)
            .map_err(|e| db_error(dir, format!("cannot encode the index: {e}")))?;
        write_atomic(&dir.join(INDEX_FILE), (text + "\n").as_bytes())?;
        Ok(())
    }

    /// Reads a directory written by [`GtDatabase::save`], checking that the index and
    /// the points agree.
    pub fn load(dir: &Path) -> Result<GtDatabase> {
        let index_path = dir.join(INDEX_FILE);
        let text = fusiondet_kitti::error::read_text(&index_path)?;
        let index: IndexFile = serde_json::from_str(&text)
            .map_err(|e| db_error(&index_path, format!("not a database index: {e}")))?;
        if index.format != FORMAT || index.version != VERSION {
            return Err(db_error(
                &index_path,
                format!(
                    "format {} version {}, expected {FORMAT} version {VERSION}",
                    index.format, index.version
                ),
            ));
        }
        let points_path = dir.join(POINTS_FILE);
        let bytes = fusiondet_kitti::error::read_regular(
            &points_path,
            fusiondet_kitti::error::MAX_BINARY_BYTES,
        )?;
        let points = parse_velodyne(&bytes, &points_path)?;
        if points.len() != index.total_points {
            return Err(db_error(
                &points_path,
                format!(
                    "holds {} points but the index says {}; the two files do not belong \
                     together (rebuild the database)",
                    points.len(),
                    index.total_points
                ),
            ));
        }
        for (i, o) in index.objects.iter().enumerate() {
            if o.offset
                .checked_add(o.num_points)
                .is_none_or(|end| end > points.len())
            {
                return Err(db_error(
                    &index_path,
                    format!(
                        "object {i} (frame {} #{}) reaches past the {} points",
                        o.frame,
                        o.index,
                        points.len()
                    ),
                ));
            }
        }
        let pseudo = if index.pseudo {
            read_pseudo(&dir.join(PSEUDO_FILE), index.total_pseudo.unwrap_or(0))?
        } else {
            Vec::new()
        };
        for (i, o) in index.objects.iter().enumerate() {
            if o.pseudo_offset
                .checked_add(o.num_pseudo)
                .is_none_or(|end| end > pseudo.len())
            {
                return Err(db_error(
                    &index_path,
                    format!(
                        "object {i} (frame {} #{}) reaches past the {} pseudo points",
                        o.frame,
                        o.index,
                        pseudo.len()
                    ),
                ));
            }
        }
        Ok(GtDatabase {
            objects: index.objects,
            points,
            with_pseudo: index.pseudo,
            pseudo,
        })
    }
}

/// `pseudo.bin`: float32 × 6 per point, `expected` of them.
fn read_pseudo(path: &Path, expected: usize) -> Result<Vec<PseudoPoint>> {
    let bytes =
        fusiondet_kitti::error::read_regular(path, fusiondet_kitti::error::MAX_BINARY_BYTES)?;
    if bytes.len() != expected * 24 {
        return Err(db_error(
            path,
            format!(
                "holds {} bytes but the index says {expected} pseudo points of 24 bytes; the \
                 files do not belong together (rebuild the database)",
                bytes.len()
            ),
        ));
    }
    Ok(bytes
        .chunks_exact(24)
        .map(|c| {
            std::array::from_fn(|k| {
                f32::from_le_bytes(c[4 * k..4 * k + 4].try_into().expect("4 bytes"))
            })
        })
        .collect())
}

/// A point (of any width) relative to a box centre.
fn relative<const N: usize>(p: &[f32; N], b: &LidarBox) -> [f32; N] {
    let mut out = *p;
    for (a, c) in [b.x, b.y, b.z].into_iter().enumerate() {
        out[a] = (p[a] as f64 - c) as f32;
    }
    out
}

fn db_error(path: &Path, message: String) -> VoxelError {
    VoxelError::Database {
        path: path.display().to_string(),
        message,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::tests::kitti_frame;
    use fusiondet_kitti::Box2d;

    fn object(height: f64, truncation: f64, occlusion: i32) -> Object {
        Object {
            class: ObjectClass::Car,
            truncation,
            occlusion,
            alpha: 0.0,
            bbox: Box2d {
                x1: 100.0,
                y1: 100.0,
                x2: 150.0,
                y2: 100.0 + height - 1.0,
            },
            box3d: Default::default(),
            score: None,
        }
    }

    #[test]
    fn difficulty_follows_the_kitti_levels() {
        assert_eq!(kitti_difficulty(&object(40.0, 0.15, 0)), 0);
        assert_eq!(kitti_difficulty(&object(39.0, 0.0, 0)), 1);
        assert_eq!(kitti_difficulty(&object(60.0, 0.3, 1)), 1);
        assert_eq!(kitti_difficulty(&object(60.0, 0.31, 1)), 2);
        assert_eq!(kitti_difficulty(&object(25.0, 0.5, 2)), 2);
        assert_eq!(kitti_difficulty(&object(24.0, 0.0, 0)), -1);
        assert_eq!(kitti_difficulty(&object(60.0, 0.0, 3)), -1);
    }

    /// Restricting a database to some frames gives what building it from those frames
    /// alone gives (objects, order, points), and keeps its pseudo flag.
    #[test]
    fn a_database_restricted_to_frames_is_the_one_built_from_them() {
        let (a, b) = (kitti_frame("000001"), kitti_frame("000002"));
        let both = GtDatabase::from_frames([&a, &b]);
        assert!(
            both.len() > GtDatabase::of_frame(&b).len(),
            "both frames hold objects"
        );
        assert_eq!(
            both.restricted_to_frames(|f| f == "000002"),
            GtDatabase::of_frame(&b)
        );
        assert_eq!(both.restricted_to_frames(|_| true), both);
        let mut marked = both.clone();
        marked.mark_pseudo();
        let none = marked.restricted_to_frames(|_| false);
        assert!(none.is_empty() && none.has_pseudo());
    }

    #[test]
    fn a_kitti_frame_builds_a_database_that_survives_disk() {
        let frame = kitti_frame("000001");
        let db = GtDatabase::of_frame(&frame);
        let labelled = frame
            .objects
            .iter()
            .filter(|o| o.class != ObjectClass::DontCare)
            .count();
        assert_eq!(db.len(), labelled);
        for (i, o) in db.objects().iter().enumerate() {
            assert_eq!(o.frame, "000001");
            // Stored relative to the centre: every point lies in the box moved to the origin.
            let at_origin = LidarBox {
                x: 0.0,
                y: 0.0,
                z: 0.0,
                ..o.bbox
            };
            let pts = db.points_of(i);
            assert_eq!(pts.len(), o.num_points);
            let slack = LidarBox {
                dx: at_origin.dx + 1e-4,
                dy: at_origin.dy + 1e-4,
                dz: at_origin.dz + 1e-4,
                ..at_origin
            };
            assert!(points_in_box(&slack, pts).iter().all(|&b| b));
        }
        assert!(db.objects().iter().any(|o| o.num_points > 20));

        let dir = tempfile::tempdir().unwrap();
        let mut two = db.clone();
        two.extend(db.clone());
        two.save(dir.path()).unwrap();
        let back = GtDatabase::load(dir.path()).unwrap();
        // The points come back bit for bit; the boxes to the last bit or so (JSON).
        assert_eq!(back.points, two.points);
        assert_eq!(back.len(), two.len());
        for (a, b) in back.objects().iter().zip(two.objects()) {
            let (p, q) = (a.bbox.to_array(), b.bbox.to_array());
            assert!((0..7).all(|k| (p[k] - q[k]).abs() <= 1e-12 * q[k].abs().max(1.0)));
            let strip = |o: &DbObject| DbObject {
                bbox: LidarBox::default(),
                ..o.clone()
            };
            assert_eq!(strip(a), strip(b));
        }
        assert_eq!(back.points_of(labelled), db.points_of(0));

        // An index that does not match its points is refused, naming the file.
        std::fs::write(dir.path().join(POINTS_FILE), [0u8; 32]).unwrap();
        let err = GtDatabase::load(dir.path()).unwrap_err().to_string();
        assert!(
            err.contains(POINTS_FILE) && err.contains("index says"),
            "{err}"
        );
        std::fs::write(dir.path().join(INDEX_FILE), "{}").unwrap();
        let err = GtDatabase::load(dir.path()).unwrap_err().to_string();
        assert!(err.contains(INDEX_FILE), "{err}");
    }

    /// Pseudo points inside a box are stored relative to its centre, survive disk with
    /// the rest, and a database written without them still loads as before.
    #[test]
    fn pseudo_points_are_cut_stored_and_optional() {
        let frame = kitti_frame("000001");
        let plain = GtDatabase::of_frame(&frame);
        let car = plain.objects()[0].bbox;
        // Two pseudo points inside the first object's box, one far outside.
        let cloud: Vec<PseudoPoint> = vec![
            [car.x as f32, car.y as f32, car.z as f32, 0.1, 0.2, 0.3],
            [
                car.x as f32,
                car.y as f32,
                (car.z + 0.25 * car.dz) as f32,
                0.4,
                0.5,
                0.6,
            ],
            [
                (car.x + 50.0) as f32,
                car.y as f32,
                car.z as f32,
                0.0,
                0.0,
                0.0,
            ],
        ];
        let db = GtDatabase::of_frame_with_pseudo(&frame, &cloud);
        assert!(db.has_pseudo() && !plain.has_pseudo());
        assert_eq!(db.objects()[0].num_pseudo, 2);
        let p = db.pseudo_of(0);
        assert!(p[0][..3].iter().all(|v| v.abs() < 1e-5) && p[0][3..] == [0.1, 0.2, 0.3]);
        assert!((p[1][2] as f64 - 0.25 * car.dz).abs() < 1e-5);
        assert_eq!(db.points_of(0), plain.points_of(0));

        let dir = tempfile::tempdir().unwrap();
        let mut two = plain.clone();
        two.extend(db.clone());
        assert!(two.has_pseudo());
        two.save(dir.path()).unwrap();
        let back = GtDatabase::load(dir.path()).unwrap();
        // Points bit for bit (the boxes to an ulp, through JSON).
        assert_eq!(
            (&back.points, &back.pseudo, back.with_pseudo),
            (&two.points, &two.pseudo, true)
        );
        let offsets = |d: &GtDatabase| -> Vec<[usize; 4]> {
            d.objects()
                .iter()
                .map(|o| [o.offset, o.num_points, o.pseudo_offset, o.num_pseudo])
                .collect()
        };
        assert_eq!(offsets(&back), offsets(&two));
        assert_eq!(back.pseudo_of(plain.len()), db.pseudo_of(0));
        // A pseudo file that does not match the index is refused by name.
        std::fs::write(dir.path().join(PSEUDO_FILE), [0u8; 24]).unwrap();
        let err = GtDatabase::load(dir.path()).unwrap_err().to_string();
        assert!(err.contains(PSEUDO_FILE), "{err}");

        // An index as databases without pseudo points were written: no pseudo keys.
        let old = tempfile::tempdir().unwrap();
        plain.save(old.path()).unwrap();
        let text = std::fs::read_to_string(old.path().join(INDEX_FILE)).unwrap();
        let stripped: String = text
            .lines()
            .filter(|l| !l.contains("pseudo"))
            .map(|l| format!("{l}\n"))
            .collect();
        let stripped = stripped.replace(",\n    }", "\n    }");
        std::fs::write(old.path().join(INDEX_FILE), stripped).unwrap();
        assert!(!old.path().join(PSEUDO_FILE).exists());
        let back = GtDatabase::load(old.path()).unwrap();
        assert!(!back.has_pseudo());
        assert_eq!(back.points_of(0), plain.points_of(0));
    }
}
