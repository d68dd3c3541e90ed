//! The case folder: one `case.json` describing the DSA views (geometry in mm and image files),
//! what the image values mean, the working volume, the prior mesh, optional ground truth and the
//! provenance of everything. See `docs/DATA.md` for the format.

pub mod images;
pub mod prior_check;

use std::path::{Path, PathBuf};

use ctadsa_render::{ConeBeamView, Intrinsics, TigreGeometry, ViewSet};
use glam::DMat4;
use serde::{Deserialize, Serialize};

use crate::data::mesh::{TriMesh, io::read_mesh};
use crate::data::volume::{BoxMm, Grid};
use crate::error::{CoreError, Result, check_file_name, read_file, write_file};
use images::{Image, NO_ARRIVAL, read_image};
use prior_check::check_prior_in_views;

/// The value of `format` in every case file.
pub const CASE_FORMAT: &str = "ctadsa-case";
/// The case format version this library writes and reads.
pub const CASE_VERSION: u32 = 1;
/// The case file name inside a case folder.
pub const CASE_FILE: &str = "case.json";

/// The most views a case may have (a biplane C-arm gives 2, the paper uses 2–3; rotational runs
/// subsampled for training rarely exceed a few dozen).
pub const MAX_VIEWS: usize = 64;

/// The most detector pixels of all views together (kept as `f32`: 2 GiB, e.g. 64 views of
/// 2048² pixels), checked before any image is read.
pub const MAX_TOTAL_PIXELS: u64 = 1 << 29;

/// FNV-1a (64 bits) of `text`, as 16 hex digits: stable across builds and platforms (what
/// case fingerprints and experiment cells' configuration hashes are made of).
pub fn text_hash(text: &str) -> String {
    format!("{:016x}", fnv1a(FNV1A_START, text.as_bytes()))
}

/// The FNV-1a state before the first byte.
pub const FNV1A_START: u64 = 0xcbf2_9ce4_8422_2325;

/// FNV-1a (64 bits) continued from `state` over `bytes` (start from [`FNV1A_START`]); any one
/// changed byte changes the result.
pub fn fnv1a(state: u64, bytes: &[u8]) -> u64 {
    bytes.iter().fold(state, |h, &b| (h ^ b as u64).wrapping_mul(0x0100_0000_01b3))
}

/// FNV-1a continued from `state` over the bytes of the file at `path`, read in blocks; returns
/// the new state and the file's length (bytes). Only a regular file of at most
/// [`MAX_INPUT_BYTES`](crate::error::MAX_INPUT_BYTES) is read (as [`read_file`] does).
pub fn fnv1a_file(state: u64, path: &Path) -> Result<(u64, u64)> {
    use std::io::Read as _;
    let limit = crate::error::check_input_file(path)?;
    let mut file = std::fs::File::open(path).map_err(|e| CoreError::io(path, e))?.take(limit);
    let (mut state, mut bytes, mut block) = (state, 0u64, vec![0u8; 1 << 20]);
    loop {
        let n = file.read(&mut block).map_err(|e| CoreError::io(path, e))?;
        if n == 0 {
            return Ok((state, bytes));
        }
        state = fnv1a(state, &block[..n]);
        bytes += n as u64;
    }
}

/// Where the data came from.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Provenance {
    /// The anatomy's source (e.g. "BraVa BG0002 (NeuroMorpho.Org), Wright et al. 2013").
    pub source: String,
    /// The program and settings that made the case.
    pub generator: String,
    /// Free-form notes (licences, commits, modifications).
    #[serde(default)]
    pub notes: Vec<String>,
}

/// What the pixel values are.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImageValues {
    /// Human-readable units, e.g. "contrast × mm (line integral)".
    pub units: String,
    /// If the images were divided by a constant (the reference divides by the maximum over all
    /// views), that constant: physical value = stored value × `normalised_by`.
    #[serde(default)]
    pub normalised_by: Option<f64>,
    /// Contrast (value per mm of vessel) used to synthesise the images, when known.
    #[serde(default)]
    pub contrast_per_mm: Option<f64>,
}

