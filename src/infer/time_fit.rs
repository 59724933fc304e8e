//! Momentum fitted over the whole sequence at once (the joint time fit).
//!
//! Frame by frame, momentum enters through accelerations differentiated from
//! noisy tracks, and every frame strikes its own compromise between stress and
//! momentum rows; over an impact those per-frame errors do not cancel, so the
//! integrated impulse can miss the measured change of velocity. Here the
//! unknowns are every frame's contact forces together with each tracked
//! grain's position and velocity per frame:
//!
//! ```text
//!   minimise   Σ_frames ‖W_k (K_st f_k − b_st,k)‖²        stress, weight 1/(σ_s · frame scale)
//!            + Σ_grains ‖(x_k − x̂_k) / σ_x‖²               the raw tracks
//!            + Σ_contacts ‖(f_{k−1} − 2 f_k + f_{k+1}) / σ_r‖²   forces change smoothly in time
//!            + Σ_frames ‖10 W_k (Σ r × f − I α)‖²                 moments, ten times the stress weight
//!   subject to x_{k+1} = x_k + v_k Δt + Δt² (a_k/3 + a_{k+1}/6),
//!              v_{k+1} = v_k + Δt (a_k + a_{k+1})/2,   a_k = (Σ f)/m + g   (per grain)
//!              friction cones.
//! ```
//!
//! The tracks are fitted, not differentiated, so no filter and no per-frame
//! weight is needed; σ_r (the roughness of a contact force from one frame to
//! the next) is the one new scale. Contacts are followed across frames by the
//! pair of bodies they join (contact ids are only unique within a frame); a
//! contact absent from a frame has zero force there.

use super::{cones, ConeModel, InferOptions};
use crate::assemble::{self, AssembleOptions, Assembly};
use crate::error::{Error, Result};
use crate::scene::{Body, Scene, Vec3};
use crate::solver::cascade::{self, CascadeSettings};
use crate::solver::sparse_ls::EqualityLeastSquares;
use crate::solver::{Attempt, Solution, SolveStatus, Triplets};
use crate::solver::{Cone, ConicProblem, Term};
use std::collections::BTreeMap;
use std::time::Instant;

/// Settings of [`infer_time_fit`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimeFitOptions {
    /// Frames per second (consecutive frames of the sequence are 1/fps apart).
    pub fps: f64,
    /// Standard deviation of each tracked coordinate [m]; `None`: estimated
    /// from the tracks ([`super::kinematics::estimate_position_sd`]).
    pub position_sd: Option<f64>,
    /// Relative noise of the stresses (weights the stress rows of a frame by
    /// 1/(σ_s × the frame's rms stress load)).
    pub stress_sd: f64,
    /// σ_r: standard deviation of the second difference of a contact force
    /// component from frame to frame [N]. `None`: [`ROUGHNESS_FACTOR`] times
    /// its rms in a frame-by-frame answer ([`estimate_roughness`]).
    pub roughness: Option<f64>,
}

impl TimeFitOptions {
    pub fn new(fps: f64) -> Self {
        TimeFitOptions {
            fps,
            position_sd: None,
            stress_sd: 0.1,
            roughness: None,
        }
    }
}

/// σ_r by default, relative to the rms second difference of the
/// frame-by-frame answer (which lands near the true forces' own: 60 against
/// 63 N on `impact`). Measured on `impact`, twelve draws of 0.1 % position
/// noise, stress sd 0.1: ×0.25 relerr 0.060, ×0.5 0.042, ×1 0.029, ×2 0.021,
/// ×4 0.020, ×16 0.036 — a rough force history is better served by a loose
/// prior than by a tight one.
pub const ROUGHNESS_FACTOR: f64 = 3.0;

/// Weight of the moment rows Σ r × f = Iα against the frame's stress rows
/// (their sd is the stress noise over this). Hard moment rows left the joint
/// system on `bed-impact` unsolvable (the active set stalled at its first
/// step, the interior point failed); on `impact` weights 100 and 10 give the
/// hard rows' answer (relerr 0.018–0.022), 1 loosens it (0.023–0.027).
pub const MOMENT_WEIGHT: f64 = 10.0;

/// Tenfold loosenings of the position sd tried when the joint system is too ill-conditioned.
const MAX_LOOSENINGS: usize = 3;

/// Smallest position sd used, relative to the median grain radius.
pub const POSITION_SD_FLOOR: f64 = 1e-5;

