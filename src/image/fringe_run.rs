//! The photoelastic fit as one run — what `grainforce photoelastic` and
//! Python's `grainforce.photoelastic` both do: read the photograph and the
//! scene folder, settle the fringe stress (f_σ / t, or a unit one to be
//! scaled to the walls' load cells), choose the contacts to fit, fit, and
//! gather the forces and the report. The front ends only parse their
//! arguments into [`PhotoelasticConfig`] and write what [`PhotoelasticRun`]
//! holds.

use super::fringe_fit::{
    fit_fringes, fit_fringes_per_disk, fitted_image, local_restarts, wall_scale, Balance,
    FringeFit, FringeFitSettings, LocalRestart, Polariscope, DEFAULT_CANDIDATE_GAP,
};
use super::{load_channel, Channel, FloatImage, PixelFrame, FRAME_FILE};
use crate::error::{Error, Result};
use crate::scene::{read_scene, write_file_atomically, write_forces, Body, Forces, Scene};
use std::path::Path;

/// Which of the scene's contacts are fitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum ContactChoice {
    /// Every contact of the scene; the fringes decide which carry force.
    /// The default: on the detected 58-disk render it gives relerr 0.187
    /// where `Evidence` gives 1.275 (a contact wrongly judged unloaded
    /// pushes its load onto its neighbours).
    #[default]
    All,
    /// Those `detect` judged force-bearing (`force_bearing` in the scene's
    /// contacts-evidence.csv: G² over the packing's floor on both disks);
    /// the others carry zero. Every contact when the file is absent.
    Evidence,
}

/// The friction coefficient of a run where a contact and the scene give
/// none (`--mu`): a polymer photoelastic disk's friction (~0.6) widened by
/// the detected contact normal's error (a few degrees). Measured on the
/// three PeGS photographs with box walls, μ 0.5 / 0.7 / 1 / 2 left 0.20 /
/// 0.80 / 0.80 / 0.89 of fixed48's disks, 0.00 / 0.00 / 0.62 / 0.52 of
/// narrow21's and 0.77 / 0.83 / 0.85 / 0.64 of step83's at least as close
/// as PeGS (docs/photoelastic.md, round 11).
pub const DEFAULT_MU: f64 = 1.0;

/// Everything a photoelastic run can be told; [`Default`] gives the CLI's
/// defaults.
#[derive(Debug, Clone, PartialEq)]
pub struct PhotoelasticConfig {
    /// Fringe constant f_σ [N/m]; `None`: fitted to the walls' load cells.
    pub fsigma: Option<f64>,
    /// Disk thickness [m]; `None`: the scene's.
    pub thickness: Option<f64>,
    /// Pixels per metre; `None`: the scene's image-frame.json.
    pub scale: Option<f64>,
    /// The channel of a colour photograph that is fitted.
    pub channel: Channel,
    pub mu: f64,
    /// Friction coefficient of the wall contacts without their own
    /// (`None`: `mu`).
    pub wall_mu: Option<f64>,
    /// Balance as a weighted penalty of this weight instead of exactly.
    pub balance_weight: Option<f64>,
    pub blur: f64,
    pub edge: f64,
    pub iterations: usize,
    /// The per-disk fit instead (each disk alone, sides averaged).
    pub per_disk: bool,
    pub contacts: ContactChoice,
    /// Near-miss disk pairs (gap below this share of the smaller radius)
    /// fitted as candidate contacts, listed in the report (0: off). None:
    /// [`DEFAULT_CANDIDATE_GAP`] on a scene from `detect` (its
    /// contacts-evidence.csv present), off on others (a DEM's, PeGS's).
    /// On a scene from `detect` near-miss disk–wall pairs are candidates too.
    pub candidate_gap: Option<f64>,
    /// Weight of the term that fits unsupported contacts to zero (0: off).
    pub sparsity: f64,
    /// Dark or bright field, or read from the photograph.
    pub polariscope: Polariscope,
    /// Each disk's background a plane (light falling off across it).
    pub lighting: bool,
    /// Where disks are still flagged after the narrow start, fit again
    /// from a fit with balance as a penalty of this weight, and keep the
    /// lower residual (0: off; [`DEFAULT_PENALTY_START`]).
    pub penalty_start: f64,
    /// Under exact balance, fit first from a fit with every wedge at this
    /// μ, when it is below `mu`; where that leaves disks flagged, fit the
    /// plain fit too and keep the lower residual (0: off;
    /// [`DEFAULT_NARROW_START`]).
    pub narrow_start: f64,
    /// After the fit and its second starts, each flagged disk refitted
    /// with its and its neighbours' contacts free from up to this many
    /// starts, kept where the whole objective falls (0: off;
    /// [`DEFAULT_LOCAL_STARTS`]).
    pub local_starts: usize,
}