/// A view's geometry: TIGRE-style C-arm parameters or an explicit registration result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum ViewGeometry {
    /// C-arm parameters (mm, degrees), conventions of `ctadsa_render::TigreGeometry`.
    Tigre {
        dsd_mm: f64,
        dso_mm: f64,
        detector_px: [u32; 2],
        pixel_mm: [f64; 2],
        #[serde(default)]
        offset_mm: [f64; 2],
        primary_deg: f64,
        #[serde(default)]
        secondary_deg: f64,
    },
    /// A world-to-camera matrix (rows; mm) and pinhole intrinsics (px), e.g. from a 2-D/3-D
    /// registration: camera x along image columns, y along rows (down), z from the source
    /// towards the detector.
    Matrix { world_to_camera: [[f64; 4]; 4], focal_px: [f64; 2], principal_px: [f64; 2], detector_px: [u32; 2] },
}

impl ViewGeometry {
    /// From TIGRE parameters.
    pub fn from_tigre(g: &TigreGeometry) -> Self {
        ViewGeometry::Tigre {
            dsd_mm: g.dsd_mm,
            dso_mm: g.dso_mm,
            detector_px: g.detector_px,
            pixel_mm: g.pixel_mm,
            offset_mm: g.offset_mm,
            primary_deg: g.primary_deg,
            secondary_deg: g.secondary_deg,
        }
    }

    /// The renderer's view.
    pub fn to_view(&self) -> std::result::Result<ConeBeamView, ctadsa_render::RenderError> {
        match *self {
            ViewGeometry::Tigre { dsd_mm, dso_mm, detector_px, pixel_mm, offset_mm, primary_deg, secondary_deg } => {
                ConeBeamView::from_tigre(&TigreGeometry {
                    dsd_mm,
                    dso_mm,
                    detector_px,
                    pixel_mm,
                    offset_mm,
                    primary_deg,
                    secondary_deg,
                })
            }
            ViewGeometry::Matrix { world_to_camera, focal_px, principal_px, detector_px } => {
                let m = DMat4::from_cols_array_2d(&world_to_camera).transpose();
                ConeBeamView::from_world_to_camera(
                    m,
                    Intrinsics { focal_px, principal_px },
                    detector_px[0],
                    detector_px[1],
                )
            }
        }
    }

    /// Detector size `[width, height]` in pixels.
    pub fn detector_px(&self) -> [u32; 2] {
        match self {
            ViewGeometry::Tigre { detector_px, .. } | ViewGeometry::Matrix { detector_px, .. } => *detector_px,
        }
    }
}

/// Largest [`ViewEntry::arrival_offset_frames`] a case may give.
pub const MAX_ARRIVAL_OFFSET_FRAMES: f64 = 1000.0;

/// Largest frame an arrival map ([`ViewEntry::arrival`]) may hold: far beyond any DSA run
/// (tens of frames per second for under a minute), small enough to stay a whole `f32`.
pub const MAX_ARRIVAL_FRAME: f32 = 100_000.0;

/// The fewest voxels along each axis of a case's working volume (`volume.voxel_mm` against the
/// box): a coarser grid cannot hold a vessel, so the case is refused rather than run.
pub const MIN_VOLUME_VOXELS_PER_AXIS: usize = 4;