/// What [`infer_time_fit`] did.
#[derive(Debug, Clone, serde::Serialize)]
pub struct TimeFitReport {
    pub frames: usize,
    /// Force unknowns (all frames) and kinematic unknowns (positions, velocities).
    pub force_unknowns: usize,
    pub kinematic_unknowns: usize,
    /// Grain tracks and contact tracks (contacts followed across frames).
    pub grain_tracks: usize,
    pub contact_tracks: usize,
    pub position_sd: f64,
    pub position_sd_estimated: bool,
    pub stress_sd: f64,
    /// σ_r used [N], and whether it was estimated.
    pub roughness: f64,
    pub roughness_estimated: bool,
    /// The stage that gave the answer: `LeastSquares` when the unconstrained
    /// fit already met friction.
    pub solver_status: SolveStatus,
    /// Each stage tried (the active set's solves and final pieces, or why it
    /// stalled and what the interior point did).
    pub solver_attempts: Vec<Attempt>,
    pub seconds: f64,
    pub warnings: Vec<String>,
}

impl TimeFitReport {
    /// How the joint problem was solved, as the summary prints it.
    pub fn solver_text(&self) -> String {
        if self.solver_status == SolveStatus::LeastSquares && self.solver_attempts.is_empty() {
            return "least squares (friction met as is)".into();
        }
        let attempts: Vec<String> = self.solver_attempts.iter().map(|a| a.to_string()).collect();
        attempts.join("; ")
    }
}

impl std::fmt::Display for TimeFitReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "time fit: {} frames, {} force + {} kinematic unknowns, {} grain tracks, {} contact tracks; {}; {:.3} s",
            self.frames,
            self.force_unknowns,
            self.kinematic_unknowns,
            self.grain_tracks,
            self.contact_tracks,
            self.solver_text(),
            self.seconds
        )?;
        writeln!(
            f,
            "  position sd {:.3e} m ({}), stress sd {}, force roughness σ_r {:.3e} N ({})",
            self.position_sd,
            if self.position_sd_estimated {
                "estimated from the tracks"
            } else {
                "stated"
            },
            self.stress_sd,
            self.roughness,
            if self.roughness_estimated {
                format!("{ROUGHNESS_FACTOR} × its rms in the frame-by-frame answer")
            } else {
                "stated".into()
            }
        )?;
        for w in &self.warnings {
            writeln!(f, "  warning: {w}")?;
        }
        Ok(())
    }
}

/// Forces of every frame (per scene contact; `None` outside the fit) and the report.
#[derive(Debug, Clone)]
pub struct TimeFit {
    pub forces: Vec<Vec<Option<Vec3>>>,
    pub report: TimeFitReport,
}

/// Key of a contact across frames: the two bodies it joins, in a fixed order,
/// and the sign that turns the stored force (on `a` by `b`) into the force on
/// the first body of the key.
fn pair_key(frame: &Scene, contact: usize) -> (String, String, f64) {
    let c = &frame.contacts[contact];
    let a = frame.grains[c.a].id.clone();
    match c.b {
        Body::Grain(b) => {
            let b = frame.grains[b].id.clone();
            if b < a {
                (b, a, -1.0)
            } else {
                (a, b, 1.0)
            }
        }
        Body::Wall(w) => (a, format!("wall:{}", frame.walls[w].name), 1.0),
    }
}

/// Contact tracks: for each pair of bodies, per frame, the contact indices
/// joining them (usually one) with their sign.
type ContactTracks = BTreeMap<(String, String), Vec<Vec<(usize, f64)>>>;

fn contact_tracks(frames: &[Scene]) -> ContactTracks {
    let mut tracks: ContactTracks = BTreeMap::new();
    for (k, frame) in frames.iter().enumerate() {
        for i in 0..frame.contacts.len() {
            let (a, b, sign) = pair_key(frame, i);
            tracks
                .entry((a, b))
                .or_insert_with(|| vec![Vec::new(); frames.len()])[k]
                .push((i, sign));
        }
    }
    tracks
}

/// σ_r from a frame-by-frame answer: the rms second difference, per force
/// component, over the frames where a contact holds in three consecutive
/// frames. Its noise inflates it, which errs on the side of smoothing less.
/// `None` when no contact lasts three frames.
pub fn estimate_roughness(frames: &[Scene], forces: &[Vec<Option<Vec3>>]) -> Option<f64> {
    roughness_of(&contact_tracks(frames), frames, forces)
}