impl Default for PhotoelasticConfig {
    fn default() -> Self {
        PhotoelasticConfig {
            fsigma: None,
            thickness: None,
            scale: None,
            channel: Channel::Green,
            mu: DEFAULT_MU,
            wall_mu: None,
            balance_weight: None,
            blur: 1.0,
            edge: 6.0,
            iterations: 60,
            per_disk: false,
            contacts: ContactChoice::default(),
            candidate_gap: None,
            sparsity: 0.0,
            polariscope: Polariscope::Auto,
            lighting: false,
            penalty_start: DEFAULT_PENALTY_START,
            narrow_start: DEFAULT_NARROW_START,
            local_starts: DEFAULT_LOCAL_STARTS,
        }
    }
}

/// What a run gives.
pub struct PhotoelasticRun {
    /// The scene as read (every contact, in its order).
    pub scene: Scene,
    pub image: FloatImage,
    pub frame: PixelFrame,
    /// The settings of the fit (the fringe stress scaled to the walls when
    /// f_σ was fitted).
    pub settings: FringeFitSettings,
    /// Forces per contact of `scene` (zero for a contact left out).
    pub fit: FringeFit,
    /// Contacts left out of the fit (their ids), and why.
    pub left_out: Vec<String>,
    pub contacts: ContactChoice,
    /// f_σ [N/m] fitted to the walls, and whether the thickness was assumed 1 m.
    pub fsigma_fitted: Option<(f64, bool)>,
    /// The second starts fitted, in turn.
    pub second_starts: Vec<SecondStart>,
    /// The local restarts, one per disk flagged after the second starts.
    pub local_restarts: Vec<LocalRestart>,
}

impl PhotoelasticRun {
    /// forces.csv's rows.
    pub fn forces(&self) -> Forces {
        let forces: Vec<_> = self.fit.forces.iter().map(|f| [f[0], f[1], 0.0]).collect();
        Forces::from_scene(&self.scene, &forces)
    }

    /// What the user should know about the answer (in the report as
    /// `warnings`; the CLI prints them): under exact balance, a fit in which
    /// no contact touches a wall. Without an external load, balance on every
    /// disk leaves compressive contacts only the zero field (the trace of
    /// Σ branch ⊗ force vanishes and each compressive contact adds −r f_n to
    /// it; docs/photoelastic.md), so only disks whose balance is left out
    /// carry load.
    pub fn warnings(&self) -> Vec<String> {
        let holds_a_wall = (self.scene.contacts.iter())
            .any(|c| matches!(c.b, Body::Wall(_)) && !self.left_out.contains(&c.id));
        let mut out = Vec::new();
        if self.settings.balance == Balance::Hard && !holds_a_wall {
            out.push(NO_WALL_WARNING.to_string());
        }
        out
    }

    /// The report as the CLI writes it.
    pub fn report_json(&self) -> serde_json::Value {
        let mut value = serde_json::to_value(&self.fit.report).expect("the report serialises");
        value["contacts"] = serde_json::json!(self.contacts);
        value["left_out"] = serde_json::json!(self.left_out);
        value["warnings"] = serde_json::json!(self.warnings());
        value["second_starts"] = serde_json::json!(self.second_starts);
        value["local_restarts"] = serde_json::json!(self.local_restarts);
        if let Some((f, assumed)) = self.fsigma_fitted {
            value["fsigma_fitted_to_walls"] = serde_json::json!(f);
            value["fsigma_thickness_assumed"] = serde_json::json!(assumed);
        }
        value
    }

