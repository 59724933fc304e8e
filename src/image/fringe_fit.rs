//! Contact forces from a photoelastic photograph: one fit of every contact
//! force to the fringes of all disks at once, under each disk's balance and
//! Coulomb friction.
//!
//! Unknowns: one force per contact, (u_n, u_t) in the contact's frame (u_n
//! the compressive normal part on grain `a`, so action equals reaction by
//! construction). Each disk's stress is [`disk_stress`](super::photoelastic::disk_stress)
//! of its loads, its fringe order N = (σ₁ − σ₂)/f_σ, and a pixel's intensity
//! b_d + c_d S with S = ½ − ½ cos(2πN) e^{−2π² s²}: sin²(πN) averaged over the
//! pixel and the optics' blur, s the blur radius times |∇N| (dense fringes
//! fade to grey, as a camera sees them). b_d and c_d, each disk's background
//! and contrast, are fitted in closed form at every step.
//!
//! Each Gauss–Newton / Levenberg–Marquardt step is one constrained least
//! squares, min Σ_d ‖J_d δ − r_d‖² + μ ‖D δ‖² subject to K_eq (f + δ) = 0 and
//! the Coulomb wedge on f + δ: a [`ConicProblem`] with two terms. J_d is dense
//! only over disk d's own contacts, so each disk enters as a few rows
//! (its k × k normal matrix factored), whatever its pixel count.
//!
//! The start avoids the per-disk fit's failure: each disk's load level from
//! its fringe gradients G² = ⟨|∇I|²⟩ matched to the model's G² of the same
//! disk under equal normal loads (calibrated on the image's own contrast),
//! turned into a balanced, friction-admissible field by one constrained
//! least squares, then fitted with the blur widened and narrowed in three
//! stages (a smoother objective first, fewer local minima).

use super::detect::profile::Laps;
use super::fringe_kernel::{self, Jacobian, KernelLoad, KernelOptics, Precision};
use super::{FloatImage, PixelFrame};
use crate::error::{Error, Result};
use crate::scene::{Body, Contact, Scene};
use crate::solver::cascade::{self, CascadeSettings, FactorSlot, Pattern};
use crate::solver::Triplets;
use crate::solver::{Cone, ConicProblem, Solution, Term};
use rayon::prelude::*;
use std::f64::consts::PI;

#[path = "fringe_multistart.rs"]
mod fringe_multistart;
pub use fringe_multistart::{local_restarts, LocalRestart, LocalStart};

/// How each disk's balance of force and moment enters the fit.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub enum Balance {
    /// Exact: K_eq f = 0 (the default).
    Hard,
    /// A weighted penalty w Σ_d ‖(ΣF, ΣM/R)_d / F₀‖² beside the fringe
    /// residual (F₀ = f_σ R, the force of about one fringe), where a frame
    /// is known not to balance (missing contacts, dynamics).
    Penalty(f64),
}

#[derive(Debug, Clone)]
pub struct FringeFitSettings {
    /// The stress of one fringe order, f_σ / t [Pa] (fringe constant [N/m]
    /// over the thickness [m]); forces come out in N/m, per unit thickness.
    pub fringe_stress: f64,
    /// Friction coefficient where a contact has none of its own.
    pub mu: f64,
    /// Friction coefficient of the contacts with walls that have none of
    /// their own (None: as the others). A detected scene knows nothing of
    /// its walls' friction; smooth walls carry no tangential force.
    pub wall_mu: Option<f64>,
    pub balance: Balance,
    /// Gaussian blur of the optics [px] (the pixel's own area is added).
    pub blur_px: f64,
    /// Pixels closer than this to a disk's edge are not fitted (its dark rim).
    pub edge_px: f64,
    /// Largest number of Levenberg–Marquardt steps, all stages together.
    pub max_iterations: usize,
    /// The final stage also stops at a step (accepted at its first trial)
    /// that moves the forces by at most this share of what the pixel noise
    /// moves them by (the report's `timing.ends`). 0 (the default): at its
    /// relative tolerance or step budget alone. Off: at 0.1 it saved 1–9
    /// of 126–280 steps and no measurable CPU, at 0.3 step83's share fell
    /// below its floor (docs/photoelastic.md, round 18).
    pub data_accuracy: f64,
    /// A disk whose fit explains less than this share of its intensity
    /// variance (and shows fringes) is flagged.
    pub poor_fit: f64,
    /// Start from these forces (scene contact order, force on `a` by `b`
    /// [N/m]; e.g. the previous frame's) instead of the fringe gradients.
    pub start: Option<Vec<[f64; 2]>>,
    /// Contacts the fringes do not support are fitted to zero and dropped
    /// (0: off). The final stage adds α Σ_c u_n²/(u_n² + ε²) (a smoothed
    /// count of loaded contacts, reweighted each step) with α this many
    /// times the per-pixel residual variance at the stage's start: a contact
    /// stays only if it explains that many pixels' worth of residual. Those
    /// left below ε are dropped and the rest refitted without the term, so
    /// the kept forces carry no bias from it.
    pub sparsity: f64,
    /// Disk pairs closer than this share of the smaller radius and not in
    /// the scene are fitted too, as candidate contacts (normal and point on
    /// the centre line; None or 0: off). Reported in `candidates`. The
    /// photoelastic run turns them on ([`DEFAULT_CANDIDATE_GAP`]) for a
    /// scene from `detect`: a detected circle found a few pixels small loses
    /// its contacts, and the fringes load the true ones back
    /// (docs/photoelastic.md, round 9).
    pub candidate_gap: Option<f64>,
    /// With `candidate_gap`, disk–wall pairs within it are candidates too:
    /// a disk whose circle stops short of a wall by less than the gap (over
    /// its radius) and is not listed against it. A wall's line is read from
    /// its listed contacts (their mean point and normal); a wall without
    /// contacts, or whose contacts are not on one line, gets none. Fitted
    /// as one more path, kept where it ends with the lower residual. The
    /// photoelastic run turns it on for a scene from `detect`
    /// (docs/photoelastic.md, round 10).
    pub wall_candidates: bool,
    /// After the fit, contacts whose [`contact_support`] is below this are
    /// dropped and the rest refitted (None: off).
    pub support_prune: Option<f64>,
    /// Try each accepted step longer, by the gain it made over the
    /// Gauss–Newton prediction (off: measured on the detected render it
    /// converges in fewer steps, 54–57 of 60, to the minimum the plain fit
    /// reaches in 73, but that answer, relerr 0.189, is not better than the
    /// plain fit's unconverged one, 0.184; docs/photoelastic.md).
    pub extrapolate: bool,
    /// Each disk's background is a plane, fitted with its contrast in
    /// closed form at every step, instead of a constant: light that falls
    /// off across a disk is not taken for fringes (off by default;
    /// docs/photoelastic.md "Judged alike").
    pub lighting: bool,
    /// The polariscope: dark field (bright fringes on dark, unloaded disks),
    /// bright field (dark fringes on bright disks: each disk's contrast is
    /// fitted negative), or read from the photograph at the start.
    pub polariscope: Polariscope,
    /// Where walls have friction and the fit starts from the fringe
    /// gradients, a second path is fitted too — the start and the coarse
    /// stages with every wall contact nearly frictionless (μ 0.02), the walls' friction in
    /// the final stage only — and the lower final residual kept (exact
    /// balance only; the photoelastic run turns it on for a scene from
    /// `detect`: on detected geometry the walls' friction from the start
    /// leads to sideways wall loads and loaded false wall contacts; where
    /// walls carry friction the other path wins; docs/photoelastic.md,
    /// round 9). Costs a second fit in that case.
    pub smooth_walls_first: bool,
    /// With `smooth_walls_first`, the walls-frictionless-first path alone:
    /// for a fit that is only a start (the narrow start's first fit, whose
    /// answer is refitted; docs/photoelastic.md, round 19).
    pub walls_first_alone: bool,
    /// Work the fits of one run share (each disk's G² levels): a run's
    /// paths and second starts are fitted from clones of one settings value
    /// and find it done (docs/photoelastic.md, round 13).
    pub shared: SharedWork,
}

/// Each disk's G² load levels ([`load_levels`]) as scanned by any fit made
/// with a clone of the same [`FringeFitSettings`], under a key of all they
/// depend on (the disk's loads, pixels and intensities, the optics), so a
/// path or a second start reuses the same numbers bit for bit instead of
/// scanning them again. Clones share it; it is not part of a settings
/// value's equality.
#[derive(Clone, Default)]
pub struct SharedWork(std::sync::Arc<std::sync::Mutex<LevelMemo>>);

type LevelMemo = std::collections::HashMap<Vec<u64>, Vec<f64>>;

/// Entries past which [`SharedWork`] starts over (a long-lived settings
/// value fitted to frame after frame would otherwise keep every frame's).
const SHARED_WORK_ENTRIES: usize = 100_000;

impl SharedWork {
    fn get(&self, key: &[u64]) -> Option<Vec<f64>> {
        let memo = self.0.lock().unwrap_or_else(|e| e.into_inner());
        memo.get(key).cloned()
    }

    fn put(&self, key: Vec<u64>, levels: &[f64]) {
        let mut memo = self.0.lock().unwrap_or_else(|e| e.into_inner());
        if memo.len() >= SHARED_WORK_ENTRIES {
            memo.clear();
        }
        memo.insert(key, levels.to_vec());
    }
}

impl std::fmt::Debug for SharedWork {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("SharedWork")
    }
}

impl PartialEq for SharedWork {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

/// How the photograph was lit: [`FringeFitSettings::polariscope`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Polariscope {
    /// Crossed polarisers: I = b + c sin²(πN), dark where unloaded.
    Dark,
    /// Parallel polarisers: I = b − c sin²(πN), bright where unloaded.
    Bright,
    /// Both fitted, the one closer to the photograph kept (twice the time).
    #[default]
    Auto,
}

impl std::str::FromStr for Polariscope {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "dark" => Ok(Polariscope::Dark),
            "bright" => Ok(Polariscope::Bright),
            "auto" => Ok(Polariscope::Auto),
            other => Err(format!(
                "unknown polariscope {other:?} (expected dark, bright or auto)"
            )),
        }
    }
}

/// The default [`FringeFitSettings::candidate_gap`], a share of the smaller
/// radius: wide enough for the detected circles' worst radius errors (up to
/// 0.1 R small on the rendered packings), narrow enough that the false
/// candidates stay few (round 4: at 0.3 R they took their neighbours' load).
pub const DEFAULT_CANDIDATE_GAP: f64 = 0.2;

impl FringeFitSettings {
    pub fn new(fringe_stress: f64) -> Self {
        FringeFitSettings {
            fringe_stress,
            mu: 0.5,
            wall_mu: None,
            balance: Balance::Hard,
            blur_px: 1.0,
            edge_px: 6.0,
            max_iterations: 60,
            data_accuracy: 0.0,
            poor_fit: 0.5,
            start: None,
            sparsity: 0.0,
            candidate_gap: None,
            wall_candidates: false,
            support_prune: None,
            extrapolate: false,
            lighting: false,
            polariscope: Polariscope::Auto,
            smooth_walls_first: false,
            walls_first_alone: false,
            shared: SharedWork::default(),
        }
    }

    fn validate(&self) -> Result<()> {
        let ok = |v: f64| v.is_finite() && v >= 0.0;
        if !(self.fringe_stress.is_finite() && self.fringe_stress > 0.0) {
            return Err(Error::Invalid(format!(
                "the fringe stress f_σ/t must be positive, not {}",
                self.fringe_stress
            )));
        }
        if !(ok(self.mu)
            && self.wall_mu.is_none_or(ok)
            && ok(self.blur_px)
            && ok(self.edge_px)
            && ok(self.sparsity)
            && ok(self.data_accuracy)
            && self.candidate_gap.is_none_or(ok)
            && self.support_prune.is_none_or(f64::is_finite))
        {
            return Err(Error::Invalid(
                "fringe fit: friction, blur, edge band, sparsity, data accuracy and candidate gap must be finite and not negative".into(),
            ));
        }
        if let Balance::Penalty(w) = self.balance {
            if !(w.is_finite() && w > 0.0) {
                return Err(Error::Invalid(format!(
                    "the balance weight must be positive, not {w}"
                )));
            }
        }
        if self.max_iterations == 0 {
            return Err(Error::Invalid(
                "the fringe fit needs at least one iteration".into(),
            ));
        }
        Ok(())
    }
}

/// How well one disk's fringes are explained.
#[derive(Debug, Clone, serde::Serialize)]
pub struct DiskFit {
    pub grain: String,
    /// Pixels fitted.
    pub pixels: usize,
    pub background: f64,
    pub contrast: f64,
    /// Root-mean-square intensity residual.
    pub rms: f64,
    /// Share of the disk's intensity variance the fit explains, 1 − SSR/SST.
    pub explained: f64,
    /// |ΣF| / Σ|F| of the fitted forces on this disk.
    pub imbalance: f64,
    /// The load level its fringe gradients gave at the start [N/m]: equal
    /// normal loads at its contacts showing the photograph's G².
    pub start_level: f64,
    /// The photograph's G² = ⟨|∇I|²⟩ over the fitted pixels [per px²].
    pub g2: f64,
    /// The fit does not explain this disk's fringes.
    pub flagged: bool,
}

/// Where the fit's time went [s, wall clock].
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct FitTiming {
    /// Reading the disks' pixels.
    pub prepare: f64,
    /// The fringe-gradient load levels and the balanced start.
    pub start: f64,
    /// Smoothing the photograph (envelope and smoothed stages).
    pub smoothing: f64,
    /// The model, its residual and normal equations at each step.
    pub evaluate: f64,
    /// The constrained solves of the steps.
    pub solve: f64,
    /// The objective at each trial step.
    pub trials: f64,
    /// Constrained solves (trial steps included).
    pub solves: usize,
    /// Solves whose answer missed the imposed balance (rejected).
    pub unbalanced_steps: usize,
    /// Steps per stage (envelope, smoothed …, final: on a quarter of the
    /// pixels, then on all).
    pub steps: Vec<usize>,
    /// Accepted steps tried longer, and those the longer one bettered.
    pub extrapolations: usize,
    pub extrapolated: usize,
    /// How each stage of `steps` ended, against the data's accuracy.
    pub ends: Vec<StageEnd>,
}

impl FitTiming {
    /// `earlier`'s stages put before this fit's own (a refit after a fit).
    fn after(&mut self, earlier: &FitTiming) {
        self.steps.splice(0..0, earlier.steps.iter().copied());
        self.ends.splice(0..0, earlier.ends.iter().copied());
    }
}

/// How a Levenberg–Marquardt stage ended: its last accepted step against
/// what the noise moves the forces by, on the stage's own data (the
/// solver's measure, `sparse_interior_point::noise_size`).
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct StageEnd {
    /// ‖J s‖ / (σ̂ √k) of the last accepted step s (0: no step). ‖J s‖/σ̂
    /// bounds how far any force, or sum of forces, moved in its own
    /// standard deviations (covariance σ̂² (JᵀJ)⁻¹ on the balanced
    /// problem's k free directions); σ̂ √k is about the length of the
    /// noise's own effect on the forces in that norm.
    pub last_move: f64,
    /// σ̂, the residual's noise per pixel: √(objective / (pixels − k)).
    pub noise: f64,
    /// k: the unknowns less the imposed balance rows.
    pub free: usize,
    /// The stage stopped on that step, its move within the data's accuracy.
    pub at_data_accuracy: bool,
}

impl std::fmt::Display for FitTiming {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "prepare {:.3} s, start {:.3} s, smoothing {:.3} s, evaluate {:.3} s, solve {:.3} s ({} solves, {} off balance), trials {:.3} s, steps per stage {:?}, their last steps against the noise's effect {} (* at the data's accuracy), {} of {} steps extrapolated",
            self.prepare,
            self.start,
            self.smoothing,
            self.evaluate,
            self.solve,
            self.solves,
            self.unbalanced_steps,
            self.trials,
            self.steps,
            self.ends
                .iter()
                .map(|e| format!("{:.2}{}", e.last_move, if e.at_data_accuracy { "*" } else { "" }))
                .collect::<Vec<_>>()
                .join(", "),
            self.extrapolated,
            self.extrapolations
        )
    }
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct FringeFitReport {
    pub method: &'static str,
    pub fringe_stress: f64,
    pub balance: Balance,
    pub mu: f64,
    pub blur_px: f64,
    /// The bright-field model was fitted (dark fringes, negative contrast).
    pub bright_field: bool,
    pub iterations: usize,
    /// The fit's paths fitted through the intensity stages: 2 where both
    /// wall paths were ([`FringeFitSettings::smooth_walls_first`]), 1 where
    /// one path was fitted or one was well behind after the envelope stage.
    pub paths: usize,
    /// Σ of squared intensity residuals at the start and at the end.
    pub objective_start: f64,
    pub objective: f64,
    /// The Levenberg–Marquardt damping of the last step.
    pub damping: f64,
    /// Median and largest imbalance over the disks whose balance was imposed.
    pub median_imbalance: f64,
    pub max_imbalance: f64,
    /// Disks whose contacts admit no balanced, compressive,
    /// friction-admissible load set (one contact, or two not within the
    /// friction angle of opposite: a contact missed by detection): their
    /// balance is left out of the fit, their loads are the fringes' alone.
    pub balance_left_out: Vec<String>,
    pub flagged: Vec<String>,
    pub seconds: f64,
    pub timing: FitTiming,
    pub disks: Vec<DiskFit>,
    /// Contacts (scene ids, then candidates') the sparsity term fitted to
    /// zero and the refit left out.
    pub dropped: Vec<String>,
    /// Near-miss disk pairs fitted as candidate contacts (`candidate_gap`).
    pub candidates: Vec<CandidateContact>,
    /// The photograph was fitted binned this many pixels a side (1: as it
    /// is; large disks, [`FIT_RADIUS_PX`]); `disks`' pixels and G² are the
    /// binned photograph's.
    pub pixel_bin: u32,
}

/// A near-miss disk pair (or disk and wall) fitted as a contact: grain `a`
/// and grain or wall `b` by index into the scene, force on `a` by `b` [N/m]
/// (zero when dropped).
#[derive(Debug, Clone, serde::Serialize)]
pub struct CandidateContact {
    pub id: String,
    pub a: usize,
    pub b: usize,
    /// `b` is a wall (index into the scene's walls), not a grain.
    pub wall: bool,
    pub point: [f64; 2],
    pub normal: [f64; 2],
    /// Gap between the disks over the smaller radius.
    pub gap: f64,
    pub force: [f64; 2],
    pub dropped: bool,
}

/// The fitted forces (force on grain `a` by `b`, scene axes, N/m, in the
/// scene's contact order) and the report.
#[derive(Debug, Clone)]
pub struct FringeFit {
    pub forces: Vec<[f64; 2]>,
    pub report: FringeFitReport,
}

impl FringeFit {
    /// `scene` with the fit's candidate contacts appended as contacts, and
    /// the forces of both in that order (to score candidates with the rest).
    pub fn with_candidates(&self, scene: &Scene) -> (Scene, Vec<[f64; 2]>) {
        let mut scene = scene.clone();
        let mut forces = self.forces.clone();
        for c in &self.report.candidates {
            scene.contacts.push(Contact {
                id: c.id.clone(),
                a: c.a,
                b: if c.wall {
                    Body::Wall(c.b)
                } else {
                    Body::Grain(c.b)
                },
                point: [c.point[0], c.point[1], 0.0],
                normal: [c.normal[0], c.normal[1], 0.0],
                mu: None,
            });
            forces.push(c.force);
        }
        (scene, forces)
    }
}

/// One load on a disk: contact `contact`'s force, on this disk with `sign`.
#[derive(Debug, Clone, Copy)]
struct Load {
    /// The unknowns' pair (2 × unknown, 2 × unknown + 1).
    unknown: usize,
    sign: f64,
    /// On the disk's boundary [m].
    point: [f64; 2],
    normal: [f64; 2],
    tangent: [f64; 2],
}

impl Load {
    /// The force on the disk per unit (u_n, u_t).
    fn directions(&self) -> [[f64; 2]; 2] {
        let s = self.sign;
        [
            [-s * self.normal[0], -s * self.normal[1]],
            [s * self.tangent[0], s * self.tangent[1]],
        ]
    }
}

struct DiskData {
    grain: usize,
    centre: [f64; 2],
    radius: f64,
    loads: Vec<Load>,
    /// Fitted pixels: scene position and intensity.
    points: Vec<[f64; 2]>,
    intensity: Vec<f64>,
    /// Pixel (column, row) of each point, for gradients and the overlay.
    pixels: Vec<(u32, u32)>,
}

/// What one evaluation of a disk gives.
#[derive(Default, Clone)]
struct DiskEval {
    background: f64,
    contrast: f64,
    ssr: f64,
    sst: f64,
    /// Normal matrix JᵀJ (k × k, row-major) and Jᵀr over the disk's local unknowns.
    normal: Vec<f64>,
    rhs: Vec<f64>,
    model: Vec<f64>,
}