/// [`estimate_roughness`] on contact tracks already built.
fn roughness_of(
    tracks: &ContactTracks,
    frames: &[Scene],
    forces: &[Vec<Option<Vec3>>],
) -> Option<f64> {
    let dim = frames.first()?.dim;
    let (mut sum, mut count) = (0.0, 0usize);
    for track in tracks.values() {
        let value = |k: usize| -> Option<Vec3> {
            match track[k].as_slice() {
                &[(i, sign)] => forces
                    .get(k)?
                    .get(i)
                    .copied()
                    .flatten()
                    .map(|f| [sign * f[0], sign * f[1], sign * f[2]]),
                _ => None,
            }
        };
        for k in 1..frames.len().saturating_sub(1) {
            if let (Some(f0), Some(f1), Some(f2)) = (value(k - 1), value(k), value(k + 1)) {
                for a in 0..dim {
                    sum += (f0[a] - 2.0 * f1[a] + f2[a]).powi(2);
                    count += 1;
                }
            }
        }
    }
    let rms = (sum / count.max(1) as f64).sqrt();
    (count > 0 && rms > 0.0 && rms.is_finite()).then_some(rms)
}

/// Where a frame's modelled contact lives in the joint unknowns.
#[derive(Clone)]
struct JointContact {
    /// First joint column and number of unknowns.
    col: usize,
    count: usize,
    /// Unit force direction of each unknown (times the joint force unit).
    directions: [Vec3; 3],
}

/// Appends one row to (t, rhs).
fn push_row(t: &mut Triplets, rhs: &mut Vec<f64>, entries: &[(usize, f64)], value: f64) {
    t.nrows += 1;
    for &(col, v) in entries {
        t.push(t.nrows - 1, col, v);
    }
    rhs.push(value);
}