/// One view of the case.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViewEntry {
    /// Short name ("ap", "lat", "oblique-45").
    pub name: String,
    /// The image the method uses, relative to the case folder (`.tiff` exact, or `.png`).
    pub image: String,
    /// Value per count when `image` is a 16-bit PNG.
    #[serde(default)]
    pub png_scale: Option<f64>,
    /// A 16-bit PNG copy for viewing, relative to the case folder, with its scale.
    #[serde(default)]
    pub preview_png: Option<String>,
    pub geometry: ViewGeometry,
    /// Optional, from a time-resolved run: per pixel, the frame (0, 1, …) at which the contrast
    /// first fills a vessel along its ray, −1 where none fills; a 32-bit float TIFF of the
    /// image's size, relative to the case folder ([`Case::arrival_maps`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub arrival: Option<String>,
    /// How late (frames) this view's frames were taken after the run's clock: frame f of
    /// `arrival` says the contrast came between f + this and f + 1 + this frames. A biplane
    /// system images its planes alternately, the lateral plane's frames half a frame after the
    /// frontal's (0.5); 0 (the default): every view at the same instants.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub arrival_offset_frames: f64,
}

/// Serde's `skip_serializing_if` for settings whose default is 0.
pub(crate) fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

/// The prior (what a CTA segmentation shows).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PriorEntry {
    /// Prior surface mesh (OBJ, PLY or STL, world mm), relative to the case folder.
    pub mesh: String,
    /// How it was made, e.g. "segments with diameter ≥ 1.5 mm".
    #[serde(default)]
    pub description: String,
    /// The diameter threshold (mm) used, if any.
    #[serde(default)]
    pub threshold_mm: Option<f64>,
}

/// Ground truth for evaluation (never read by the reconstruction).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GroundTruth {
    /// The complete vessel surface.
    pub complete_mesh: String,
    /// The vessels missing from the prior.
    #[serde(default)]
    pub missing_mesh: Option<String>,
    /// The complete label volume (NIfTI).
    #[serde(default)]
    pub labels: Option<String>,
    /// The centreline tree (SWC), when the case came from one.
    #[serde(default)]
    pub tree: Option<String>,
    /// When the images were made with view poses that differ from the geometry written in the
    /// case (a simulated registration error), the true correction of each view
    /// (`ctadsa_core::method::pose` convention: `[ω (rad), t (mm)]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub view_corrections: Option<Vec<[f64; 6]>>,
}

/// The content of `case.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CaseFile {
    /// Always [`CASE_FORMAT`].
    pub format: String,
    /// [`CASE_VERSION`].
    pub version: u32,
    pub name: String,
    pub provenance: Provenance,
    pub image_values: ImageValues,
    /// The working volume: the box the vessels lie in (mm) and the voxel size used for it.
    pub volume: VolumeEntry,
    pub views: Vec<ViewEntry>,
    #[serde(default)]
    pub prior: Option<PriorEntry>,
    #[serde(default)]
    pub ground_truth: Option<GroundTruth>,
}

/// The reconstruction box.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VolumeEntry {
    pub min_mm: [f64; 3],
    pub max_mm: [f64; 3],
    /// Voxel edge of the working grid (mm).
    pub voxel_mm: f64,
}

impl VolumeEntry {
    /// As a box.
    pub fn bounds(&self) -> BoxMm {
        BoxMm { min_mm: self.min_mm, max_mm: self.max_mm }
    }
}

/// A case read from disk, with its images loaded and checked.
#[derive(Debug, Clone)]
pub struct Case {
    /// The folder.
    pub dir: PathBuf,
    pub file: CaseFile,
    /// The views, all of one detector size.
    pub views: ViewSet,
    /// One image per view, matching its detector size.
    pub images: Vec<Image>,
}

impl CaseFile {
    /// Parses and checks `case.json` text (`path` is for messages).
    pub fn parse(text: &str, path: &Path) -> Result<Self> {
        let file: CaseFile =
            serde_json::from_str(text).map_err(|e| CoreError::format(path, format!("invalid case file: {e}")))?;
        file.validate(path)?;
        Ok(file)
    }

