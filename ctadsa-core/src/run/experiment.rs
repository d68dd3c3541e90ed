//! An experiment matrix: (case × prior × view subset × method) completion runs, each in its own
//! cell folder, and after them the matrix's ensembles (the mean of some methods' runs of the same
//! case, prior and views, [`crate::run::ensemble`]), a cell each. A cell is finished when its
//! `cell.json` exists; running one cell writes only inside its folder, so the run cells can run in
//! any order, in parallel or as the tasks of a SLURM job array, the ensemble cells once their
//! members have finished, and [`Experiment::collect`] gathers whatever is finished into
//! `results.csv`, a Markdown table in the paper's layout (mean ± std over cases) and Fig. 3-style
//! plots.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::time::Instant;

use burn::tensor::Device;
use serde::Deserialize;

use crate::config::Config;
use crate::data::case::{
    CASE_FILE, Case, CaseFile, FNV1A_START, MAX_VIEWS, PriorEntry, fnv1a, fnv1a_file, refuse_folder_of_cases, text_hash,
};
use crate::error::{CoreError, Result, check_file_name, read_file, to_json, write_file};
use crate::eval::metrics::SurfaceScores;
use crate::output::export::RunSummary;
use crate::output::plot::{PALETTE, Series, line_plot};
use crate::run::completion::{Monitor, Outcome, Start, run_completion};
use crate::run::ensemble::{MAX_ENSEMBLE_RUNS, run_ensemble};
use crate::run::lock::FolderLock;
pub use crate::run::results::CellResult;
use crate::run::results::{configurations_table, mean_std, priors_of, results_csv, results_table};

/// One method (row of the paper's tables): a config file and overrides.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Method {
    pub name: String,
    /// Config path, relative to the matrix file.
    pub config: PathBuf,
    #[serde(default)]
    pub set: Vec<String>,
}

/// An ensemble of the matrix's methods: for each case, prior and view subset, the mean of those
/// methods' finished runs (`ctadsa ensemble` on their cells), scored as a method of its own.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EnsembleOf {
    /// The ensemble's name: its cells' folder and its row in the tables.
    pub name: String,
    /// The methods averaged (2 to [`MAX_ENSEMBLE_RUNS`], each once); the first gives the
    /// configuration, Gaussians and renders written.
    pub methods: Vec<String>,
}

/// The matrix file (`configs/experiments/*.toml`).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Matrix {
    /// View subsets (indices into the case's views).
    pub views: Vec<Vec<usize>>,
    /// Prior folders under each case's `priors/` (empty: the case's own prior).
    #[serde(default)]
    pub priors: Vec<String>,
    /// Overrides for every cell.
    #[serde(default)]
    pub set: Vec<String>,
    pub methods: Vec<Method>,
    /// Ensembles of the methods, each one more cell per case, prior and view subset.
    #[serde(default)]
    pub ensembles: Vec<EnsembleOf>,
}

/// The view counts of a matrix, in its order, each once.
fn view_counts(matrix: &Matrix) -> Vec<usize> {
    let mut v: Vec<usize> = matrix.views.iter().map(Vec::len).collect();
    v.dedup();
    v
}

/// The names of a matrix's methods, then of its ensembles, in its order: its tables' rows.
fn method_names(matrix: &Matrix) -> Vec<String> {
    matrix.methods.iter().map(|m| m.name.clone()).chain(matrix.ensembles.iter().map(|e| e.name.clone())).collect()
}

/// What a cell does.
#[derive(Debug, Clone)]
pub enum CellWork {
    /// A completion run of one method.
    Run(Method),
    /// The mean of the finished runs of other cells: those of the same case, prior and views,
    /// one per method of the ensemble, by index in [`Experiment::cells`].
    Ensemble { name: String, members: Vec<usize> },
}

impl CellWork {
    /// The method's or the ensemble's name (the cell folder's last part, the table's row).
    pub fn name(&self) -> &str {
        match self {
            Self::Run(method) => &method.name,
            Self::Ensemble { name, .. } => name,
        }
    }
}

/// One run of the matrix.
#[derive(Debug, Clone)]
pub struct Cell {
    pub case_dir: PathBuf,
    pub case_name: String,
    pub work: CellWork,
    pub views: Vec<usize>,
    pub prior: Option<String>,
    /// `<out>/cells/<case>/<prior>/views-<list>/<method or ensemble>`.
    pub dir: PathBuf,
    /// A hash of the cell's whole configuration (method config, the matrix's and the caller's
    /// overrides, its views, as TOML; an ensemble's: its members' hashes, in order).
    pub config_hash: String,
    /// The case's [`CaseFile::fingerprint`] when the matrix was read (`None`: the case could
    /// not be read then; its cell says why when it runs).
    pub case_fingerprint: Option<String>,
    /// The digest of the files the cell reads from its case ([`case_files_digest`]) when the
    /// matrix was read (`None`: the case could not be read then).
    pub case_files: Option<String>,
}

impl Cell {
    /// One line naming the cell.
    pub fn label(&self) -> String {
        format!(
            "{} / {} / views {:?} / {}",
            self.case_name,
            self.prior.as_deref().unwrap_or("case prior"),
            self.views,
            match &self.work {
                CellWork::Run(method) => method.name.clone(),
                CellWork::Ensemble { name, .. } => format!("ensemble {name}"),
            }
        )
    }

    /// Whether the cell averages other cells' runs.
    pub fn is_ensemble(&self) -> bool {
        matches!(self.work, CellWork::Ensemble { .. })
    }

