//! Ablation tables over several training seeds: each configuration's AP as the mean over
//! its seeds with the seeds' range, and under every configuration after the first (the
//! baseline) its difference from the baseline, marked † where the two configurations'
//! seed ranges do not overlap — the difference is larger than what reseeding alone moved.
//! The layouts follow DASANet's Tables 4 (3D and BEV AP, easy / moderate / hard) and 6–8
//! (by distance, occlusion and LiDAR points).

use crate::ablation::{AblationRow, bin_header, find_bin, markdown_table};
use crate::breakdown::BreakdownAxis;
use crate::protocol::{Difficulty, Metric};
use fusiondet_kitti::ObjectClass;
use std::fmt::Write as _;

/// The runs of one configuration, one per seed (all evaluated on the same frames).
#[derive(Debug, Clone)]
pub struct SeedGroup {
    pub name: String,
    pub runs: Vec<AblationRow>,
}

/// One cell over seeds.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Spread {
    mean: f64,
    min: f64,
    max: f64,
}

impl Spread {
    fn of(values: &[f64]) -> Option<Spread> {
        if values.is_empty() {
            return None;
        }
        Some(Spread {
            mean: values.iter().sum::<f64>() / values.len() as f64,
            min: values.iter().copied().fold(f64::INFINITY, f64::min),
            max: values.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        })
    }

    /// Whether the seed ranges of two configurations are disjoint.
    fn separated(&self, other: &Spread) -> bool {
        self.max < other.min || other.max < self.min
    }
}

/// A table of `columns` values per run (`value(run, column)`; `None`: no value), one
/// row per configuration with mean and range, one difference row per non-baseline one.
fn seed_table(
    groups: &[SeedGroup],
    header: Vec<String>,
    columns: usize,
    value: impl Fn(&AblationRow, usize) -> Option<f64>,
) -> String {
    let spreads: Vec<Vec<Option<Spread>>> = groups
        .iter()
        .map(|g| {
            (0..columns)
                .map(|c| {
                    let v: Vec<f64> = g.runs.iter().filter_map(|r| value(r, c)).collect();
                    // A cell counts only when every seed has it.
                    (v.len() == g.runs.len()).then(|| Spread::of(&v)).flatten()
                })
                .collect()
        })
        .collect();
    let mut body = Vec::new();
    for (k, (g, cells)) in groups.iter().zip(&spreads).enumerate() {
        let mut row = vec![format!("{} ({} seeds)", g.name, g.runs.len())];
        row.extend(cells.iter().map(|c| match c {
            Some(s) => format!("{:.2} [{:.2}–{:.2}]", s.mean, s.min, s.max),
            None => "-".to_string(),
        }));
        body.push(row);
        if k == 0 {
            continue;
        }
        let mut diff = vec![format!("*vs {}*", groups[0].name)];
        diff.extend(cells.iter().zip(&spreads[0]).map(|(c, b)| match (c, b) {
            (Some(c), Some(b)) => format!(
                "{:+.2}{}",
                c.mean - b.mean,
                if c.separated(b) { " †" } else { "" }
            ),
            _ => "-".to_string(),
        }));
        body.push(diff);
    }
    markdown_table(&header, &body)
}

/// Table 4's layout over seeds: AP_R40 3D and BEV, easy / moderate / hard, under overlap
/// setting `setting`.
pub fn seed_ablation_table(groups: &[SeedGroup], class: ObjectClass, setting: usize) -> String {
    let mut header = vec!["Configuration".to_string()];
    for m in ["3D", "BEV"] {
        for d in ["Easy", "Mod.", "Hard"] {
            header.push(format!("{m} {d}"));
        }
    }
    let mut out = format!(
        "{class}, AP_R40 in %: mean over seeds [lowest–highest]; † where the seed ranges of the \
         configuration and the baseline do not overlap\n\n"
    );
    out += &seed_table(groups, header, 6, |r, c| {
        let metric = if c < 3 { Metric::ThreeD } else { Metric::Bev };
        r.report
            .get(class, metric, setting)
            .map(|res| res.ap40[c % 3])
    });
    out
}

/// Tables 6–8's layout over seeds: AP_R40 by distance, occlusion and LiDAR points at
/// `difficulty`, for `metric`.
pub fn seed_breakdown_table(
    groups: &[SeedGroup],
    class: ObjectClass,
    setting: usize,
    metric: Metric,
    difficulty: Difficulty,
) -> String {
    let bins: Vec<(BreakdownAxis, &'static str)> = BreakdownAxis::ALL
        .into_iter()
        .flat_map(|a| a.bins().map(|b| (a, b)))
        .collect();
    let mut header = vec!["Configuration".to_string()];
    header.extend(bins.iter().map(|&(a, b)| bin_header(a, b)));
    let d = difficulty.index();
    let label = if metric == Metric::ThreeD {
        "3D"
    } else {
        "BEV"
    };
    let mut out = format!(
        "{class}, {label} AP_R40 in % by distance, occlusion and LiDAR points ({}): mean over \
         seeds [lowest–highest], † as above\n\n",
        difficulty.as_str()
    );
    out += &seed_table(groups, header, bins.len(), |r, c| {
        let (axis, bin) = bins[c];
        find_bin(r.breakdown.as_deref()?, class, metric, setting, axis, bin)?.ap40[d]
    });
    let _ = writeln!(out);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::OverlapSetting;
    use crate::report::{EvalReport, MetricResult};

    /// A Car report whose 3D and BEV AP_R40 are `v` at every difficulty.
    fn row(name: &str, v: f64) -> AblationRow {
        let results = [Metric::ThreeD, Metric::Bev]
            .into_iter()
            .map(|metric| MetricResult {
                class: ObjectClass::Car,
                metric,
                setting: 0,
                min_overlap: 0.7,
                ap11: [v; 3],
                ap40: [v; 3],
                curves: Default::default(),
            })
            .collect();
        let report = EvalReport {
            frames: 10,
            classes: vec![ObjectClass::Car],
            settings: vec![OverlapSetting::STRICT],
            aos_computed: true,
            results,
        };
        AblationRow::new(name, report)
    }

    #[test]
    fn means_ranges_and_separated_differences() {
        let groups = vec![
            SeedGroup {
                name: "base".into(),
                runs: vec![row("b1", 80.0), row("b2", 82.0)],
            },
            SeedGroup {
                name: "close".into(),
                runs: vec![row("c1", 81.0), row("c2", 83.0)],
            },
            SeedGroup {
                name: "far".into(),
                runs: vec![row("f1", 85.0), row("f2", 86.0)],
            },
        ];
        let t = seed_ablation_table(&groups, ObjectClass::Car, 0);
        assert!(
            t.contains("base (2 seeds)") && t.contains("81.00 [80.00–82.00]"),
            "{t}"
        );
        // close: +1.00, ranges overlap; far: +4.50, ranges apart.
        let line = |name: &str| {
            t.lines()
                .skip_while(|l| !l.contains(name))
                .nth(1)
                .unwrap()
                .to_string()
        };
        assert!(
            line("close (2 seeds)").contains("+1.00") && !line("close (2 seeds)").contains('†'),
            "{t}"
        );
        assert!(line("far (2 seeds)").contains("+4.50 †"), "{t}");
    }
}