/// Model constants of one evaluation.
#[derive(Clone, Copy)]
struct Optics {
    /// Fringe stress in force units of the unknowns, per metre.
    fringe: f64,
    /// Blur variance [m²].
    blur2: f64,
    /// Contrast when a disk's own cannot be fitted, and the range allowed.
    contrast: f64,
    /// Fit the fringe envelope instead of the intensity: the model is
    /// c π |∇N| e^{−2π² s²} / √2 per pixel (the root of the local mean of
    /// |∇I|²), with the image scale [px/m] given here.
    envelope: Option<f64>,
    /// Each disk's background is a plane b + g·(p − centre) (its light
    /// falling off across it) instead of a constant.
    lighting: bool,
    /// Contrasts are negative (dark fringes, bright field).
    bright_field: bool,
    /// The kernel's float: single in every fit, double for the tests of
    /// the model's derivatives against finite differences.
    precision: Precision,
}

/// The Flamant field at p of a unit force along `dir` at q and its spatial
/// derivatives, in closed form: with e = p − q and z = e_x + i e_y,
/// D = (σ_xx − σ_yy) + i 2σ_xy = −(2/π) (e·dir) / z̄², so
/// ∂D/∂x = −(2/π) (dir_x z̄⁻² − 2 (e·dir) z̄⁻³) and
/// ∂D/∂y = −(2/π) (dir_y z̄⁻² + 2i (e·dir) z̄⁻³).
/// Returns [Re D, Im D, ∂Re D/∂x, ∂Re D/∂y, ∂Im D/∂x, ∂Im D/∂y]; points
/// nearer q than `floor` are taken at that distance (no gradient there).
#[cfg(test)]
fn flamant(q: [f64; 2], p: [f64; 2], dir: [f64; 2], floor: f64) -> [f64; 6] {
    FlamantGeometry::new(q, p, floor).field(dir)
}

/// The part of the Flamant field at p of a load at q that does not depend
/// on the load's direction: e = p − q (floored), z̄⁻² and z̄⁻³. Both
/// directions of a load share it. The model one pixel at a time, as stated
/// here, is the reference the batched kernel ([`super::fringe_kernel`])
/// is tested against.
#[cfg(test)]
#[derive(Clone, Copy)]
struct FlamantGeometry {
    e: [f64; 2],
    w2: [f64; 2],
    w3: [f64; 2],
    /// Nearer q than the floor: no gradient (and nothing at all at q).
    near: bool,
    at_load: bool,
}

#[cfg(test)]
impl FlamantGeometry {
    #[inline]
    fn new(q: [f64; 2], p: [f64; 2], floor: f64) -> Self {
        let (mut ex, mut ey) = (p[0] - q[0], p[1] - q[1]);
        let r2 = ex * ex + ey * ey;
        let near = r2 < floor * floor;
        if near {
            if r2 == 0.0 {
                return FlamantGeometry {
                    e: [0.0; 2],
                    w2: [0.0; 2],
                    w3: [0.0; 2],
                    near,
                    at_load: true,
                };
            }
            let k = floor / r2.sqrt();
            ex *= k;
            ey *= k;
        }
        let r2 = ex * ex + ey * ey;
        // w = 1/z̄ = z/|z|².
        let (wr, wi) = (ex / r2, ey / r2);
        let (w2r, w2i) = (wr * wr - wi * wi, 2.0 * wr * wi);
        let (w3r, w3i) = (w2r * wr - w2i * wi, w2r * wi + w2i * wr);
        FlamantGeometry {
            e: [ex, ey],
            w2: [w2r, w2i],
            w3: [w3r, w3i],
            near,
            at_load: false,
        }
    }

    /// The field of a unit force along `dir` and its derivatives (see
    /// [`flamant`] for the layout).
    #[inline]
    fn field(&self, dir: [f64; 2]) -> [f64; 6] {
        if self.at_load {
            return [0.0; 6];
        }
        let ([ex, ey], [w2r, w2i], [w3r, w3i]) = (self.e, self.w2, self.w3);
        let k = -2.0 / PI;
        let proj = ex * dir[0] + ey * dir[1];
        let (dr, di) = (k * proj * w2r, k * proj * w2i);
        if self.near {
            return [dr, di, 0.0, 0.0, 0.0, 0.0];
        }
        let (xr, xi) = (
            k * (dir[0] * w2r - 2.0 * proj * w3r),
            k * (dir[0] * w2i - 2.0 * proj * w3i),
        );
        // 2i·P·w³ = 2P(−w3i + i w3r).
        let (yr, yi) = (
            k * (dir[1] * w2r - 2.0 * proj * w3i),
            k * (dir[1] * w2i + 2.0 * proj * w3r),
        );
        [dr, di, xr, yr, xi, yi]
    }
}

/// At a pixel with field `f` (`FlamantGeometry::field` layout): |D|, ∇|D|,
/// s² = blur² |∇N|² and whether |D| is above round-off (else no gradient).
#[cfg(test)]
#[inline]
fn order_and_gradient(f: &[f64; 6], optics: &Optics) -> (f64, [f64; 2], f64, bool) {
    let fr = optics.fringe;
    let (d1, d2) = (f[0], f[1]);
    let d = (d1 * d1 + d2 * d2).sqrt();
    let big = 1e-12 * (d1.abs() + d2.abs() + 1e-300);
    let live = d > big;
    let (gd, s2) = if live {
        let gd = [(d1 * f[2] + d2 * f[4]) / d, (d1 * f[3] + d2 * f[5]) / d];
        (
            gd,
            optics.blur2 * (gd[0] * gd[0] + gd[1] * gd[1]) / (fr * fr),
        )
    } else {
        ([0.0; 2], 0.0)
    };
    (d, gd, s2, live)
}

/// The weights w with ∂S/∂u_m = w·c_m, c_m an unknown's Flamant numbers
/// (`FlamantGeometry::field` layout) and `f` = Σ u_m c_m: S depends on u
/// through |D| (∂S/∂|D| = `by_order`) and through g = ∇|D| (∂S/∂g =
/// `by_gradient` g). With e = D/|D|, ∂|D| = e·∂D and
/// ∂g_j = (∂D·∂_j D + D·∂_j ∂D)/|D| − g_j ∂|D|/|D|, which is linear in c_m.
#[cfg(test)]
#[inline]
fn jacobian_weights(f: [f64; 6], d: f64, g: [f64; 2], by_order: f64, by_gradient: f64) -> [f64; 6] {
    let (e1, e2) = (f[0] / d, f[1] / d);
    let q = by_gradient;
    let r = by_order - q * (g[0] * g[0] + g[1] * g[1]) / d;
    [
        r * e1 + q * (g[0] * f[2] + g[1] * f[3]) / d,
        r * e2 + q * (g[0] * f[4] + g[1] * f[5]) / d,
        q * e1 * g[0],
        q * e1 * g[1],
        q * e2 * g[0],
        q * e2 * g[1],
    ]
}

impl DiskData {
    /// The same disk and loads on the pixels `keep` (indices, in order).
    fn keeping(&self, keep: &[usize]) -> DiskData {
        DiskData {
            grain: self.grain,
            centre: self.centre,
            radius: self.radius,
            loads: self.loads.clone(),
            points: keep.iter().map(|&i| self.points[i]).collect(),
            intensity: keep.iter().map(|&i| self.intensity[i]).collect(),
            pixels: keep.iter().map(|&i| self.pixels[i]).collect(),
        }
    }

    fn local_unknowns(&self) -> usize {
        2 * self.loads.len()
    }

    /// S and (when `jacobian`) ∂S/∂u per pixel, for the local unknowns `u`.
    /// The field is linear in u: each unknown m gives six Flamant numbers
    /// c_m per pixel (D and its gradient), and S depends on u only through
    /// |D| and |∇|D||, so ∂S/∂u_m = w·c_m with one weight vector w per pixel
    /// (the chain rule, [`jacobian_weights`]). A residual-only evaluation
    /// takes each load's force vector at once (the field is linear in it).
    /// (Keeping each pixel's Flamant numbers for a whole stage instead was
    /// measured no faster on the loaded 2-core machine, at ~50 MB.)
    fn fringes(&self, u: &[f64], optics: &Optics, jacobian: bool) -> (Vec<f64>, Jacobian) {
        let loads: Vec<KernelLoad> = (self.loads.iter())
            .map(|l| KernelLoad {
                point: l.point,
                directions: l.directions(),
            })
            .collect();
        let fr = optics.fringe;
        let kernel = KernelOptics {
            fringe: fr,
            blur2: optics.blur2,
            envelope_gain: optics
                .envelope
                .map(|px_per_m| optics.contrast * PI / (std::f64::consts::SQRT_2 * fr * px_per_m)),
            precision: optics.precision,
        };
        let floor = 1e-3 * self.radius;
        fringe_kernel::fringes(
            &self.points,
            self.centre,
            &loads,
            u,
            &kernel,
            floor,
            jacobian,
        )
    }

    /// Background and contrast in closed form, the residual and (with
    /// `jacobian`) the normal equations of the step.
    fn evaluate(&self, u: &[f64], optics: &Optics, jacobian: bool) -> DiskEval {
        let n = self.points.len();
        if n == 0 {
            return DiskEval {
                normal: vec![0.0; self.local_unknowns().pow(2)],
                rhs: vec![0.0; self.local_unknowns()],
                ..Default::default()
            };
        }
        let (s, ds) = self.fringes(u, optics, jacobian);
        if optics.envelope.is_some() {
            return self.evaluate_envelope(&s, &ds, jacobian);
        }
        let nf = n as f64;
        let mean_i = self.intensity.iter().sum::<f64>() / nf;
        let mean_s = s.iter().sum::<f64>() / nf;
        let (mut vss, mut vis, mut sst) = (0.0, 0.0, 0.0);
        for (a, b) in s.iter().zip(&self.intensity) {
            vss += (a - mean_s) * (a - mean_s);
            vis += (a - mean_s) * (b - mean_i);
            sst += (b - mean_i) * (b - mean_i);
        }
        // With a lighting plane, S and I are regressed with the plane's
        // slopes projected out (the mean is already out).
        let slopes = if optics.lighting {
            self.slope_basis()
        } else {
            Vec::new()
        };
        for q in &slopes {
            let (qs, qi) = (dot(q, &s), dot(q, &self.intensity));
            vss -= qs * qs;
            vis -= qs * qi;
        }
        // A disk without fringe variation takes the packing's contrast; a
        // fitted one is kept within a factor 3 of it.
        // Fringes are dark on a bright disk in a bright-field polariscope.
        let c_ref = if optics.bright_field {
            -optics.contrast
        } else {
            optics.contrast
        };
        let (low, high) = if optics.bright_field {
            (3.0 * c_ref, c_ref / 3.0)
        } else {
            (c_ref / 3.0, 3.0 * c_ref)
        };
        let contrast = if vss > 1e-3 * nf * 0.01 {
            (vis / vss).clamp(low, high)
        } else {
            c_ref
        };
        let background = mean_i - contrast * mean_s;
        let mut model: Vec<f64> = s.iter().map(|v| background + contrast * v).collect();
        for q in &slopes {
            // The plane's slope along q fitted to what the fringes leave.
            let g = dot(q, &self.intensity) - contrast * dot(q, &s);
            for (m, qi) in model.iter_mut().zip(q) {
                *m += g * qi;
            }
        }
        let residual: Vec<f64> = self
            .intensity
            .iter()
            .zip(&model)
            .map(|(a, b)| a - b)
            .collect();
        let ssr = residual.iter().map(|r| r * r).sum();
        let k = self.local_unknowns();
        let (mut normal, mut rhs) = (vec![0.0; k * k], vec![0.0; k]);
        if jacobian && k > 0 {
            let mut mean_ds = ds.weighted_sums(None);
            for m in &mut mean_ds {
                *m /= nf;
            }
            // Each column's part along the plane's slopes, projected out too.
            let slope_ds: Vec<Vec<f64>> =
                (slopes.iter()).map(|q| ds.weighted_sums(Some(q))).collect();
            // The rows' centred parts; the contrast is applied once at the end.
            ds.normal_equations(
                &residual,
                &mean_ds,
                &slopes,
                &slope_ds,
                &mut normal,
                &mut rhs,
            );
            for a in 0..k {
                rhs[a] *= contrast;
                for b in a..k {
                    normal[a * k + b] *= contrast * contrast;
                    normal[b * k + a] = normal[a * k + b];
                }
            }
        }
        DiskEval {
            background,
            contrast,
            ssr,
            sst,
            normal,
            rhs,
            model,
        }
    }

    /// The lighting plane's two slopes over the disk's pixels: x and y
    /// about their means, orthonormalised (Gram–Schmidt); none for a disk
    /// too small to tell a slope.
    fn slope_basis(&self) -> Vec<Vec<f64>> {
        let n = self.points.len() as f64;
        let mut basis: Vec<Vec<f64>> = Vec::new();
        for axis in 0..2 {
            let mean = self.points.iter().map(|p| p[axis]).sum::<f64>() / n;
            let mut v: Vec<f64> = self.points.iter().map(|p| p[axis] - mean).collect();
            for q in &basis {
                let a = dot(q, &v);
                for (x, qi) in v.iter_mut().zip(q) {
                    *x -= a * qi;
                }
            }
            let norm = dot(&v, &v).sqrt();
            if norm > 1e-9 * self.radius * n.sqrt() {
                v.iter_mut().for_each(|x| *x /= norm);
                basis.push(v);
            }
        }
        basis
    }

    /// The envelope fit's residual (data in `intensity`) and normal equations.
    fn evaluate_envelope(&self, model: &[f64], dm: &Jacobian, jacobian: bool) -> DiskEval {
        let k = self.local_unknowns();
        let (mut normal, mut rhs) = (vec![0.0; k * k], vec![0.0; k]);
        let residual: Vec<f64> = (self.intensity.iter().zip(model))
            .map(|(y, m)| y - m)
            .collect();
        let ssr = residual.iter().map(|r| r * r).sum();
        if jacobian && k > 0 {
            let zero = vec![0.0; k];
            dm.normal_equations(&residual, &zero, &[], &[], &mut normal, &mut rhs);
        }
        for a in 0..k {
            for b in 0..a {
                normal[a * k + b] = normal[b * k + a];
            }
        }
        DiskEval {
            ssr,
            normal,
            rhs,
            model: model.to_vec(),
            ..Default::default()
        }
    }

    fn gather(&self, x: &[f64]) -> Vec<f64> {
        let mut u = Vec::with_capacity(self.local_unknowns());
        for l in &self.loads {
            u.push(x[2 * l.unknown]);
            u.push(x[2 * l.unknown + 1]);
        }
        u
    }
}

impl DiskData {
    /// This disk with `values` in place of its intensities. (Fitting the
    /// smoothed stages on every 2nd pixel only was tried: at r = 20 px it led
    /// the fit from the truth ±10 % into another basin, relerr 0.146 against
    /// 0.004.)
    fn with_intensity(&self, values: Vec<f64>) -> DiskData {
        DiskData {
            grain: self.grain,
            centre: self.centre,
            radius: self.radius,
            loads: self.loads.clone(),
            points: self.points.clone(),
            intensity: values,
            pixels: self.pixels.clone(),
        }
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The problem shared by the joint and the per-disk fits.
struct Prepared {
    disks: Vec<DiskData>,
    /// Unknown pairs: one per contact (joint) or per contact side (per disk).
    unknowns: usize,
    /// The force scale F₀ = f_σ R̄ [N/m] of the unknowns.
    scale: f64,
    optics: Optics,
    /// One pixel [m].
    pixel: f64,
    /// Disks whose balance is imposed (or penalised); a disk whose contacts
    /// admit no balanced compressive, friction-admissible load set (a
    /// contact missed by detection) is left out, else its zero would spread
    /// through its neighbours to the whole packing.
    balanced: Vec<bool>,
    /// Unknowns held at a value (column, value) by equalities beside the
    /// balance: the unknowns a local restart does not free
    /// (fringe_multistart).
    pinned: Vec<(usize, f64)>,
}

impl Prepared {
    /// Disk `d` as a problem of its own with these of its loads (numbered
    /// 0, 1, … there): the per-disk fit and the contact support test refit
    /// a disk alone.
    fn alone(&self, d: &DiskData, mut loads: Vec<Load>) -> Prepared {
        for (i, l) in loads.iter_mut().enumerate() {
            l.unknown = i;
        }
        Prepared {
            unknowns: loads.len(),
            disks: vec![DiskData {
                grain: d.grain,
                centre: d.centre,
                radius: d.radius,
                loads,
                points: d.points.clone(),
                intensity: d.intensity.clone(),
                pixels: d.pixels.clone(),
            }],
            scale: self.scale,
            optics: self.optics,
            pixel: self.pixel,
            balanced: vec![false],
            pinned: Vec::new(),
        }
    }
}

fn prepare(
    image: &FloatImage,
    frame: &PixelFrame,
    scene: &Scene,
    settings: &FringeFitSettings,
    per_side: bool,
) -> Result<Prepared> {
    settings.validate()?;
    frame.validate()?;
    if scene.dim != 2 {
        return Err(Error::Invalid(
            "the fringe fit needs a 2D scene (disks)".into(),
        ));
    }
    if (image.width(), image.height()) != (frame.width, frame.height) {
        return Err(Error::Invalid(format!(
            "the image is {}×{} px but its pixel frame says {}×{}",
            image.width(),
            image.height(),
            frame.width,
            frame.height
        )));
    }
    let s = frame.px_per_m;
    let mut disks: Vec<DiskData> = Vec::with_capacity(scene.grains.len());
    for (g, grain) in scene.grains.iter().enumerate() {
        let radius = grain.equivalent_radius(2);
        if !(radius.is_finite() && radius > 0.0) {
            return Err(Error::Invalid(format!(
                "grain {}: no positive radius for the fringe fit",
                grain.id
            )));
        }
        disks.push(DiskData {
            grain: g,
            centre: [grain.position[0], grain.position[1]],
            radius,
            loads: Vec::new(),
            points: Vec::new(),
            intensity: Vec::new(),
            pixels: Vec::new(),
        });
    }
    let mut unknowns = 0;
    for (k, c) in scene.contacts.iter().enumerate() {
        let len = c.normal[0].hypot(c.normal[1]);
        if !(len.is_finite() && len > 0.0) {
            return Err(Error::Invalid(format!(
                "contact {}: its normal has no direction",
                c.id
            )));
        }
        let n = [c.normal[0] / len, c.normal[1] / len];
        let t = [-n[1], n[0]];
        let mut sides = vec![(c.a, 1.0)];
        if let Body::Grain(b) = c.b {
            sides.push((b, -1.0));
        }
        for (g, sign) in sides {
            let d = &mut disks[g];
            // The load acts where the contact meets this disk's circle.
            let towards = [sign * n[0], sign * n[1]];
            let point = [
                d.centre[0] + d.radius * towards[0],
                d.centre[1] + d.radius * towards[1],
            ];
            let unknown = if per_side { unknowns } else { k };
            if per_side {
                unknowns += 1;
            }
            d.loads.push(Load {
                unknown,
                sign,
                point,
                normal: n,
                tangent: t,
            });
        }
    }
    if !per_side {
        unknowns = scene.contacts.len();
    }
    // Pixels inside each disk, clear of its rim (disks on both cores: the
    // refit's prepare is serial work between two fits).
    let (w, h) = (frame.width as i64, frame.height as i64);
    disks.par_iter_mut().for_each(|d| {
        let c = frame.to_pixel(d.centre);
        let r = d.radius * s - settings.edge_px;
        if r < 2.0 {
            return;
        }
        let (x0, x1) = (
            ((c[0] - r).floor() as i64).max(0),
            ((c[0] + r).ceil() as i64).min(w - 1),
        );
        let (y0, y1) = (
            ((c[1] - r).floor() as i64).max(0),
            ((c[1] + r).ceil() as i64).min(h - 1),
        );
        for y in y0..=y1 {
            for x in x0..=x1 {
                let (dx, dy) = (x as f64 - c[0], y as f64 - c[1]);
                if dx * dx + dy * dy <= r * r {
                    d.points.push(frame.to_scene([x as f64, y as f64]));
                    d.intensity
                        .push(image.get_pixel(x as u32, y as u32)[0] as f64);
                    d.pixels.push((x as u32, y as u32));
                }
            }
        }
    });
    let mut radii: Vec<f64> = disks.iter().map(|d| d.radius).collect();
    radii.sort_by(f64::total_cmp);
    let scale = settings.fringe_stress * radii[radii.len() / 2];
    let blur_px2 = settings.blur_px.powi(2) + 1.0 / 12.0;
    let optics = Optics {
        fringe: settings.fringe_stress / scale,
        blur2: blur_px2 / (s * s),
        contrast: contrast_estimate(&disks),
        envelope: None,
        lighting: settings.lighting,
        bright_field: settings.polariscope == Polariscope::Bright,
        precision: kernel_precision(),
    };
    let balanced = vec![true; disks.len()];
    Ok(Prepared {
        disks,
        unknowns,
        scale,
        optics,
        pixel: 1.0 / s,
        balanced,
        pinned: Vec::new(),
    })
}

/// Set to run the fringe kernel in f64 throughout, for measuring what its
/// f32 costs in the answers (docs/photoelastic.md, round 19).
const DOUBLE_ENV: &str = "GRAINFORCE_FRINGE_DOUBLE";

fn kernel_precision() -> Precision {
    if std::env::var_os(DOUBLE_ENV).is_some() {
        Precision::Double
    } else {
        Precision::Single
    }
}

/// The packing's fringe contrast: the upper quartile over the disks of each
/// disk's 2–98 % intensity range (a disk with a full fringe spans it).
fn contrast_estimate(disks: &[DiskData]) -> f64 {
    let mut ranges: Vec<f64> = disks
        .par_iter()
        .filter(|d| d.intensity.len() > 20)
        .map(|d| {
            let mut v = d.intensity.clone();
            v.sort_by(f64::total_cmp);
            let at = |q: f64| v[((v.len() - 1) as f64 * q) as usize];
            at(0.98) - at(0.02)
        })
        .collect();
    if ranges.is_empty() {
        return 0.5;
    }
    ranges.sort_by(f64::total_cmp);
    ranges[(ranges.len() * 3) / 4].max(1e-3)
}

/// A disk's pixels on their bounding grid (NaN outside the fitted set).
struct PixelGrid {
    x0: u32,
    y0: u32,
    width: usize,
    height: usize,
}

impl PixelGrid {
    fn of(d: &DiskData) -> Option<PixelGrid> {
        let (mut x0, mut y0, mut x1, mut y1) = (u32::MAX, u32::MAX, 0, 0);
        for &(x, y) in &d.pixels {
            x0 = x0.min(x);
            y0 = y0.min(y);
            x1 = x1.max(x);
            y1 = y1.max(y);
        }
        (!d.pixels.is_empty()).then(|| PixelGrid {
            x0,
            y0,
            width: (x1 - x0 + 1) as usize,
            height: (y1 - y0 + 1) as usize,
        })
    }

    /// The disk's pixels selected by `subset` (all when `None`) off the
    /// grid's border, as (column, row): those with four neighbours.
    fn inner_pixels<'a>(
        &'a self,
        d: &'a DiskData,
        subset: Option<&'a [bool]>,
    ) -> impl Iterator<Item = (usize, usize)> + 'a {
        d.pixels.iter().enumerate().filter_map(move |(i, &(x, y))| {
            let (xi, yi) = ((x - self.x0) as usize, (y - self.y0) as usize);
            let border = xi == 0 || yi == 0 || xi + 1 == self.width || yi + 1 == self.height;
            (subset.is_none_or(|s| s[i]) && !border).then_some((xi, yi))
        })
    }

