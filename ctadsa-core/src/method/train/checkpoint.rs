//! Checkpoints: save (atomically), list, and resume with the same case and settings.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use burn::module::{Module, Param};
use burn::optim::ModuleOptimizer;
use burn::tensor::{Device, Tensor, TensorData};
use serde::{Deserialize, Serialize};

use crate::config::Config;
use crate::data::case::{Case, FNV1A_START, fnv1a_file};
use crate::data::volume::BoxMm;
use crate::error::{CoreError, Result, read_file, to_json, write_file};
use crate::method::densify::DensifyStats;
use crate::method::model::{GaussianInit, GaussianModel, ScaleBounds};
use ctadsa_ops::optim::state_edit::edit_state;
use ctadsa_ops::readback::host_vec;

use super::{StepLog, Trainer, new_optimizers, prepare_views, run_working_box};

/// What a checkpoint stores besides the model and optimizer.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct CheckpointState {
    iteration: usize,
    gaussians: usize,
    n1: usize,
    n2: usize,
    history: Vec<StepLog>,
    /// The working box of the run (absent in checkpoints of older versions).
    #[serde(default)]
    working_box: Option<BoxMm>,
    /// The settings that shape the trajectory ([`training_settings`]); a resume with other
    /// settings is refused (absent in checkpoints of older versions).
    #[serde(default)]
    training_settings: Option<String>,
    /// The case the run belongs to ([`Case::fingerprint`]); a resume on another case is refused
    /// (absent in checkpoints of older versions).
    #[serde(default)]
    case: Option<String>,
    /// Length and FNV-1a of every other file of the checkpoint, checked before a resume reads
    /// them (absent in checkpoints of older versions).
    #[serde(default)]
    files: Option<BTreeMap<String, FileDigest>>,
}

/// A checkpoint file's length (bytes) and FNV-1a (16 hex digits).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct FileDigest {
    bytes: u64,
    fnv1a: String,
}

impl FileDigest {
    /// The digest of the file at `path`, read in blocks.
    fn of(path: &Path) -> Result<Self> {
        let (state, bytes) = fnv1a_file(FNV1A_START, path)?;
        Ok(Self { bytes, fnv1a: format!("{state:016x}") })
    }
}

/// The digests of the files `names` in checkpoint folder `dir`.
fn digests(dir: &Path, names: &[&str]) -> Result<BTreeMap<String, FileDigest>> {
    names.iter().map(|name| Ok((name.to_string(), FileDigest::of(&dir.join(name))?))).collect()
}

/// Refuses a checkpoint whose files are not what `state.json` says was written (damaged,
/// truncated or replaced), naming the first such file.
fn verify_files(dir: &Path, recorded: &BTreeMap<String, FileDigest>) -> Result<()> {
    for (name, expected) in recorded {
        let path = dir.join(name);
        if name.contains(['/', '\\']) || name.starts_with('.') {
            return Err(CoreError::format(
                &dir.join("state.json"),
                format!("lists a file outside the checkpoint: `{name}`"),
            ));
        }
        let found = FileDigest::of(&path)?;
        if found != *expected {
            return Err(CoreError::format(
                &path,
                format!(
                    "damaged: {} bytes with FNV-1a {}, where state.json records {} bytes with {}",
                    found.bytes, found.fnv1a, expected.bytes, expected.fnv1a
                ),
            ));
        }
    }
    Ok(())
}

/// The configuration less what may change on resume (`[output]`, `run.iterations`,
/// `run.checkpoint_every`, `run.prior_only_member`, `run.member_seeds`,
/// `run.member_tracks_max_views`, `run.member_reseeds`, `run.member_iterations`), as TOML.
fn training_settings(cfg: &Config) -> String {
    let mut c = cfg.clone();
    c.output = Default::default();
    c.run.iterations = 0;
    c.run.checkpoint_every = 0;
    // The member is a second model beside this one; it changes nothing of this one's training.
    c.run.prior_only_member = false;
    c.run.member_seeds.clear();
    c.run.member_tracks_max_views = 0;
    c.run.member_reseeds = false;
    c.run.member_iterations = 0;
    c.to_toml()
}