    /// The report's text as `--report` writes it.
    pub fn report_text(&self) -> String {
        let text =
            serde_json::to_string_pretty(&self.report_json()).expect("the report serialises");
        text + "\n"
    }

    /// Writes what `grainforce photoelastic -o FORCES --report REPORT
    /// --overlay OVERLAY` writes (`None` skips one), each file atomically;
    /// the overlay, the only part that can fail, is drawn before the first
    /// file is written.
    pub fn write(
        &self,
        forces: Option<&Path>,
        report: Option<&Path>,
        overlay: Option<&Path>,
    ) -> Result<()> {
        let both = overlay.map(|_| self.overlay()).transpose()?;
        if let Some(path) = forces {
            write_forces(path, &self.forces())?;
        }
        if let Some(path) = report {
            write_file_atomically(path, self.report_text().as_bytes())?;
        }
        if let (Some(path), Some(both)) = (overlay, &both) {
            super::save_gray(path, both, 8)?;
        }
        Ok(())
    }

    /// The photograph (left) and the fitted fringes (right) side by side.
    pub fn overlay(&self) -> Result<FloatImage> {
        let fitted = fitted_image(
            &self.image,
            &self.frame,
            &self.scene,
            &self.settings,
            &self.fit.forces,
        )?;
        let (w, h) = self.image.dimensions();
        Ok(FloatImage::from_fn(2 * w, h, |x, y| {
            if x < w {
                *self.image.get_pixel(x, y)
            } else {
                *fitted.get_pixel(x - w, y)
            }
        }))
    }
}

/// The ids of the contacts `detect` judged force-bearing, from
/// contacts-evidence.csv (`None` without the file).
pub fn force_bearing_contacts(scene_dir: &Path) -> Result<Option<Vec<String>>> {
    let path = scene_dir.join(EVIDENCE_FILE);
    if !path.exists() {
        return Ok(None);
    }
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .from_path(&path)
        .map_err(|e| Error::data(&path, None, None, e.to_string()))?;
    let headers = reader
        .headers()
        .map_err(|e| Error::data(&path, Some(1), None, e.to_string()))?
        .clone();
    let column = |name: &str| {
        headers
            .iter()
            .position(|h| h == name)
            .ok_or_else(|| Error::data(&path, Some(1), Some(name), format!("no column `{name}`")))
    };
    let (id, bearing) = (column("contact")?, column("force_bearing")?);
    let frame = headers.iter().position(|h| h == "frame");
    let mut out = Vec::new();
    for (k, record) in reader.records().enumerate() {
        let line = k + 2;
        let record = record.map_err(|e| Error::data(&path, Some(line), None, e.to_string()))?;
        if frame.is_some_and(|f| record.get(f).is_some_and(|v| v != "0")) {
            continue;
        }
        let contact = record.get(id).unwrap_or("");
        match record.get(bearing).unwrap_or("") {
            "yes" if !contact.is_empty() => out.push(contact.to_string()),
            "yes" | "no" => {}
            other => {
                return Err(Error::data(
                    &path,
                    Some(line),
                    Some("force_bearing"),
                    format!("expected yes or no, not `{other}`"),
                ))
            }
        }
    }
    Ok(Some(out))
}

const EVIDENCE_FILE: &str = "contacts-evidence.csv";

/// [`PhotoelasticRun::warnings`] without a wall contact.
const NO_WALL_WARNING: &str = "no fitted contact touches a wall, and a balanced field of \
compressive forces without an external load is zero: only disks whose balance is left out carry \
load. Give the walls that hold the packing (`detect` puts four along the packing's bounding box \
unless told `--walls none`), or a balance penalty (--balance-weight)";

