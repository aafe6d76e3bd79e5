//! Learning-rate schedule: step decay, as the frustum detectors were published
//! (F-ConvNet: ×0.1 at epoch 20 of 50; FCAM: every 22 epochs; SAF: every 10).

use serde::{Deserialize, Serialize};

/// Multiply the base rate by `factor` at each listed epoch (0-based epoch index at
/// which the new rate starts), or every `every` epochs if given.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StepDecay {
    pub base_lr: f64,
    pub factor: f64,
    #[serde(default)]
    pub milestones: Vec<usize>,
    #[serde(default)]
    pub every: Option<usize>,
}

impl StepDecay {
    /// The learning rate used throughout epoch `epoch` (0-based).
    pub fn lr_at(&self, epoch: usize) -> f64 {
        let decays = match self.every {
            Some(n) if n > 0 => epoch / n,
            _ => self.milestones.iter().filter(|&&m| epoch >= m).count(),
        };
        self.base_lr * self.factor.powi(decays as i32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn milestones_and_periodic_decay() {
        let s = StepDecay {
            base_lr: 1e-3,
            factor: 0.1,
            milestones: vec![20],
            every: None,
        };
        assert_eq!(s.lr_at(0), 1e-3);
        assert_eq!(s.lr_at(19), 1e-3);
        assert!((s.lr_at(20) - 1e-4).abs() < 1e-18);
        assert!((s.lr_at(49) - 1e-4).abs() < 1e-18);
        let p = StepDecay {
            base_lr: 1e-3,
            factor: 0.1,
            milestones: vec![],
            every: Some(10),
        };
        assert!((p.lr_at(25) - 1e-5).abs() < 1e-18);
    }
}