    /// The cell's result when it has finished with its present configuration on its present
    /// case (a readable `cell.json` of the same [`Cell::config_hash`] and case fingerprint).
    pub fn finished(&self) -> Option<CellResult> {
        // Bounded and regular files only: a FIFO or /dev/zero in a cell folder must not hang or
        // exhaust memory (it reads as "not finished").
        let bytes = crate::error::read_file(&self.dir.join("cell.json")).ok()?;
        let result: CellResult = serde_json::from_slice(&bytes).ok()?;
        let same = |ran_on: &Option<String>, now: &Option<String>| match (ran_on, now) {
            (Some(ran_on), Some(now)) => ran_on == now,
            _ => true,
        };
        let same_case =
            same(&result.case_fingerprint, &self.case_fingerprint) && same(&result.case_files, &self.case_files);
        (result.config_hash.as_deref() == Some(self.config_hash.as_str()) && same_case).then_some(result)
    }

    /// Whether a `cell.json` is there but of another configuration or case (its `case.json` or
    /// a file it reads re-made), or unreadable (rerun when run).
    pub fn stale(&self) -> bool {
        self.dir.join("cell.json").exists() && self.finished().is_none()
    }
}

/// The lock file of a cell being run ([`FolderLock`]).
const CELL_LOCK: &str = "cell.lock";

/// The most cells a matrix may have (cases × priors × view subsets × methods): far beyond a
/// study's, and each cell's configuration is checked when the matrix is read.
pub const MAX_CELLS: usize = 100_000;

/// A matrix over cases, with its cells in a fixed order — the runs by (case, prior, views,
/// method), then the ensembles by (case, prior, views, ensemble) — so that a cell's index names
/// the same run on every machine, and adding an ensemble renumbers no run.
#[derive(Debug, Clone)]
pub struct Experiment {
    pub matrix: Matrix,
    /// Folder of the matrix file (method configs are relative to it).
    pub matrix_dir: PathBuf,
    /// Overrides for every cell: the matrix's, then the caller's.
    pub common: Vec<String>,
    pub cells: Vec<Cell>,
    pub out: PathBuf,
}

fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

fn put(m: &mut BTreeMap<String, Option<f64>>, prefix: &str, s: Option<&SurfaceScores>) {
    let s = s.copied();
    m.insert(format!("{prefix}cd_mean_mm"), s.and_then(|s| finite(s.cd_mean_mm)));
    m.insert(format!("{prefix}cd_sum_mm"), s.and_then(|s| finite(s.cd_sum_mm)));
    m.insert(format!("{prefix}hd95_mm"), s.and_then(|s| finite(s.hd95_mm)));
    m.insert(format!("{prefix}hd_mm"), s.and_then(|s| finite(s.hd_mm)));
}

/// `d1p50mm` → 1.5.
fn threshold_of(tag: &str) -> Option<f64> {
    tag.strip_prefix('d')?.strip_suffix("mm")?.replace('p', ".").parse().ok()
}

/// The case with another of its priors (and the matching missing-vessel surface).
fn with_prior(case: &Case, tag: &str) -> Result<Case> {
    let mut c = case.clone();
    let prior = format!("priors/{tag}/prior.obj");
    let missing = format!("priors/{tag}/missing.obj");
    for p in [&prior, &missing] {
        if !case.path(p).exists() {
            return Err(CoreError::format(
                &case.dir.join("case.json"),
                format!("{p} does not exist (synthesise the case with this prior threshold)"),
            ));
        }
    }
    let threshold = threshold_of(tag);
    c.file.prior = Some(PriorEntry { mesh: prior, description: format!("prior {tag}"), threshold_mm: threshold });
    if let Some(gt) = c.file.ground_truth.as_mut() {
        gt.missing_mesh = Some(missing);
    }
    Ok(c)
}

/// The metrics of a finished run as a cell's flat map.
fn cell_metrics(summary: &RunSummary) -> BTreeMap<String, Option<f64>> {
    let mut metrics = BTreeMap::new();
    let m = summary.metrics.as_ref();
    put(&mut metrics, "", m.map(|m| &m.overall));
    put(&mut metrics, "roi_", m.and_then(|m| m.roi.as_ref()));
    put(&mut metrics, "prior_", m.and_then(|m| m.prior.as_ref()));
    if let Some(c) = &summary.coverage {
        metrics.insert("missing_recall".into(), c.missing_recall.and_then(finite));
        metrics.insert("missing_surface_within_1mm".into(), c.missing_surface_within_1mm.and_then(finite));
        metrics.insert("false_surface".into(), finite(c.false_surface));
    }
    if let Some(c) = &summary.centreline.scores {
        metrics.insert("centreline_recall".into(), finite(c.recall));
        metrics.insert("centreline_precision".into(), finite(c.precision));
        metrics.insert("centreline_radius_error_mm".into(), finite(c.radius_error_mm));
    }
    if let Some(t) = &summary.topology {
        metrics.insert("cl_dice".into(), finite(t.cl_dice));
        metrics.insert("betti0_error".into(), Some(t.betti0_error as f64));
    }
    // The untouched prior mesh, scored the same way, for comparison.
    let p = summary.prior_metrics.as_ref();
    put(&mut metrics, "untouched_prior_", p.map(|m| &m.overall));
    metrics
}