/// The settings that depend on where the scene came from, as a run sets
/// them: `detected` for a scene from `detect` (its contacts-evidence.csv
/// present), `asked` the candidate gap asked for. A detected scene's contact
/// list misses the contacts of circles found small, and it knows nothing of
/// its walls' friction: candidates, and the walls-frictionless-first path
/// beside the other (round 9); its circles found small stop short of walls
/// too, so disk–wall candidates (round 10: the bundled render's disk 3 – top
/// wall, 0.047 of its 0.085 relerr alone). Scenes that list their own
/// contacts (a DEM's, PeGS's) are fitted as given.
pub fn set_for_scene(settings: &mut FringeFitSettings, detected: bool, asked: Option<f64>) {
    settings.candidate_gap = candidate_gap(asked, detected);
    settings.smooth_walls_first = detected;
    settings.wall_candidates = detected;
}

/// The candidate gap a run uses: the one asked for (0: none), else the
/// default on a scene from `detect` and none on others.
fn candidate_gap(asked: Option<f64>, detected: bool) -> Option<f64> {
    match asked {
        Some(gap) => (gap > 0.0).then_some(gap),
        None => detected.then_some(DEFAULT_CANDIDATE_GAP),
    }
}

/// Reads the photograph and the scene folder and fits (see the module).
pub fn run(image: &Path, scene_dir: &Path, config: &PhotoelasticConfig) -> Result<PhotoelasticRun> {
    let scene = read_scene(scene_dir)?;
    let picture = load_channel(image, config.channel)?;
    let frame = match config.scale {
        Some(s) if !(s.is_finite() && s > 0.0) => {
            return Err(Error::Invalid(format!("`scale` must be positive, not {s}")))
        }
        Some(s) => PixelFrame::at_origin(s, picture.width(), picture.height()),
        None => {
            let path = scene_dir.join(FRAME_FILE);
            if !path.exists() {
                return Err(Error::Invalid(format!(
                    "no `scale` given and no {FRAME_FILE} in {}",
                    scene_dir.display()
                )));
            }
            PixelFrame::read(&path)?
        }
    };
    if (frame.width, frame.height) != picture.dimensions() {
        return Err(Error::data(
            image,
            None,
            None,
            format!(
                "the image is {}×{} px but the scene's pixel frame is {}×{}",
                picture.width(),
                picture.height(),
                frame.width,
                frame.height
            ),
        ));
    }
    let thickness = config.thickness.or(scene.settings.thickness);
    if let Some(t) = thickness.filter(|t| !(t.is_finite() && *t > 0.0)) {
        return Err(Error::Invalid(format!(
            "`thickness` must be positive, not {t}"
        )));
    }
    for (name, value) in [
        ("penalty_start", config.penalty_start),
        ("narrow_start", config.narrow_start),
    ] {
        if !(value.is_finite() && value >= 0.0) {
            return Err(Error::Invalid(format!(
                "`{name}` must be 0 or more, not {value}"
            )));
        }
    }
    let walls_measured = scene.walls.iter().any(|w| w.measured_force.is_some());
    let fringe_stress = match (config.fsigma, thickness) {
        (Some(f), _) if !(f.is_finite() && f > 0.0) => {
            return Err(Error::Invalid(format!(
                "`fsigma` must be positive, not {f}"
            )))
        }
        (Some(f), Some(t)) => f / t,
        (Some(_), None) => {
            return Err(Error::Invalid(
                "`fsigma` needs the disks' thickness: give `thickness` or set it in scene.json"
                    .into(),
            ))
        }
        // Forces scale with f_σ: fit at 1 Pa, then scale to the walls.
        (None, _) if walls_measured => 1.0,
        (None, _) => {
            return Err(Error::Invalid(
                "give `fsigma`, or walls.csv with the walls' measured forces to fit it".into(),
            ))
        }
    };
    let mut settings = FringeFitSettings::new(fringe_stress);
    settings.mu = config.mu;
    settings.wall_mu = config.wall_mu;
    settings.blur_px = config.blur;
    settings.edge_px = config.edge;
    settings.max_iterations = config.iterations;
    let detected = scene_dir.join(EVIDENCE_FILE).is_file();
    set_for_scene(&mut settings, detected, config.candidate_gap);
    settings.sparsity = config.sparsity;
    settings.polariscope = config.polariscope;
    settings.lighting = config.lighting;
    if let Some(w) = config.balance_weight {
        settings.balance = Balance::Penalty(w);
    }
    // The contacts fitted: all, or detect's force-bearing ones.
    let kept: Vec<bool> = match config.contacts {
        ContactChoice::All => vec![true; scene.contacts.len()],
        ContactChoice::Evidence => match force_bearing_contacts(scene_dir)? {
            Some(ids) => {
                let ids: std::collections::HashSet<String> = ids.into_iter().collect();
                scene.contacts.iter().map(|c| ids.contains(&c.id)).collect()
            }
            None => vec![true; scene.contacts.len()],
        },
    };
    let mut fitted_scene = scene.clone();
    fitted_scene.contacts = scene
        .contacts
        .iter()
        .zip(&kept)
        .filter(|(_, k)| **k)
        .map(|(c, _)| c.clone())
        .collect();
    let mut second_starts = Vec::new();
    let mut restarts = Vec::new();
    let mut fit = if config.per_disk {
        fit_fringes_per_disk(&picture, &frame, &fitted_scene, &settings)?
    } else {
        let firsts = second_starts_in_order(config.penalty_start, config.narrow_start);
        let (fit, tried) =
            fit_with_second_starts(&picture, &frame, &fitted_scene, &settings, &firsts)?;
        second_starts = tried;
        let (fit, done) = local_restarts(
            &picture,
            &frame,
            &fitted_scene,
            &settings,
            fit,
            config.local_starts,
        )?;
        restarts = done;
        fit
    };
    // Back to the scene's contacts, zero where left out.
    let mut all = vec![[0.0; 2]; scene.contacts.len()];
    let mut next = fit.forces.iter();
    for (slot, k) in all.iter_mut().zip(&kept) {
        if *k {
            *slot = *next.next().expect("one force per fitted contact");
        }
    }
    fit.forces = all;
    let mut fsigma_fitted = None;
    if config.fsigma.is_none() {
        let k = wall_scale(&scene, &fit.forces).ok_or_else(|| {
            Error::Invalid(
                "cannot fit f_σ: no measured wall has a contact with compressive fitted force"
                    .into(),
            )
        })?;
        let candidates = fit.report.candidates.iter_mut().map(|c| &mut c.force);
        for f in fit.forces.iter_mut().chain(candidates) {
            f[0] *= k;
            f[1] *= k;
        }
        settings.fringe_stress *= k;
        fit.report.fringe_stress = settings.fringe_stress;
        fsigma_fitted = Some((
            settings.fringe_stress * thickness.unwrap_or(1.0),
            thickness.is_none(),
        ));
    }
    let left_out = scene
        .contacts
        .iter()
        .zip(&kept)
        .filter(|(_, k)| !**k)
        .map(|(c, _)| c.id.clone())
        .collect();
    Ok(PhotoelasticRun {
        scene,
        image: picture,
        frame,
        settings,
        fit,
        left_out,
        contacts: config.contacts,
        fsigma_fitted,
        second_starts,
        local_restarts: restarts,
    })
}