    fn index(&self, x: u32, y: u32) -> usize {
        (y - self.y0) as usize * self.width + (x - self.x0) as usize
    }

    fn scatter(&self, d: &DiskData, values: &[f64]) -> Vec<f64> {
        let mut grid = vec![f64::NAN; self.width * self.height];
        for (&(x, y), v) in d.pixels.iter().zip(values) {
            grid[self.index(x, y)] = *v;
        }
        grid
    }
}

/// Mean squared intensity gradient (central differences, per px²) over the
/// disk's pixels selected by `subset` (all when `None`) whose four
/// neighbours are fitted pixels too.
fn mean_squared_gradient(d: &DiskData, values: &[f64], subset: Option<&[bool]>) -> f64 {
    let Some(g) = PixelGrid::of(d) else {
        return 0.0;
    };
    let grid = g.scatter(d, values);
    let (mut sum, mut count) = (0.0, 0usize);
    for (xi, yi) in g.inner_pixels(d, subset) {
        let at = |xx: usize, yy: usize| grid[yy * g.width + xx];
        let gx = 0.5 * (at(xi + 1, yi) - at(xi - 1, yi));
        let gy = 0.5 * (at(xi, yi + 1) - at(xi, yi - 1));
        if gx.is_finite() && gy.is_finite() {
            sum += gx * gx + gy * gy;
            count += 1;
        }
    }
    if count == 0 {
        0.0
    } else {
        sum / count as f64
    }
}

/// The central-difference stencils (left, right, up, down: indices into
/// the disk's pixels) of the pixels [`mean_squared_gradient`] averages over,
/// in its order: for a scan over many values on one pixel set.
fn gradient_stencils(d: &DiskData, subset: Option<&[bool]>) -> Vec<[usize; 4]> {
    let Some(g) = PixelGrid::of(d) else {
        return Vec::new();
    };
    let mut at = vec![usize::MAX; g.width * g.height];
    for (i, &(x, y)) in d.pixels.iter().enumerate() {
        at[g.index(x, y)] = i;
    }
    let mut out = Vec::new();
    for (xi, yi) in g.inner_pixels(d, subset) {
        let of = |xx: usize, yy: usize| at[yy * g.width + xx];
        let s = [
            of(xi - 1, yi),
            of(xi + 1, yi),
            of(xi, yi - 1),
            of(xi, yi + 1),
        ];
        if s.iter().all(|&j| j != usize::MAX) {
            out.push(s);
        }
    }
    out
}

/// [`mean_squared_gradient`] of finite `values` over `stencils`.
fn stencil_mean_squared_gradient(stencils: &[[usize; 4]], values: &[f64]) -> f64 {
    let mut sum = 0.0;
    for &[left, right, up, down] in stencils {
        let gx = 0.5 * (values[right] - values[left]);
        let gy = 0.5 * (values[down] - values[up]);
        sum += gx * gx + gy * gy;
    }
    if stencils.is_empty() {
        0.0
    } else {
        sum / stencils.len() as f64
    }
}

/// The disk's intensities smoothed by a Gaussian of `sigma_px` within its
/// fitted pixels (normalised convolution, so the rim does not bleed in).
fn smoothed_intensity(d: &DiskData, sigma_px: f64) -> Vec<f64> {
    smooth_values(d, &d.intensity, sigma_px)
}

/// `values` (one per fitted pixel, NaN for none) smoothed by a Gaussian of
/// `sigma_px` within the disk's fitted pixels.
fn smooth_values(d: &DiskData, values: &[f64], sigma_px: f64) -> Vec<f64> {
    let Some(g) = PixelGrid::of(d) else {
        return Vec::new();
    };
    if sigma_px <= 0.0 {
        return values.to_vec();
    }
    let values = g.scatter(d, values);
    let reach = (3.0 * sigma_px).ceil() as isize;
    let kernel: Vec<f64> = (-reach..=reach)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma_px * sigma_px)).exp())
        .collect();
    let (w, h) = (g.width as isize, g.height as isize);
    // Tap by tap over a whole row (vectorised): each output pixel still
    // sums its taps in order, those off the grid skipped.
    let pass = |src: &[f64], weight: &[f64], horizontal: bool| -> (Vec<f64>, Vec<f64>) {
        let mut out = vec![0.0; src.len()];
        let mut out_w = vec![0.0; src.len()];
        for y in 0..h {
            let row = y * w;
            for (k, kv) in kernel.iter().enumerate() {
                let o = k as isize - reach;
                // Output columns [lo, hi) and where their taps start.
                let (lo, hi, from) = if horizontal {
                    let (lo, hi) = ((-o).max(0), (w - o).min(w));
                    (lo, hi, row + lo + o)
                } else if (0..h).contains(&(y + o)) {
                    (0, w, (y + o) * w)
                } else {
                    continue;
                };
                if lo >= hi {
                    continue;
                }
                let (at, len, from) = ((row + lo) as usize, (hi - lo) as usize, from as usize);
                let taps = src[from..from + len].iter().zip(&weight[from..from + len]);
                let outs = out[at..at + len].iter_mut().zip(&mut out_w[at..at + len]);
                for ((acc, acc_w), (v, wv)) in outs.zip(taps) {
                    *acc += kv * v;
                    *acc_w += kv * wv;
                }
            }
        }
        (out, out_w)
    };
    let weight: Vec<f64> = values
        .iter()
        .map(|v| if v.is_finite() { 1.0 } else { 0.0 })
        .collect();
    let masked: Vec<f64> = values
        .iter()
        .map(|v| if v.is_finite() { *v } else { 0.0 })
        .collect();
    let (a, aw) = pass(&masked, &weight, true);
    let (b, bw) = pass(&a, &aw, false);
    d.pixels
        .iter()
        .map(|&(x, y)| {
            let i = g.index(x, y);
            if bw[i] > 0.0 {
                b[i] / bw[i]
            } else {
                0.0
            }
        })
        .collect()
}

/// The photograph's fringe envelope per fitted pixel: the root of the local
/// (Gaussian, `sigma_px`) mean of |∇I|².
fn envelope_data(d: &DiskData, sigma_px: f64) -> Vec<f64> {
    let Some(g) = PixelGrid::of(d) else {
        return Vec::new();
    };
    let grid = g.scatter(d, &d.intensity);
    let squared: Vec<f64> = d
        .pixels
        .iter()
        .map(|&(x, y)| {
            let (xi, yi) = ((x - g.x0) as usize, (y - g.y0) as usize);
            if xi == 0 || yi == 0 || xi + 1 == g.width || yi + 1 == g.height {
                return f64::NAN;
            }
            let at = |xx: usize, yy: usize| grid[yy * g.width + xx];
            let gx = 0.5 * (at(xi + 1, yi) - at(xi - 1, yi));
            let gy = 0.5 * (at(xi, yi + 1) - at(xi, yi - 1));
            gx * gx + gy * gy
        })
        .collect();
    smooth_values(d, &squared, sigma_px)
        .into_iter()
        .map(|v| v.max(0.0).sqrt())
        .collect()
}

/// The problem with each disk's intensities replaced by its fringe envelope.
fn enveloped(p: &Prepared, sigma_px: f64) -> Prepared {
    Prepared {
        disks: p
            .disks
            .par_iter()
            .map(|d| d.with_intensity(envelope_data(d, sigma_px)))
            .collect(),
        unknowns: p.unknowns,
        scale: p.scale,
        optics: p.optics,
        pixel: p.pixel,
        balanced: p.balanced.clone(),
        pinned: p.pinned.clone(),
    }
}

/// Each contact side's force (in units of F₀) from the fringe gradients
/// near it: over the disk's pixels within 0.6 R of the load and nearer it
/// than any other load of the disk, the level at which that load alone
/// (normal) gives the model the photograph's G² (model contrast: the
/// packing's). Returned per disk, per load.
fn load_levels(p: &Prepared, shared: &SharedWork) -> Vec<Vec<f64>> {
    let levels: Vec<f64> = (0..28).map(|i| 0.02 * 1.3f64.powi(i)).collect();
    p.disks
        .par_iter()
        .map(|d| {
            if d.points.len() < 20 {
                return vec![0.0; d.loads.len()];
            }
            let key = level_key(p, d);
            if let Some(done) = shared.get(&key) {
                return done;
            }
            let out: Vec<f64> = (0..d.loads.len())
                .map(|l| load_level(p, d, l, &levels))
                .collect();
            shared.put(key, &out);
            out
        })
        .collect()
}

/// Everything [`load_level`] reads of disk `d`, as bits: the optics, the
/// disk's circle and loads, and a hash of its pixels and intensities.
fn level_key(p: &Prepared, d: &DiskData) -> Vec<u64> {
    let o = &p.optics;
    let mut key = vec![
        o.fringe.to_bits(),
        o.blur2.to_bits(),
        o.contrast.to_bits(),
        o.envelope.map_or(u64::MAX, f64::to_bits),
        u64::from(o.lighting) | u64::from(o.bright_field) << 1,
        p.pixel.to_bits(),
        d.radius.to_bits(),
        d.centre[0].to_bits(),
        d.centre[1].to_bits(),
    ];
    for l in &d.loads {
        let numbers = [l.sign, l.point[0], l.point[1], l.normal[0], l.normal[1]];
        key.extend(numbers.iter().chain(&l.tangent).map(|v| v.to_bits()));
    }
    let words = (d.points.iter().zip(&d.intensity))
        .flat_map(|(pt, v)| [pt[0].to_bits(), pt[1].to_bits(), v.to_bits()]);
    key.push(d.points.len() as u64);
    key.push(hash_words(words));
    key
}

/// A 64-bit hash of `words`: a multiply–rotate step per word (FxHash's)
/// and a final avalanche (MurmurHash3's). Not for adversarial input; std's
/// SipHash over each disk's pixels was 1.2 % of a run.
fn hash_words(words: impl Iterator<Item = u64>) -> u64 {
    let mut h = words.fold(0x9e37_79b9_7f4a_7c15u64, |h, w| {
        (h.rotate_left(5) ^ w).wrapping_mul(0x517c_c1b7_2722_0a95)
    });
    h ^= h >> 33;
    h = h.wrapping_mul(0xff51_afd7_ed55_8ccd);
    h ^= h >> 33;
    h = h.wrapping_mul(0xc4ce_b9a5_3c8b_51e5);
    h ^ (h >> 33)
}

/// [`load_levels`] of load `l` of disk `d`, scanned over `levels`.
fn load_level(p: &Prepared, d: &DiskData, l: usize, levels: &[f64]) -> f64 {
    let q = d.loads[l].point;
    // The load alone on the pixels near it (and their neighbours, for the
    // gradients): a few hundred pixels, not the whole disk, at each level.
    // Squared distances: libm's hypot per pixel and load was 1 % of a run.
    let reach = 0.6 * d.radius + 2.0 * p.pixel;
    let distance2 = |pt: [f64; 2], a: [f64; 2]| (pt[0] - a[0]).powi(2) + (pt[1] - a[1]).powi(2);
    let keep: Vec<usize> = (0..d.points.len())
        .filter(|&i| distance2(d.points[i], q) < reach * reach)
        .collect();
    let mut load = d.loads[l];
    load.unknown = 0;
    let sub = DiskData {
        loads: vec![load],
        ..d.keeping(&keep)
    };
    let near: Vec<bool> = (sub.points.iter())
        .map(|pt| {
            let own = distance2(*pt, q);
            own < (0.6 * d.radius).powi(2) && d.loads.iter().all(|o| distance2(*pt, o.point) >= own)
        })
        .collect();
    if near.iter().filter(|v| **v).count() < 10 {
        return 0.0;
    }
    let stencils = gradient_stencils(&sub, Some(&near));
    let target = stencil_mean_squared_gradient(&stencils, &sub.intensity);
    let mut previous = (0.0f64, 0.0f64);
    // Past the model's largest G² (dense fringes fade under blur) the level
    // of that largest G² is the answer.
    let mut highest = (0.0f64, 0.0f64);
    for &level in levels {
        let (s, _) = sub.fringes(&[level, 0.0], &p.optics, false);
        let model: Vec<f64> = s.iter().map(|v| p.optics.contrast * v).collect();
        let g2 = stencil_mean_squared_gradient(&stencils, &model);
        if g2 >= target {
            let (l0, g0) = previous;
            if l0 > 0.0 && g0 > 0.0 && g2 > g0 {
                let t = (target.ln() - g0.ln()) / (g2.ln() - g0.ln());
                return (l0.ln() + t * (level.ln() - l0.ln())).exp();
            }
            return level;
        }
        if g2 > highest.1 {
            highest = (level, g2);
        }
        previous = (level, g2);
    }
    highest.0
}

/// K_eq: per balanced grain, Σ F = 0 and Σ r × F / R = 0 (3 rows), over
/// the unknowns.
fn balance_rows(p: &Prepared) -> Triplets {
    let count = p.balanced.iter().filter(|b| **b).count();
    let mut k = Triplets::new(3 * count, 2 * p.unknowns);
    let kept = p.disks.iter().zip(&p.balanced).filter(|(_, b)| **b);
    for (g, (d, _)) in kept.enumerate() {
        for l in &d.loads {
            let dirs = l.directions();
            let r = [
                (l.point[0] - d.centre[0]) / d.radius,
                (l.point[1] - d.centre[1]) / d.radius,
            ];
            for (j, dir) in dirs.iter().enumerate() {
                let col = 2 * l.unknown + j;
                k.push(3 * g, col, dir[0]);
                k.push(3 * g + 1, col, dir[1]);
                k.push(3 * g + 2, col, r[0] * dir[1] - r[1] * dir[0]);
            }
        }
    }
    k
}

/// The equalities of a step: [`balance_rows`] = 0, then each pinned
/// unknown = its value.
fn constraint_rows(p: &Prepared) -> (Triplets, Vec<f64>) {
    let mut rows = balance_rows(p);
    let mut values = vec![0.0; rows.nrows];
    for &(col, value) in &p.pinned {
        rows.nrows += 1;
        rows.push(rows.nrows - 1, col, 1.0);
        values.push(value);
    }
    (rows, values)
}

/// Whether disk `d` alone can carry a balanced set of compressive,
/// friction-admissible loads at its contacts: the loads nearest unit normal
/// ones under its own balance and wedges, not all zero. A disk with one
/// contact, or two not within the friction angle of opposite, cannot.
fn can_balance(d: &DiskData, cones: &[Cone]) -> Result<bool> {
    let k = d.loads.len();
    if k < 2 {
        return Ok(false);
    }
    let carried: f64 = local_unit_loads(d, cones)?.iter().sum();
    Ok(carried > 1e-3 * k as f64)
}

/// The normal loads (over F₀) nearest unit ones that disk `d` alone can
/// carry under its own balance and wedges: one per load of `d`.
fn local_unit_loads(d: &DiskData, cones: &[Cone]) -> Result<Vec<f64>> {
    let k = d.loads.len();
    let mut balance = Triplets::new(3, 2 * k);
    let mut target = Triplets::new(2 * k, 2 * k);
    let mut rhs = vec![0.0; 2 * k];
    let mut wedges = Vec::with_capacity(k);
    for (i, l) in d.loads.iter().enumerate() {
        let r = [
            (l.point[0] - d.centre[0]) / d.radius,
            (l.point[1] - d.centre[1]) / d.radius,
        ];
        for (j, dir) in l.directions().iter().enumerate() {
            balance.push(0, 2 * i + j, dir[0]);
            balance.push(1, 2 * i + j, dir[1]);
            balance.push(2, 2 * i + j, r[0] * dir[1] - r[1] * dir[0]);
        }
        target.push(2 * i, 2 * i, 1.0);
        target.push(2 * i + 1, 2 * i + 1, 0.1);
        rhs[2 * i] = 1.0;
        let mu = match cones.get(l.unknown) {
            Some(Cone::Wedge { mu, .. }) => *mu,
            _ => 0.0,
        };
        wedges.push(Cone::Wedge {
            normal: 2 * i,
            tangent: 2 * i + 1,
            mu,
        });
    }
    let zeros = [0.0; 3];
    let problem = ConicProblem {
        n: 2 * k,
        terms: vec![Term {
            matrix: &target,
            rhs: &rhs,
            weight: 1.0,
        }],
        equalities: vec![(&balance, &zeros)],
        lambda: 0.0,
        regularized: 0,
        cones: wedges,
    };
    let x = admissible_optimum(&problem)?;
    Ok((0..k).map(|i| x[2 * i]).collect())
}

/// Leaves out the balance of disks until no contact that `start` loads is
/// forced to zero by the balance and wedges. Each disk may balance alone
/// and the whole still admit no load at some contacts: a disk with two
/// contacts fixes its force's line (its chord), and three-force disks then
/// need their lines to meet inside the wedges. Such a set (a contact lost
/// by detection, or dropped by a prune) pins those contacts at zero, the
/// start cannot be kept, and the fit would either leave it unbalanced (no
/// step is accepted) or zero contacts the evidence loads. At each pass the
/// field nearest unit normal loads is found; among the balanced disks at a
/// loaded contact it leaves unloaded (and that cannot be loaded alone),
/// those with the fewest contacts (whose balance restricts the most, the
/// likeliest to have lost one) are left out and listed.
fn release_forced_zeros(
    p: &mut Prepared,
    scene: &Scene,
    settings: &FringeFitSettings,
    start: &[f64],
) -> Result<()> {
    for _ in 0..p.disks.len() {
        let unit = unit_field(p, scene, settings)?;
        let mut forced = Vec::new();
        let pinned = |k: &usize| unit[2 * k] < FORCED_ZERO && start[2 * k] > SPARSE_EPS;
        for k in (0..p.unknowns).filter(pinned) {
            // The field nearest unit loads may leave a contact unloaded to
            // load others: asked to load it alone, can the rest carry it?
            if !can_load(p, scene, settings, k)? {
                forced.push(k);
            }
        }
        if !release_fewest(p, &forced) {
            return Ok(());
        }
    }
    Ok(())
}

/// Leaves out the balance of the balanced disks at the contacts `forced`
/// (to zero) that have the fewest contacts; false when there are none.
fn release_fewest(p: &mut Prepared, forced: &[usize]) -> bool {
    let mut forced_at = vec![false; p.unknowns];
    for &k in forced {
        forced_at[k] = true;
    }
    let suspects: Vec<usize> = (0..p.disks.len())
        .filter(|&g| p.balanced[g] && p.disks[g].loads.iter().any(|l| forced_at[l.unknown]))
        .collect();
    let Some(fewest) = suspects.iter().map(|&g| p.disks[g].loads.len()).min() else {
        return false;
    };
    for g in suspects {
        if p.disks[g].loads.len() == fewest {
            p.balanced[g] = false;
        }
    }
    true
}