/// A digest (16 hex digits) of the names and bytes of the files a cell reads from its case: the
/// view images and arrival maps, the prior mesh (`priors/<tag>/` when the matrix names the
/// prior) and the ground truth. A file re-made under the same name (a prior cut from other
/// labels, views imported again) changes it where `case.json` may stay as it was. A file that
/// cannot be read enters by its name alone; the cell's run says what is wrong with it.
pub fn case_files_digest(dir: &Path, file: &CaseFile, prior: Option<&str>) -> String {
    let mut names: Vec<String> = Vec::new();
    for view in &file.views {
        names.push(view.image.clone());
        names.extend(view.arrival.clone());
    }
    let gt = file.ground_truth.as_ref();
    match prior {
        Some(tag) => names.extend([format!("priors/{tag}/prior.obj"), format!("priors/{tag}/missing.obj")]),
        None => {
            names.extend(file.prior.as_ref().map(|p| p.mesh.clone()));
            names.extend(gt.and_then(|g| g.missing_mesh.clone()));
        }
    }
    if let Some(gt) = gt {
        names.push(gt.complete_mesh.clone());
        names.extend(gt.labels.clone());
        names.extend(gt.tree.clone());
    }
    let state = names.iter().fold(FNV1A_START, |state, name| {
        let state = fnv1a(state, name.as_bytes());
        fnv1a_file(state, &dir.join(name)).map(|(state, _)| state).unwrap_or(state)
    });
    format!("{state:016x}")
}

/// `<out>/cells/<case>/<prior or "case">/views-<list>/<method or ensemble>`.
fn cell_dir(out: &Path, case_name: &str, prior: Option<&str>, views: &[usize], name: &str) -> PathBuf {
    let tag = views.iter().map(|v| v.to_string()).collect::<Vec<_>>().join("-");
    out.join("cells").join(case_name).join(prior.unwrap_or("case")).join(format!("views-{tag}")).join(name)
}

/// Refuses an ensemble of fewer than two methods or more than [`MAX_ENSEMBLE_RUNS`], of a method
/// the matrix does not have, or of one method twice.
fn check_ensemble(ensemble: &EnsembleOf, methods: &[Method]) -> std::result::Result<(), String> {
    let name = &ensemble.name;
    let n = ensemble.methods.len();
    if !(2..=MAX_ENSEMBLE_RUNS).contains(&n) {
        return Err(format!(
            "the ensemble `{name}` averages {n} method(s); an ensemble averages 2 to {MAX_ENSEMBLE_RUNS}"
        ));
    }
    for (i, m) in ensemble.methods.iter().enumerate() {
        if !methods.iter().any(|method| &method.name == m) {
            let known: Vec<String> = methods.iter().map(|m| format!("`{}`", m.name)).collect();
            return Err(format!(
                "the ensemble `{name}` names `{m}`, which is no method of the matrix ({})",
                known.join(", ")
            ));
        }
        if ensemble.methods[..i].contains(m) {
            return Err(format!("the ensemble `{name}` names `{m}` twice"));
        }
    }
    Ok(())
}

fn case_file(dir: &Path) -> Option<CaseFile> {
    let path = dir.join(CASE_FILE);
    let text = String::from_utf8(read_file(&path).ok()?).ok()?;
    CaseFile::parse(&text, &path).ok()
}