/// The weight of [`PhotoelasticConfig::penalty_start`] by default: of 1,
/// 10 and 100 on the three PeGS photographs with box walls, 10 ended lowest
/// on step83 (objective 3262.9 → 1706.0; docs/photoelastic.md, round 10).
/// At round 16's defaults it is kept on no render but on fixed48, which
/// without it falls from 0.97 to 0.86 of disks as close as PeGS ("The
/// second starts at round 16's defaults").
pub const DEFAULT_PENALTY_START: f64 = 10.0;

/// The μ of [`PhotoelasticConfig::narrow_start`] by default: narrower than
/// the rendered packings' friction (their DEM's, 0.5, round 11's choice),
/// where the wider wedges of the default μ reach a worse basin from the
/// fringe start. On DEM packing 2 with the outermost outlines 0.5 ended in
/// another basin (objective 1082, relerr 0.073), 0.3 in the lower one (462,
/// 0.0076); the other renders and the PeGS photographs do as well or better
/// (docs/photoelastic.md, round 16).
pub const DEFAULT_NARROW_START: f64 = 0.3;

/// [`PhotoelasticConfig::local_starts`] by default: off. Measured with 5
/// on the renders and the three PeGS photographs, no answer was better and
/// fixed48 with μ 1000 and lighting worse (0.89 → 0.83 of the disks at
/// least as close as PeGS, its objective lower), at 20–90 % more time
/// (docs/photoelastic.md, round 13).
pub const DEFAULT_LOCAL_STARTS: usize = 0;