    /// The checks of [`CaseFile::parse`] (`path` is for messages): also for a case about to be
    /// written, so that nothing is written for one that would not load.
    pub fn validate(&self, path: &Path) -> Result<()> {
        let file = self;
        if file.format != CASE_FORMAT {
            return Err(CoreError::format(path, format!("`format` is `{}`, expected `{CASE_FORMAT}`", file.format)));
        }
        if file.version != CASE_VERSION {
            return Err(CoreError::format(
                path,
                format!("case version {} is not supported (this build reads {CASE_VERSION})", file.version),
            ));
        }
        if file.views.is_empty() {
            return Err(CoreError::format(path, "the case has no views"));
        }
        if file.views.len() > MAX_VIEWS {
            return Err(CoreError::format(path, format!("{} views; at most {MAX_VIEWS} are read", file.views.len())));
        }
        let pixels: u64 = file.views.iter().map(|v| v.geometry.detector_px()).map(|[w, h]| w as u64 * h as u64).sum();
        if pixels > MAX_TOTAL_PIXELS {
            return Err(CoreError::format(
                path,
                format!("the views' detectors hold {pixels} pixels together; at most {MAX_TOTAL_PIXELS} are read"),
            ));
        }
        check_file_name(&file.name, "case name").map_err(|e| CoreError::format(path, e))?;
        let mut names = std::collections::BTreeSet::new();
        for v in &file.views {
            check_file_name(&v.name, "view name").map_err(|e| CoreError::format(path, e))?;
            // Outputs are named after the view (renders/<name>.png): two of one name would
            // overwrite each other's.
            if !names.insert(v.name.to_ascii_lowercase()) {
                return Err(CoreError::format(path, format!("two views are named `{}`", v.name)));
            }
        }
        // One direction twice adds no depth information, only weight (the same run imported
        // twice, a view copied by hand).
        for (i, a) in file.views.iter().enumerate() {
            if let Some(b) = file.views[i + 1..].iter().find(|b| b.geometry == a.geometry) {
                return Err(CoreError::format(
                    path,
                    format!("views `{}` and `{}` have the same geometry: one direction given twice", a.name, b.name),
                ));
            }
        }
        for v in &file.views {
            if let Some(s) = v.png_scale
                && !(s.is_finite() && s > 0.0)
            {
                return Err(CoreError::format(
                    path,
                    format!("view `{}`: `png_scale` must be a positive number, got {s}", v.name),
                ));
            }
            let offset = v.arrival_offset_frames;
            if !(offset.is_finite() && (0.0..=MAX_ARRIVAL_OFFSET_FRAMES).contains(&offset)) {
                return Err(CoreError::format(
                    path,
                    format!(
                        "view `{}`: `arrival_offset_frames` must be in [0, {MAX_ARRIVAL_OFFSET_FRAMES}], got {offset}",
                        v.name
                    ),
                ));
            }
        }
        let b = file.volume.bounds();
        let finite = b.min_mm.iter().chain(&b.max_mm).all(|v| v.is_finite());
        if !finite || !(0..3).all(|a| b.max_mm[a] > b.min_mm[a]) || !(file.volume.voxel_mm > 0.0) {
            let v = &file.volume;
            return Err(CoreError::format(
                path,
                format!(
                    "`volume`: min_mm {:?} to max_mm {:?} at voxel_mm {} is not a box (each max must exceed its min, \
                     all finite, the voxel size positive)",
                    v.min_mm, v.max_mm, v.voxel_mm
                ),
            ));
        }
        let grid = Grid::covering(&b, file.volume.voxel_mm)
            .map_err(|e| CoreError::format(path, format!("`volume.voxel_mm` {}: {e}", file.volume.voxel_mm)))?;
        if grid.dims.iter().any(|&n| n < MIN_VOLUME_VOXELS_PER_AXIS) {
            let size = b.size_mm();
            return Err(CoreError::format(
                path,
                format!(
                    "`volume.voxel_mm` {} is coarser than the working box ({:.1} × {:.1} × {:.1} mm gives {:?} \
                     voxels): at least {MIN_VOLUME_VOXELS_PER_AXIS} voxels per axis are needed",
                    file.volume.voxel_mm, size[0], size[1], size[2], grid.dims
                ),
            ));
        }
        Ok(())
    }