/// Below this share of contacts able to carry load, the balance pins the
/// packing at zero. Each disk may balance alone and the whole admit no load
/// ([`release_forced_zeros`]): detected packings cut by the picture's
/// border (neighbours outside it never detected) admitted none at all on
/// three photographs, and the fit started from zero stayed there (every
/// disk flagged, 159 of 176 forces zero; docs/photoelastic.md, round 17).
/// The three PeGS photographs admit load at 43–88 % of their contacts.
const PINNED_PACKING_SHARE: f64 = 0.25;

/// For a fit from the fringes under exact balance: while fewer than
/// [`PINNED_PACKING_SHARE`] of the contacts can carry load, leaves out the
/// balance of the fewest-contact disks at the others (as
/// [`release_forced_zeros`] does for a given start, without its per-contact
/// test: a contact the field nearest unit loads leaves unloaded is counted
/// as pinned).
fn release_pinned_packing(
    p: &mut Prepared,
    scene: &Scene,
    settings: &FringeFitSettings,
) -> Result<()> {
    if settings.balance != Balance::Hard || p.unknowns == 0 {
        return Ok(());
    }
    for _ in 0..p.disks.len() {
        let unit = unit_field(p, scene, settings)?;
        let pinned: Vec<usize> = (0..p.unknowns)
            .filter(|&k| unit[2 * k] < FORCED_ZERO)
            .collect();
        let loadable = (p.unknowns - pinned.len()) as f64;
        if loadable >= PINNED_PACKING_SHARE * p.unknowns as f64 || !release_fewest(p, &pinned) {
            return Ok(());
        }
    }
    Ok(())
}

/// Whether contact `k` can carry a load under the balance of `p`'s balanced
/// disks and every wedge: the admissible field nearest a unit normal load
/// there (the others held small but free).
fn can_load(p: &Prepared, scene: &Scene, settings: &FringeFitSettings, k: usize) -> Result<bool> {
    let n = 2 * p.unknowns;
    let mut target = Triplets::new(n, n);
    let mut rhs = vec![0.0; n];
    for i in 0..n {
        target.push(i, i, if i == 2 * k { 1.0 } else { 1e-2 });
    }
    rhs[2 * k] = 1.0;
    let balance = balance_rows(p);
    let zeros = vec![0.0; balance.nrows];
    let terms = vec![Term {
        matrix: &target,
        rhs: &rhs,
        weight: 1.0,
    }];
    let cones = friction_cones(scene, settings);
    let problem = constrained_problem(n, terms, &balance, &zeros, settings, cones);
    let x = admissible_optimum(&problem)?;
    Ok(x[2 * k] >= FORCED_ZERO)
}

/// A contact whose largest admissible share of a unit load is below this
/// is taken as forced to zero.
const FORCED_ZERO: f64 = 1e-3;

/// Each contact's wedge: its own μ, else the walls' (for a wall contact),
/// else the scene's, else the settings'.
fn friction_cones(scene: &Scene, settings: &FringeFitSettings) -> Vec<Cone> {
    scene
        .contacts
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let wall = settings.wall_mu.filter(|_| matches!(c.b, Body::Wall(_)));
            Cone::Wedge {
                normal: 2 * k,
                tangent: 2 * k + 1,
                mu: c.mu.or(wall).or(scene.settings.mu).unwrap_or(settings.mu),
            }
        })
        .collect()
}

/// The optimum of a one-off constrained least squares that only decides
/// (a disk's unit loads, a load test, the contacts a unit field leaves
/// unloaded) on the steps' sparse route rather than clarabel alone: the
/// active set answers these exactly, in a fraction of the time.
fn admissible_optimum(problem: &ConicProblem) -> Result<Vec<f64>> {
    Ok(admissible_solution(problem)?.x)
}

/// The optimum of a fit's start by clarabel, as before: the fit's path
/// from it depends on its last digits (the exact optimum sent step83 at
/// μ 1000 to another basin, share 0.83 → 0.64; docs round 19).
fn start_optimum(problem: &ConicProblem) -> Result<Vec<f64>> {
    Ok(cascade::solve(problem, None, &CascadeSettings::default())?
        .solution
        .x)
}

/// [`admissible_optimum`] with the route that answered.
fn admissible_solution(problem: &ConicProblem) -> Result<Solution> {
    StepSolver::default().solution(problem)
}

fn constrained_problem<'a>(
    n: usize,
    terms: Vec<Term<'a>>,
    balance: &'a Triplets,
    zeros: &'a [f64],
    settings: &FringeFitSettings,
    cones: Vec<Cone>,
) -> ConicProblem<'a> {
    let mut problem = ConicProblem {
        n,
        terms,
        equalities: Vec::new(),
        lambda: 0.0,
        regularized: 0,
        cones,
    };
    match settings.balance {
        Balance::Hard => problem.equalities.push((balance, zeros)),
        Balance::Penalty(w) => problem.terms.push(Term {
            matrix: balance,
            rhs: zeros,
            weight: w,
        }),
    }
    problem
}

/// The balanced, friction-admissible field nearest the G² load levels:
/// min Σ (u_n − F_c)² + 0.01 Σ u_t² under balance and friction.
fn balanced_start(
    p: &Prepared,
    scene: &Scene,
    settings: &FringeFitSettings,
    levels: &[Vec<f64>],
) -> Result<Vec<f64>> {
    nearest_balanced(p, scene, settings, levels, start_optimum)
}

/// The balanced, friction-admissible field nearest unit loads, to find the
/// contacts the balance and wedges leave unloaded.
fn unit_field(p: &Prepared, scene: &Scene, settings: &FringeFitSettings) -> Result<Vec<f64>> {
    let ones: Vec<Vec<f64>> = p.disks.iter().map(|d| vec![1.0; d.loads.len()]).collect();
    nearest_balanced(p, scene, settings, &ones, admissible_optimum)
}

/// The balanced, friction-admissible field nearest `levels`, by `optimum`.
fn nearest_balanced(
    p: &Prepared,
    scene: &Scene,
    settings: &FringeFitSettings,
    levels: &[Vec<f64>],
    optimum: fn(&ConicProblem) -> Result<Vec<f64>>,
) -> Result<Vec<f64>> {
    let n = 2 * p.unknowns;
    // Each contact's level: the geometric mean of its sides' (or its one side's).
    let mut product = vec![1.0; p.unknowns];
    let mut sides = vec![0.0; p.unknowns];
    for (d, side_levels) in p.disks.iter().zip(levels) {
        for (l, v) in d.loads.iter().zip(side_levels) {
            product[l.unknown] *= v.max(1e-3);
            sides[l.unknown] += 1.0;
        }
    }
    let mut target = vec![0.0; n];
    let mut identity = Triplets::new(n, n);
    for k in 0..p.unknowns {
        if sides[k] > 0.0 {
            target[2 * k] = product[k].powf(1.0 / sides[k]);
        }
        identity.push(2 * k, 2 * k, 1.0);
        identity.push(2 * k + 1, 2 * k + 1, 0.1);
    }
    let balance = balance_rows(p);
    let zeros = vec![0.0; balance.nrows];
    let terms = vec![Term {
        matrix: &identity,
        rhs: &target,
        weight: 1.0,
    }];
    let problem = constrained_problem(
        n,
        terms,
        &balance,
        &zeros,
        settings,
        friction_cones(scene, settings),
    );
    optimum(&problem)
}

/// The balanced, friction-admissible field nearest a given start `x0` (a
/// previous frame's forces, or a fit's with contacts dropped): Levenberg–
/// Marquardt keeps only steps that lower the residual, and every step meets
/// the balance, so from an unbalanced start whose residual no balanced
/// field beats it would stay where it started, out of balance.
fn feasible_start(
    p: &Prepared,
    scene: &Scene,
    settings: &FringeFitSettings,
    x0: Vec<f64>,
) -> Result<Vec<f64>> {
    let cones = friction_cones(scene, settings);
    if let Balance::Penalty(_) = settings.balance {
        // The balance is a term of the fit: only the wedges are hard.
        let mut x = x0;
        for c in &cones {
            c.project(&mut x);
        }
        return Ok(x);
    }
    let n = 2 * p.unknowns;
    let mut identity = Triplets::new(n, n);
    for i in 0..n {
        identity.push(i, i, 1.0);
    }
    let (balance, zeros) = constraint_rows(p);
    let terms = vec![Term {
        matrix: &identity,
        rhs: &x0,
        weight: 1.0,
    }];
    let problem = constrained_problem(n, terms, &balance, &zeros, settings, cones);
    start_optimum(&problem)
}

fn objective(p: &Prepared, x: &[f64], optics: &Optics) -> f64 {
    // Summed in disk order: rayon's parallel sum splits where threads steal,
    // so its last bits (and the steps decided on them) changed run to run.
    let per_disk: Vec<f64> = p
        .disks
        .par_iter()
        .map(|d| d.evaluate(&d.gather(x), optics, false).ssr)
        .collect();
    per_disk.iter().sum()
}

/// Levenberg–Marquardt from `x`, each step a constrained least squares
/// (`constraints` = balance and cones) or, without them, free.
struct Stepper<'a> {
    p: &'a Prepared,
    scene: Option<&'a Scene>,
    settings: &'a FringeFitSettings,
    /// The sparsity term's weight in per-pixel residual variances (0: none).
    sparsity: f64,
    /// A step accepted at its first trial that moves the forces by at most
    /// this share of the noise's effect ([`StageEnd::last_move`]) ends the
    /// stage (0: off).
    accuracy: f64,
}

/// ε of the sparsity term, in the unknowns' force unit F₀ = f_σ R (about one
/// fringe): a twentieth of it, below what the fringes resolve.
const SPARSE_EPS: f64 = 0.05;

/// The sparsity term α Σ_c u_n²/(u_n² + ε²) at x.
fn sparsity_penalty(x: &[f64], alpha: f64) -> f64 {
    if alpha == 0.0 {
        return 0.0;
    }
    let e2 = SPARSE_EPS * SPARSE_EPS;
    x.chunks(2)
        .map(|u| {
            let n2 = u[0] * u[0];
            alpha * n2 / (n2 + e2)
        })
        .sum()
}

/// The sparsity term's quadratic majorizer at x as least-squares rows
/// √(α/(u_n² + ε²)) u_n ≈ 0 (u²/(u² + ε²) is concave in u², so its tangent
/// in u² lies above it: each step lowers the true term).
fn sparsity_rows(x: &[f64], alpha: f64) -> Triplets {
    let n = x.len();
    let mut rows = Triplets::new(n / 2, n);
    for k in 0..n / 2 {
        let w = alpha / (x[2 * k] * x[2 * k] + SPARSE_EPS * SPARSE_EPS);
        rows.push(k, 2 * k, w.sqrt());
    }
    rows
}

/// One Levenberg–Marquardt stage's cost, printed to stderr by the
/// detection's stopwatch when `GRAINFORCE_PROFILE` is set (where a fit's
/// time goes: pixels, steps and evaluations per stage).
fn stage_lap(
    laps: &mut Laps,
    p: &Prepared,
    optics: &Optics,
    steps: usize,
    (full, residual_only): (usize, usize),
    objective: f64,
    end: StageEnd,
) {
    if !laps.running() {
        return;
    }
    let pixels: usize = p.disks.iter().map(|d| d.points.len()).sum();
    let stage = match optics.envelope {
        Some(_) => "envelope".to_string(),
        None => format!(
            "blur {:.2} px{}",
            optics.blur2.sqrt() / p.pixel,
            if optics.bright_field { " bright" } else { "" }
        ),
    };
    laps.lap(&format!(
        "fringe stage {stage:<18} {pixels:>7} px {:>4} unknowns {steps:>3} steps {full:>3}+{residual_only} evaluations, objective {objective:.2}, last step {:.3} of the noise{}:",
        2 * p.unknowns,
        end.last_move,
        if end.at_data_accuracy { " (the data's accuracy)" } else { "" }
    ));
}

struct LmOutcome {
    x: Vec<f64>,
    iterations: usize,
    damping: f64,
    /// The stage's objective at `x`.
    objective: f64,
    end: StageEnd,
}

impl Stepper<'_> {
    fn run(
        &self,
        mut x: Vec<f64>,
        optics: &Optics,
        max_iterations: usize,
        tolerance: f64,
        timing: &mut FitTiming,
    ) -> Result<LmOutcome> {
        let p = self.p;
        let n = 2 * p.unknowns;
        let (balance, zeros) = constraint_rows(p);
        let mut solver = StepSolver::default();
        let mut damping = 1e-3;
        let mut iterations = 0;
        let mut current = f64::INFINITY;
        let mut stalls = 0;
        let mut first_accepted = true;
        // The evaluation at x, with or without the Jacobian.
        let evaluate = |x: &[f64], jacobian: bool| -> Vec<DiskEval> {
            p.disks
                .par_iter()
                .map(|d| d.evaluate(&d.gather(x), optics, jacobian))
                .collect()
        };
        let mut laps = Laps::start();
        let clock = std::time::Instant::now();
        let mut evals = evaluate(&x, true);
        timing.evaluate += clock.elapsed().as_secs_f64();
        let mut evaluations = (1usize, 0usize);
        // The sparsity weight from this stage's own residual level.
        let pixels: usize = p.disks.iter().map(|d| d.points.len()).sum();
        let ssr0: f64 = evals.iter().map(|e| e.ssr).sum();
        let alpha = self.sparsity * ssr0 / pixels.max(1) as f64;
        let sparse_zeros = vec![0.0; p.unknowns];
        let imposed = match (self.scene, self.settings.balance) {
            (Some(_), Balance::Hard) => balance.nrows,
            _ => 0,
        };
        let mut end = StageEnd {
            free: n.saturating_sub(imposed).max(1),
            ..StageEnd::default()
        };
        let degrees_of_freedom = pixels.saturating_sub(end.free).max(1) as f64;
        while iterations < max_iterations {
            current = evals.iter().map(|e| e.ssr).sum::<f64>() + sparsity_penalty(&x, alpha);
            let sparse = (alpha > 0.0).then(|| sparsity_rows(&x, alpha));
            // Each disk's normal equations as rows: G = V Λ Vᵀ → √λ vᵀ x ≈ vᵀ(h + G u)/√λ.
            let mut rows = Triplets::new(0, n);
            let mut rhs = Vec::new();
            let mut diagonal = vec![0.0; n];
            for (d, e) in p.disks.iter().zip(&evals) {
                let k = d.local_unknowns();
                if k == 0 || d.points.is_empty() {
                    continue;
                }
                let g = nalgebra::DMatrix::from_row_slice(k, k, &e.normal);
                let u = d.gather(&x);
                let gu = &g * nalgebra::DVector::from_column_slice(&u);
                let eig = nalgebra::SymmetricEigen::new(g);
                let top = eig.eigenvalues.iter().fold(0.0f64, |m, v| m.max(*v));
                if top <= 0.0 {
                    continue;
                }
                let cols: Vec<usize> = d
                    .loads
                    .iter()
                    .flat_map(|l| [2 * l.unknown, 2 * l.unknown + 1])
                    .collect();
                for (m, &c) in cols.iter().enumerate() {
                    diagonal[c] += e.normal[m * k + m];
                }
                for (j, &lambda) in eig.eigenvalues.iter().enumerate() {
                    if lambda <= 1e-10 * top {
                        continue;
                    }
                    let v = eig.eigenvectors.column(j);
                    let root = lambda.sqrt();
                    let row = rows.nrows;
                    rows.nrows += 1;
                    let mut b = 0.0;
                    for m in 0..k {
                        rows.push(row, cols[m], root * v[m]);
                        b += v[m] * (e.rhs[m] + gu[m]);
                    }
                    rhs.push(b / root);
                }
            }
            let floor = 1e-6 * diagonal.iter().fold(0.0f64, |m, v| m.max(*v)).max(1e-12);
            let mut accepted = false;
            for attempt in 0..10 {
                let mut damp = Triplets::new(n, n);
                let mut damp_rhs = vec![0.0; n];
                for i in 0..n {
                    let w = (damping * (diagonal[i] + floor)).sqrt();
                    damp.push(i, i, w);
                    damp_rhs[i] = w * x[i];
                }
                let clock = std::time::Instant::now();
                let candidate = self.step(
                    &rows,
                    &rhs,
                    &damp,
                    &damp_rhs,
                    sparse.as_ref().map(|m| (m, sparse_zeros.as_slice())),
                    &balance,
                    &zeros,
                    &x,
                    &mut solver,
                )?;
                timing.solve += clock.elapsed().as_secs_f64();
                timing.solves += 1;
                let hard = self.scene.is_some() && self.settings.balance == Balance::Hard;
                if hard && balance_violation(&balance, &zeros, &candidate) > BALANCE_TOLERANCE {
                    // Never take a step off the imposed balance; a smaller one may hold it.
                    timing.unbalanced_steps += 1;
                    damping *= 6.0;
                    continue;
                }
                let clock = std::time::Instant::now();
                // The Jacobian is needed at the accepted trial alone: it is
                // evaluated with the first trial while first trials are
                // being accepted (the usual run), else after acceptance.
                let speculate = attempt == 0 && first_accepted;
                let trial_evals = evaluate(&candidate, speculate);
                if speculate {
                    evaluations.0 += 1;
                } else {
                    evaluations.1 += 1;
                }
                let trial: f64 = trial_evals.iter().map(|e| e.ssr).sum::<f64>()
                    + sparsity_penalty(&candidate, alpha);
                let spent = clock.elapsed().as_secs_f64();
                if speculate {
                    timing.evaluate += spent;
                } else {
                    timing.trials += spent;
                }
                if trial.is_finite() && trial < current {
                    let mut candidate = candidate;
                    let mut trial = trial;
                    let mut trial_evals = trial_evals;
                    // Gauss–Newton under-predicts the gain where the fringe
                    // residual is large: a longer step along the same
                    // direction, from the gain ratio, when it stays feasible.
                    if speculate && hard && self.settings.extrapolate {
                        let rho = (current - trial) / predicted_gain(p, &evals, &x, &candidate);
                        let cones =
                            friction_cones(self.scene.expect("hard balance"), self.settings);
                        let longer = extrapolated(&x, &candidate, rho, &cones).filter(|l| {
                            balance_violation(&balance, &zeros, l) <= BALANCE_TOLERANCE
                        });
                        if let Some(longer) = longer {
                            let clock = std::time::Instant::now();
                            let longer_evals = evaluate(&longer, true);
                            timing.evaluate += clock.elapsed().as_secs_f64();
                            timing.extrapolations += 1;
                            let at: f64 = longer_evals.iter().map(|e| e.ssr).sum::<f64>()
                                + sparsity_penalty(&longer, alpha);
                            if at.is_finite() && at < trial {
                                timing.extrapolated += 1;
                                candidate = longer;
                                trial = at;
                                trial_evals = longer_evals;
                            }
                        }
                    }
                    let gain = (current - trial) / current.max(1e-300);
                    let ssr: f64 = trial_evals.iter().map(|e| e.ssr).sum();
                    let noise2 = (ssr / degrees_of_freedom).max(f64::MIN_POSITIVE);
                    end.noise = noise2.sqrt();
                    end.last_move =
                        (step_norm2(p, &evals, &x, &candidate) / (noise2 * end.free as f64)).sqrt();
                    end.at_data_accuracy =
                        self.accuracy > 0.0 && attempt == 0 && end.last_move <= self.accuracy;
                    x = candidate;
                    evals = if speculate {
                        trial_evals
                    } else {
                        let clock = std::time::Instant::now();
                        let at = evaluate(&x, true);
                        timing.evaluate += clock.elapsed().as_secs_f64();
                        evaluations.0 += 1;
                        at
                    };
                    first_accepted = attempt == 0;
                    current = trial;
                    damping = (damping / 3.0).max(1e-9);
                    accepted = true;
                    stalls = if gain < tolerance { stalls + 1 } else { 0 };
                    break;
                }
                damping *= 6.0;
            }
            iterations += 1;
            if !accepted || stalls >= 2 || end.at_data_accuracy {
                break;
            }
        }
        stage_lap(&mut laps, p, optics, iterations, evaluations, current, end);
        Ok(LmOutcome {
            x,
            iterations,
            damping,
            objective: current,
            end,
        })
    }

    #[allow(clippy::too_many_arguments)]
    fn step(
        &self,
        rows: &Triplets,
        rhs: &[f64],
        damp: &Triplets,
        damp_rhs: &[f64],
        sparse: Option<(&Triplets, &[f64])>,
        balance: &Triplets,
        zeros: &[f64],
        x: &[f64],
        solver: &mut StepSolver,
    ) -> Result<Vec<f64>> {
        let n = x.len();
        let mut terms = vec![
            Term {
                matrix: rows,
                rhs,
                weight: 1.0,
            },
            Term {
                matrix: damp,
                rhs: damp_rhs,
                weight: 1.0,
            },
        ];
        if let Some((matrix, rhs)) = sparse {
            terms.push(Term {
                matrix,
                rhs,
                weight: 1.0,
            });
        }
        match self.scene {
            Some(scene) => {
                let problem = constrained_problem(
                    n,
                    terms,
                    balance,
                    zeros,
                    self.settings,
                    friction_cones(scene, self.settings),
                );
                solver.solve(&problem)
            }
            None => {
                // Free steps (the per-disk baseline): dense normal equations.
                let mut a = nalgebra::DMatrix::<f64>::zeros(n, n);
                let mut b = nalgebra::DVector::<f64>::zeros(n);
                for t in [(rows, rhs), (damp, damp_rhs)] {
                    let (m, r) = t;
                    let mut by_row: Vec<Vec<(usize, f64)>> = vec![Vec::new(); m.nrows];
                    for ((&i, &j), &v) in m.rows.iter().zip(&m.cols).zip(&m.vals) {
                        by_row[i].push((j, v));
                    }
                    for (i, entries) in by_row.iter().enumerate() {
                        for &(j1, v1) in entries {
                            b[j1] += v1 * r[i];
                            for &(j2, v2) in entries {
                                a[(j1, j2)] += v1 * v2;
                            }
                        }
                    }
                }
                let solved = a
                    .cholesky()
                    .map(|c| c.solve(&b))
                    .ok_or_else(|| Error::Invalid("fringe fit: a singular per-disk step".into()))?;
                Ok(solved.iter().copied().collect())
            }
        }
    }
}