impl Experiment {
    /// Reads and checks the matrix file (names usable as folder names, every method's config
    /// valid with the overrides) and lays out its cells for `cases` under `out`.
    pub fn load(matrix_path: &Path, cases: &[PathBuf], out: &Path, overrides: &[String]) -> Result<Self> {
        let bytes = read_file(matrix_path)?;
        let text = String::from_utf8(bytes).map_err(|_| CoreError::format(matrix_path, "not UTF-8 text"))?;
        let matrix: Matrix =
            toml::from_str(&text).map_err(|e| CoreError::format(matrix_path, format!("invalid matrix: {e}")))?;
        let bad = |problem: String| CoreError::format(matrix_path, problem);
        if matrix.views.is_empty() || matrix.methods.is_empty() {
            return Err(bad("the matrix needs at least one view subset and one method".into()));
        }
        let cells = matrix.views.len() as u128
            * (matrix.methods.len() + matrix.ensembles.len()) as u128
            * matrix.priors.len().max(1) as u128
            * cases.len().max(1) as u128;
        if cells > MAX_CELLS as u128 {
            return Err(bad(format!(
                "{cells} cells (cases × priors × view subsets × (methods + ensembles)); a matrix has at most {MAX_CELLS}"
            )));
        }
        if matrix.views.iter().any(|v| v.is_empty()) {
            return Err(bad(
                "an empty view subset: list the views each cell uses (e.g. [0, 1] or [0, 1, 2]); the tables compare view counts"
                    .into(),
            ));
        }
        if let Some(v) = matrix.views.iter().find(|v| v.len() > MAX_VIEWS) {
            return Err(bad(format!("a view subset of {} views; a case has at most {MAX_VIEWS}", v.len())));
        }
        for m in &matrix.methods {
            check_file_name(&m.name, "method name").map_err(bad)?;
        }
        for e in &matrix.ensembles {
            check_file_name(&e.name, "ensemble name").map_err(bad)?;
        }
        for p in &matrix.priors {
            check_file_name(p, "prior folder").map_err(bad)?;
        }
        // Two entries of one name would run into one cell folder.
        fn first_repeat<T: Ord + Clone>(items: impl IntoIterator<Item = T>) -> Option<T> {
            let mut seen = BTreeSet::new();
            items.into_iter().find(|i| !seen.insert(i.clone()))
        }
        if let Some(m) = first_repeat(method_names(&matrix)) {
            return Err(bad(format!("two methods or ensembles are named `{m}`")));
        }
        for e in &matrix.ensembles {
            check_ensemble(e, &matrix.methods).map_err(bad)?;
        }
        if let Some(v) = first_repeat(matrix.views.iter().cloned()) {
            return Err(bad(format!("the view subset {v:?} is listed twice")));
        }
        if let Some(p) = first_repeat(matrix.priors.iter().cloned()) {
            return Err(bad(format!("the prior `{p}` is listed twice")));
        }
        let matrix_dir = matrix_path.parent().unwrap_or(Path::new(".")).to_path_buf();
        let mut common = matrix.set.clone();
        common.extend(overrides.iter().cloned());
        // Each (method, view subset)'s whole configuration, hashed: a cell's identity.
        let mut config_hashes = BTreeMap::new();
        for m in &matrix.methods {
            for views in &matrix.views {
                let list = views.iter().map(|v| v.to_string()).collect::<Vec<_>>().join(",");
                let overrides = [common.clone(), m.set.clone(), vec![format!("run.views=[{list}]")]].concat();
                let cfg = Config::load(Some(&matrix_dir.join(&m.config)), &overrides)
                    .map_err(|e| bad(format!("method {}: {e}", m.name)))?;
                config_hashes.insert((m.name.clone(), views.clone()), text_hash(&cfg.to_toml()));
            }
        }
        let case_names: Vec<String> = cases
            .iter()
            .map(|d| d.file_name().map(|n| n.to_string_lossy().to_string()).unwrap_or_else(|| "case".into()))
            .collect();
        if let Some(name) = first_repeat(case_names.iter().cloned()) {
            return Err(CoreError::invalid(format!(
                "two cases are named `{name}` (the last part of their folder): their cells would share folders"
            )));
        }
        let priors: Vec<Option<String>> =
            if matrix.priors.is_empty() { vec![None] } else { matrix.priors.iter().cloned().map(Some).collect() };
        let mut cells = Vec::new();
        for case_dir in cases {
            let case_name =
                case_dir.file_name().map(|n| n.to_string_lossy().to_string()).unwrap_or_else(|| "case".into());
            check_file_name(&case_name, "case folder name").map_err(CoreError::invalid)?;
            refuse_folder_of_cases(case_dir)?;
            // A view the case does not have fails each of its cells: refused when the matrix is
            // read. (A case that cannot be read yet says so in its cells.)
            let file = case_file(case_dir);
            let case_fingerprint = file.as_ref().map(CaseFile::fingerprint);
            if let Some(n) = file.as_ref().map(|f| f.views.len())
                && let Some(v) = matrix.views.iter().find(|v| v.iter().any(|&i| i >= n))
            {
                return Err(bad(format!(
                    "the view subset {v:?} names a view that case `{case_name}` lacks (it has {n})"
                )));
            }
            // So is a prior the case was not synthesised with.
            if let Some(p) = matrix.priors.iter().find(|p| {
                case_dir.join(CASE_FILE).is_file() && !case_dir.join("priors").join(p).join("prior.obj").is_file()
            }) {
                return Err(bad(format!(
                    "case `{case_name}` has no prior `{p}` ({} does not exist; `ctadsa synth --prior-diameter` makes one \
                     per threshold)",
                    case_dir.join("priors").join(p).join("prior.obj").display()
                )));
            }
            for prior in &priors {
                let case_files = file.as_ref().map(|f| case_files_digest(case_dir, f, prior.as_deref()));
                for views in &matrix.views {
                    for method in &matrix.methods {
                        let config_hash = config_hashes[&(method.name.clone(), views.clone())].clone();
                        cells.push(Cell {
                            case_dir: case_dir.clone(),
                            case_name: case_name.clone(),
                            dir: cell_dir(out, &case_name, prior.as_deref(), views, &method.name),
                            work: CellWork::Run(method.clone()),
                            views: views.clone(),
                            prior: prior.clone(),
                            config_hash,
                            case_fingerprint: case_fingerprint.clone(),
                            case_files: case_files.clone(),
                        });
                    }
                }
            }
        }
        // The ensembles after every run, each over the run cells of its case, prior and views.
        let runs = cells.len();
        for run_of_first_method in (0..runs).step_by(matrix.methods.len()) {
            let first = cells[run_of_first_method].clone();
            for ensemble in &matrix.ensembles {
                let members: Vec<usize> = ensemble
                    .methods
                    .iter()
                    .map(|m| {
                        let offset = matrix.methods.iter().position(|method| &method.name == m);
                        run_of_first_method + offset.expect("checked: an ensemble names methods of the matrix")
                    })
                    .collect();
                let hashes: Vec<&str> = members.iter().map(|&m| cells[m].config_hash.as_str()).collect();
                cells.push(Cell {
                    dir: cell_dir(out, &first.case_name, first.prior.as_deref(), &first.views, &ensemble.name),
                    work: CellWork::Ensemble { name: ensemble.name.clone(), members },
                    config_hash: text_hash(&format!("ensemble of {}", hashes.join(" "))),
                    ..first.clone()
                });
            }
        }
        Ok(Self { matrix, matrix_dir, common, cells, out: out.to_path_buf() })
    }