/// How the first fit of a second start differs from the plain fit.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FirstFit {
    /// Balance as a penalty of this weight.
    Penalty(f64),
    /// Every wedge at this μ, narrower than the fit's.
    Narrow(f64),
}

/// A second start of a run, fitted where the fit so far leaves disks
/// flagged: a first fit ([`FirstFit`]), then the run's own fit (exact
/// balance, its μ) from the first fit's forces.
#[derive(Debug, Clone, serde::Serialize)]
pub struct SecondStart {
    pub first: FirstFit,
    /// The final objective of the fit it was compared with (none where it
    /// was kept without one: fitted before the plain fit and flagging no
    /// disk), and its own.
    pub compared_objective: Option<f64>,
    pub objective: f64,
    /// Disks whose balance it leaves out.
    pub balance_left_out: usize,
    /// Disks whose fringes its answer leaves unexplained (flagged).
    pub flagged: usize,
    /// The wall paths its first fit fitted through the intensity stages
    /// (that fit's `paths`: a narrow start's is 1, round 19).
    pub first_paths: usize,
    /// Both its fits' steps.
    pub steps: usize,
    /// Kept: its objective is the lower and it leaves out the balance of no
    /// disk the fit it was compared with keeps balanced.
    pub kept: bool,
    /// Both its fits [s] (in the report's `seconds`, not here: a report's
    /// other fields are the same run to run).
    #[serde(skip)]
    pub seconds: f64,
}

/// The second starts of a run in the order they are tried: the narrow
/// start first (before the plain fit, round 18), the penalty start only
/// where the fit is still poor after it. At round 16's defaults the narrow start was kept on four of five
/// renders and step83 at μ 1000, leaving no render's disk flagged; the
/// penalty start only on fixed48 and narrow21 at μ 1000, where the narrow
/// start was not (docs/photoelastic.md, round 17).
pub fn second_starts_in_order(penalty_start: f64, narrow_start: f64) -> [FirstFit; 2] {
    [
        FirstFit::Narrow(narrow_start),
        FirstFit::Penalty(penalty_start),
    ]
}