/// `section.key` → value of every setting in a TOML document.
fn flat_settings(text: &str) -> std::collections::BTreeMap<String, String> {
    fn flatten(prefix: &str, v: &toml::Value, out: &mut std::collections::BTreeMap<String, String>) {
        match v {
            toml::Value::Table(t) => {
                for (k, v) in t {
                    let key = if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") };
                    flatten(&key, v, out);
                }
            }
            other => {
                out.insert(prefix.to_string(), other.to_string());
            }
        }
    }
    let mut out = std::collections::BTreeMap::new();
    if let Ok(v) = toml::from_str::<toml::Table>(text) {
        flatten("", &toml::Value::Table(v), &mut out);
    }
    out
}

/// The training settings (`section.key`) in which a checkpoint's `saved` settings and the
/// `current` ones differ. `[output]` never counts, nor the tracker's settings (`init.track_*`,
/// `init.arrival_track_*`) of a model that tracks on neither side; a key that only one side has (a setting added or
/// removed between versions) counts only when its value is not the default.
fn settings_differences(saved: &str, current: &str) -> Vec<String> {
    let (a, b) = (flat_settings(saved), flat_settings(current));
    let defaults = flat_settings(&training_settings(&Config::default()));
    let value = |side: &std::collections::BTreeMap<String, String>, k: &str| side.get(k).or(defaults.get(k)).cloned();
    const TRACKING: &str = "init.track_max_views";
    let untracked = value(&a, TRACKING).as_deref() == Some("0") && value(&b, TRACKING).as_deref() == Some("0");
    let keys: std::collections::BTreeSet<&String> = a.keys().chain(b.keys()).collect();
    keys.into_iter()
        .filter(|k| !k.starts_with("output."))
        .filter(|k| !(untracked && (k.starts_with("init.track_") || k.starts_with("init.arrival_track_"))))
        .filter(|k| value(&a, k) != value(&b, k))
        .cloned()
        .collect()
}

/// Loads a checkpoint's model into `skeleton`. A checkpoint of a version whose hash table padded
/// every level to `T` rows (`[F, levels · T]`) is loaded as such and compacted to `[F, R]`; the
/// table parameter's id is then returned, so that its Adam moments can be compacted too.
fn load_model(skeleton: GaussianModel, path: &Path) -> Result<(GaussianModel, Option<u64>)> {
    let error = |e: &dyn std::fmt::Debug| CoreError::format(path, format!("cannot load model (same config?): {e:?}"));
    let first = match skeleton.clone().try_load_file(path) {
        Ok(model) => return Ok((model, None)),
        Err(e) => e,
    };
    let c = skeleton.field.grid.config;
    let mut padded = skeleton;
    let table = &padded.field.grid.tables;
    let zeros = Tensor::<2>::zeros([c.features, c.padded_rows()], &table.val().device());
    padded.field.grid.tables = Param::initialized(table.id, zeros);
    let Ok(mut model) = padded.try_load_file(path) else { return Err(error(&first)) };
    let table = &model.field.grid.tables;
    let device = table.val().device();
    let compact = c.compact_table(&host_vec(table.val()));
    let compact = Tensor::<2>::from_data(TensorData::new(compact, [c.features, c.rows()]), &device);
    let id = table.id;
    model.field.grid.tables = Param::initialized(id, compact.require_grad());
    Ok((model, Some(id.val())))
}