/// Fits the forces of all `frames` jointly with the tracks (see the module
/// documentation). `opts` supplies the assembly (μ, gravity, selection) and
/// the cone model (exact cones only: the active set solves the joint problem);
/// `frame_by_frame` (the per-frame answer) is needed only to estimate σ_r when
/// `fit.roughness` is `None`.
pub fn infer_time_fit(
    frames: &[Scene],
    opts: &InferOptions,
    fit: &TimeFitOptions,
    frame_by_frame: Option<&[Vec<Option<Vec3>>]>,
) -> Result<TimeFit> {
    opts.conic.check()?;
    let start = Instant::now();
    let nf = frames.len();
    check_settings(nf, opts, fit)?;
    let ctracks = contact_tracks(frames);
    let (roughness, roughness_estimated) =
        force_roughness(fit.roughness, &ctracks, frames, frame_by_frame)?;
    let dt = 1.0 / fit.fps;
    let dim = frames[0].dim;
    if let Some(k) = frames.iter().position(|f| f.dim != dim) {
        return Err(Error::Invalid(format!(
            "frame {} is {}D, the first is {dim}D",
            frames[k].frame.unwrap_or(k as i64),
            frames[k].dim
        )));
    }

    // Assemble every frame; momentum rows are rebuilt below, so no pruning.
    let assemble_opts = AssembleOptions {
        prune_single_contacts: false,
        single_system: false,
        ..opts.assemble.clone()
    };
    let assemblies = frames
        .iter()
        .map(|f| assemble::assemble(f, &assemble_opts))
        .collect::<Result<Vec<_>>>()?;
    // The joint force unit: the largest frame's force scale.
    let force_unit = assemblies
        .iter()
        .map(|a| a.scales.force)
        .fold(0.0, f64::max)
        .max(f64::MIN_POSITIVE);
    let columns = ForceColumns::place(frames, &assemblies, opts.cone)?;
    let force_unknowns = columns.ncols;
    let placed = &columns.placed;

    // Net force on grain p of frame k, per axis: joint columns and coefficients
    // (in joint force units), and whether the grain's forces are all modelled.
    let net_force = |k: usize, p: usize| -> Option<NetForce> {
        let frame = &frames[k];
        let mut net = vec![Vec::new(); dim];
        for (i, c) in frame.contacts.iter().enumerate() {
            let sign = if c.a == p {
                1.0
            } else if c.b == Body::Grain(p) {
                -1.0
            } else {
                continue;
            };
            let jc = placed[k][i].as_ref()?;
            for j in 0..jc.count {
                for (axis, entries) in net.iter_mut().enumerate() {
                    let v = sign * jc.directions[j][axis];
                    if v != 0.0 {
                        entries.push((jc.col + j, v));
                    }
                }
            }
        }
        Some(net)
    };
    let position_sd_estimated = fit.position_sd.is_none();
    let position_sd = track_sd(fit.position_sd, frames, &assemblies)?;

    let mut warnings: Vec<String> = Vec::new();
    let mut rows = JointRows {
        a: Triplets::new(0, 0),
        b: Vec::new(),
        c: Triplets::new(0, 0),
        d: Vec::new(),
    };
    // Kinematic columns: per track segment and frame, x (dim) then v·Δt (dim),
    // both in units of the first σ_x about the segment's first measured
    // position; a later σ_x changes only the track rows' weights.
    let segments = grain_segments(frames, &net_force)?;
    let mut ncols = force_unknowns;
    let mut first_col = Vec::with_capacity(segments.len());
    for seg in &segments {
        first_col.push(ncols);
        ncols += 2 * dim * seg.frames.len();
    }
    let kinematic_unknowns = ncols - force_unknowns;
    rows.a.ncols = ncols;
    rows.c.ncols = ncols;

    rows.append_frames(&assemblies, fit.stress_sd, force_unit, dim);
    let gravity = opts.assemble.gravity.unwrap_or_else(|| frames[0].gravity());
    let kinematics = Kinematics {
        frames,
        segments: &segments,
        first_col: &first_col,
        dt,
        gravity,
        force_unit,
        unit: position_sd,
    };
    let track_rows = rows.append_tracks(&kinematics, position_sd);
    let contact_track_count = rows.append_roughness(&ctracks, placed, dim, force_unit / roughness);
    if contact_track_count == 0 {
        warnings.push("no contact lasts long enough for the roughness prior".into());
    }

    let (solved, position_sd) = solve_joint(
        rows,
        &columns,
        ncols,
        &track_rows,
        position_sd,
        opts,
        start,
        &mut warnings,
    )?;
    warnings.extend(solved.warnings);
    let forces = columns.forces(&solved.x, force_unit);
    let report = TimeFitReport {
        frames: nf,
        force_unknowns,
        kinematic_unknowns,
        grain_tracks: segments.len(),
        contact_tracks: contact_track_count,
        position_sd,
        position_sd_estimated,
        stress_sd: fit.stress_sd,
        roughness,
        roughness_estimated,
        solver_status: solved.status,
        solver_attempts: solved.attempts,
        seconds: start.elapsed().as_secs_f64(),
        warnings,
    };
    Ok(TimeFit { forces, report })
}

/// The settings and the sequence are usable at all.
fn check_settings(nf: usize, opts: &InferOptions, fit: &TimeFitOptions) -> Result<()> {
    if nf < 3 {
        return Err(Error::Invalid(format!(
            "the time fit needs a sequence of at least 3 frames, got {nf}"
        )));
    }
    if !(fit.fps > 0.0 && fit.fps.is_finite()) {
        return Err(Error::Invalid(format!(
            "the time fit needs a positive frame rate, got {}",
            fit.fps
        )));
    }
    if !(fit.stress_sd > 0.0 && fit.stress_sd.is_finite()) {
        return Err(Error::Invalid(format!(
            "the time fit weighs the stresses by 1/σ_s: `stress_sd` must be positive, got {}",
            fit.stress_sd
        )));
    }
    if let ConeModel::Pyramid(_) = opts.cone {
        return Err(Error::Invalid(
            "the time fit solves friction with the active set, which takes exact cones only (drop `cone`)"
                .into(),
        ));
    }
    Ok(())
}

/// σ_r as given, or estimated from the frame-by-frame answer; and whether estimated.
fn force_roughness(
    given: Option<f64>,
    ctracks: &ContactTracks,
    frames: &[Scene],
    frame_by_frame: Option<&[Vec<Option<Vec3>>]>,
) -> Result<(f64, bool)> {
    Ok(match given {
        Some(r) if r > 0.0 && r.is_finite() => (r, false),
        Some(r) => {
            return Err(Error::Invalid(format!(
                "the force roughness σ_r must be positive and finite, got {r}"
            )))
        }
        None => {
            let forces = frame_by_frame.ok_or_else(|| {
                Error::Invalid(
                    "the time fit needs σ_r (`roughness`) or a frame-by-frame answer to estimate it from"
                        .into(),
                )
            })?;
            let r = roughness_of(ctracks, frames, forces).ok_or_else(|| {
                Error::Invalid(
                    "cannot estimate the force roughness: no contact lasts three frames with a force; give `roughness`"
                        .into(),
                )
            })?;
            (ROUGHNESS_FACTOR * r, true)
        }
    })
}

