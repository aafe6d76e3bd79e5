//! Learning-rate schedules: step decay per epoch, as the frustum detectors were
//! published (F-ConvNet: ×0.1 at epoch 20 of 50; FCAM: every 22 epochs; SAF: every 10),
//! and the one-cycle policy per step that OpenPCDet trains Voxel R-CNN with.

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

/// One cycle (Smith; OpenPCDet's `adam_onecycle`): from `max_lr / div_factor` up to
/// `max_lr` over the first `pct_start` of all steps, then down to
/// `max_lr / div_factor / final_div_factor`, both along half a cosine.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OneCycle {
    pub max_lr: f64,
    pub div_factor: f64,
    pub pct_start: f64,
    #[serde(default = "default_final_div")]
    pub final_div_factor: f64,
}

fn default_final_div() -> f64 {
    1e4
}

impl OneCycle {
    /// OpenPCDet's Voxel R-CNN values: max 0.01, ÷10 at the start, 40% warm-up.
    pub fn voxel_rcnn() -> OneCycle {
        OneCycle {
            max_lr: 0.01,
            div_factor: 10.0,
            pct_start: 0.4,
            final_div_factor: 1e4,
        }
    }

    /// The rate of step `step` (0-based) of `total` steps.
    pub fn lr_at(&self, step: usize, total: usize) -> f64 {
        let low = self.max_lr / self.div_factor;
        let cos = |start: f64, end: f64, pct: f64| {
            end + (start - end) / 2.0 * ((std::f64::consts::PI * pct.clamp(0.0, 1.0)).cos() + 1.0)
        };
        let warm = (self.pct_start * total as f64).max(1.0);
        let t = step as f64;
        if t < warm {
            cos(low, self.max_lr, t / warm)
        } else {
            let rest = (total as f64 - warm).max(1.0);
            cos(self.max_lr, low / self.final_div_factor, (t - warm) / rest)
        }
    }

    pub fn validate(&self) -> Result<(), String> {
        // NaN fails every test; a rate above 10 would only diverge.
        let ok = self.max_lr > 0.0
            && self.max_lr <= 10.0
            && self.div_factor >= 1.0
            && self.div_factor <= 1e6
            && self.final_div_factor >= 1.0
            && self.final_div_factor <= 1e9
            && (0.0..1.0).contains(&self.pct_start);
        if ok {
            Ok(())
        } else {
            Err(format!(
                "train.one_cycle {self:?}: needs max_lr in (0, 10], div_factor in [1, 1e6], \
                 final_div_factor in [1, 1e9], pct_start in [0, 1)"
            ))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_cycle_rises_then_falls() {
        let s = OneCycle::voxel_rcnn();
        let total = 100;
        assert!((s.lr_at(0, total) - 1e-3).abs() < 1e-12);
        assert!((s.lr_at(40, total) - 1e-2).abs() < 1e-12);
        // Half-way up the cosine: the mean of the ends.
        assert!((s.lr_at(20, total) - 5.5e-3).abs() < 1e-12);
        assert!(s.lr_at(70, total) < 1e-2 && s.lr_at(70, total) > s.lr_at(90, total));
        assert!((s.lr_at(100, total) - 1e-7).abs() < 1e-15);
    }

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