    /// Runs cell `index` on `device` (autodiff) and writes its `cell.json`. A run cell continues
    /// from the newest checkpoint an interrupted attempt with the same settings left (a
    /// SIGTERM'd SLURM task, requeued), else starts from scratch; an ensemble cell averages its
    /// members' runs, and is refused, naming them, while one of them is not finished. The cell
    /// is locked while it runs: a second process on it is refused. `None` when the monitor
    /// stopped it.
    pub fn run_cell(&self, index: usize, device: Device, monitor: &mut dyn Monitor) -> Result<Option<CellResult>> {
        let cell = self.cells.get(index).ok_or_else(|| {
            CoreError::invalid(format!("cell {index} does not exist (the matrix has {} cells)", self.cells.len()))
        })?;
        let waiting: Vec<String> =
            self.waits_for(index).into_iter().map(|m| format!("{m} ({})", self.cells[m].label())).collect();
        if !waiting.is_empty() {
            return Err(CoreError::invalid(format!(
                "cell {index} ({}) averages cells that are not finished: {}; run them first",
                cell.label(),
                waiting.join(", ")
            )));
        }
        let case = Case::load(&cell.case_dir)?;
        let case_fingerprint = case.fingerprint();
        let case_files = case_files_digest(&cell.case_dir, &case.file, cell.prior.as_deref());
        let case = match &cell.prior {
            Some(tag) => with_prior(&case, tag)?,
            None => case,
        };
        let view_list = cell.views.iter().map(|v| v.to_string()).collect::<Vec<_>>().join(",");
        let _lock = FolderLock::take(&cell.dir, CELL_LOCK, "the cell")?;
        let start = Instant::now();
        let (summary, members_seconds) = match &cell.work {
            CellWork::Run(method) => {
                let mut overrides = self.common.clone();
                overrides.extend(method.set.iter().cloned());
                overrides.push(format!("run.views=[{view_list}]"));
                let cfg = Config::load(Some(&self.matrix_dir.join(&method.config)), &overrides)?;
                match self.run_method(cell, &case, cfg, device, monitor)? {
                    Some(summary) => (summary, 0.0),
                    None => return Ok(None),
                }
            }
            CellWork::Ensemble { members, .. } => {
                remove_file_if_present(&cell.dir.join("cell.json"))?;
                let runs: Vec<PathBuf> = members.iter().map(|&m| self.cells[m].dir.clone()).collect();
                let summary = run_ensemble(&case, &runs, device, &cell.dir, true, monitor)?;
                let seconds = members.iter().filter_map(|&m| self.cells[m].finished()).map(|r| r.seconds).sum();
                (summary, seconds)
            }
        };
        let result = CellResult {
            case: cell.case_name.clone(),
            method: cell.work.name().to_string(),
            views: cell.views.len(),
            view_list,
            prior: cell.prior.clone().unwrap_or_else(|| "case".into()),
            prior_threshold_mm: case.file.prior.as_ref().and_then(|p| p.threshold_mm),
            seconds: members_seconds + start.elapsed().as_secs_f64(),
            gaussians: summary.gaussians,
            metrics: cell_metrics(&summary),
            config_hash: Some(cell.config_hash.clone()),
            case_fingerprint: Some(case_fingerprint),
            case_files: Some(case_files),
        };
        let path = cell.dir.join("cell.json");
        write_file(&path, to_json(&result, &path)?.as_bytes())?;
        Ok(Some(result))
    }

    /// The completion run of a run cell (locked by the caller), continued or from scratch as
    /// [`Experiment::run_cell`] says; `None` when the monitor stopped it.
    fn run_method(
        &self,
        cell: &Cell,
        case: &Case,
        cfg: Config,
        device: Device,
        monitor: &mut dyn Monitor,
    ) -> Result<Option<RunSummary>> {
        let attempted = !cell.dir.join("cell.json").exists()
            && !crate::method::train::Trainer::checkpoints(&cell.dir.join("checkpoints")).is_empty();
        let outcome = if attempted {
            monitor.note(&format!("{}: continuing the interrupted attempt", cell.label()));
            match run_completion(case, cfg.clone(), device.clone(), &cell.dir, Start::Resume("latest"), monitor) {
                Ok(outcome) => outcome,
                Err(e) => {
                    monitor.note(&format!("{}: cannot continue ({e}); starting again", cell.label()));
                    run_completion(case, cfg, device, &cell.dir, Start::Overwrite, monitor)?
                }
            }
        } else {
            remove_file_if_present(&cell.dir.join("cell.json"))?;
            run_completion(case, cfg, device, &cell.dir, Start::Overwrite, monitor)?
        };
        Ok(match outcome {
            Outcome::Finished(summary) => Some(*summary),
            Outcome::Interrupted { .. } => None,
        })
    }

    /// The cells that cell `index` averages and that are not finished (none for a run cell or a
    /// cell that does not exist).
    pub fn waits_for(&self, index: usize) -> Vec<usize> {
        match self.cells.get(index).map(|c| &c.work) {
            Some(CellWork::Ensemble { members, .. }) => {
                members.iter().copied().filter(|&m| self.cells[m].finished().is_none()).collect()
            }
            _ => Vec::new(),
        }
    }

    /// The results of the finished cells, in cell order.
    pub fn finished(&self) -> Vec<CellResult> {
        self.cells.iter().filter_map(Cell::finished).collect()
    }