    /// The case's name and a hash of this content ([`Case::fingerprint`]).
    pub fn fingerprint(&self) -> String {
        let text = serde_json::to_string(self).unwrap_or_default();
        format!("{} {}", self.name, text_hash(&text))
    }

    /// Writes `case.json` into `dir`.
    pub fn save(&self, dir: &Path) -> Result<()> {
        let text = serde_json::to_string_pretty(self).map_err(|e| CoreError::invalid(e.to_string()))?;
        write_file(&dir.join(CASE_FILE), text.as_bytes())
    }
}

/// Refuses a folder that has no `case.json` but holds case folders (`cases/` given for
/// `cases/BG0002`), naming some of them, so that the mistake reads as what it is rather than as
/// a missing file. Other folders pass, whether they exist or not. At most 4,096 entries are
/// looked at, so a huge folder costs no time.
pub fn refuse_folder_of_cases(dir: &Path) -> Result<()> {
    const MAX_ENTRIES_LOOKED_AT: usize = 4096;
    const NAMED: usize = 3;
    if dir.join(CASE_FILE).exists() {
        return Ok(());
    }
    let Ok(entries) = std::fs::read_dir(dir) else { return Ok(()) };
    let mut held: Vec<String> = entries
        .take(MAX_ENTRIES_LOOKED_AT)
        .flatten()
        .filter(|e| e.path().join(CASE_FILE).is_file())
        .map(|e| e.file_name().to_string_lossy().to_string())
        .collect();
    held.sort();
    let Some(first) = held.first() else { return Ok(()) };
    let example = dir.join(first);
    let more = if held.len() > NAMED { format!(" and {} more", held.len() - NAMED) } else { String::new() };
    held.truncate(NAMED);
    Err(CoreError::format(
        dir,
        format!(
            "not a case folder (no {CASE_FILE}) but a folder of cases ({}{more}): name a case folder itself, e.g. `{}`",
            held.join(", "),
            example.display()
        ),
    ))
}

impl Case {
    /// Reads `dir/case.json` and all view images; checks geometry, image sizes and pixels.
    pub fn load(dir: &Path) -> Result<Self> {
        refuse_folder_of_cases(dir)?;
        let path = dir.join(CASE_FILE);
        let text = String::from_utf8(read_file(&path)?).map_err(|_| CoreError::format(&path, "not UTF-8 text"))?;
        let file = CaseFile::parse(&text, &path)?;
        let mut views = Vec::new();
        let mut images = Vec::new();
        for (i, v) in file.views.iter().enumerate() {
            let view =
                v.geometry.to_view().map_err(|e| CoreError::format(&path, format!("view {i} (`{}`): {e}", v.name)))?;
            let img_path = dir.join(&v.image);
            let img = read_image(&img_path, v.png_scale)?;
            if (img.width, img.height) != (view.width(), view.height()) {
                return Err(CoreError::format(
                    &img_path,
                    format!(
                        "image is {} × {} pixels but view `{}` has a {} × {} detector",
                        img.width,
                        img.height,
                        v.name,
                        view.width(),
                        view.height()
                    ),
                ));
            }
            if img.max() <= 0.0 {
                return Err(CoreError::format(
                    &img_path,
                    format!(
                        "view `{}` has no positive pixel: the views must show the vessels as positive values \
                         (line integrals of the contrast: subtracted and log-converted)",
                        v.name
                    ),
                ));
            }
            views.push(view);
            images.push(img);
        }
        let views = ViewSet::new(views).map_err(|e| CoreError::format(&path, e.to_string()))?;
        Ok(Self { dir: dir.to_path_buf(), file, views, images })
    }