impl Trainer {
    /// Writes a checkpoint folder (model, optimizer, state); returns its path.
    /// The folder is written under a temporary name and renamed when complete, so a kill while
    /// saving leaves the previous checkpoints as they were.
    pub fn save_checkpoint(&mut self, dir: &Path) -> Result<PathBuf> {
        self.flush_logs()?;
        self.sync_stats();
        let done = dir.join(format!("ckpt-{:07}", self.iteration));
        let ck = dir.join(format!(".ckpt-{:07}.partial-{}", self.iteration, std::process::id()));
        if ck.exists() {
            std::fs::remove_dir_all(&ck).map_err(|e| CoreError::io(&ck, e))?;
        }
        std::fs::create_dir_all(&ck).map_err(|e| CoreError::io(&ck, e))?;
        self.model()
            .clone()
            .save_file(ck.join("model.bpk"))
            .map_err(|e| CoreError::format(&ck.join("model.bpk"), format!("cannot save model: {e:?}")))?;
        for (optim, name) in [(&self.optim, "optim.bpk"), (&self.field_optim, "optim-field.bpk")] {
            optim
                .save(ck.join(name))
                .map_err(|e| CoreError::format(&ck.join(name), format!("cannot save optimizer: {e:?}")))?;
        }
        if let Some((poses, optim)) = &self.poses {
            let (mp, op) = (ck.join("poses.bpk"), ck.join("poses-optim.bpk"));
            poses.clone().save_file(&mp).map_err(|e| CoreError::format(&mp, format!("cannot save poses: {e:?}")))?;
            optim.save(&op).map_err(|e| CoreError::format(&op, format!("cannot save pose optimizer: {e:?}")))?;
        }
        let stats: Vec<u8> = self.stats.sum.iter().chain(&self.stats.count).flat_map(|v| v.to_le_bytes()).collect();
        write_file(&ck.join("stats.bin"), &stats)?;
        let mut names = vec!["model.bpk", "optim.bpk", "optim-field.bpk", "stats.bin"];
        if self.poses.is_some() {
            names.extend(["poses.bpk", "poses-optim.bpk"]);
        }
        let state = CheckpointState {
            iteration: self.iteration,
            gaussians: self.model().len(),
            n1: self.n1,
            n2: self.n2,
            history: self.history.clone(),
            working_box: Some(self.working_box),
            training_settings: Some(training_settings(&self.cfg)),
            case: Some(self.case_fingerprint.clone()),
            files: Some(digests(&ck, &names)?),
        };
        let state_path = ck.join("state.json");
        write_file(&state_path, to_json(&state, &state_path)?.as_bytes())?;
        // A checkpoint of this iteration already there (a re-export saves the last one again)
        // moves aside before the new one moves in, and is deleted only after: at every moment a
        // complete checkpoint is listed by `checkpoints` (the moved one as a fallback).
        let old = dir.join(format!(".ckpt-{:07}.old-{}", self.iteration, std::process::id()));
        if done.exists() {
            std::fs::rename(&done, &old).map_err(|e| CoreError::io(&done, e))?;
        }
        std::fs::rename(&ck, &done).map_err(|e| CoreError::io(&done, e))?;
        // Folders a killed process left half-written are never read, and replaced ones are done
        // with; remove them.
        for stale in std::fs::read_dir(dir).map_err(|e| CoreError::io(dir, e))?.flatten() {
            let name = stale.file_name();
            let Some(name) = name.to_str() else { continue };
            let replaced = name.starts_with(".ckpt-") && name.contains(".old-");
            if (name.starts_with(".ckpt-") && name.contains(".partial-")) || replaced {
                let _ = std::fs::remove_dir_all(stale.path());
            }
        }
        Ok(done)
    }