/// σ_x as given or estimated from the tracks, floored.
fn track_sd(given: Option<f64>, frames: &[Scene], assemblies: &[Assembly]) -> Result<f64> {
    // Frames without contacts have no length scale of their own.
    let length_scale = assemblies
        .iter()
        .filter(|a| !a.systems.is_empty())
        .map(|a| a.scales.length)
        .fold(0.0, f64::max);
    let position_sd = given
        .unwrap_or_else(|| super::kinematics::estimate_position_sd(frames))
        // Exact tracks: the floor keeps the normal equations conditioned (at
        // 1e-9 R the refinement stalled at 2e-5 on noise-free `impact`), and
        // the frame-to-frame integrator is not more exact than that anyway.
        .max(POSITION_SD_FLOOR * length_scale.max(f64::MIN_POSITIVE));
    if !position_sd.is_finite() {
        return Err(Error::Invalid(format!(
            "the position sd must be finite, got {position_sd}"
        )));
    }
    Ok(position_sd)
}

/// The force columns of the joint system: frame by frame, system by system.
struct ForceColumns {
    /// Per frame, per scene contact: its columns (`None`: not inferred).
    placed: Vec<Vec<Option<JointContact>>>,
    cones: Vec<Cone>,
    /// (first column, count) of each contact's unknowns.
    blocks: Vec<(usize, usize)>,
    ncols: usize,
}

impl ForceColumns {
    fn place(frames: &[Scene], assemblies: &[Assembly], cone_model: ConeModel) -> Result<Self> {
        let dim = frames[0].dim;
        let mut ncols = 0;
        let mut placed: Vec<Vec<Option<JointContact>>> = Vec::with_capacity(frames.len());
        let mut cone_list: Vec<Cone> = Vec::new();
        let mut blocks = Vec::new();
        for (frame, assembly) in frames.iter().zip(assemblies) {
            let mut here = vec![None; frame.contacts.len()];
            for system in &assembly.systems {
                for cone in cones(system, cone_model) {
                    cone_list.push(cone.shifted(ncols));
                }
                for u in &system.unknowns {
                    let count = u.count(dim);
                    blocks.push((ncols + u.offset, count));
                    here[u.contact] = Some(JointContact {
                        col: ncols + u.offset,
                        count,
                        directions: u.directions,
                    });
                }
                ncols += system.n;
            }
            placed.push(here);
        }
        if ncols == 0 {
            return Err(Error::Invalid(
                "the time fit found no contact force to infer in any frame".into(),
            ));
        }
        Ok(ForceColumns {
            placed,
            cones: cone_list,
            blocks,
            ncols,
        })
    }

    /// Each frame's contact forces from the joint unknowns.
    fn forces(&self, x: &[f64], force_unit: f64) -> Vec<Vec<Option<Vec3>>> {
        self.placed
            .iter()
            .map(|here| {
                here.iter()
                    .map(|jc| {
                        jc.as_ref().map(|jc| {
                            let mut f = [0.0; 3];
                            for j in 0..jc.count {
                                for (axis, fa) in f.iter_mut().enumerate() {
                                    *fa += x[jc.col + j] * jc.directions[j][axis] * force_unit;
                                }
                            }
                            f
                        })
                    })
                    .collect()
            })
            .collect()
    }
}

/// The joint system: least-squares rows A x ≈ b, hard rows C x = d.
struct JointRows {
    a: Triplets,
    b: Vec<f64>,
    c: Triplets,
    d: Vec<f64>,
}

/// What the track and integrator rows read.
struct Kinematics<'a> {
    frames: &'a [Scene],
    segments: &'a [Segment],
    first_col: &'a [usize],
    dt: f64,
    gravity: Vec3,
    force_unit: f64,
    /// The kinematic columns' unit (the first σ_x).
    unit: f64,
}