    /// The arrival maps of the views ([`ViewEntry::arrival`]), when every view has one: each of
    /// the view's size, its values whole frames from 0 to [`MAX_ARRIVAL_FRAME`] or −1 (no
    /// vessel), some pixel filled.
    pub fn arrival_maps(&self) -> Result<Option<Vec<Image>>> {
        let Some(paths) = self.file.views.iter().map(|v| v.arrival.as_ref()).collect::<Option<Vec<_>>>() else {
            return Ok(None);
        };
        let mut maps = Vec::new();
        for ((relative, entry), image) in paths.into_iter().zip(&self.file.views).zip(&self.images) {
            let path = self.dir.join(relative);
            let map = read_image(&path, None)?;
            if (map.width, map.height) != (image.width, image.height) {
                return Err(CoreError::format(
                    &path,
                    format!(
                        "arrival map is {} × {} pixels but view `{}`'s image is {} × {}",
                        map.width, map.height, entry.name, image.width, image.height
                    ),
                ));
            }
            let frame = |f: f32| (0.0..=MAX_ARRIVAL_FRAME).contains(&f) && f.fract() == 0.0;
            if let Some(i) = map.data.iter().position(|&f| !(f == NO_ARRIVAL || frame(f))) {
                return Err(CoreError::format(
                    &path,
                    format!(
                        "pixel (column {}, row {}) is {}: an arrival map holds whole frames from 0 to {}, or −1 \
                         where no vessel fills",
                        i as u32 % map.width,
                        i as u32 / map.width,
                        map.data[i],
                        MAX_ARRIVAL_FRAME
                    ),
                ));
            }
            // A map where nothing fills would reject every point of the view in the arrival checks.
            if !map.data.iter().any(|&f| frame(f)) {
                return Err(CoreError::format(
                    &path,
                    format!(
                        "no pixel of view `{}`'s arrival map fills (every pixel is −1): an arrival map marks \
                         where the vessels fill",
                        entry.name
                    ),
                ));
            }
            maps.push(map);
        }
        Ok(Some(maps))
    }

    /// The prior mesh, if the case has one; refused when it does not lie where the views look
    /// ([`check_prior_in_views`]).
    pub fn prior_mesh(&self) -> Result<Option<TriMesh>> {
        let Some(prior) = &self.file.prior else { return Ok(None) };
        let path = self.dir.join(&prior.mesh);
        let mesh = read_mesh(&path)?;
        check_prior_in_views(&mesh, self.views.views(), &path)?;
        Ok(Some(mesh))
    }

    /// The case's name and a hash of its `case.json` content (views, geometry, prior, volume):
    /// what checkpoints and run summaries record, so that a run is resumed and diagnosed only on
    /// the case it was made on.
    pub fn fingerprint(&self) -> String {
        self.file.fingerprint()
    }

    /// Path of a file named in the case, relative to the case folder.
    pub fn path(&self, relative: &str) -> PathBuf {
        self.dir.join(relative)
    }

    /// The same case with only the views at `indices`.
    pub fn select_views(&self, indices: &[usize]) -> Result<Self> {
        let mut out = self.clone();
        for &i in indices {
            if i >= self.file.views.len() {
                return Err(CoreError::invalid(format!(
                    "view {i} does not exist (case has {})",
                    self.file.views.len()
                )));
            }
        }
        // The same view twice would count its pixels double and pass for a second direction.
        for (k, &i) in indices.iter().enumerate() {
            if indices[..k].contains(&i) {
                return Err(CoreError::invalid(format!("view {i} is selected twice (`run.views`: {indices:?})")));
            }
        }
        if indices.is_empty() {
            return Err(CoreError::invalid("no view selected (`run.views` is empty)"));
        }
        out.file.views = indices.iter().map(|&i| self.file.views[i].clone()).collect();
        out.images = indices.iter().map(|&i| self.images[i].clone()).collect();
        out.views = self.views.select(indices)?;
        Ok(out)
    }
}