/// The constrained solve of one Levenberg–Marquardt step, through the
/// cascade on a sparse pattern kept across steps (the symbolic analysis is
/// done once): the least squares when it meets every friction wedge, else the
/// active set on the same factorisation, then the interior points.
#[derive(Default)]
struct StepSolver {
    /// Each contact's (u_n, u_t) coupled in the pattern, for the wedges' rows.
    pattern: Option<Pattern>,
    slot: FactorSlot,
}

impl StepSolver {
    fn solve(&mut self, problem: &ConicProblem) -> Result<Vec<f64>> {
        Ok(self.solution(problem)?.x)
    }

    /// The answer, projected onto the wedges, with the route that gave it.
    fn solution(&mut self, problem: &ConicProblem) -> Result<Solution> {
        let pattern = self.pattern.get_or_insert_with(|| {
            let mut blocks = Triplets::new(problem.cones.len(), problem.n);
            for (k, c) in problem.cones.iter().enumerate() {
                if let Cone::Wedge {
                    normal, tangent, ..
                } = *c
                {
                    blocks.push(k, normal, 1.0);
                    blocks.push(k, tangent, 1.0);
                }
            }
            Pattern {
                dim: 2,
                contact_blocks: blocks,
            }
        });
        let solved = cascade::solve(
            problem,
            Some((pattern, &self.slot)),
            &CascadeSettings::default(),
        )?;
        let mut solution = solved.solution;
        for c in &problem.cones {
            c.project(&mut solution.x);
        }
        Ok(solution)
    }
}

/// The Gauss–Newton model's decrease of the squared residual for the step
/// from `x` to `to`: Σ_disks 2 sᵀ(Jᵀr) − sᵀ JᵀJ s.
fn predicted_gain(p: &Prepared, evals: &[DiskEval], x: &[f64], to: &[f64]) -> f64 {
    let (slope, curvature) = gauss_newton_terms(p, evals, x, to);
    2.0 * slope - curvature
}

/// sᵀ JᵀJ s for the step s from `x` to `to`: its length in the metric of
/// the forces' inverse covariance (over σ̂²).
fn step_norm2(p: &Prepared, evals: &[DiskEval], x: &[f64], to: &[f64]) -> f64 {
    gauss_newton_terms(p, evals, x, to).1
}

/// Σ_disks sᵀ(Jᵀr) and sᵀ JᵀJ s for the step s from `x` to `to`.
fn gauss_newton_terms(p: &Prepared, evals: &[DiskEval], x: &[f64], to: &[f64]) -> (f64, f64) {
    let (mut slope, mut curvature) = (0.0, 0.0);
    for (d, e) in p.disks.iter().zip(evals) {
        let k = d.local_unknowns();
        if k == 0 || d.points.is_empty() {
            continue;
        }
        let step: Vec<f64> = (d.gather(to).iter().zip(d.gather(x)))
            .map(|(b, a)| b - a)
            .collect();
        for m in 0..k {
            slope += step[m] * e.rhs[m];
            for j in 0..k {
                curvature += step[m] * e.normal[m * k + j] * step[j];
            }
        }
    }
    (slope, curvature)
}

/// Longest extrapolation of an accepted step, in step lengths.
const MAX_EXTRAPOLATION: f64 = 4.0;

/// `x + t (to − x)` with t = 1/(2 − ρ), the minimum along the step of the
/// parabola through the objective's value and slope at `x` that gains ρ
/// times the model's prediction at t = 1 (at most [`MAX_EXTRAPOLATION`]),
/// cut to stay in every friction wedge; None when that is not > 1.25 steps.
/// Balance is linear, so it holds along the step.
fn extrapolated(x: &[f64], to: &[f64], rho: f64, cones: &[Cone]) -> Option<Vec<f64>> {
    if !(rho.is_finite() && rho > 1.2) {
        return None;
    }
    let wanted = if rho >= 2.0 - 1.0 / MAX_EXTRAPOLATION {
        MAX_EXTRAPOLATION
    } else {
        1.0 / (2.0 - rho)
    };
    let step: Vec<f64> = to.iter().zip(x).map(|(b, a)| b - a).collect();
    // Largest t with a·(to + (t − 1) step) ≥ 0 for each linear inequality a.
    let mut t = wanted;
    let mut limit = |value: f64, slope: f64| {
        if slope < 0.0 {
            t = t.min(1.0 + 0.95 * value.max(0.0) / -slope);
        }
    };
    for c in cones {
        match *c {
            Cone::NonNegative { normal } => limit(to[normal], step[normal]),
            Cone::Wedge {
                normal,
                tangent,
                mu,
            } => {
                limit(to[normal], step[normal]);
                limit(
                    mu * to[normal] - to[tangent],
                    mu * step[normal] - step[tangent],
                );
                limit(
                    mu * to[normal] + to[tangent],
                    mu * step[normal] + step[tangent],
                );
            }
            _ => return None,
        }
    }
    (t > 1.25).then(|| x.iter().zip(&step).map(|(a, s)| a + t * s).collect())
}

/// The largest |K x| over the balance rows, relative to the largest
/// unknown (at least F₀): how far `x` is from balance.
fn balance_violation(balance: &Triplets, values: &[f64], x: &[f64]) -> f64 {
    let mut row: Vec<f64> = values.iter().map(|v| -v).collect();
    for ((&i, &j), &v) in balance.rows.iter().zip(&balance.cols).zip(&balance.vals) {
        row[i] += v * x[j];
    }
    let size = x.iter().fold(1.0f64, |m, v| m.max(v.abs()));
    row.iter().fold(0.0f64, |m, r| m.max(r.abs())) / size
}

/// A step whose balance rows miss by more than this (relative, see
/// [`balance_violation`]) is rejected: the solver's interior points stop at
/// ~10⁻⁸, a softened or failed answer far above.
const BALANCE_TOLERANCE: f64 = 1e-6;

/// Extra blur of the stages, in units of the median disk radius [px]: the
/// photograph and the model are smoothed alike, so the first stages see only
/// the coarse fringes (a smoother objective, fewer local minima).
const STAGES: [f64; 3] = [0.08, 0.04, 0.0];

/// A stage ends after two steps in a row that lower the objective by less
/// than this share: the coarse stages (envelope, smoothed) only lead into
/// the final stage's basin, so they stop early; the final one converges.
const COARSE_TOLERANCE: f64 = 1e-3;
const FINAL_TOLERANCE: f64 = 1e-5;

/// Every `stride`-th pixel in x and y of each disk (a quarter of them at
/// stride 2): a smoothed stage's data is band-limited ([`stride_for`]), so
/// the coarse stages fit on a subset (the smoothing itself is done on all
/// pixels first), and the final stage converges on one before it is
/// polished on all ([`FINAL_STRIDE`]).
fn thinned(p: &Prepared, stride: u32) -> Prepared {
    let disks = (p.disks.iter())
        .map(|d| {
            let keep: Vec<usize> = (0..d.pixels.len())
                .filter(|&i| {
                    stride <= 1 || (d.pixels[i].0 % stride == 0 && d.pixels[i].1 % stride == 0)
                })
                .collect();
            d.keeping(&keep)
        })
        .collect();
    Prepared {
        disks,
        balanced: p.balanced.clone(),
        pinned: p.pinned.clone(),
        ..*p
    }
}

/// The pixel stride a stage smoothed by `sigma_px` can be fitted on
/// (σ ≥ 1.5 stride px); the 0.04 R stage of large disks is thinned further
/// ([`stage_stride`]). Stride 4 at σ 3.3 px sent the bench's noise seed 3
/// into another basin (docs/photoelastic.md, round 11).
fn stride_for(sigma_px: f64) -> u32 {
    ((sigma_px / 1.5).floor() as u32).clamp(1, 4)
}

/// Disks at least this large [px] fit the 0.04 R stage ([`STAGES`]\[1\],
/// σ ≥ 1.2 px) on every 2nd pixel too: its time fell by ~3/4 with every
/// bench answer and real-photo share unchanged. Smaller disks keep every
/// pixel (round 2 saw stride 2 change the basin at r = 20 px), and the
/// coarser stages keep [`stride_for`]: stride 2 in all three smoothed stages
/// from r = 30 px moved fixed48's answer (docs/photoelastic.md, round 14).
const FINE_STAGE_THIN_RADIUS_PX: f64 = 30.0;

/// The pixel stride of smoothed stage `i` of [`STAGES`] for disks of median
/// radius `radius_px`.
fn stage_stride(i: usize, radius_px: f64) -> u32 {
    let thin_fine = i == 1 && radius_px >= FINE_STAGE_THIN_RADIUS_PX;
    stride_for(STAGES[i] * radius_px).max(if thin_fine { 2 } else { 1 })
}

/// The final (unsmoothed) stage first converges on every `FINAL_STRIDE`-th
/// pixel in x and y, then is polished on all of them with at least
/// [`POLISH_STEPS`] of its budget left: on the subset each step costs a
/// quarter and the fit reaches the full set's basin (docs/photoelastic.md,
/// round 11).
const FINAL_STRIDE: u32 = 2;
const POLISH_STEPS: usize = 5;

/// The polish on all pixels of disks at least [`FINE_STAGE_THIN_RADIUS_PX`]
/// large takes at most this many steps: there a quarter of the pixels
/// already samples the fringes finely, and the polish's 3–5 steps to its
/// tolerance cost about a third of the pixel work. Every render's relerr
/// and real-photo share was unchanged (docs/photoelastic.md, round 17).
const THIN_POLISH_STEPS: usize = 1;

/// Disks of a median radius of at least twice this [px] are fitted on the
/// photograph binned k × k, k = ⌊R / FIT_RADIUS_PX⌋, so that they span
/// 40–80 px there: a disk shows as many fringes at any resolution, so the
/// extra pixels of a larger one add cost and memory (∝ R²), not
/// information. A bin's mean is what a camera of k× coarser pixels sees,
/// which the model's pixel term already describes (docs/photoelastic.md,
/// round 17).
const FIT_RADIUS_PX: f64 = 40.0;

/// The bin factor of [`FIT_RADIUS_PX`] for `scene` in `frame` (1: none).
fn pixel_bin(frame: &PixelFrame, scene: &Scene) -> u32 {
    let mut radii: Vec<f64> = (scene.grains.iter())
        .map(|g| g.equivalent_radius(2) * frame.px_per_m)
        .filter(|r| r.is_finite())
        .collect();
    if radii.is_empty() {
        return 1;
    }
    radii.sort_by(f64::total_cmp);
    let bin = (radii[radii.len() / 2] / FIT_RADIUS_PX).floor();
    (bin as u32).clamp(1, frame.width.min(frame.height).max(1))
}

/// The photograph binned `bin` × `bin` (each pixel the mean of its block;
/// a partial last row or column is dropped), its frame (the same scene
/// positions) and `settings` in its pixels.
fn binned(
    image: &FloatImage,
    frame: &PixelFrame,
    settings: &FringeFitSettings,
    bin: u32,
) -> (FloatImage, PixelFrame, FringeFitSettings) {
    let (width, height) = (image.width() / bin, image.height() / bin);
    let share = 1.0 / (bin * bin) as f32;
    let out = FloatImage::from_fn(width, height, |x, y| {
        let mut sum = 0.0f32;
        for v in y * bin..(y + 1) * bin {
            for u in x * bin..(x + 1) * bin {
                sum += image.get_pixel(u, v)[0];
            }
        }
        ::image::Luma([sum * share])
    });
    let dropped_rows = (frame.height - height * bin) as f64;
    let frame = PixelFrame {
        px_per_m: frame.px_per_m / bin as f64,
        origin: [
            frame.origin[0],
            frame.origin[1] + dropped_rows / frame.px_per_m,
        ],
        width,
        height,
    };
    // The optics' blur in the coarse pixels; the bin's own box is the
    // model's pixel term.
    let settings = FringeFitSettings {
        blur_px: settings.blur_px / bin as f64,
        edge_px: settings.edge_px / bin as f64,
        ..settings.clone()
    };
    (out, frame, settings)
}

/// `fit` at the resolution [`pixel_bin`] chooses: on the binned photograph
/// where disks are large (the report saying so, its blur in the
/// photograph's pixels), None where they are fitted as they are.
fn at_fit_resolution(
    image: &FloatImage,
    frame: &PixelFrame,
    scene: &Scene,
    settings: &FringeFitSettings,
    fit: impl Fn(&FloatImage, &PixelFrame, &FringeFitSettings) -> Result<FringeFit>,
) -> Option<Result<FringeFit>> {
    let bin = pixel_bin(frame, scene);
    if bin <= 1 || (image.width(), image.height()) != (frame.width, frame.height) {
        return None;
    }
    let (image, frame, coarse) = binned(image, frame, settings, bin);
    Some(fit(&image, &frame, &coarse).map(|mut done| {
        done.report.pixel_bin = bin;
        done.report.blur_px = settings.blur_px;
        done
    }))
}

/// The problem with each disk's intensities smoothed by `sigma_px`.
fn smoothed(p: &Prepared, sigma_px: f64) -> Prepared {
    Prepared {
        disks: p
            .disks
            .par_iter()
            .map(|d| d.with_intensity(smoothed_intensity(d, sigma_px)))
            .collect(),
        unknowns: p.unknowns,
        scale: p.scale,
        optics: p.optics,
        pixel: p.pixel,
        balanced: p.balanced.clone(),
        pinned: p.pinned.clone(),
    }
}

/// [`Polariscope::Auto`] for the per-disk fit: the fit under each
/// polariscope, and the one whose fringes come closer to the photograph
/// kept (steps and seconds of both). The joint fit decides early instead
/// ([`Stages::decide_polariscope`]).
/// A vote of the disks at the start was tried instead and picked the dark
/// field on real bright-field photographs (docs/photoelastic.md, round 9).
fn either_polariscope(
    settings: &FringeFitSettings,
    fit: impl Fn(&FringeFitSettings) -> Result<FringeFit>,
) -> Result<FringeFit> {
    let lit = |polariscope| FringeFitSettings {
        polariscope,
        ..settings.clone()
    };
    let dark = fit(&lit(Polariscope::Dark))?;
    let bright = fit(&lit(Polariscope::Bright))?;
    let (steps, seconds) = (
        dark.report.iterations + bright.report.iterations,
        dark.report.seconds + bright.report.seconds,
    );
    let mut kept = if bright.report.objective < dark.report.objective {
        bright
    } else {
        dark
    };
    kept.report.iterations = steps;
    kept.report.seconds = seconds;
    Ok(kept)
}

fn stage_optics(
    p: &Prepared,
    frame: &PixelFrame,
    settings: &FringeFitSettings,
    extra_px: f64,
) -> Optics {
    let s = frame.px_per_m;
    Optics {
        blur2: (settings.blur_px.powi(2) + 1.0 / 12.0 + extra_px * extra_px) / (s * s),
        ..p.optics
    }
}

/// Fits every contact force of `scene` to the fringes of `image` (one
/// channel, intensities in [0, 1]; green for a colour photograph) placed in
/// the scene by `frame`: all disks at once, under balance and friction.
/// With `candidate_gap`, near-miss disk pairs are fitted too; with
/// `sparsity`, contacts the fringes do not support are fitted to zero,
/// dropped (listed in the report) and the rest refitted.
pub fn fit_fringes(
    image: &FloatImage,
    frame: &PixelFrame,
    scene: &Scene,
    settings: &FringeFitSettings,
) -> Result<FringeFit> {
    settings.validate()?;
    if let Some(done) = at_fit_resolution(image, frame, scene, settings, |i, f, s| {
        fit_fringes(i, f, scene, s)
    }) {
        return done;
    }
    let started = std::time::Instant::now();
    let (mut work, mut gaps) = with_candidates(scene, settings.candidate_gap);
    let mut start = settings.clone();
    // Candidates start unloaded (a start of the wrong length is refused below).
    if let Some(forces) = start
        .start
        .as_mut()
        .filter(|f| f.len() == scene.contacts.len())
    {
        forces.resize(work.contacts.len(), [0.0; 2]);
    }
    let (mut fit, mut x) = fit_scene(image, frame, &work, &start, settings.sparsity)?;
    // Under `Auto`, the prune and the refit keep the polariscope the fit chose.
    let settings = &FringeFitSettings {
        polariscope: match fit.report.bright_field {
            true => Polariscope::Bright,
            false => Polariscope::Dark,
        },
        ..settings.clone()
    };
    if let Some(walled) = with_wall_candidates(image, frame, &work, &mut fit, settings)? {
        (fit, x) = walled.fit;
        work = std::borrow::Cow::Owned(walled.scene);
        gaps.extend(walled.gaps);
    }
    let mut dropped = vec![false; work.contacts.len()];
    if settings.sparsity > 0.0 {
        for (k, d) in dropped.iter_mut().enumerate() {
            *d = x[2 * k] < SPARSE_EPS;
        }
    }
    if let Some(floor) = settings.support_prune {
        let support = contact_support(image, frame, &work, &fit.forces, settings)?;
        for (d, s) in dropped.iter_mut().zip(&support) {
            *d |= *s < floor;
        }
    }
    if dropped.iter().any(|d| *d) {
        // Refit the kept contacts without the term, from the sparse fit.
        let mut kept = work.clone().into_owned();
        kept.contacts = (work.contacts.iter().zip(&dropped))
            .filter(|(_, d)| !**d)
            .map(|(c, _)| c.clone())
            .collect();
        let mut refit = settings.clone();
        refit.start = Some(
            (fit.forces.iter().zip(&dropped))
                .filter(|(_, d)| !**d)
                .map(|(f, _)| *f)
                .collect(),
        );
        let (again, _) = fit_scene(image, frame, &kept, &refit, 0.0)?;
        let mut next = again.forces.iter();
        let forces = (dropped.iter())
            .map(|d| match d {
                true => [0.0; 2],
                false => *next.next().expect("one force per kept contact"),
            })
            .collect();
        let first = fit.report;
        fit = FringeFit {
            forces,
            report: again.report,
        };
        fit.report.iterations += first.iterations;
        fit.report.objective_start = first.objective_start;
        fit.report.timing.after(&first.timing);
    }
    fit.report.dropped = (work.contacts.iter().zip(&dropped))
        .filter(|(_, d)| **d)
        .map(|(c, _)| c.id.clone())
        .collect();
    let n = scene.contacts.len();
    fit.report.candidates = (work.contacts[n..].iter().zip(&gaps))
        .zip(fit.forces[n..].iter().zip(&dropped[n..]))
        .map(|((c, &gap), (f, &dropped))| CandidateContact {
            id: c.id.clone(),
            a: c.a,
            b: match c.b {
                Body::Grain(b) | Body::Wall(b) => b,
            },
            wall: matches!(c.b, Body::Wall(_)),
            point: [c.point[0], c.point[1]],
            normal: [c.normal[0], c.normal[1]],
            gap,
            force: *f,
            dropped,
        })
        .collect();
    fit.forces.truncate(n);
    fit.report.seconds = started.elapsed().as_secs_f64();
    Ok(fit)
}

