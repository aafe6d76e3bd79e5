//! A dense image of depths in metres (row-major, f32; 0 = no measurement).

#[derive(Debug, Clone, PartialEq)]
pub struct DepthMap {
    pub width: usize,
    pub height: usize,
    /// `height` rows of `width` depths.
    pub data: Vec<f32>,
}

impl DepthMap {
    /// An empty map (every pixel without measurement).
    pub fn empty(width: usize, height: usize) -> DepthMap {
        DepthMap {
            width,
            height,
            data: vec![0.0; width * height],
        }
    }

    pub fn get(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }

    pub fn set(&mut self, x: usize, y: usize, depth: f32) {
        self.data[y * self.width + x] = depth;
    }

    /// Pixels with a measurement.
    pub fn valid_count(&self) -> usize {
        self.data.iter().filter(|&&d| d > 0.0).count()
    }
}