/// The fit from the fringe start (the plain fit), or the best of it and
/// the second starts `firsts`, fitted in turn, each only while the best so
/// far leaves disks flagged (fringes unexplained) under exact balance, and
/// kept where it ends lower under the same balance. The fit they end with is
/// the run's own problem (μ, exact balance); only the start differs. A
/// penalty start lets the first fit leave the basin the exact balance holds
/// it in (round 10, step83: objective 3262.9 → 1706.0); a narrow one the
/// basin of sideways loads that wide wedges admit from the fringe start
/// (round 11). All are judged on the same pixels and polariscope (the plain
/// fit's), so the lower residual decides (docs/photoelastic.md, round 11).
///
/// A narrow start first in `firsts` is fitted before the plain fit, and
/// where its answer flags no disk the plain fit is not fitted at all: on
/// every render that answer was kept and flagged none, so the plain fit
/// (half the run's steps) was paid for nothing (round 18). Its record then
/// has no `compared_objective`. Where the plain fit is made, it takes the
/// narrow start's polariscope. The narrow start's first fit runs one wall
/// path (`start_fits`), so a run decides its polariscope once.
pub fn fit_with_second_starts(
    image: &FloatImage,
    frame: &PixelFrame,
    scene: &Scene,
    settings: &FringeFitSettings,
    firsts: &[FirstFit],
) -> Result<(FringeFit, Vec<SecondStart>)> {
    let useful = |first: &FirstFit| match *first {
        FirstFit::Penalty(w) => w > 0.0,
        FirstFit::Narrow(mu) => mu > 0.0 && mu < settings.mu,
    };
    if settings.balance != Balance::Hard || settings.start.is_some() {
        return Ok((fit_fringes(image, frame, scene, settings)?, Vec::new()));
    }
    let mut firsts = firsts.iter().copied().filter(useful).peekable();
    let mut early = None;
    if let Some(&first @ FirstFit::Narrow(_)) = firsts.peek() {
        firsts.next();
        let fits = start_fits(image, frame, scene, settings, settings.polariscope, first)?;
        // Without a plain fit, the refit (the run's μ) says which disks may
        // be out of balance.
        let refit_left_out = fits.second.report.balance_left_out.clone();
        let answer = start_answer(settings, first, &fits, &refit_left_out);
        if answer.report.flagged.is_empty() {
            let (fit, record) = kept_alone(first, answer, &fits);
            return Ok((fit, vec![record]));
        }
        early = Some((first, fits));
    }
    // The plain fit takes the polariscope the narrow start chose, so both
    // are judged under one: deciding it again costs a 0.08 R stage per path
    // (unthinned on step83's r ≈ 33 px: 10 % of its run, round 18), and it
    // chose the same on every case.
    let plain_settings = match &early {
        Some((_, fits)) => FringeFitSettings {
            polariscope: polariscope_of(&fits.started),
            ..settings.clone()
        },
        None => settings.clone(),
    };
    let plain = fit_fringes(image, frame, scene, &plain_settings)?;
    let polariscope = polariscope_of(&plain);
    let mut best = plain;
    let mut tried = Vec::new();
    // The narrow start fitted before the plain fit is judged against it.
    if let Some((first, fits)) = early {
        let (fit, record) = judged(settings, best, first, fits);
        best = fit;
        tried.push(record);
    }
    // In turn, not at once: a start is fitted only where the one before
    // left disks flagged (round 17: the penalty start costs a third of the
    // CPU where the narrow start already explains every disk). Each start's
    // disks are still evaluated on both cores.
    for first in firsts {
        if best.report.flagged.is_empty() {
            break;
        }
        let fits = start_fits(image, frame, scene, settings, polariscope, first)?;
        let (fit, record) = judged(settings, best, first, fits);
        best = fit;
        tried.push(record);
    }
    Ok((best, tried))
}

/// The polariscope a fit ended with.
fn polariscope_of(fit: &FringeFit) -> Polariscope {
    match fit.report.bright_field {
        true => Polariscope::Bright,
        false => Polariscope::Dark,
    }
}

/// A second start's two fits: the first fit's answer, the exact refit from
/// it, and the seconds both took.
struct StartFits {
    started: FringeFit,
    second: FringeFit,
    seconds: f64,
}

impl StartFits {
    fn steps(&self) -> usize {
        self.started.report.iterations + self.second.report.iterations
    }
}

/// The first fit ([`FirstFit`]) under `polariscope`, then the run's own fit
/// (exact balance, its μ) from its forces under the polariscope the first
/// fit ended with. A narrow first fit runs the walls-frictionless-first
/// path alone (round 19: on the bundled `detect` scene the two paths tied
/// and the run's steps fell from 136 to 74, its answer the same).
fn start_fits(
    image: &FloatImage,
    frame: &PixelFrame,
    scene: &Scene,
    settings: &FringeFitSettings,
    polariscope: Polariscope,
    first: FirstFit,
) -> Result<StartFits> {
    let clock = std::time::Instant::now();
    let mut first_settings = FringeFitSettings {
        polariscope,
        ..settings.clone()
    };
    match first {
        FirstFit::Penalty(w) => first_settings.balance = Balance::Penalty(w),
        FirstFit::Narrow(mu) => {
            first_settings.mu = mu;
            first_settings.wall_mu = settings.wall_mu.map(|w| w.min(mu));
            // Only a start: its answer is refitted at the run's μ, so one
            // wall path (the one that won or tied on every render, round 18).
            first_settings.walls_first_alone = true;
        }
    }
    let started = fit_fringes(image, frame, scene, &first_settings)?;
    let exact = FringeFitSettings {
        start: Some(started.forces.clone()),
        polariscope: polariscope_of(&started),
        ..settings.clone()
    };
    let second = fit_fringes(image, frame, scene, &exact)?;
    Ok(StartFits {
        started,
        second,
        seconds: clock.elapsed().as_secs_f64(),
    })
}