/// `scene` with every disk pair closer than `gap` × the smaller radius and
/// not already in contact added as a contact (normal and point on the
/// centre line), and each added pair's gap over the smaller radius.
fn with_candidates(scene: &Scene, gap: Option<f64>) -> (std::borrow::Cow<'_, Scene>, Vec<f64>) {
    let Some(gap) = gap.filter(|g| *g > 0.0) else {
        return (std::borrow::Cow::Borrowed(scene), Vec::new());
    };
    let listed: std::collections::HashSet<(usize, usize)> = (scene.contacts.iter())
        .filter_map(|c| match c.b {
            Body::Grain(b) => Some((c.a.min(b), c.a.max(b))),
            Body::Wall(_) => None,
        })
        .collect();
    let mut out = scene.clone();
    let mut gaps = Vec::new();
    let g = &scene.grains;
    for i in 0..g.len() {
        for j in i + 1..g.len() {
            let (pi, pj) = (g[i].position, g[j].position);
            let (ri, rj) = (g[i].equivalent_radius(2), g[j].equivalent_radius(2));
            let (dx, dy) = (pj[0] - pi[0], pj[1] - pi[1]);
            let distance = dx.hypot(dy);
            let smaller = ri.min(rj);
            let relative = (distance - ri - rj) / smaller;
            if !(relative < gap && distance > 0.0) || listed.contains(&(i, j)) {
                continue;
            }
            let n = [dx / distance, dy / distance, 0.0];
            out.contacts.push(crate::scene::Contact {
                id: format!("candidate:{}-{}", g[i].id, g[j].id),
                a: i,
                b: Body::Grain(j),
                point: [pi[0] + ri * n[0], pi[1] + ri * n[1], 0.0],
                normal: n,
                mu: None,
            });
            gaps.push(relative);
        }
    }
    (std::borrow::Cow::Owned(out), gaps)
}

/// The fit with disk–wall candidates added: the scene, the added pairs'
/// gaps and the refit (forces, report, unknowns).
struct WalledFit {
    scene: Scene,
    gaps: Vec<f64>,
    fit: (FringeFit, Vec<f64>),
}

/// With `wall_candidates`, the scene with the disk–wall candidates
/// ([`add_wall_candidates`]) fitted too, kept only where its final objective
/// is below `fit`'s, the fit without them (None otherwise, or with none to
/// add; `fit` then counts the extra path's steps): the same pixels, and the candidates can carry zero, so the
/// fringes choose. Fitted alone they reach the right basin where a wall
/// contact was missed (bundled render: objective 730 against 1413, relerr
/// 0.012 against 0.085) but can lead the coarse stages into a worse one
/// elsewhere (noise seed 3: 2191 against 1397, 0.20 against 0.12); refitted
/// from `fit`'s answer instead they stay in its basin (0.077). Costs one
/// path: walls frictionless first where [`fit_scene`] fits two (that path
/// won on every detected render), and `fit`'s polariscope; fitted only
/// where some candidate's disk is flagged by `fit`.
fn with_wall_candidates(
    image: &FloatImage,
    frame: &PixelFrame,
    scene: &Scene,
    fit: &mut FringeFit,
    settings: &FringeFitSettings,
) -> Result<Option<WalledFit>> {
    let Some(gap) = settings.candidate_gap.filter(|g| *g > 0.0) else {
        return Ok(None);
    };
    if !settings.wall_candidates {
        return Ok(None);
    }
    let mut walled = scene.clone();
    let gaps = add_wall_candidates(&mut walled, gap);
    // Only where a candidate's disk says a contact is missing: its fringes
    // unexplained (flagged). A disk whose balance is left out but that shows
    // no fringes needs no load (the bundled render's disk 10 by the right
    // wall: its candidate is fitted to zero).
    let flagged = &fit.report.flagged;
    let missing = (walled.contacts[scene.contacts.len()..].iter())
        .any(|c| flagged.contains(&scene.grains[c.a].id));
    if !missing {
        return Ok(None);
    }
    let start = settings.start.as_ref().map(|forces| {
        let mut forces = forces.clone();
        forces.resize(walled.contacts.len(), [0.0; 2]);
        forces
    });
    let refit = FringeFitSettings {
        start,
        ..settings.clone()
    };
    let walls_first = two_paths(&walled, &refit);
    let (mut again, x) = fit_path(
        image,
        frame,
        &walled,
        &refit,
        settings.sparsity,
        walls_first,
    )?;
    if again.report.objective >= fit.report.objective {
        fit.report.iterations += again.report.iterations;
        return Ok(None);
    }
    again.report.iterations += fit.report.iterations;
    again.report.objective_start = fit.report.objective_start;
    again.report.timing.after(&fit.report.timing);
    Ok(Some(WalledFit {
        scene: walled,
        gaps,
        fit: (again, x),
    }))
}

/// Appends to `scene` every disk–wall pair closer than `gap` × the disk's
/// radius and not already in contact (normal the wall's, point on its
/// line), and returns each added pair's gap over the radius. A wall's line
/// is its listed contacts' mean point and normal
/// ([`super::contacts::wall_line_of_contacts`]); a disk must face the wall
/// from the side its contacts do.
fn add_wall_candidates(scene: &mut Scene, gap: f64) -> Vec<f64> {
    let mut gaps = Vec::new();
    for w in 0..scene.walls.len() {
        let Some((point, normal)) = super::contacts::wall_line_of_contacts(scene, w) else {
            continue;
        };
        if !is_straight(scene, w, point, normal) {
            continue;
        }
        let listed: std::collections::HashSet<usize> = (scene.contacts.iter())
            .filter(|c| c.b == Body::Wall(w))
            .map(|c| c.a)
            .collect();
        for (a, grain) in scene.grains.iter().enumerate() {
            let r = grain.equivalent_radius(2);
            // The disk's centre to the wall, along the wall's normal.
            let reach = (point[0] - grain.position[0]) * normal[0]
                + (point[1] - grain.position[1]) * normal[1];
            let relative = (reach - r) / r;
            if listed.contains(&a) || !(reach > 0.0 && relative < gap) {
                continue;
            }
            let id = format!("candidate:{}-{}", grain.id, scene.walls[w].name);
            let at = [
                grain.position[0] + reach * normal[0],
                grain.position[1] + reach * normal[1],
            ];
            scene.contacts.push(crate::scene::Contact {
                id,
                a,
                b: Body::Wall(w),
                point: [at[0], at[1], 0.0],
                normal: [normal[0], normal[1], 0.0],
                mu: None,
            });
            gaps.push(relative);
        }
    }
    gaps
}

/// Whether wall `w`'s listed contacts lie on one line (`point`, `normal`):
/// every normal within 5° of it and every point within a tenth of its
/// disk's radius. Loads from outside a cut-out cluster, or a curved
/// boundary, have no line to measure a gap to.
fn is_straight(scene: &Scene, w: usize, point: [f64; 2], normal: [f64; 2]) -> bool {
    let cos_5_degrees = 5f64.to_radians().cos();
    (scene.contacts.iter().filter(|c| c.b == Body::Wall(w))).all(|c| {
        let n = [c.normal[0], c.normal[1]];
        let along = (n[0] * normal[0] + n[1] * normal[1]) / n[0].hypot(n[1]);
        let off = (c.point[0] - point[0]) * normal[0] + (c.point[1] - point[1]) * normal[1];
        along > cos_5_degrees && off.abs() < 0.1 * scene.grains[c.a].equivalent_radius(2)
    })
}

/// The joint fit of `scene`'s contacts, `sparsity` in the final stage; the
/// forces, the report and the final unknowns. With `smooth_walls_first`
/// and walls that have friction, fitted twice — walls frictionless until
/// the final stage, and with their friction throughout — and the lower
/// final objective kept: the same problem in its final stage, two paths
/// to it (the first avoids a basin of sideways wall loads on detected
/// geometry; the second is needed where the walls do carry friction). A
/// path well behind the other after the envelope stage
/// ([`EARLY_PATH_MARGIN`]) is not continued. With `walls_first_alone`, the
/// first path only.
fn fit_scene(
    image: &FloatImage,
    frame: &PixelFrame,
    scene: &Scene,
    settings: &FringeFitSettings,
    sparsity: f64,
) -> Result<(FringeFit, Vec<f64>)> {
    let walls_first = two_paths(scene, settings);
    if !walls_first || settings.walls_first_alone {
        return fit_path(image, frame, scene, settings, sparsity, walls_first);
    }
    // The two paths share nothing but their inputs: fitted at once on two
    // cores (each sums its objective in disk order, so the same bits
    // whatever the schedule).
    // Their G² levels are the same: scanned once, before they part.
    load_levels(
        &prepare(image, frame, scene, settings, false)?,
        &settings.shared,
    );
    let begin = |walls_first| begin_path(image, frame, scene, settings, walls_first);
    let (first, throughout) = rayon::join(|| begin(true), || begin(false));
    let (first, throughout) = (first?, throughout?);
    let finish = |begun| finish_path(frame, scene, settings, sparsity, begun);
    // A path well behind after the envelope stage is not continued.
    let alone = |ahead: BegunPath, behind: BegunPath| {
        let mut kept = finish(ahead)?;
        kept.0.report.iterations += behind.iterations;
        Ok(kept)
    };
    let (a, b) = (first.envelope_objective, throughout.envelope_objective);
    if a < EARLY_PATH_MARGIN * b {
        return alone(first, throughout);
    }
    if b < EARLY_PATH_MARGIN * a {
        return alone(throughout, first);
    }
    let (first, throughout) = rayon::join(|| finish(first), || finish(throughout));
    let (first, throughout) = (first?, throughout?);
    let steps = first.0.report.iterations + throughout.0.report.iterations;
    let mut kept = if first.0.report.objective <= throughout.0.report.objective {
        first
    } else {
        throughout
    };
    kept.0.report.iterations = steps;
    kept.0.report.paths = 2;
    Ok(kept)
}

/// Where one of [`fit_scene`]'s two paths ends its envelope stage below
/// this share of the other's objective, it alone is continued. On the five
/// renders and three PeGS photographs (plain fits and narrow starts, round
/// 18) every path ahead by more than 10 % there ended lower, or within
/// 7·10⁻⁶ of the other (the same basin); paths closer there ended in either
/// order (step83's plain fit: 4.6 % behind after the envelope, 41 % ahead
/// at the end).
const EARLY_PATH_MARGIN: f64 = 0.9;

/// Whether [`fit_scene`] fits two paths: `smooth_walls_first`, walls with
/// friction, the fringe start and exact balance (under a balance penalty
/// the residual alone does not rank the paths).
fn two_paths(scene: &Scene, settings: &FringeFitSettings) -> bool {
    let rough_walls = (scene.contacts.iter().zip(friction_cones(scene, settings))).any(
        |(c, cone)| matches!((c.b, cone), (Body::Wall(_), Cone::Wedge { mu, .. }) if mu > 0.0),
    );
    let hard = settings.balance == Balance::Hard;
    settings.smooth_walls_first && settings.start.is_none() && rough_walls && hard
}

/// One path of [`fit_scene`]: `walls_first` holds the walls frictionless
/// in the start and the coarse stages.
fn fit_path(
    image: &FloatImage,
    frame: &PixelFrame,
    scene: &Scene,
    settings: &FringeFitSettings,
    sparsity: f64,
    walls_first: bool,
) -> Result<(FringeFit, Vec<f64>)> {
    let begun = begin_path(image, frame, scene, settings, walls_first)?;
    finish_path(frame, scene, settings, sparsity, begun)
}

/// A path of [`fit_scene`] up to the end of its envelope stage (the start
/// and the envelope; with a start given, the start only).
struct BegunPath {
    started: std::time::Instant,
    laps: Laps,
    timing: FitTiming,
    p: Prepared,
    /// The scene of the coarse stages, where it differs (walls frictionless).
    coarse_scene: Option<Scene>,
    final_balanced: Vec<bool>,
    levels: Vec<Vec<f64>>,
    start_x: Vec<f64>,
    x: Vec<f64>,
    iterations: usize,
    /// The envelope stage's final objective (infinite without one).
    envelope_objective: f64,
}

/// [`fit_path`] up to the end of its envelope stage.
fn begin_path(
    image: &FloatImage,
    frame: &PixelFrame,
    scene: &Scene,
    settings: &FringeFitSettings,
    walls_first: bool,
) -> Result<BegunPath> {
    let started = std::time::Instant::now();
    let mut laps = Laps::start();
    let mut timing = FitTiming::default();
    let mut p = prepare(image, frame, scene, settings, false)?;
    timing.prepare = started.elapsed().as_secs_f64();
    let clock = std::time::Instant::now();
    let cones = friction_cones(scene, settings);
    p.balanced = p
        .disks
        .par_iter()
        .map(|d| can_balance(d, &cones))
        .collect::<Result<_>>()?;
    // From the fringe gradients, the start and the coarse stages hold the
    // walls frictionless (a disk that then cannot balance alone is left out
    // of them); the final stage gives the walls their friction.
    let coarse_scene = (walls_first && settings.start.is_none())
        .then(|| frictionless_walls(scene))
        .flatten();
    let coarse = coarse_scene.as_ref().unwrap_or(scene);
    if settings.start.is_none() {
        release_pinned_packing(&mut p, scene, settings)?;
    }
    let final_balanced = p.balanced.clone();
    if coarse_scene.is_some() {
        let cones = friction_cones(coarse, settings);
        let alone: Vec<bool> = (p.disks.par_iter())
            .map(|d| can_balance(d, &cones))
            .collect::<Result<_>>()?;
        for (b, a) in p.balanced.iter_mut().zip(alone) {
            *b &= a;
        }
        release_pinned_packing(&mut p, coarse, settings)?;
    }
    laps.lap(&format!(
        "fringe path (walls first {walls_first}, {} contacts): prepare",
        scene.contacts.len()
    ));
    let levels = load_levels(&p, &settings.shared);
    laps.lap("fringe path: G² levels");
    let given_x = match &settings.start {
        Some(forces) => Some(to_unknowns(scene, forces, p.scale)?),
        None => None,
    };
    let mut x = match &given_x {
        Some(x0) => {
            if settings.balance == Balance::Hard {
                release_forced_zeros(&mut p, scene, settings, x0)?;
            }
            feasible_start(&p, scene, settings, x0.clone())?
        }
        None => balanced_start(&p, coarse, settings, &levels)?,
    };
    // The objective is reported at the start as given (before it is
    // balanced), under the polariscope the fit ends with.
    let start_x = given_x.unwrap_or_else(|| x.clone());
    timing.start = clock.elapsed().as_secs_f64();
    laps.lap("fringe path: balanced start");
    let radius_px = p.scale / settings.fringe_stress * frame.px_per_m;
    let mut iterations = 0;
    let mut envelope_objective = f64::INFINITY;
    if settings.start.is_none() {
        // The envelope first: smooth in the forces, its minimum near the
        // intensity fit's basin.
        let clock = std::time::Instant::now();
        let sigma = (0.08 * radius_px).max(2.0);
        let env = thinned(&enveloped(&p, sigma), stride_for(sigma));
        timing.smoothing += clock.elapsed().as_secs_f64();
        let optics = Optics {
            envelope: Some(frame.px_per_m),
            ..stage_optics(&p, frame, settings, 0.0)
        };
        let stepper = Stepper {
            p: &env,
            scene: Some(coarse),
            settings,
            sparsity: 0.0,
            accuracy: stage_accuracy(settings, false),
        };
        let out = stepper.run(
            x,
            &optics,
            settings.max_iterations / 3,
            COARSE_TOLERANCE,
            &mut timing,
        )?;
        x = out.x;
        iterations += out.iterations;
        envelope_objective = out.objective;
        timing.steps.push(out.iterations);
        timing.ends.push(out.end);
    }
    Ok(BegunPath {
        started,
        laps,
        timing,
        p,
        coarse_scene,
        final_balanced,
        levels,
        start_x,
        x,
        iterations,
        envelope_objective,
    })
}

/// The rest of [`fit_path`] from `begun`: the intensity stages and the report.
fn finish_path(
    frame: &PixelFrame,
    scene: &Scene,
    settings: &FringeFitSettings,
    sparsity: f64,
    begun: BegunPath,
) -> Result<(FringeFit, Vec<f64>)> {
    let BegunPath {
        started,
        mut laps,
        mut timing,
        mut p,
        coarse_scene,
        final_balanced,
        levels,
        start_x,
        x,
        iterations,
        ..
    } = begun;
    let coarse = coarse_scene.as_ref().unwrap_or(scene);
    let radius_px = p.scale / settings.fringe_stress * frame.px_per_m;
    let stages = Stages {
        frame,
        settings,
        scene,
        coarse,
        walls_first: coarse_scene.is_some(),
        final_balanced: &final_balanced,
        radius_px,
        sparsity,
    };
    let mut state = StageState {
        x,
        iterations,
        discarded: 0,
        damping: 0.0,
        objective: f64::INFINITY,
    };
    let mut next = 0;
    if settings.polariscope == Polariscope::Auto {
        next = stages.decide_polariscope(&mut p, &mut state, &mut timing)?;
    }
    for i in next..STAGES.len() {
        stages.run(i, &mut p, &mut state, &mut timing)?;
    }
    let StageState {
        x,
        iterations,
        discarded,
        damping,
        ..
    } = state;
    let iterations = iterations + discarded;
    laps.lap("fringe path: stages");
    let objective_start = objective(&p, &start_x, &p.optics);
    let forces = to_forces(scene, &x, p.scale);
    let report = report(
        "joint",
        &p,
        scene,
        settings,
        &x,
        &forces,
        &levels,
        objective_start,
        iterations,
        damping,
        started,
        timing,
    );
    Ok((FringeFit { forces, report }, x))
}

/// The last stage whose end decides [`Polariscope::Auto`]: both
/// polariscopes are fitted through it from the shared start and envelope
/// stage (neither depends on the polariscope), and the lower objective
/// continues alone (docs/photoelastic.md, "An early polariscope").
const DECIDE_POLARISCOPE_AFTER: usize = 0;
const _: () = assert!(DECIDE_POLARISCOPE_AFTER < STAGES.len());

/// Where a path's stages have brought the unknowns.
#[derive(Clone)]
struct StageState {
    x: Vec<f64>,
    /// Steps on this path (the stages' budgets come from them).
    iterations: usize,
    /// Steps of the polariscope not kept (reported, not budgeted).
    discarded: usize,
    damping: f64,
    objective: f64,
}

/// What every intensity stage of one path shares.
struct Stages<'a> {
    frame: &'a PixelFrame,
    settings: &'a FringeFitSettings,
    scene: &'a Scene,
    coarse: &'a Scene,
    walls_first: bool,
    final_balanced: &'a [bool],
    radius_px: f64,
    sparsity: f64,
}

impl Stages<'_> {
    /// Stages up to [`DECIDE_POLARISCOPE_AFTER`] under each polariscope,
    /// the better kept in `p` and `state`; the next stage to run.
    /// `GRAINFORCE_POLARISCOPE_TRACE` (a diagnostic) runs both to the end
    /// instead, printing each stage's objective, and keeps the lower final one.
    fn decide_polariscope(
        &self,
        p: &mut Prepared,
        state: &mut StageState,
        timing: &mut FitTiming,
    ) -> Result<usize> {
        let trace = std::env::var_os("GRAINFORCE_POLARISCOPE_TRACE").is_some();
        let last = if trace {
            STAGES.len() - 1
        } else {
            DECIDE_POLARISCOPE_AFTER
        };
        let balanced = p.balanced.clone();
        let mut best: Option<(bool, StageState)> = None;
        for bright in [false, true] {
            p.optics.bright_field = bright;
            p.balanced = balanced.clone();
            let mut s = state.clone();
            let mut objectives = Vec::new();
            for i in 0..=last {
                self.run(i, p, &mut s, timing)?;
                objectives.push(s.objective);
            }
            if trace {
                eprintln!("polariscope trace: bright {bright} stage objectives {objectives:?}");
            }
            match best.as_mut() {
                Some((_, b)) if s.objective >= b.objective => {
                    b.discarded += s.iterations - state.iterations;
                }
                Some((_, b)) => {
                    s.discarded += b.iterations - state.iterations;
                    best = Some((bright, s));
                }
                None => best = Some((bright, s)),
            }
        }
        let (bright, kept) = best.expect("two polariscopes fitted");
        *state = kept;
        p.optics.bright_field = bright;
        if trace || last + 1 == STAGES.len() {
            return Ok(STAGES.len());
        }
        p.balanced = balanced;
        Ok(last + 1)
    }

    /// Stage `i` of [`STAGES`] from `state`.
    fn run(
        &self,
        i: usize,
        p: &mut Prepared,
        state: &mut StageState,
        timing: &mut FitTiming,
    ) -> Result<()> {
        let (frame, settings, scene, coarse) = (self.frame, self.settings, self.scene, self.coarse);
        let extra = STAGES[i];
        let left = settings.max_iterations.saturating_sub(state.iterations);
        let budget = if i + 1 == STAGES.len() {
            left
        } else {
            left / 3
        };
        if budget == 0 {
            return Ok(());
        }
        let sigma = extra * self.radius_px;
        let clock = std::time::Instant::now();
        let stage = if sigma > 0.5 {
            Some(thinned(
                &smoothed(p, sigma),
                stage_stride(i, self.radius_px),
            ))
        } else {
            None
        };
        timing.smoothing += clock.elapsed().as_secs_f64();
        let last = i + 1 == STAGES.len();
        if last && self.walls_first && p.balanced != self.final_balanced {
            // Disks left out of the coarse stages' balance are held to it
            // again: the nearest balanced field, from which steps are taken.
            p.balanced = self.final_balanced.to_vec();
            state.x = feasible_start(p, scene, settings, std::mem::take(&mut state.x))?;
        }
        let stepper = Stepper {
            p: stage.as_ref().unwrap_or(p),
            scene: Some(if last { scene } else { coarse }),
            settings,
            sparsity: if last { self.sparsity } else { 0.0 },
            accuracy: stage_accuracy(settings, last),
        };
        let optics = stage_optics(
            p,
            frame,
            settings,
            if stage.is_some() { sigma } else { 0.0 },
        );
        let tolerance = if last {
            FINAL_TOLERANCE
        } else {
            COARSE_TOLERANCE
        };
        let mut budget = budget;
        if last && stage.is_none() && budget > POLISH_STEPS {
            // Converged on a subset first, polished on every pixel.
            let subset = thinned(p, FINAL_STRIDE);
            let out = Stepper {
                p: &subset,
                ..stepper
            }
            .run(
                std::mem::take(&mut state.x),
                &optics,
                budget - POLISH_STEPS,
                tolerance,
                timing,
            )?;
            state.x = out.x;
            state.iterations += out.iterations;
            timing.steps.push(out.iterations);
            timing.ends.push(out.end);
            budget -= out.iterations;
            if self.radius_px >= FINE_STAGE_THIN_RADIUS_PX {
                budget = budget.min(THIN_POLISH_STEPS);
            }
        }
        let out = stepper.run(
            std::mem::take(&mut state.x),
            &optics,
            budget,
            tolerance,
            timing,
        )?;
        state.x = out.x;
        state.iterations += out.iterations;
        state.damping = out.damping;
        state.objective = out.objective;
        timing.steps.push(out.iterations);
        timing.ends.push(out.end);
        Ok(())
    }
}