    /// Writes `results.csv`, `table.md` and (with several priors) the Fig. 3 plots from the
    /// finished cells; returns the Markdown table.
    pub fn collect(&self) -> Result<String> {
        let mut results = self.finished();
        results.sort_by(|a, b| (&a.case, &a.prior, a.views, &a.method).cmp(&(&b.case, &b.prior, b.views, &b.method)));
        write_file(&self.out.join("results.csv"), results_csv(&results).as_bytes())?;
        let md = format!(
            "{}\nPer method and view count, with the median wall-clock of a cell:\n\n{}",
            results_table(&results, &method_names(&self.matrix), &view_counts(&self.matrix)),
            configurations_table(&results)
        );
        write_file(&self.out.join("table.md"), md.as_bytes())?;
        self.write_fig3(&results)?;
        Ok(md)
    }

    /// Fig. 3: ROI metrics against the prior threshold, one series per method and view count.
    fn write_fig3(&self, results: &[CellResult]) -> Result<()> {
        let priors = priors_of(results);
        if priors.len() < 2 {
            return Ok(());
        }
        for (key, label, file) in
            [("roi_cd_sum_mm", "CD ROI (mm)", "fig3-cd-roi.png"), ("roi_hd95_mm", "HD95 ROI (mm)", "fig3-hd95-roi.png")]
        {
            let mut series = Vec::new();
            for name in method_names(&self.matrix) {
                for v in view_counts(&self.matrix) {
                    let mut pts: Vec<(f64, f64)> = Vec::new();
                    for p in &priors {
                        let s: Vec<f64> = results
                            .iter()
                            .filter(|r| r.method == name && &r.prior == p && r.views == v)
                            .filter_map(|r| r.metrics.get(key).copied().flatten())
                            .collect();
                        if let (Some(t), Some((mean, _))) = (threshold_of(p), mean_std(&s)) {
                            pts.push((t, mean));
                        }
                    }
                    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
                    let rgb = PALETTE[series.len() % PALETTE.len()];
                    series.push(Series { name: format!("{name} {v}v"), points: pts, rgb });
                }
            }
            let title = format!("{label}: mean over the cases, per method and view count");
            line_plot(&self.out.join(file), &title, "prior threshold (mm)", label, &series, false)?;
        }
        Ok(())
    }
}