    /// Restores a run from a checkpoint folder written by [`Trainer::save_checkpoint`], with the
    /// same case and configuration.
    pub fn resume(case: &Case, cfg: Config, device: Device, checkpoint: &Path) -> Result<Self> {
        cfg.validate()?;
        let state_path = checkpoint.join("state.json");
        let state: CheckpointState = serde_json::from_slice(&read_file(&state_path)?)
            .map_err(|e| CoreError::format(&state_path, format!("invalid checkpoint state: {e}")))?;
        // state.json carries no digest of its own: its counts must agree with each other.
        if let Some(last) = state.history.last()
            && last.iteration != state.iteration
        {
            return Err(CoreError::format(
                &state_path,
                format!("`iteration` = {} but the loss history ends at step {}", state.iteration, last.iteration),
            ));
        }
        if let Some((name, n)) =
            [("n1", state.n1), ("n2", state.n2)].into_iter().find(|&(_, n)| n > crate::config::MAX_GAUSSIANS)
        {
            return Err(CoreError::format(
                &state_path,
                format!("`{name}` = {n} is past the {} Gaussians a run may have", crate::config::MAX_GAUSSIANS),
            ));
        }
        if let Some(saved) = &state.training_settings {
            let differ = settings_differences(saved, &training_settings(&cfg));
            if !differ.is_empty() {
                return Err(CoreError::format(
                    &state_path,
                    format!(
                        "this checkpoint belongs to a run with other settings ({}); resume with the run's \
                         config.toml, or start a new run",
                        differ.join(", ")
                    ),
                ));
            }
        }
        let fingerprint = case.fingerprint();
        if let Some(saved) = state.case.as_ref().filter(|saved| **saved != fingerprint) {
            return Err(CoreError::format(
                &state_path,
                format!(
                    "this checkpoint belongs to another case (`{saved}`, this one is `{fingerprint}`: name and a \
                     hash of case.json); resume with the run's case, or start a new run"
                ),
            ));
        }
        if let Some(files) = &state.files {
            verify_files(checkpoint, files)?;
        }
        let (views, images) = prepare_views(case, &cfg)?;
        let prior = case.prior_mesh()?;
        let working_box = match state.working_box {
            Some(b) => b,
            None => run_working_box(case, &cfg, &views, &images, prior.as_ref())?,
        };
        let voxel_mm = case.file.volume.voxel_mm;
        let bounds = ScaleBounds::from_voxel(voxel_mm, cfg.model.scale_min_voxels, cfg.model.scale_max_voxels);
        let n = state.gaussians;
        let model_path = checkpoint.join("model.bpk");
        let model_bytes = std::fs::metadata(&model_path).map_err(|e| CoreError::io(&model_path, e))?.len();
        // Ten f32 per Gaussian (mean, raw scale, rotation) must be in the model file.
        if n == 0 || n > crate::config::MAX_GAUSSIANS || model_bytes < 40 * n as u64 {
            return Err(CoreError::format(
                &state_path,
                format!("`gaussians` = {n} does not fit the checkpoint's model.bpk ({model_bytes} bytes)"),
            ));
        }
        let skeleton_init =
            GaussianInit { means: vec![0.0; 3 * n], raw_scales: vec![0.0; 3 * n], rotations: vec![0.0; 4 * n] };
        let size = working_box.size_mm();
        let field = GaussianModel::new_field(
            &cfg.field,
            working_box.min_mm.map(|v| v as f32),
            size.map(|v| v as f32),
            1.0,
            cfg.run.seed ^ 0xF1E1D,
            &device,
        );
        let skeleton = GaussianModel::new(&skeleton_init, field, bounds, &device);
        let (model, padded_table) = load_model(skeleton, &model_path)?;
        let mut t = Self::assemble(
            cfg,
            device,
            views,
            images,
            prior.as_ref(),
            model,
            working_box,
            voxel_mm,
            state.n1,
            state.n2,
        )?;
        // Checkpoints of versions with one optimizer hold both states in optim.bpk.
        let optim_path = checkpoint.join("optim.bpk");
        let field_path = Some(checkpoint.join("optim-field.bpk")).filter(|p| p.exists()).unwrap_or(optim_path.clone());
        let (gaussian_optim, field_optim) = new_optimizers(&t.cfg);
        let load = |optim: ModuleOptimizer, path: &Path| {
            optim.load(path).map_err(|e| CoreError::format(path, format!("cannot load optimizer state: {e:?}")))
        };
        t.optim = load(gaussian_optim, &optim_path)?;
        t.field_optim = load(field_optim, &field_path)?;
        if let Some(id) = padded_table {
            let c = t.cfg.field.encoding;
            let padded = [c.features, c.padded_rows()];
            t.field_optim = edit_state(t.field_optim, |s| {
                (s.param_id == id && s.shape == padded)
                    .then(|| (c.compact_table(&s.values), vec![c.features, c.rows()]))
            })
            .map_err(|e| CoreError::format(&field_path, e.to_string()))?;
        }
        if let Some((poses, optim)) = t.poses.take() {
            let (mp, op) = (checkpoint.join("poses.bpk"), checkpoint.join("poses-optim.bpk"));
            let poses = poses
                .try_load_file(&mp)
                .map_err(|e| CoreError::format(&mp, format!("cannot load view poses (was [pose] enabled?): {e:?}")))?;
            let optim =
                optim.load(&op).map_err(|e| CoreError::format(&op, format!("cannot load pose optimizer: {e:?}")))?;
            t.poses = Some((poses, optim));
        }
        let stats = read_file(&checkpoint.join("stats.bin"))?;
        if stats.len() != 8 * n {
            return Err(CoreError::format(
                &checkpoint.join("stats.bin"),
                format!("{} bytes, where {n} Gaussians' densification statistics take {}", stats.len(), 8 * n),
            ));
        }
        let vals: Vec<f32> = stats.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
        t.stats = DensifyStats { sum: vals[..n].to_vec(), count: vals[n..].to_vec() };
        t.case_fingerprint = fingerprint;
        if t.cfg.init.checks_arrival() {
            t.arrival = crate::method::arrival::seed_arrival_maps(case, &t.cfg)?;
        }
        t.iteration = state.iteration;
        t.history = state.history;
        t.announced = t.history.len();
        Ok(t)
    }