/// Set to a share to override the final stage's
/// [`FringeFitSettings::data_accuracy`], and `…_COARSE` to give the
/// envelope and smoothed stages one, for measuring only: they have none, as
/// at 1 (steps within the noise's effect on their smoothed data) step83's
/// share fell below its floor too (docs/photoelastic.md, round 18).
const ACCURACY_ENV: &str = "GRAINFORCE_FRINGE_ACCURACY";

/// The data-accuracy share of the final or a coarse stage (0: off).
fn stage_accuracy(settings: &FringeFitSettings, last: bool) -> f64 {
    let (name, default) = match last {
        true => (ACCURACY_ENV.to_string(), settings.data_accuracy),
        false => (format!("{ACCURACY_ENV}_COARSE"), 0.0),
    };
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// The walls' μ in the coarse stages of the walls-first path: nearly
/// frictionless, a wedge wide enough for the step solver (at 0 its steps
/// left the balance).
const COARSE_WALL_MU: f64 = 0.02;

/// `scene` with every wall contact (nearly) frictionless; None without wall contacts.
fn frictionless_walls(scene: &Scene) -> Option<Scene> {
    let walls = |c: &&mut crate::scene::Contact| matches!(c.b, Body::Wall(_));
    let mut out = scene.clone();
    let mut any = false;
    for c in out.contacts.iter_mut().filter(walls) {
        c.mu = Some(COARSE_WALL_MU);
        any = true;
    }
    any.then_some(out)
}

/// How much each contact's load explains of its disks' fringes: for each
/// contact of `scene` (with `forces`, e.g. a fit's), its disks' squared
/// intensity residual when it is removed and their other loads refitted
/// freely (each disk alone, 10 steps), less the residual with it, over the
/// residual with it. Near 0: the fringes do not need the contact; a
/// statistic relative to the disks' own residual level.
pub fn contact_support(
    image: &FloatImage,
    frame: &PixelFrame,
    scene: &Scene,
    forces: &[[f64; 2]],
    settings: &FringeFitSettings,
) -> Result<Vec<f64>> {
    let p = prepare(image, frame, scene, settings, false)?;
    let x = to_unknowns(scene, forces, p.scale)?;
    let optics = stage_optics(&p, frame, settings, 0.0);
    // Disk d's residual with its loads but `skip` refitted freely from x.
    let refitted = |d: &DiskData, skip: Option<usize>| -> Result<f64> {
        let loads: Vec<Load> = (d.loads.iter())
            .filter(|l| Some(l.unknown) != skip)
            .copied()
            .collect();
        let u0: Vec<f64> = (loads.iter())
            .flat_map(|l| [x[2 * l.unknown], x[2 * l.unknown + 1]])
            .collect();
        let sub = p.alone(d, loads);
        if u0.is_empty() {
            return Ok(sub.disks[0].evaluate(&[], &optics, false).ssr);
        }
        let stepper = Stepper {
            p: &sub,
            scene: None,
            settings,
            sparsity: 0.0,
            accuracy: 0.0,
        };
        let out = stepper.run(u0, &optics, 10, FINAL_TOLERANCE, &mut FitTiming::default())?;
        Ok(sub.disks[0].evaluate(&out.x, &optics, false).ssr)
    };
    // Each disk refitted with all its loads: the baseline of the same freedom.
    let full: Vec<f64> = (p.disks.par_iter())
        .map(|d| refitted(d, None))
        .collect::<Result<_>>()?;
    (0..scene.contacts.len())
        .into_par_iter()
        .map(|k| {
            let (mut with, mut without) = (0.0, 0.0);
            for (d, f) in p.disks.iter().zip(&full) {
                if d.loads.iter().any(|l| l.unknown == k) {
                    with += f;
                    without += refitted(d, Some(k))?;
                }
            }
            Ok((without - with) / with.max(1e-300))
        })
        .collect()
}

/// The per-disk fit the field uses (PeGS-like), as a baseline: each disk's
/// forces fitted to its own fringes alone (no balance, no friction, forces
/// of either sign), from the same G² start (or `start`, each side from its
/// contact's force), and the two sides of each contact averaged.
pub fn fit_fringes_per_disk(
    image: &FloatImage,
    frame: &PixelFrame,
    scene: &Scene,
    settings: &FringeFitSettings,
) -> Result<FringeFit> {
    if let Some(done) = at_fit_resolution(image, frame, scene, settings, |i, f, s| {
        fit_fringes_per_disk(i, f, scene, s)
    }) {
        return done;
    }
    if settings.polariscope == Polariscope::Auto {
        return either_polariscope(settings, |s| fit_fringes_per_disk(image, frame, scene, s));
    }
    let started = std::time::Instant::now();
    let mut timing = FitTiming::default();
    let p = prepare(image, frame, scene, settings, true)?;
    timing.prepare = started.elapsed().as_secs_f64();
    let levels = load_levels(&p, &settings.shared);
    let mut x = vec![0.0; 2 * p.unknowns];
    if let Some(forces) = &settings.start {
        // Both sides of a contact start from its force.
        let given = to_unknowns(scene, forces, p.scale)?;
        let mut side = 0;
        for (k, c) in scene.contacts.iter().enumerate() {
            let sides = if matches!(c.b, Body::Grain(_)) { 2 } else { 1 };
            for _ in 0..sides {
                x[2 * side..2 * side + 2].copy_from_slice(&given[2 * k..2 * k + 2]);
                side += 1;
            }
        }
    } else {
        for (d, side_levels) in p.disks.iter().zip(&levels) {
            for (l, v) in d.loads.iter().zip(side_levels) {
                x[2 * l.unknown] = *v;
            }
        }
    }
    let objective_start = objective(&p, &x, &p.optics);
    let optics = stage_optics(&p, frame, settings, 0.0);
    // Each disk on its own: a problem of its loads only.
    let results: Vec<(Vec<f64>, usize)> = p
        .disks
        .par_iter()
        .map(|d| {
            let sub = p.alone(d, d.loads.clone());
            let u0 = d.gather(&x);
            if u0.is_empty() {
                return Ok((u0, 0));
            }
            let stepper = Stepper {
                p: &sub,
                scene: None,
                settings,
                sparsity: 0.0,
                accuracy: 0.0,
            };
            let out = stepper.run(
                u0,
                &optics,
                settings.max_iterations,
                FINAL_TOLERANCE,
                &mut FitTiming::default(),
            )?;
            Ok((out.x, out.iterations))
        })
        .collect::<Result<_>>()?;
    let mut iterations = 0;
    for (d, (u, its)) in p.disks.iter().zip(&results) {
        iterations = iterations.max(*its);
        for (i, l) in d.loads.iter().enumerate() {
            x[2 * l.unknown] = u[2 * i];
            x[2 * l.unknown + 1] = u[2 * i + 1];
        }
    }
    // Average the sides of each contact.
    let mut joint = vec![0.0; 2 * scene.contacts.len()];
    let mut count = vec![0.0; scene.contacts.len()];
    let mut side = 0;
    for (k, c) in scene.contacts.iter().enumerate() {
        let sides = if matches!(c.b, Body::Grain(_)) { 2 } else { 1 };
        for _ in 0..sides {
            joint[2 * k] += x[2 * side];
            joint[2 * k + 1] += x[2 * side + 1];
            count[k] += 1.0;
            side += 1;
        }
    }
    for k in 0..scene.contacts.len() {
        joint[2 * k] /= count[k];
        joint[2 * k + 1] /= count[k];
    }
    let forces = to_forces(scene, &joint, p.scale);
    // The report's residuals are those of each disk's own fit.
    let report = report(
        "per-disk",
        &p,
        scene,
        settings,
        &x,
        &forces,
        &levels,
        objective_start,
        iterations,
        0.0,
        started,
        timing,
    );
    Ok(FringeFit { forces, report })
}

fn to_forces(scene: &Scene, x: &[f64], scale: f64) -> Vec<[f64; 2]> {
    scene
        .contacts
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let len = c.normal[0].hypot(c.normal[1]);
            let n = [c.normal[0] / len, c.normal[1] / len];
            let t = [-n[1], n[0]];
            let (un, ut) = (x[2 * k] * scale, x[2 * k + 1] * scale);
            [-un * n[0] + ut * t[0], -un * n[1] + ut * t[1]]
        })
        .collect()
}

/// Forces (scene axes) to the unknowns (u_n, u_t) / F₀.
fn to_unknowns(scene: &Scene, forces: &[[f64; 2]], scale: f64) -> Result<Vec<f64>> {
    if forces.len() != scene.contacts.len() {
        return Err(Error::Invalid(format!(
            "{} forces for {} contacts",
            forces.len(),
            scene.contacts.len()
        )));
    }
    let mut x = vec![0.0; 2 * scene.contacts.len()];
    for (k, (c, f)) in scene.contacts.iter().zip(forces).enumerate() {
        let len = c.normal[0].hypot(c.normal[1]);
        let n = [c.normal[0] / len, c.normal[1] / len];
        let t = [-n[1], n[0]];
        x[2 * k] = -(f[0] * n[0] + f[1] * n[1]) / scale;
        x[2 * k + 1] = (f[0] * t[0] + f[1] * t[1]) / scale;
    }
    Ok(x)
}

/// |ΣF| / Σ|F| of each grain under `forces` (0 for a grain without force,
/// or with only round-off: Σ|F| below 10⁻⁹ of the most loaded grain's).
pub fn imbalances(scene: &Scene, forces: &[[f64; 2]]) -> Vec<f64> {
    let mut sum = vec![[0.0f64; 2]; scene.grains.len()];
    let mut total = vec![0.0f64; scene.grains.len()];
    for (c, f) in scene.contacts.iter().zip(forces) {
        sum[c.a][0] += f[0];
        sum[c.a][1] += f[1];
        total[c.a] += f[0].hypot(f[1]);
        if let Body::Grain(b) = c.b {
            sum[b][0] -= f[0];
            sum[b][1] -= f[1];
            total[b] += f[0].hypot(f[1]);
        }
    }
    // A grain whose forces are round-off next to the packing's counts as unloaded.
    let floor = 1e-9 * total.iter().fold(0.0f64, |m, t| m.max(*t));
    sum.iter()
        .zip(&total)
        .map(|(s, t)| {
            if *t > floor {
                s[0].hypot(s[1]) / t
            } else {
                0.0
            }
        })
        .collect()
}

#[allow(clippy::too_many_arguments)]
fn report(
    method: &'static str,
    p: &Prepared,
    scene: &Scene,
    settings: &FringeFitSettings,
    x: &[f64],
    forces: &[[f64; 2]],
    levels: &[Vec<f64>],
    objective_start: f64,
    iterations: usize,
    damping: f64,
    started: std::time::Instant,
    timing: FitTiming,
) -> FringeFitReport {
    let imbalance = imbalances(scene, forces);
    let evals: Vec<DiskEval> = p
        .disks
        .par_iter()
        .map(|d| d.evaluate(&d.gather(x), &p.optics, false))
        .collect();
    let disks: Vec<DiskFit> = p
        .disks
        .iter()
        .zip(&evals)
        .map(|(d, e)| {
            let n = d.points.len().max(1) as f64;
            let explained = if e.sst > 0.0 {
                1.0 - e.ssr / e.sst
            } else {
                1.0
            };
            let shows_fringes = (e.sst / n).sqrt() > 0.05 * p.optics.contrast;
            DiskFit {
                grain: scene.grains[d.grain].id.clone(),
                pixels: d.points.len(),
                background: e.background,
                contrast: e.contrast,
                rms: (e.ssr / n).sqrt(),
                explained,
                imbalance: imbalance[d.grain],
                start_level: levels
                    .get(d.grain)
                    .map(|v| v.iter().sum::<f64>() / v.len().max(1) as f64)
                    .unwrap_or(0.0)
                    * p.scale,
                g2: mean_squared_gradient(d, &d.intensity, None),
                flagged: shows_fringes && explained < settings.poor_fit,
            }
        })
        .collect();
    let mut sorted: Vec<f64> = imbalance
        .iter()
        .zip(&p.balanced)
        .filter(|(_, b)| **b)
        .map(|(v, _)| *v)
        .collect();
    sorted.sort_by(f64::total_cmp);
    FringeFitReport {
        method,
        fringe_stress: settings.fringe_stress,
        balance: settings.balance,
        mu: settings.mu,
        blur_px: settings.blur_px,
        bright_field: p.optics.bright_field,
        iterations,
        paths: 1,
        objective_start,
        objective: evals.iter().map(|e| e.ssr).sum(),
        damping,
        median_imbalance: sorted.get(sorted.len() / 2).copied().unwrap_or(0.0),
        max_imbalance: sorted.last().copied().unwrap_or(0.0),
        balance_left_out: p
            .disks
            .iter()
            .zip(&p.balanced)
            // A rattler has no balance to leave out.
            .filter(|(d, b)| !**b && !d.loads.is_empty())
            .map(|(d, _)| scene.grains[d.grain].id.clone())
            .collect(),
        flagged: disks
            .iter()
            .filter(|d| d.flagged)
            .map(|d| d.grain.clone())
            .collect(),
        seconds: started.elapsed().as_secs_f64(),
        timing,
        disks,
        dropped: Vec::new(),
        candidates: Vec::new(),
        pixel_bin: 1,
    }
}

/// The photograph with each fitted disk's pixels replaced by the fitted
/// fringes (b_d + c_d S), for an overlay beside the photograph.
pub fn fitted_image(
    image: &FloatImage,
    frame: &PixelFrame,
    scene: &Scene,
    settings: &FringeFitSettings,
    forces: &[[f64; 2]],
) -> Result<FloatImage> {
    let p = prepare(image, frame, scene, settings, false)?;
    if forces.len() != scene.contacts.len() {
        return Err(Error::Invalid(format!(
            "{} forces for {} contacts",
            forces.len(),
            scene.contacts.len()
        )));
    }
    let x = to_unknowns(scene, forces, p.scale)?;
    let mut out = image.clone();
    for d in &p.disks {
        let e = d.evaluate(&d.gather(&x), &p.optics, false);
        for (&(px, py), v) in d.pixels.iter().zip(&e.model) {
            out.put_pixel(px, py, ::image::Luma([v.clamp(0.0, 1.0) as f32]));
        }
    }
    Ok(out)
}

