//! How long a training run took, read from its own step log (which checkpoints keep, so a run
//! resumed across sittings is timed as one): the sum of the step times, the median step and its
//! stages, the same per quarter of the run (the step grows with the number of Gaussians), and
//! the densification calls.

use serde::Serialize;

use crate::method::train::{StageTimes, StepLog};
use crate::stats::percentile;

/// The training time of a run, in seconds.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TrainingTime {
    /// Steps logged.
    pub steps: usize,
    /// Σ of every step's stage times (s): the run's training time without start-up,
    /// checkpoints and the export. A step during which the process was stopped counts the
    /// pause.
    pub steps_s: f64,
    /// Median step (s) over the run and the median of each stage.
    pub median_step_s: f64,
    pub median_stages_s: StageTimes,
    /// The run in four consecutive quarters of its steps.
    pub quarters: Vec<TrainingPhase>,
    /// Densification calls, their median and largest time (s).
    pub densify_calls: usize,
    pub densify_median_s: f64,
    pub densify_max_s: f64,
}

/// A stretch of consecutive steps.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TrainingPhase {
    /// Iterations done after the stretch's first and last step.
    pub iterations: [usize; 2],
    /// Gaussians after its first and its last step.
    pub gaussians: [usize; 2],
    /// Median step (s).
    pub median_step_s: f64,
}

/// The median of `values` (0 for none).
fn median(values: &[f64]) -> f64 {
    if values.is_empty() { 0.0 } else { percentile(values, 50.0) }
}

impl TrainingTime {
    /// The time of the run whose step log is `history`; `None` when it has no steps.
    pub fn of(history: &[StepLog]) -> Option<Self> {
        if history.is_empty() {
            return None;
        }
        let step_s: Vec<f64> = history.iter().map(|s| s.times.total()).collect();
        let stage = |pick: fn(&StageTimes) -> f64| median(&history.iter().map(|s| pick(&s.times)).collect::<Vec<_>>());
        let quarters = (0..4)
            .filter_map(|q| {
                let range = q * history.len() / 4..(q + 1) * history.len() / 4;
                let (a, b) = (history[range.clone()].first()?, history[range.clone()].last()?);
                Some(TrainingPhase {
                    iterations: [a.iteration, b.iteration],
                    gaussians: [a.gaussians, b.gaussians],
                    median_step_s: median(&step_s[range]),
                })
            })
            .collect();
        let densify: Vec<f64> = history.iter().map(|s| s.times.densify).filter(|&t| t > 0.0).collect();
        Some(Self {
            steps: history.len(),
            steps_s: step_s.iter().sum(),
            median_step_s: median(&step_s),
            median_stages_s: StageTimes {
                field: stage(|t| t.field),
                render: stage(|t| t.render),
                losses: stage(|t| t.losses),
                backward: stage(|t| t.backward),
                optimizer: stage(|t| t.optimizer),
                densify: stage(|t| t.densify),
                wait: stage(|t| t.wait),
            },
            quarters,
            densify_calls: densify.len(),
            densify_median_s: median(&densify),
            densify_max_s: densify.iter().copied().fold(0.0, f64::max),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn step(iteration: usize, gaussians: usize, field: f64, densify: f64) -> StepLog {
        StepLog {
            iteration,
            gaussians,
            times: StageTimes { field, backward: 0.1, densify, ..StageTimes::default() },
            ..StepLog::default()
        }
    }

    #[test]
    fn sums_steps_and_takes_medians_per_quarter_and_of_densify_calls() {
        // 8 steps: the second half twice as slow (more Gaussians), two densify calls.
        let history: Vec<StepLog> = (1..=8)
            .map(|i| {
                let field = if i <= 4 { 0.1 } else { 0.3 };
                let densify = match i {
                    3 => 0.05,
                    6 => 0.07,
                    _ => 0.0,
                };
                step(i, if i <= 4 { 100 } else { 200 + i }, field, densify)
            })
            .collect();
        let t = TrainingTime::of(&history).unwrap();
        assert_eq!(t.steps, 8);
        assert!((t.steps_s - (4.0 * 0.2 + 4.0 * 0.4 + 0.12)).abs() < 1e-12);
        // Steps: 0.2, 0.2, 0.25, 0.2, 0.4, 0.47, 0.4, 0.4 → median of the middle two (0.25, 0.4).
        assert!((t.median_step_s - 0.325).abs() < 1e-12);
        assert!((t.median_stages_s.field - 0.2).abs() < 1e-12);
        assert_eq!(t.median_stages_s.densify, 0.0);
        assert_eq!(t.quarters.len(), 4);
        assert_eq!(t.quarters[0].iterations, [1, 2]);
        assert_eq!(t.quarters[3].gaussians, [207, 208]);
        assert!((t.quarters[1].median_step_s - 0.225).abs() < 1e-12);
        assert!((t.quarters[2].median_step_s - 0.435).abs() < 1e-12);
        assert_eq!(t.densify_calls, 2);
        assert!((t.densify_median_s - 0.06).abs() < 1e-12 && (t.densify_max_s - 0.07).abs() < 1e-12);
        assert_eq!(TrainingTime::of(&[]), None);
        // Fewer steps than quarters: only the non-empty quarters.
        assert_eq!(TrainingTime::of(&history[..2]).unwrap().quarters.len(), 2);
    }

    /// On a GPU the stages only queue work and the loss read every few steps waits for it: the
    /// wait is part of the run's time, and step logs written before it was recorded still load.
    #[test]
    fn the_wait_for_the_device_counts_and_old_step_logs_load_without_it() {
        let mut history: Vec<StepLog> = (1..=4).map(|i| step(i, 100, 0.01, 0.0)).collect();
        history[3].times.wait = 2.0;
        let t = TrainingTime::of(&history).unwrap();
        assert!((t.steps_s - (4.0 * 0.11 + 2.0)).abs() < 1e-12);
        assert_eq!(t.median_stages_s.wait, 0.0);
        let old = r#"{"iteration":3,"loss":0.5,"l1":0.1,"ssim":0.9,"fn_loss":0.0,"pa_loss":0.0,"gaussians":7,
            "times":{"field":0.1,"render":0.2,"losses":0.0,"backward":0.3,"optimizer":0.1,"densify":0.0}}"#;
        let log: StepLog = serde_json::from_str(old).unwrap();
        assert_eq!(log.times.wait, 0.0);
        assert!((log.times.total() - 0.7).abs() < 1e-12);
    }
}
