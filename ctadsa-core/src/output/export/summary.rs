//! The numbers of a finished run (`summary.json`).

use serde::Serialize;

use crate::data::projector::correction::PoseError;
use crate::data::vessel_evidence::ViewReading;
use crate::eval::metrics::RegionScores;
use crate::eval::surface_metrics::Coverage;
use crate::eval::topology::TopologyScores;
use crate::method::arrival::ArrivalReading;
use crate::method::field_health::DensitySpread;
use crate::method::train::Trainer;
use crate::method::training_time::TrainingTime;
use crate::output::centreline::CentrelineSummary;
use crate::output::extraction::LevelScore;

/// Numbers of a finished run.
#[derive(Debug, Clone, Serialize)]
pub struct RunSummary {
    /// The case folder the run used (as given).
    pub case_dir: String,
    /// The case's [`Case::fingerprint`](crate::data::case::Case::fingerprint) (name and a hash
    /// of its `case.json`).
    pub case_fingerprint: String,
    pub iterations: usize,
    pub gaussians: usize,
    pub n1: usize,
    pub n2: usize,
    /// Iso-level of the extracted surface (density units) and the triangle count.
    pub mc_level: f64,
    /// With `output.level_from_views`: every candidate level and its silhouette Dice.
    pub level_scores: Vec<LevelScore>,
    /// With `output.faint_mask_threshold`: the lower level the faint vessels may go down to
    /// (density units).
    pub faint_level: Option<f64>,
    pub mesh_triangles: usize,
    /// Connected components dropped as floaters (`output.min_island_mm2`) or as not linked
    /// to the prior (`output.connected_level_fraction`).
    pub islands_dropped: usize,
    pub final_loss: f64,
    /// The field's densities at the Gaussians' centres; a constant field has collapsed
    /// ([`crate::method::field_health`]).
    pub field_densities: Option<DensitySpread>,
    pub field_constant: bool,
    /// The training time from the run's step log (across resumes; [`TrainingTime`]).
    pub training_time: Option<TrainingTime>,
    /// The prior-only member whose density was averaged in (`run.prior_only_member`).
    pub prior_only_member: Option<MemberSummary>,
    /// The further image-seeded members averaged in (`run.member_seeds`), in that order.
    pub seed_members: Vec<MemberSummary>,
    /// An ensemble's runs (`ctadsa ensemble`), their folders in order (the first gives the
    /// configuration, the Gaussians and the renders, and the numbers above and its members'
    /// below are its own); empty (and left out of `summary.json`) for a run alone.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub ensemble_runs: Vec<String>,
    /// Scores of the completed surface (exact distances, `docs/METRICS.md`) when the case has
    /// ground truth.
    pub metrics: Option<RegionScores>,
    /// Missing-vessel recall and false surface of the completed surface.
    pub coverage: Option<Coverage>,
    /// The completed surface in the paper's convention (vertex point sets).
    pub paper_metrics: Option<RegionScores>,
    /// The same scores for the prior alone (what the run started from), for comparison.
    pub prior_metrics: Option<RegionScores>,
    pub prior_coverage: Option<Coverage>,
    /// The completed centreline (`centreline.swc` / `.vtp`) and its scores against the true tree.
    pub centreline: CentrelineSummary,
    /// clDice and the Betti-0 error of the completed volume against the true one
    /// ([`crate::eval::topology`]), when the case has a true tree.
    pub topology: Option<TopologyScores>,
    /// With pose refinement on a case whose true view corrections are known: how far each
    /// refined view is from the truth.
    pub pose_errors: Option<Vec<PoseError>>,
    /// When the case has arrival maps: how noisy each of the run's views' map is and the median
    /// it was read through (`run.arrival_median_px`, `run.arrival_noisy_share`).
    pub arrival_readings: Option<Vec<ArrivalReading>>,
    /// How each of the run's views was read for its vessels: its noise, its bright value and
    /// whether its pixels under 3 σ were read along lines ([`crate::data::vessel_evidence`]).
    pub view_readings: Vec<ViewReading>,
}

/// A member of a run (`run.prior_only_member`, `run.member_seeds`).
#[derive(Debug, Clone, Serialize)]
pub struct MemberSummary {
    /// Its `run.seed`.
    pub seed: u64,
    pub gaussians: usize,
    pub final_loss: f64,
    /// Its training time (the run's own is [`RunSummary::training_time`]).
    pub training_time: Option<TrainingTime>,
}

impl MemberSummary {
    pub(super) fn of(member: &Trainer) -> Self {
        Self {
            seed: member.cfg().run.seed,
            gaussians: member.model().len(),
            final_loss: member.history().last().map_or(f64::NAN, |s| s.loss),
            training_time: TrainingTime::of(member.history()),
        }
    }
}