impl JointRows {
    /// Stress rows and moment rows of every frame, both least squares.
    fn append_frames(
        &mut self,
        assemblies: &[Assembly],
        stress_sd: f64,
        force_unit: f64,
        dim: usize,
    ) {
        let loads: Vec<f64> = assemblies.iter().map(frame_load).collect();
        let largest_load = loads.iter().copied().fold(0.0, f64::max);
        let mut offset = 0;
        for (assembly, load) in assemblies.iter().zip(&loads) {
            // A frame without stress is not exact: floor its noise.
            let noise = stress_sd * load.max(1e-3 * largest_load).max(f64::MIN_POSITIVE);
            for system in &assembly.systems {
                let scale = system.scales.force * system.scales.length;
                let column = force_unit / system.scales.force;
                append_rows(
                    &mut self.a,
                    &mut self.b,
                    &system.stress,
                    &system.stress_rhs,
                    offset,
                    column * scale / noise,
                    scale / noise,
                    |_| true,
                );
                let nm = system.momentum_rows_per_grain();
                let weight = MOMENT_WEIGHT * scale / noise;
                append_rows(
                    &mut self.a,
                    &mut self.b,
                    &system.momentum,
                    &system.momentum_rhs,
                    offset,
                    column * weight,
                    weight,
                    |row| row % nm >= dim,
                );
                offset += system.n;
            }
        }
    }

    /// Tracks (least squares) and the integrator (hard). Returns each track
    /// row's triplet, right-hand side and measured offset, to reweigh them.
    fn append_tracks(&mut self, k: &Kinematics, position_sd: f64) -> Vec<(usize, usize, f64)> {
        let (frames, dt, unit) = (k.frames, k.dt, k.unit);
        let dim = frames[0].dim;
        let mut track_rows: Vec<(usize, usize, f64)> = Vec::new();
        for (seg, &col0) in k.segments.iter().zip(k.first_col) {
            let x_col = |i: usize, axis: usize| col0 + 2 * dim * i + axis;
            let v_col = |i: usize, axis: usize| col0 + 2 * dim * i + dim + axis;
            let (k0, p0) = seg.frames[0];
            let origin = frames[k0].grains[p0].position;
            for (i, &(f, p)) in seg.frames.iter().enumerate() {
                let measured = frames[f].grains[p].position;
                for axis in 0..dim {
                    let off = measured[axis] - origin[axis];
                    track_rows.push((self.a.nnz(), self.b.len(), off));
                    push_row(
                        &mut self.a,
                        &mut self.b,
                        &[(x_col(i, axis), 1.0)],
                        off / position_sd,
                    );
                }
            }
            // a_k = N_k/m + g; in the columns' unit a Δt² term weighs h = Δt² F/(m unit).
            let h = dt * dt * k.force_unit / (seg.mass * unit);
            let g_term = |axis: usize| dt * dt * k.gravity[axis] / unit;
            for i in 0..seg.frames.len() - 1 {
                for axis in 0..dim {
                    let (now, next) = (&seg.nets[i][axis], &seg.nets[i + 1][axis]);
                    let mut x_row = vec![
                        (x_col(i + 1, axis), 1.0),
                        (x_col(i, axis), -1.0),
                        (v_col(i, axis), -1.0),
                    ];
                    x_row.extend(now.iter().map(|&(col, s)| (col, -h * s / 3.0)));
                    x_row.extend(next.iter().map(|&(col, s)| (col, -h * s / 6.0)));
                    push_row(&mut self.c, &mut self.d, &x_row, 0.5 * g_term(axis));
                    let mut v_row = vec![(v_col(i + 1, axis), 1.0), (v_col(i, axis), -1.0)];
                    v_row.extend(now.iter().chain(next).map(|&(col, s)| (col, -0.5 * h * s)));
                    push_row(&mut self.c, &mut self.d, &v_row, g_term(axis));
                }
            }
        }
        track_rows
    }