/// The one scalar that brings the fitted wall forces closest to the walls'
/// load cells (`measured_force`), Σ W·F / Σ |F|²: forces scale with the
/// fringe stress, so multiplying both by it fits f_σ to the walls. `None`
/// without a measured wall that has fitted contacts.
pub fn wall_scale(scene: &Scene, forces: &[[f64; 2]]) -> Option<f64> {
    let mut fitted = vec![[0.0f64; 2]; scene.walls.len()];
    let mut touched = vec![false; scene.walls.len()];
    for (c, f) in scene.contacts.iter().zip(forces) {
        if let Body::Wall(w) = c.b {
            fitted[w][0] += f[0];
            fitted[w][1] += f[1];
            touched[w] = true;
        }
    }
    let (mut num, mut den) = (0.0, 0.0);
    for ((wall, f), t) in scene.walls.iter().zip(&fitted).zip(&touched) {
        if let (Some(m), true) = (wall.measured_force, *t) {
            num += m[0] * f[0] + m[1] * f[1];
            den += f[0] * f[0] + f[1] * f[1];
        }
    }
    (den > 0.0 && num > 0.0).then(|| num / den)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The one-off solves that only decide (a disk's unit loads, load
    /// tests, the unit field) are answered by the sparse stages, exactly,
    /// not by clarabel: a contact pulled open (its optimum the apex) and one
    /// inside its wedge. (The starts stay on clarabel: `start_optimum`.)
    #[test]
    fn one_off_solves_take_the_sparse_route() {
        let n = 4;
        let mut identity = Triplets::new(n, n);
        for i in 0..n {
            identity.push(i, i, 1.0);
        }
        let rhs = [-1.0, 0.2, 2.0, 0.5];
        let problem = ConicProblem {
            n,
            terms: vec![Term {
                matrix: &identity,
                rhs: &rhs,
                weight: 1.0,
            }],
            equalities: Vec::new(),
            lambda: 0.0,
            regularized: 0,
            cones: (0..2)
                .map(|k| Cone::Wedge {
                    normal: 2 * k,
                    tangent: 2 * k + 1,
                    mu: 0.5,
                })
                .collect(),
        };
        let sol = admissible_solution(&problem).unwrap();
        assert!(!sol.status.is_interior_point(), "{:?}", sol.status);
        for (x, e) in sol.x.iter().zip([0.0, 0.0, 2.0, 0.5]) {
            assert!((x - e).abs() < 1e-9, "{:?}", sol.x);
        }
    }

    fn disk() -> DiskData {
        let radius = 0.01;
        let centre = [0.2, 0.1];
        let loads = [(0.3, 1.0), (2.2, -1.0), (4.0, 1.0)]
            .iter()
            .enumerate()
            .map(|(k, &(angle, sign)): (usize, &(f64, f64))| {
                let n = [sign * f64::cos(angle), sign * f64::sin(angle)];
                Load {
                    unknown: k,
                    sign,
                    point: [
                        centre[0] + radius * sign * n[0],
                        centre[1] + radius * sign * n[1],
                    ],
                    normal: n,
                    tangent: [-n[1], n[0]],
                }
            })
            .collect();
        let mut points = Vec::new();
        for i in 0..12 {
            for j in 0..12 {
                let p = [
                    centre[0] + (i as f64 - 5.5) * 1.3e-3,
                    centre[1] + (j as f64 - 5.5) * 1.3e-3,
                ];
                if (p[0] - centre[0]).hypot(p[1] - centre[1]) < 0.8 * radius {
                    points.push(p);
                }
            }
        }
        let n = points.len();
        DiskData {
            grain: 0,
            centre,
            radius,
            loads,
            points,
            intensity: (0..n).map(|i| 0.3 + 0.2 * (i as f64 * 0.7).sin()).collect(),
            pixels: (0..n).map(|i| (i as u32, 0)).collect(),
        }
    }

    /// The model one pixel at a time with libm (the kernel before it was
    /// batched): the reference the batched kernel must match to round-off.
    fn scalar_fringes(
        this: &DiskData,
        u: &[f64],
        optics: &Optics,
        jacobian: bool,
    ) -> (Vec<f64>, Vec<f64>) {
        let k = this.local_unknowns();
        let floor = 1e-3 * this.radius;
        let n = this.points.len();
        let mut s_all = Vec::with_capacity(n);
        let mut ds_all = if jacobian {
            vec![0.0; n * k]
        } else {
            Vec::new()
        };
        let directions: Vec<[[f64; 2]; 2]> = this.loads.iter().map(|l| l.directions()).collect();
        let forces: Vec<[f64; 2]> = (directions.iter().enumerate())
            .map(|(l, [dn, dt])| {
                let (un, ut) = (u[2 * l], u[2 * l + 1]);
                [un * dn[0] + ut * dt[0], un * dn[1] + ut * dt[1]]
            })
            .collect();
        let fr = optics.fringe;
        // Per unknown: its Flamant numbers at this pixel.
        let mut coef = vec![[0.0f64; 6]; k];
        for (i, p) in this.points.iter().enumerate() {
            // D's real and imaginary parts and their x, y derivatives, laid
            // out as `FlamantGeometry::field`.
            let mut f = [0.0f64; 6];
            for (l, load) in this.loads.iter().enumerate() {
                let geometry = FlamantGeometry::new(load.point, *p, floor);
                if !jacobian {
                    let c = geometry.field(forces[l]);
                    for (fa, ca) in f.iter_mut().zip(&c) {
                        *fa += ca;
                    }
                    continue;
                }
                for (j, dir) in directions[l].iter().enumerate() {
                    let c = geometry.field(*dir);
                    let x = u[2 * l + j];
                    for (fa, ca) in f.iter_mut().zip(&c) {
                        *fa += ca * x;
                    }
                    coef[2 * l + j] = c;
                }
            }
            let (d, gd, s2, live) = order_and_gradient(&f, optics);
            let fade = (-2.0 * PI * PI * s2).exp();
            // ∂S/∂|D| and ∂S/∂|∇|D||·(1/|∇|D||) … see `jacobian_weights`.
            let (by_order, by_gradient) = if let Some(px_per_m) = optics.envelope {
                let norm = (gd[0] * gd[0] + gd[1] * gd[1]).sqrt();
                let gain = optics.contrast * PI / (std::f64::consts::SQRT_2 * fr * px_per_m);
                s_all.push(gain * norm * fade);
                if !(jacobian && live && norm > 0.0) {
                    continue;
                }
                (0.0, gain * fade * (1.0 - 4.0 * PI * PI * s2) / norm)
            } else {
                let (sin, cos) = (2.0 * PI * d / fr).sin_cos();
                s_all.push(0.5 - 0.5 * cos * fade);
                if !(jacobian && live) {
                    continue;
                }
                (
                    PI * fade * sin / fr,
                    2.0 * PI * PI * fade * cos * optics.blur2 / (fr * fr),
                )
            };
            let w = jacobian_weights(f, d, gd, by_order, by_gradient);
            for (out, c) in ds_all[i * k..(i + 1) * k].iter_mut().zip(&coef) {
                *out = w[0] * c[0]
                    + w[1] * c[1]
                    + w[2] * c[2]
                    + w[3] * c[3]
                    + w[4] * c[4]
                    + w[5] * c[5];
            }
        }
        (s_all, ds_all)
    }

    /// The batched kernel (and its AVX2 build) gives the scalar model's S
    /// and ∂S/∂u to round-off: the intensity and the envelope, with and
    /// without the Jacobian, on pixels at a load, within its floor, at the
    /// centre, a short last batch, and the zero field (no live pixel).
    #[test]
    fn batched_fringes_match_the_scalar_model() {
        let mut d = disk();
        let q = d.loads[0].point;
        let floor = 1e-3 * d.radius;
        d.points.extend([
            q,
            [q[0] + 0.3 * floor, q[1]],
            [q[0] + 2.0 * floor, q[1] - floor],
            d.centre,
        ]);
        if d.points.len() % 8 == 0 {
            d.points.push([d.centre[0] + 1e-4, d.centre[1]]);
        }
        for u in [[1.3, 0.2, 0.7, -0.1, 2.1, 0.4], [0.0; 6]] {
            for envelope in [None, Some(3.0e4)] {
                for jacobian in [false, true] {
                    let optics = Optics {
                        fringe: 1.0 / d.radius,
                        blur2: 1e-8,
                        contrast: 0.6,
                        envelope,
                        lighting: false,
                        bright_field: false,
                        precision: Precision::Double,
                    };
                    let (s, ds) = d.fringes(&u, &optics, jacobian);
                    let (s0, ds0) = scalar_fringes(&d, &u, &optics, jacobian);
                    // Within round-off of the largest value (libm's sine,
                    // cosine and exponential against the kernel's own).
                    let close = |a: &[f64], b: &[f64]| {
                        let size = b.iter().fold(1e-300f64, |m, v| m.max(v.abs()));
                        a.len() == b.len()
                            && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-12 * size)
                    };
                    assert!(close(&s, &s0), "S, {envelope:?}, jacobian {jacobian}");
                    let ds = ds.rows();
                    assert!(close(&ds, &ds0), "∂S/∂u, {envelope:?}");
                    assert!(s.iter().all(|v| v.is_finite()));
                    // Pixels without a field give no row, as in the scalar model.
                    let dead = |v: &[f64]| v.iter().map(|x| *x == 0.0).collect::<Vec<_>>();
                    assert_eq!(dead(&ds), dead(&ds0));
                }
            }
        }
    }

    /// The G² scan's stencils give `mean_squared_gradient` to the last bit,
    /// over a subset and over the whole disk, on a 2-D pixel grid.
    #[test]
    fn gradient_stencils_match_the_grid_gradient() {
        let mut d = disk();
        (d.points, d.pixels) = (Vec::new(), Vec::new());
        for i in 0..15u32 {
            for j in 0..15u32 {
                let (x, y) = (i as f64 - 7.0, j as f64 - 7.0);
                if x.hypot(y) < 7.2 {
                    d.points
                        .push([d.centre[0] + 1e-3 * x, d.centre[1] + 1e-3 * y]);
                    d.pixels.push((i + 3, j + 5));
                }
            }
        }
        let n = d.points.len();
        d.intensity = (0..n).map(|i| 0.3 + 0.2 * (i as f64 * 0.7).sin()).collect();
        let subset: Vec<bool> = (0..n).map(|i| i % 3 != 0).collect();
        for s in [None, Some(subset.as_slice())] {
            let stencils = gradient_stencils(&d, s);
            assert!(stencils.len() > n / 3, "{} stencils of {n}", stencils.len());
            let by_grid = mean_squared_gradient(&d, &d.intensity, s);
            let by_stencil = stencil_mean_squared_gradient(&stencils, &d.intensity);
            assert!(by_grid > 0.0);
            assert_eq!(by_grid.to_bits(), by_stencil.to_bits());
        }
    }

    /// The closed-form Flamant field agrees with `disk_stress` (σ_xx − σ_yy,
    /// 2σ_xy of one load) and its spatial derivatives with central differences.
    #[test]
    fn flamant_field_and_gradient() {
        let q = [0.3, -0.2];
        let mut worst: f64 = 0.0;
        for (i, dir) in [[1.0, 0.0], [0.6, -0.8], [-0.28, 0.96]].iter().enumerate() {
            for p in [[0.35, -0.1], [0.1, -0.25], [0.31, -0.19], [0.5, 0.4]] {
                let c = flamant(q, p, *dir, 1e-6);
                let s = crate::image::photoelastic::disk_stress([0.0, 0.0], 1.0, &[(q, *dir)], p);
                worst = worst.max((c[0] - (s[0] - s[1])).abs() / (1.0 + c[0].abs()));
                worst = worst.max((c[1] - 2.0 * s[2]).abs() / (1.0 + c[1].abs()));
                let h = 1e-6;
                for (axis, (re, im)) in [(0usize, (2usize, 4usize)), (1, (3, 5))] {
                    let (mut a, mut b) = (p, p);
                    a[axis] += h;
                    b[axis] -= h;
                    let (fa, fb) = (flamant(q, a, *dir, 1e-6), flamant(q, b, *dir, 1e-6));
                    let fd = [(fa[0] - fb[0]) / (2.0 * h), (fa[1] - fb[1]) / (2.0 * h)];
                    // Relative to the gradient's size at p: a component that
                    // vanishes there keeps the differences' O(h²) error.
                    let scale = 1.0 + c[2..].iter().fold(0.0f64, |m, v| m.max(v.abs()));
                    worst = worst.max((fd[0] - c[re]).abs() / scale);
                    worst = worst.max((fd[1] - c[im]).abs() / scale);
                }
            }
            assert!(worst < 1e-6, "direction {i}: {worst}");
        }
    }

    /// ∂S/∂u, blur fade included, agrees with central differences.
    #[test]
    fn fringe_derivatives_match_finite_differences() {
        let d = disk();
        for (blur, envelope) in [
            (0.0, None),
            (1e-8, None),
            (4e-8, None),
            (1e-8, Some(4e3)),
            (4e-8, Some(4e3)),
        ] {
            let optics = Optics {
                fringe: 1.0 / d.radius,
                blur2: blur,
                contrast: 0.6,
                envelope,
                lighting: false,
                bright_field: false,
                precision: Precision::Double,
            };
            let u = vec![1.3, 0.2, 0.7, -0.1, 2.1, 0.4];
            let (_, ds) = d.fringes(&u, &optics, true);
            let k = u.len();
            let mut worst: f64 = 0.0;
            for m in 0..k {
                let h = 1e-6;
                let (mut up, mut down) = (u.clone(), u.clone());
                up[m] += h;
                down[m] -= h;
                let (sp, _) = d.fringes(&up, &optics, false);
                let (sm, _) = d.fringes(&down, &optics, false);
                for i in 0..d.points.len() {
                    let fd = (sp[i] - sm[i]) / (2.0 * h);
                    worst = worst.max((fd - ds.at(i, m)).abs() / (1.0 + fd.abs()));
                }
            }
            assert!(
                worst < 1e-6,
                "blur {blur}: worst relative difference {worst}"
            );
        }
    }

    /// The step's normal equations (JᵀJ and Jᵀr over the disk's unknowns,
    /// background refitted, contrast held) from the analytic ∂S/∂u equal
    /// those from central differences of the model, in both the intensity
    /// and the envelope fit, at weak and dense fringes.
    #[test]
    fn normal_equations_match_finite_differences() {
        let d = disk();
        for (level, blur, envelope) in [
            (1.0, 1e-8, None),
            (4.0, 4e-8, None),
            (1.0, 1e-8, Some(4e3)),
            (4.0, 4e-8, Some(4e3)),
        ] {
            let optics = Optics {
                fringe: 1.0 / d.radius,
                blur2: blur,
                contrast: 0.6,
                envelope,
                lighting: false,
                bright_field: false,
                precision: Precision::Double,
            };
            let u: Vec<f64> = [1.3, 0.2, 0.7, -0.1, 2.1, 0.4]
                .iter()
                .map(|v| level * v)
                .collect();
            let (k, n) = (u.len(), d.points.len());
            let e = d.evaluate(&u, &optics, true);
            // Rows of J by differences: ∂model/∂u_m, less its mean over the
            // disk (the refitted background) in the intensity fit.
            let h = 1e-6 * level;
            let mut rows = vec![vec![0.0; k]; n];
            for m in 0..k {
                let (mut up, mut down) = (u.clone(), u.clone());
                up[m] += h;
                down[m] -= h;
                let (sp, _) = d.fringes(&up, &optics, false);
                let (sm, _) = d.fringes(&down, &optics, false);
                let fd: Vec<f64> = sp
                    .iter()
                    .zip(&sm)
                    .map(|(a, b)| (a - b) / (2.0 * h))
                    .collect();
                let mean = if envelope.is_some() {
                    0.0
                } else {
                    fd.iter().sum::<f64>() / n as f64
                };
                let gain = if envelope.is_some() { 1.0 } else { e.contrast };
                for i in 0..n {
                    rows[i][m] = gain * (fd[i] - mean);
                }
            }
            let residual: Vec<f64> = d
                .intensity
                .iter()
                .zip(&e.model)
                .map(|(a, b)| a - b)
                .collect();
            let size = |v: &[f64]| v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            let (mut worst_normal, mut worst_rhs) = (0.0f64, 0.0f64);
            for a in 0..k {
                let rhs: f64 = (0..n).map(|i| rows[i][a] * residual[i]).sum();
                worst_rhs = worst_rhs.max((rhs - e.rhs[a]).abs() / size(&e.rhs));
                for b in 0..k {
                    let g: f64 = (0..n).map(|i| rows[i][a] * rows[i][b]).sum();
                    worst_normal =
                        worst_normal.max((g - e.normal[a * k + b]).abs() / size(&e.normal));
                }
            }
            assert!(
                worst_normal < 1e-6 && worst_rhs < 1e-6,
                "level {level}, envelope {envelope:?}: JᵀJ off by {worst_normal:.2e}, Jᵀr by {worst_rhs:.2e} (relative)"
            );
        }
    }

    /// With the lighting plane (and the bright field's negative contrast)
    /// the step's rows are the model's derivatives less their projection on
    /// the plane, times the contrast: as central differences give them.
    #[test]
    fn lighting_normal_equations_match_finite_differences() {
        let d = disk();
        for bright_field in [false, true] {
            let optics = Optics {
                fringe: 1.0 / d.radius,
                blur2: 1e-8,
                contrast: 0.6,
                envelope: None,
                lighting: true,
                bright_field,
                precision: Precision::Double,
            };
            let u = vec![1.3, 0.2, 0.7, -0.1, 2.1, 0.4];
            let (k, n) = (u.len(), d.points.len());
            let e = d.evaluate(&u, &optics, true);
            assert_eq!(e.contrast < 0.0, bright_field);
            let slopes = d.slope_basis();
            assert_eq!(slopes.len(), 2);
            let mut rows = vec![vec![0.0; k]; n];
            for m in 0..k {
                let (mut up, mut down) = (u.clone(), u.clone());
                up[m] += 1e-6;
                down[m] -= 1e-6;
                let (sp, _) = d.fringes(&up, &optics, false);
                let (sm, _) = d.fringes(&down, &optics, false);
                let mut fd: Vec<f64> = (sp.iter().zip(&sm)).map(|(a, b)| (a - b) / 2e-6).collect();
                let mean = fd.iter().sum::<f64>() / n as f64;
                fd.iter_mut().for_each(|v| *v -= mean);
                for q in &slopes {
                    let a = dot(q, &fd);
                    fd.iter_mut().zip(q).for_each(|(v, qi)| *v -= a * qi);
                }
                for i in 0..n {
                    rows[i][m] = e.contrast * fd[i];
                }
            }
            let residual: Vec<f64> = (d.intensity.iter().zip(&e.model))
                .map(|(a, b)| a - b)
                .collect();
            // The residual is orthogonal to the plane it was fitted with.
            for q in &slopes {
                assert!(dot(q, &residual).abs() < 1e-9 * (1.0 + e.ssr.sqrt()));
            }
            let size = |v: &[f64]| v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            for a in 0..k {
                let rhs: f64 = (0..n).map(|i| rows[i][a] * residual[i]).sum();
                assert!((rhs - e.rhs[a]).abs() < 1e-6 * size(&e.rhs));
                for b in 0..k {
                    let g: f64 = (0..n).map(|i| rows[i][a] * rows[i][b]).sum();
                    assert!((g - e.normal[a * k + b]).abs() < 1e-6 * size(&e.normal));
                }
            }
        }
    }

    /// A binned pixel is its block's mean, placed at the block's centre in
    /// the scene (a partial last row or column dropped), and the bin is
    /// chosen from the median radius.
    #[test]
    fn binning_keeps_scene_positions() {
        let frame = PixelFrame {
            px_per_m: 250.0,
            origin: [0.1, -0.2],
            width: 10,
            height: 8,
        };
        let image = FloatImage::from_fn(10, 8, |x, y| ::image::Luma([(x + 10 * y) as f32]));
        let (coarse, at, settings) = binned(&image, &frame, &FringeFitSettings::new(1.0), 3);
        assert_eq!((coarse.width(), coarse.height()), (3, 2));
        assert_eq!((at.width, at.height), (3, 2));
        assert_eq!((settings.blur_px, settings.edge_px), (1.0 / 3.0, 2.0));
        for (bx, by) in [(0, 0), (2, 1), (1, 1)] {
            let mut centre = [0.0; 2];
            let mut mean = 0.0;
            for y in 3 * by..3 * by + 3 {
                for x in 3 * bx..3 * bx + 3 {
                    let p = frame.to_scene([x as f64, y as f64]);
                    centre = [centre[0] + p[0] / 9.0, centre[1] + p[1] / 9.0];
                    mean += image.get_pixel(x, y)[0] / 9.0;
                }
            }
            let p = at.to_scene([bx as f64, by as f64]);
            assert!((p[0] - centre[0]).abs() < 1e-12 && (p[1] - centre[1]).abs() < 1e-12);
            assert!((coarse.get_pixel(bx, by)[0] - mean).abs() < 1e-4);
        }
        let mut scene = Scene::new(2);
        for (i, r_px) in [79.0, 100.0, 130.0].into_iter().enumerate() {
            let r = r_px / frame.px_per_m;
            let mut g = crate::scene::Grain::new(i.to_string(), [0.0; 3], PI * r * r, [0.0; 6]);
            g.radius = Some(r);
            scene.grains.push(g);
        }
        let big = PixelFrame {
            width: 1000,
            height: 1000,
            ..frame
        };
        assert_eq!(pixel_bin(&big, &scene), 2);
        scene.grains.remove(1);
        assert_eq!(pixel_bin(&big, &scene), 3);
        scene.grains.pop();
        assert_eq!(pixel_bin(&big, &scene), 1);
        assert_eq!(pixel_bin(&big, &Scene::new(2)), 1);
    }

    #[test]
    fn extrapolation_follows_the_gain_ratio_and_stays_in_the_wedge() {
        let wedge = [Cone::Wedge {
            normal: 0,
            tangent: 1,
            mu: 0.5,
        }];
        let x = [1.0, 0.0];
        // Gained as predicted (a parabola's minimum at the step): no longer step.
        assert!(extrapolated(&x, &[2.0, 0.0], 1.0, &wedge).is_none());
        // ρ = 1.5: the parabola's minimum at t = 1/(2 − ρ) = 2.
        let longer = extrapolated(&x, &[2.0, 0.0], 1.5, &wedge).unwrap();
        assert!((longer[0] - 3.0).abs() < 1e-12 && longer[1] == 0.0);
        // No curvature seen (ρ ≥ 2): the longest step.
        let longest = extrapolated(&x, &[2.0, 0.0], 2.5, &wedge).unwrap();
        assert!((longest[0] - (1.0 + MAX_EXTRAPOLATION)).abs() < 1e-12);
        // Towards the wedge's edge |u_t| = μ u_n: cut to 95 % of the way.
        let cut = extrapolated(&x, &[1.0, 0.2], 1.9, &wedge).unwrap();
        assert!((cut[1] - 0.2 * (1.0 + 0.95 * 1.5)).abs() < 1e-12);
        assert!(cut[1].abs() <= 0.5 * cut[0]);
        // Already near the edge: no room for a longer step.
        assert!(extrapolated(&x, &[1.0, 0.45], 1.9, &wedge).is_none());
        assert!(extrapolated(&x, &[2.0, 0.0], f64::NAN, &wedge).is_none());
    }

    /// A second fit of the same disk takes its G² levels from the shared
    /// work (the memo is read, not rescanned); a moved load or another
    /// photograph's intensities are scanned afresh, to the same levels a
    /// fit without shared work finds.
    #[test]
    fn shared_levels_are_reused_for_the_same_disk_only() {
        let problem = |d: DiskData| Prepared {
            disks: vec![d],
            unknowns: 3,
            scale: 1.0,
            optics: Optics {
                fringe: 1.0 / 0.01,
                blur2: 1e-8,
                contrast: 0.6,
                envelope: None,
                lighting: false,
                bright_field: false,
                precision: Precision::Single,
            },
            pixel: 1.3e-3,
            balanced: vec![true],
            pinned: Vec::new(),
        };
        let bits = |levels: Vec<Vec<f64>>| -> Vec<u64> {
            levels.concat().iter().map(|v| v.to_bits()).collect()
        };
        let p = problem(disk());
        let shared = SharedWork::default();
        let cold = bits(load_levels(&p, &SharedWork::default()));
        assert!(cold.iter().any(|&v| f64::from_bits(v) > 0.0));
        assert_eq!(bits(load_levels(&p, &shared)), cold);
        // A marker in the memo shows the second look reads it.
        let marker = [7.0; 3];
        shared.put(level_key(&p, &p.disks[0]), &marker);
        assert_eq!(load_levels(&p, &shared), vec![marker.to_vec()]);
        let mut moved = disk();
        moved.loads[1].point[0] += 1e-4;
        let mut other_photo = disk();
        other_photo.intensity[5] += 0.1;
        for d in [moved, other_photo] {
            let q = problem(d);
            assert_eq!(
                bits(load_levels(&q, &shared)),
                bits(load_levels(&q, &SharedWork::default()))
            );
        }
    }

    #[test]
    fn the_fine_stage_is_thinned_on_large_disks_only() {
        // r = 40 px: the 0.04 R stage (σ 1.6 px) on every 2nd pixel as the
        // 0.08 R stage (σ 3.2 px); r = 20 px: both on every pixel; r = 35 px:
        // the 0.08 R stage (σ 2.8 px) on every pixel, as before.
        assert_eq!(stage_stride(1, 40.0), 2);
        assert_eq!(stage_stride(0, 40.0), 2);
        assert_eq!(stage_stride(1, 30.0), 2);
        assert_eq!(stage_stride(1, 29.0), 1);
        assert_eq!(stage_stride(1, 20.0), 1);
        assert_eq!(stage_stride(0, 20.0), 1);
        assert_eq!(stage_stride(0, 35.0), 1);
        assert_eq!(stage_stride(1, 80.0), 2);
    }
}