/// A second start's answer where the disks in `left_out` may be out of
/// balance: its refit, or a narrow start's own answer where that is lower
/// and leaves out no other disk's balance.
fn start_answer(
    settings: &FringeFitSettings,
    first: FirstFit,
    fits: &StartFits,
    left_out: &[String],
) -> FringeFit {
    let (started, second) = (&fits.started, &fits.second);
    // A narrow start's own answer is admissible under the run's wider
    // wedges: where it balances the disks `left_out` spares and the refit,
    // whose smoothed stages start over from it, ends higher, the answer
    // itself is the better one found.
    let lower = started.report.objective < second.report.objective;
    if matches!(first, FirstFit::Narrow(_)) && lower && balanced_as(started, left_out) {
        let mut own = started.clone();
        own.report.mu = settings.mu;
        return own;
    }
    second.clone()
}

/// Whether `fit` leaves out the balance of no disk but those in `left_out`.
fn balanced_as(fit: &FringeFit, left_out: &[String]) -> bool {
    (fit.report.balance_left_out.iter()).all(|g| left_out.contains(g))
}

/// A second start kept without a fit to compare with (its answer flags no
/// disk, so the plain fit was not fitted), and its record.
fn kept_alone(
    first: FirstFit,
    mut answer: FringeFit,
    fits: &StartFits,
) -> (FringeFit, SecondStart) {
    let record = SecondStart {
        first,
        compared_objective: None,
        objective: answer.report.objective,
        balance_left_out: answer.report.balance_left_out.len(),
        flagged: answer.report.flagged.len(),
        first_paths: fits.started.report.paths,
        steps: fits.steps(),
        kept: true,
        seconds: fits.seconds,
    };
    answer.report.objective_start = fits.started.report.objective_start;
    answer.report.iterations = fits.steps();
    answer.report.seconds = fits.seconds;
    (answer, record)
}

/// One second start judged against `best`: the better of the two, and the record.
fn judged(
    settings: &FringeFitSettings,
    best: FringeFit,
    first: FirstFit,
    fits: StartFits,
) -> (FringeFit, SecondStart) {
    // Refitted from a start the balance pins, the exact fit leaves out the
    // balance of the disks that pin it (release_forced_zeros): fewer
    // constraints, so a lower objective alone would favour it (round 11: a
    // penalty start at μ 0.5 left 11 of fixed48's disks out). Only the same
    // disks' balance may be out.
    let best_left_out = &best.report.balance_left_out;
    let mut second = start_answer(settings, first, &fits, best_left_out);
    let same_balance = balanced_as(&second, best_left_out);
    let record = SecondStart {
        first,
        compared_objective: Some(best.report.objective),
        objective: second.report.objective,
        balance_left_out: second.report.balance_left_out.len(),
        flagged: second.report.flagged.len(),
        first_paths: fits.started.report.paths,
        steps: fits.steps(),
        kept: same_balance && second.report.objective < best.report.objective,
        seconds: fits.seconds,
    };
    let steps = fits.steps();
    let mut kept = if record.kept {
        second.report.objective_start = best.report.objective_start;
        second.report.iterations = best.report.iterations + steps;
        second
    } else {
        let mut best = best;
        best.report.iterations += steps;
        best
    };
    kept.report.seconds += fits.seconds;
    (kept, record)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn candidates_by_default_on_detected_scenes_only() {
        assert_eq!(candidate_gap(None, true), Some(DEFAULT_CANDIDATE_GAP));
        assert_eq!(candidate_gap(None, false), None);
        assert_eq!(candidate_gap(Some(0.0), true), None);
        assert_eq!(candidate_gap(Some(0.1), false), Some(0.1));
    }
}