    /// Roughness rows: each contact's force, component by component, changes
    /// smoothly; absent from a frame = zero force there. Returns the number
    /// of contact tracks that gave a row.
    fn append_roughness(
        &mut self,
        ctracks: &ContactTracks,
        placed: &[Vec<Option<JointContact>>],
        dim: usize,
        weight: f64,
    ) -> usize {
        let nf = placed.len();
        let mut contact_track_count = 0;
        for track in ctracks.values() {
            // A frame where the pair has a contact that is not fitted (outside the
            // selection) or several contacts breaks the track.
            let usable = |k: usize| -> Option<Option<(&JointContact, f64)>> {
                match track[k].as_slice() {
                    [] => Some(None),
                    &[(i, sign)] => placed[k][i].as_ref().map(|jc| Some((jc, sign))),
                    _ => None,
                }
            };
            let present: Vec<usize> = (0..nf).filter(|&k| !track[k].is_empty()).collect();
            let (Some(&first), Some(&last)) = (present.first(), present.last()) else {
                continue;
            };
            let (lo, hi) = (first.saturating_sub(1), (last + 1).min(nf - 1));
            let mut any = false;
            for k in lo + 1..hi {
                let window: Option<Vec<_>> = (k - 1..=k + 1).map(usable).collect();
                let Some(window) = window else { continue };
                for axis in 0..dim {
                    let mut row = Vec::new();
                    for (slot, coef) in window.iter().zip([1.0, -2.0, 1.0]) {
                        if let Some((jc, sign)) = slot {
                            for j in 0..jc.count {
                                let v = coef * sign * jc.directions[j][axis] * weight;
                                if v != 0.0 {
                                    row.push((jc.col + j, v));
                                }
                            }
                        }
                    }
                    if !row.is_empty() {
                        push_row(&mut self.a, &mut self.b, &row, 0.0);
                        any = true;
                    }
                }
            }
            contact_track_count += usize::from(any);
        }
        contact_track_count
    }
}

/// Solves the joint system through the cascade; returns the solution and the
/// position sd finally used.
#[allow(clippy::too_many_arguments)]
fn solve_joint(
    rows: JointRows,
    columns: &ForceColumns,
    ncols: usize,
    track_rows: &[(usize, usize, f64)],
    position_sd: f64,
    opts: &InferOptions,
    start: Instant,
    warnings: &mut Vec<String>,
) -> Result<(Solution, f64)> {
    let JointRows { mut a, mut b, c, d } = rows;
    let unit = position_sd;
    // Each contact's unknowns coupled, so the active set's rows fit the pattern.
    let mut coupling = Triplets::new(columns.blocks.len(), ncols);
    for (row, &(col, count)) in columns.blocks.iter().enumerate() {
        for j in col..col + count {
            coupling.push(row, j, 1.0);
        }
    }
    let mut ls = EqualityLeastSquares::with_coupling(&a, &c, &coupling)?;
    // Very precise tracks pin the forces through the integrator alone and
    // leave the normal equations too ill-conditioned for refinement (seen:
    // noise-free 3D tracks, σ_x = 1e-7 m); the tracks are then trusted
    // tenfold less, up to three times, on the same analysis, and the report
    // says so.
    let stated_position_sd = position_sd;
    let mut position_sd = position_sd;
    let mut loosened = 0;
    let sol = loop {
        let sol = ls.solve(&a, &c, &b, &d, 0.0)?;
        if sol.converged {
            break sol;
        }
        if loosened == MAX_LOOSENINGS {
            return Err(Error::Solver(format!(
                "time fit: the joint least squares did not converge (KKT residual {:.1e}, position sd up to {position_sd:.1e} m); the tracks may be inconsistent",
                sol.kkt_residual
            )));
        }
        loosened += 1;
        position_sd *= 10.0;
        for &(entry, row, off) in track_rows {
            a.vals[entry] = unit / position_sd;
            b[row] = off / position_sd;
        }
    };
    if loosened > 0 {
        warnings.push(format!(
            "position sd raised from {stated_position_sd:.2e} to {position_sd:.2e} m: tighter tracks left the joint system too ill-conditioned"
        ));
    }
    let problem = ConicProblem {
        n: ncols,
        terms: vec![Term {
            matrix: &a,
            rhs: &b,
            weight: 1.0,
        }],
        equalities: vec![(&c, d.as_slice())],
        lambda: 0.0,
        regularized: 0,
        cones: columns.cones.clone(),
    };
    let unconstrained = Solution {
        x: sol.x,
        status: SolveStatus::LeastSquares,
        iterations: sol.refinement_steps as u32,
        solve_time: start.elapsed().as_secs_f64(),
        attempts: Vec::new(),
        softened: false,
        warnings: Vec::new(),
    };
    // The joint problem is always feasible (zero forces, free tracks), so a
    // failure is numerical: say so rather than pass its diagnosis on.
    let settings = CascadeSettings {
        active_set: true,
        exact_first: true,
        ..opts.cascade()
    };
    let solved = cascade::solve_on_factor(&mut ls, &problem, &unconstrained, &settings)
        .map_err(|e| {
            Error::Solver(format!(
                "time fit: the joint problem was not solved ({e}); infer frame by frame (`time_fit` = frames)"
            ))
        })?;
    if solved.softened {
        return Err(Error::Solver(format!(
            "time fit: the interior point met the integrator rows only softened ({}); infer frame by frame instead",
            solved.status
        )));
    }
    Ok((solved, position_sd))
}

