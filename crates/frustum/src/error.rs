//! Errors of the frustum data set, and the typed reasons a frustum is skipped.

use fusiondet_kitti::FormatError;

/// A failure that stops the data set (bad files, bad configuration). A frustum that
/// merely cannot be made (no points, box too small) is not an error but a
/// [`SkipReason`].
#[derive(Debug, thiserror::Error)]
pub enum FrustumError {
    #[error(transparent)]
    Format(#[from] FormatError),
    #[error(transparent)]
    Data(#[from] fusiondet_dataset::DataError),
    /// The calibration of a frame cannot be used.
    #[error("frame {frame}: {message}")]
    Calib { frame: String, message: String },
    /// The configuration is inconsistent; the message says which field and why.
    #[error("frustum config: {0}")]
    Config(String),
    /// A frustum that was valid when the data set was prepared no longer is
    /// (the frame's files changed underneath).
    #[error("frame {frame}: frustum {index} was valid when prepared but is now skipped ({reason})")]
    Stale {
        frame: String,
        index: usize,
        reason: SkipReason,
    },
}

pub type Result<T> = std::result::Result<T, FrustumError>;

/// Why no frustum was made for a 2D box.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SkipReason {
    /// The 2D box lies wholly outside the image.
    OutsideImage,
    /// The (clipped) 2D box is shorter than the configured minimum height.
    TooSmall,
    /// No LiDAR point projects into the box within the depth range.
    NoPoints,
    /// Training only: the frustum has points, but fewer than the configured minimum
    /// lie inside the ground-truth 3D box.
    NoObjectPoints,
    /// Detections only: the detection names a frame the data set does not hold.
    UnknownFrame,
    /// Refinement training only: the proposal overlaps no ground truth of its class
    /// enough (`proposal_crop.match_iou`).
    Unmatched,
}

impl std::fmt::Display for SkipReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            SkipReason::OutsideImage => "2D box outside the image",
            SkipReason::TooSmall => "2D box below the minimum height",
            SkipReason::NoPoints => "no LiDAR points in the frustum",
            SkipReason::NoObjectPoints => "no LiDAR points inside the ground-truth box",
            SkipReason::UnknownFrame => "frame not in the data set",
            SkipReason::Unmatched => "proposal matches no ground truth",
        })
    }
}

/// How many frustums were skipped, by reason.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SkipCounts {
    pub outside_image: usize,
    pub too_small: usize,
    pub no_points: usize,
    pub no_object_points: usize,
    pub unknown_frame: usize,
    pub unmatched: usize,
}

impl SkipCounts {
    pub fn add(&mut self, reason: SkipReason) {
        *self.slot(reason) += 1;
    }

    pub fn get(&self, reason: SkipReason) -> usize {
        match reason {
            SkipReason::OutsideImage => self.outside_image,
            SkipReason::TooSmall => self.too_small,
            SkipReason::NoPoints => self.no_points,
            SkipReason::NoObjectPoints => self.no_object_points,
            SkipReason::UnknownFrame => self.unknown_frame,
            SkipReason::Unmatched => self.unmatched,
        }
    }

    fn slot(&mut self, reason: SkipReason) -> &mut usize {
        match reason {
            SkipReason::OutsideImage => &mut self.outside_image,
            SkipReason::TooSmall => &mut self.too_small,
            SkipReason::NoPoints => &mut self.no_points,
            SkipReason::NoObjectPoints => &mut self.no_object_points,
            SkipReason::UnknownFrame => &mut self.unknown_frame,
            SkipReason::Unmatched => &mut self.unmatched,
        }
    }

    pub fn merge(&mut self, other: &SkipCounts) {
        self.outside_image += other.outside_image;
        self.too_small += other.too_small;
        self.no_points += other.no_points;
        self.no_object_points += other.no_object_points;
        self.unknown_frame += other.unknown_frame;
        self.unmatched += other.unmatched;
    }

    pub fn total(&self) -> usize {
        self.outside_image
            + self.too_small
            + self.no_points
            + self.no_object_points
            + self.unknown_frame
            + self.unmatched
    }
}

impl std::fmt::Display for SkipCounts {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} skipped ({} outside image, {} too small, {} without points, {} without object points, {} unknown frame",
            self.total(),
            self.outside_image,
            self.too_small,
            self.no_points,
            self.no_object_points,
            self.unknown_frame
        )?;
        if self.unmatched > 0 {
            write!(f, ", {} unmatched proposals", self.unmatched)?;
        }
        f.write_str(")")
    }
}