fn remove_file_if_present(path: &Path) -> Result<()> {
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(CoreError::io(path, e)),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::run::results::tests::result;

    /// A matrix with two methods, views and cases of one name is refused (they would share cell
    /// folders); a cell finished with another configuration is not finished; a cell held by a
    /// live process is refused to a second one, a dead process's lock is taken over.
    #[test]
    fn duplicate_cells_stale_results_and_locks() {
        let temp = tempfile::tempdir().unwrap();
        let dir = temp.path().to_path_buf();
        let config = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/quick.toml");
        let write = |name: &str, text: String| {
            let p = dir.join(name);
            std::fs::write(&p, text).unwrap();
            p
        };
        let method = |name: &str| format!("[[methods]]\nname = \"{name}\"\nconfig = \"{config}\"\n");
        let twice = write("twice.toml", format!("views = [[0, 1]]\n{}{}", method("m"), method("m")));
        let err = Experiment::load(&twice, &[], &dir.join("out"), &[]).unwrap_err().to_string();
        assert!(err.contains("two methods or ensembles are named `m`"), "{err}");
        let views = write("views.toml", format!("views = [[0, 1], [0, 1]]\n{}", method("m")));
        let err = Experiment::load(&views, &[], &dir.join("out"), &[]).unwrap_err().to_string();
        assert!(err.contains("listed twice"), "{err}");
        // A subset naming one view twice: refused when the matrix is read, not cell by cell.
        let repeat = write("repeat.toml", format!("views = [[0, 0]]\n{}", method("m")));
        let err = Experiment::load(&repeat, &[], &dir.join("out"), &[]).unwrap_err().to_string();
        assert!(err.contains("run.views") && err.contains("twice"), "{err}");
        let good = write("good.toml", format!("views = [[0, 1]]\n{}", method("m")));
        let cases = [dir.join("a/X"), dir.join("b/X")];
        let err = Experiment::load(&good, &cases, &dir.join("out"), &[]).unwrap_err().to_string();
        assert!(err.contains("two cases are named `X`"), "{err}");
        // The configuration is part of a cell's identity.
        let exp = Experiment::load(&good, &cases[..1], &dir.join("out"), &[]).unwrap();
        let seeded = Experiment::load(&good, &cases[..1], &dir.join("out"), &["run.seed=7".into()]).unwrap();
        assert_ne!(exp.cells[0].config_hash, seeded.cells[0].config_hash);
        let cell = &exp.cells[0];
        let mut r = result("X", "m", 2, Some(1.0));
        r.config_hash = Some(cell.config_hash.clone());
        std::fs::create_dir_all(&cell.dir).unwrap();
        std::fs::write(cell.dir.join("cell.json"), serde_json::to_string(&r).unwrap()).unwrap();
        assert!(cell.finished().is_some() && !cell.stale());
        assert!(seeded.cells[0].finished().is_none() && seeded.cells[0].stale(), "another seed's result is stale");
        // Locks.
        let lock = FolderLock::take(&cell.dir, CELL_LOCK, "the cell").unwrap();
        let err =
            FolderLock::take(&cell.dir, CELL_LOCK, "the cell").expect_err("a second holder is refused").to_string();
        assert!(err.contains("cell.lock") && err.contains(&format!("pid {}", std::process::id())), "{err}");
        drop(lock);
        assert!(!cell.dir.join("cell.lock").exists(), "released");
        std::fs::write(cell.dir.join("cell.lock"), format!("pid {} on {}", u32::MAX - 1, crate::run::lock::hostname()))
            .unwrap();
        drop(FolderLock::take(&cell.dir, CELL_LOCK, "the cell").expect("a dead process's lock is taken over"));
        // A FIFO as cell.json or as the lock: no hang, the cell is unfinished, the lock refused.
        for name in ["cell.json", "cell.lock"] {
            let p = cell.dir.join(name);
            std::fs::remove_file(&p).ok();
            assert!(std::process::Command::new("mkfifo").arg(&p).status().is_ok_and(|s| s.success()));
        }
        assert!(cell.finished().is_none(), "a FIFO is not a result");
        assert!(FolderLock::take(&cell.dir, CELL_LOCK, "the cell").is_err(), "a FIFO lock is nobody's stale lock");
    }

    /// A cell's result is its own only on the case it ran on: re-making the case (another
    /// `synth` into the same folder) or a file it reads makes the finished cell stale.
    #[test]
    fn results_on_a_case_since_remade_are_stale() {
        let temp = tempfile::tempdir().unwrap();
        let dir = temp.path().to_path_buf();
        let case_dir = dir.join("cases/C");
        crate::data::synth::synthesize(&crate::data::synth::SynthConfig::small_procedural("C"), &case_dir, &mut |_| {})
            .unwrap();
        let config = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/quick.toml");
        let matrix = dir.join("m.toml");
        std::fs::write(&matrix, format!("views = [[0, 1]]\n[[methods]]\nname = \"m\"\nconfig = \"{config}\"\n"))
            .unwrap();
        let load = || Experiment::load(&matrix, std::slice::from_ref(&case_dir), &dir.join("out"), &[]).unwrap();
        let cell = load().cells[0].clone();
        // What a cell records when it runs: the fingerprint of the case as loaded.
        let ran_on = Case::load(&case_dir).unwrap().fingerprint();
        assert_eq!(cell.case_fingerprint.as_deref(), Some(ran_on.as_str()));
        let mut r = result("C", "m", 2, Some(1.0));
        r.config_hash = Some(cell.config_hash.clone());
        r.case_fingerprint = Some(ran_on);
        std::fs::create_dir_all(&cell.dir).unwrap();
        std::fs::write(cell.dir.join("cell.json"), serde_json::to_string(&r).unwrap()).unwrap();
        assert!(cell.finished().is_some() && !cell.stale());
        // The case re-made with other settings (here: its provenance notes edited).
        let path = case_dir.join(CASE_FILE);
        let mut file = CaseFile::parse(&std::fs::read_to_string(&path).unwrap(), &path).unwrap();
        file.provenance.notes.push("re-made".into());
        file.save(&case_dir).unwrap();
        let cell = load().cells[0].clone();
        assert!(cell.finished().is_none() && cell.stale(), "a result on the earlier case is stale");
        // A result of a version that recorded no case is taken as the case's.
        r.case_fingerprint = None;
        std::fs::write(cell.dir.join("cell.json"), serde_json::to_string(&r).unwrap()).unwrap();
        assert!(cell.finished().is_some());
        // A file the cell reads re-made under the same name, case.json untouched (a prior cut
        // again from other labels): the result is stale too.
        let case = Case::load(&case_dir).unwrap();
        r.case_fingerprint = Some(case.fingerprint());
        r.case_files = Some(case_files_digest(&case_dir, &case.file, None));
        std::fs::write(cell.dir.join("cell.json"), serde_json::to_string(&r).unwrap()).unwrap();
        let cell = load().cells[0].clone();
        assert_eq!(cell.case_files, r.case_files);
        assert!(cell.finished().is_some() && !cell.stale());
        let prior = case_dir.join(&case.file.prior.as_ref().unwrap().mesh);
        let mut bytes = std::fs::read(&prior).unwrap();
        bytes.extend_from_slice(b"# re-made\n");
        std::fs::write(&prior, bytes).unwrap();
        let cell = load().cells[0].clone();
        assert!(cell.finished().is_none() && cell.stale(), "a result on the earlier prior mesh is stale");
        // A view image swapped for a FIFO: the digest does not hang (the run will say why).
        let image = case_dir.join(&case.file.views[0].image);
        std::fs::remove_file(&image).unwrap();
        assert!(std::process::Command::new("mkfifo").arg(&image).status().is_ok_and(|s| s.success()));
        assert_ne!(load().cells[0].case_files, cell.case_files);
    }

    /// `cases/` given for `cases/*`: refused when the matrix is read, naming the cases inside.
    #[test]
    fn a_folder_of_cases_given_as_a_case_is_refused() {
        let temp = tempfile::tempdir().unwrap();
        let dir = temp.path().to_path_buf();
        let config = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/quick.toml");
        let matrix = dir.join("m.toml");
        std::fs::write(&matrix, format!("views = [[0, 1]]\n[[methods]]\nname = \"m\"\nconfig = \"{config}\"\n"))
            .unwrap();
        for name in ["A", "B", "C", "D"] {
            std::fs::create_dir_all(dir.join("cases").join(name)).unwrap();
            std::fs::write(dir.join("cases").join(name).join(CASE_FILE), "{}").unwrap();
        }
        std::fs::create_dir_all(dir.join("cases/notes")).unwrap();
        let load = |case: &str| Experiment::load(&matrix, &[dir.join(case)], &dir.join("out"), &[]);
        let err = load("cases").expect_err("a folder of cases is not a case").to_string();
        assert!(err.contains("cases") && err.contains("not a case folder"), "{err}");
        assert!(err.contains("A, B, C and 1 more") && err.contains("cases/A"), "{err}");
        // A case folder, one that does not exist yet and one that holds no case are laid out.
        assert_eq!(load("cases/A").unwrap().cells.len(), 1);
        assert_eq!(load("later").unwrap().cells.len(), 1);
        assert_eq!(load("cases/notes").unwrap().cells.len(), 1);
    }

    /// Ensembles: checked when the matrix is read, laid out after every run with their members
    /// found by case, prior and views, of a configuration that follows their members', and
    /// refused to run, naming them, while a member is unfinished.
    #[test]
    #[allow(deprecated)] // burn-ndarray is the CPU backend the tests use.
    fn ensembles_follow_the_runs_they_average() {
        let temp = tempfile::tempdir().unwrap();
        let dir = temp.path().to_path_buf();
        let config = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/quick.toml");
        let methods = format!(
            "views = [[0, 1], [0, 1, 2]]\n[[methods]]\nname = \"a\"\nconfig = \"{config}\"\n\
             [[methods]]\nname = \"b\"\nconfig = \"{config}\"\nset = [\"run.seed = 7\"]\n\
             [[methods]]\nname = \"c\"\nconfig = \"{config}\"\nset = [\"run.seed = 8\"]\n"
        );
        let load = |ensembles: &str, overrides: &[String]| {
            let path = dir.join("m.toml");
            std::fs::write(&path, format!("{methods}{ensembles}")).unwrap();
            Experiment::load(&path, &[dir.join("X"), dir.join("Y")], &dir.join("out"), overrides)
        };
        let ensemble = |name: &str, of: &str| format!("[[ensembles]]\nname = \"{name}\"\nmethods = [{of}]\n");
        for (ensembles, expected) in [
            (ensemble("e", "\"a\""), "averages 1 method(s)"),
            (ensemble("e", "\"a\", \"z\""), "names `z`, which is no method of the matrix (`a`, `b`, `c`)"),
            (ensemble("e", "\"a\", \"b\", \"a\""), "names `a` twice"),
            (ensemble("a", "\"b\", \"c\""), "two methods or ensembles are named `a`"),
            (format!("{}{}", ensemble("e", "\"a\", \"b\""), ensemble("e", "\"b\", \"c\"")), "named `e`"),
            (ensemble("../e", "\"a\", \"b\""), "ensemble name"),
        ] {
            let err = load(&ensembles, &[]).expect_err(&ensembles).to_string();
            assert!(err.contains("m.toml") && err.contains(expected), "{ensembles}: {err}");
        }
        let two = format!("{}{}", ensemble("ca", "\"c\", \"a\""), ensemble("ab", "\"a\", \"b\""));
        let exp = load(&two, &[]).unwrap();
        // 2 cases × 2 view subsets × 3 methods, then × 2 ensembles.
        assert_eq!(exp.cells.len(), 12 + 8);
        assert!(exp.cells[..12].iter().all(|c| !c.is_ensemble()) && exp.cells[12..].iter().all(Cell::is_ensemble));
        let without = load("", &[]).unwrap();
        for (with, alone) in exp.cells.iter().zip(&without.cells) {
            assert_eq!((&with.dir, &with.config_hash), (&alone.dir, &alone.config_hash), "no run renumbered");
        }
        for cell in &exp.cells[12..] {
            let CellWork::Ensemble { name, members } = &cell.work else { unreachable!() };
            let names: Vec<&str> = members.iter().map(|&m| exp.cells[m].work.name()).collect();
            assert_eq!(names, if name == "ca" { ["c", "a"] } else { ["a", "b"] });
            for &m in members {
                let member = &exp.cells[m];
                assert_eq!(
                    (&member.case_name, &member.views, &member.prior),
                    (&cell.case_name, &cell.views, &cell.prior)
                );
                assert_eq!(member.dir.parent(), cell.dir.parent(), "beside its members");
            }
            assert!(cell.dir.ends_with(name) && cell.label().contains(&format!("ensemble {name}")));
        }
        // The ensemble's identity follows its members' configurations.
        let seeded = load(&two, &["run.iterations=5".into()]).unwrap();
        assert_ne!(exp.cells[12].config_hash, seeded.cells[12].config_hash);
        assert_ne!(exp.cells[12].config_hash, exp.cells[13].config_hash, "other members");
        // Run before its members: refused, naming the unfinished ones, nothing written.
        assert_eq!(exp.waits_for(12), [2, 0], "the ensemble `ca` of case X, views [0, 1]");
        assert!(exp.waits_for(0).is_empty() && exp.waits_for(99).is_empty());
        let err = exp.run_cell(12, Device::ndarray().autodiff(), &mut crate::run::completion::Silent).unwrap_err();
        let err = err.to_string();
        assert!(
            err.contains("cell 12")
                && err.contains("not finished")
                && err.contains("2 (X / case prior / views [0, 1] / c)"),
            "{err}"
        );
        assert!(!exp.cells[12].dir.exists());
    }

    #[test]
    fn matrix_names_that_would_escape_the_output_folder_are_refused() {
        let temp = tempfile::tempdir().unwrap();
        let dir = temp.path().to_path_buf();
        let path = dir.join("m.toml");
        std::fs::write(&path, "views = [[0, 1]]\n[[methods]]\nname = \"../up\"\nconfig = \"c.toml\"\n").unwrap();
        let err = Experiment::load(&path, &[], &dir.join("out"), &[]).unwrap_err().to_string();
        assert!(err.contains("m.toml") && err.contains("method name"), "{err}");
    }
}