/// Net force on a grain in one frame, per axis: (joint column, coefficient).
type NetForce = Vec<Vec<(usize, f64)>>;

/// A grain's run of consecutive frames in which it is pushed somewhere.
struct Segment {
    /// (frame, grain index) of each frame of the run.
    frames: Vec<(usize, usize)>,
    /// Net force on the grain in each frame of the run.
    nets: Vec<NetForce>,
    mass: f64,
}

/// The runs (of at least two frames, with a force in some frame) of every
/// grain tracked by id, in id order; `net_force(k, p)` is `None` where a
/// grain's contact is not fitted, which breaks a run. Errors on a loaded
/// grain without mass.
fn grain_segments(
    frames: &[Scene],
    net_force: &dyn Fn(usize, usize) -> Option<NetForce>,
) -> Result<Vec<Segment>> {
    let mut tracks: std::collections::BTreeMap<&str, Vec<(usize, usize)>> = Default::default();
    for (k, frame) in frames.iter().enumerate() {
        for (p, g) in frame.grains.iter().enumerate() {
            tracks.entry(g.id.as_str()).or_default().push((k, p));
        }
    }
    let mut segments = Vec::new();
    for track in tracks.values() {
        let mut run: Vec<(usize, usize, NetForce)> = Vec::new();
        let mut runs = Vec::new();
        for &(k, p) in track {
            let net = net_force(k, p);
            let consecutive = run.last().is_some_and(|&(kl, _, _)| kl + 1 == k);
            if !consecutive || net.is_none() {
                runs.push(std::mem::take(&mut run));
            }
            if let Some(net) = net {
                run.push((k, p, net));
            }
        }
        runs.push(run);
        for run in runs {
            let loaded = run.iter().any(|(_, _, n)| n.iter().any(|e| !e.is_empty()));
            if run.len() < 2 || !loaded {
                continue;
            }
            // The mass stated in any frame of the run (usually all, or the first).
            let mass = run
                .iter()
                .find_map(|&(k, p, _)| frames[k].grains[p].mass)
                .filter(|m| *m > 0.0 && m.is_finite());
            let Some(mass) = mass else {
                let (k0, p0) = (run[0].0, run[0].1);
                return Err(Error::Invalid(format!(
                    "grain {} (frames {}..) carries contact forces but has no positive mass; the time fit integrates its motion",
                    frames[k0].grains[p0].id,
                    frames[k0].frame.unwrap_or(k0 as i64)
                )));
            };
            let (frames_of, nets) = run.into_iter().map(|(k, p, n)| ((k, p), n)).unzip();
            segments.push(Segment {
                frames: frames_of,
                nets,
                mass,
            });
        }
    }
    Ok(segments)
}

/// A frame's rms stress load |V σ| over its grains' stress rows [N m].
fn frame_load(assembly: &assemble::Assembly) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for s in &assembly.systems {
        let unit = s.scales.force * s.scales.length;
        for v in &s.stress_rhs {
            sum += (v * unit).powi(2);
            n += 1;
        }
    }
    (sum / n.max(1) as f64).sqrt()
}

/// Appends the rows of `m` (columns shifted by `offset`, values × `scale`,
/// right-hand side × `rhs_scale`) that `keep` selects.
#[allow(clippy::too_many_arguments)]
fn append_rows(
    t: &mut Triplets,
    rhs: &mut Vec<f64>,
    m: &Triplets,
    m_rhs: &[f64],
    offset: usize,
    scale: f64,
    rhs_scale: f64,
    keep: impl Fn(usize) -> bool,
) {
    let mut new_row = vec![None; m.nrows];
    for (row, slot) in new_row.iter_mut().enumerate() {
        if keep(row) {
            *slot = Some(t.nrows);
            t.nrows += 1;
            rhs.push(m_rhs[row] * rhs_scale);
        }
    }
    for k in 0..m.nnz() {
        if let Some(row) = new_row[m.rows[k]] {
            t.push(row, m.cols[k] + offset, m.vals[k] * scale);
        }
    }
}