    /// The complete checkpoint folders under `dir` (`ckpt-` + iteration), newest first.
    /// A checkpoint being replaced (`.ckpt-N.old-PID`, see [`Trainer::save_checkpoint`]) comes
    /// after the complete one of its iteration, so that a kill between the two renames still
    /// leaves one to resume from.
    pub fn checkpoints(dir: &Path) -> Vec<PathBuf> {
        let Ok(entries) = std::fs::read_dir(dir) else { return Vec::new() };
        let mut cks: Vec<(usize, bool, PathBuf)> = entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter_map(|p| {
                let name = p.file_name()?.to_str()?;
                let (n, current) = match name.strip_prefix("ckpt-") {
                    Some(n) => (n.parse().ok()?, true),
                    None => (name.strip_prefix(".ckpt-")?.split_once(".old-")?.0.parse().ok()?, false),
                };
                p.join("state.json").exists().then_some((n, current, p))
            })
            .collect();
        cks.sort();
        cks.into_iter().rev().map(|(_, _, p)| p).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_differences_name_changed_keys_and_ignore_output_and_new_defaults() {
        let base = Config::default();
        let saved = training_settings(&base);
        assert!(settings_differences(&saved, &saved).is_empty());
        let mut other = base.clone();
        other.init.n1 += 1;
        other.loss.pa_weight *= 2.0;
        other.output.mc_level = 0.5;
        other.run.iterations += 10;
        other.run.prior_only_member = !base.run.prior_only_member;
        assert_eq!(settings_differences(&saved, &training_settings(&other)), vec!["init.n1", "loss.pa_weight"]);
        // A checkpoint of a version without a setting that now exists: equal while the setting
        // keeps its default, different once it does not.
        let without = saved.replace("knn = 3\n", "");
        assert_ne!(without, saved, "the test removes a key");
        assert!(settings_differences(&without, &saved).is_empty());
        let mut knn = base.clone();
        knn.init.knn = 5;
        assert_eq!(settings_differences(&without, &training_settings(&knn)), vec!["init.knn"]);
        // Old checkpoints stored [output]; it never counts.
        assert!(settings_differences(&(saved.clone() + "\n[output]\nmc_level = 0.9\n"), &saved).is_empty());
    }

    #[test]
    fn the_trackers_settings_count_only_for_a_model_that_tracks() {
        let base = Config::default();
        assert_eq!(base.init.track_max_views, 0, "the default model does not track");
        let mut rounds = base.clone();
        rounds.init.track_rounds = 2;
        rounds.init.arrival_track_claims = true;
        let saved = training_settings(&base);
        assert!(settings_differences(&saved, &training_settings(&rounds)).is_empty());
        let (mut tracked, mut tracked_rounds) = (base.clone(), rounds.clone());
        tracked.init.track_max_views = 2;
        tracked_rounds.init.track_max_views = 2;
        let differ = settings_differences(&training_settings(&tracked), &training_settings(&tracked_rounds));
        assert_eq!(differ, vec!["init.arrival_track_claims", "init.track_rounds"]);
        assert_eq!(settings_differences(&saved, &training_settings(&tracked)), vec!["init.track_max_views"]);
    }

    #[test]
    fn checkpoints_are_listed_newest_first_and_incomplete_ones_are_skipped() {
        let temp = tempfile::tempdir().unwrap();
        let dir = temp.path().to_path_buf();
        for (name, complete) in [
            ("ckpt-0000100", true),
            ("ckpt-0000020", true),
            ("ckpt-0000300", false),
            (".ckpt-0000400.partial-9", true),
            (".ckpt-0000100.old-9", true),
            (".ckpt-0000500.old-9", true),
        ] {
            std::fs::create_dir_all(dir.join(name)).unwrap();
            if complete {
                std::fs::write(dir.join(name).join("state.json"), "{}").unwrap();
            }
        }
        let names: Vec<String> =
            Trainer::checkpoints(&dir).iter().map(|p| p.file_name().unwrap().to_string_lossy().into()).collect();
        // A replaced checkpoint (moved aside while its successor moves in) is a fallback after
        // the current one of its iteration.
        assert_eq!(names, [".ckpt-0000500.old-9", "ckpt-0000100", ".ckpt-0000100.old-9", "ckpt-0000020"]);
        assert!(Trainer::checkpoints(&dir.join("absent")).is_empty());
    }
}
