//! Force inference: the formulations of the method and the choice of λ.
//!
//! One module per formulation, each building its conic problems for the
//! cascade (`crate::solver::cascade`):
//! - [`qs`] — `qs` (eq. 2.13): min ‖K_st f − b_st‖² s.t. K_eq f = b_eq and
//!   friction; `tikhonov` (eq. 2.14) adds λ²‖f‖², λ fixed or chosen so the
//!   inferred wall forces match the load cells (eq. 2.17, [`lambda`]); `ls`
//!   drops the inequalities: the fast floor.
//! - [`scaled`]: a global stress scale s fitted to the measured wall forces.
//! - [`dynamic`] — `dynamic` (eq. 3.18): ‖K_s f − b_s‖² + λ‖K_m f − b_m‖², λ
//!   by a rule; `soft` the same on static data.
//! - [`time_fit`]: the forces and the tracks of a sequence fitted jointly.
//!
//! [`collapse`] detects and diagnoses data that do not balance (collapsed or
//! infeasible hard-balance answers); [`context::Context`] is what a solve reads.

pub mod collapse;
pub mod config;
mod context;
pub mod dynamic;
pub mod kinematics;
mod lambda;
pub mod noise;
mod options;
mod qs;
mod report;
pub mod run;
mod scaled;
pub mod sequence;
pub mod shards;
pub mod time_fit;
pub mod uncertainty;

pub use crate::solver::active_set::ActiveSetSettings;
pub use collapse::{Collapse, OnCollapse};
pub use config::{ConfigError, InferConfig};
pub use context::cones;
pub use dynamic::{DynamicOptions, Front, LambdaRule};
pub use lambda::{LambdaPrecision, LambdaSearch, LambdaTrace};
pub use noise::StressNoise;
pub use options::{ConeModel, ConstrainedSolver, InferOptions, Method};
pub use report::InferenceReport;
pub use sequence::{infer_frames, infer_sequence, Progress};

use crate::assemble::{self, Assembly};
use crate::error::Result;
use crate::scene::{Scene, Vec3};
use crate::solver::cascade::{self, FactorCache};
use crate::solver::sparse_ls;
use context::Context;
use std::time::Instant;

/// The result of one scene (frame).
#[derive(Debug, Clone)]
pub struct Inference {
    /// Force on grain `a` by `b` per scene contact; `None` for contacts outside
    /// the inferred sub-assembly.
    pub forces: Vec<Option<Vec3>>,
    pub report: InferenceReport,
}

impl Inference {
    /// Forces with `None` replaced by zero (for metrics on the whole scene).
    pub fn forces_or_zero(&self) -> Vec<Vec3> {
        self.forces.iter().map(|f| f.unwrap_or([0.0; 3])).collect()
    }
}

/// Infers one scene. A hard-balance answer that collapses (data out of
/// balance) is never returned silently: see [`InferOptions::on_collapse`].
pub fn infer(scene: &Scene, opts: &InferOptions) -> Result<Inference> {
    // Before any work: the active set may answer without reading it.
    opts.conic.check()?;
    let hard = matches!(
        opts.method,
        Method::Qs | Method::Tikhonov | Method::Ls | Method::Scaled
    ) && !opts.allow_infeasible;
    let first = infer_once(scene, opts);
    if !hard {
        return first;
    }
    collapse::settle(scene, opts, first)
}

/// One inference with the given method, no collapse handling.
pub(crate) fn infer_once(scene: &Scene, opts: &InferOptions) -> Result<Inference> {
    let start = Instant::now();
    let soft_opts;
    let opts = if opts.method == Method::Soft {
        soft_opts = InferOptions {
            dynamic: DynamicOptions {
                rule: dynamic::soft_rule(opts.dynamic.rule),
                ..opts.dynamic.clone()
            },
            ..opts.clone()
        };
        &soft_opts
    } else {
        opts
    };
    let mut assemble_opts = opts.assemble.clone();
    // Pruning relies on momentum being a hard constraint; `scaled` couples all
    // clusters through one scale factor.
    let hard_momentum = match opts.method {
        Method::Dynamic | Method::Soft => dynamic::dynamic_lambda(opts).is_none(),
        _ => true,
    };
    assemble_opts.prune_single_contacts = hard_momentum && !opts.allow_infeasible;
    assemble_opts.single_system = opts.method == Method::Scaled;
    let assembly = assemble::assemble(scene, &assemble_opts)?;
    let mut report = InferenceReport::new(scene, opts, &assembly);
    let factors = FactorCache::new(assembly.systems.len());
    // The uniqueness check has its own factorisation and does not depend on
    // the solve, so it runs beside it: mostly sequential, the solve leaves a
    // second core idle (3D 10⁴ spheres: check 9 s, `ls` solve 10 s).
    let (identifiable, solved) = std::thread::scope(|scope| {
        let check = scope.spawn(|| check_identifiability(&assembly, opts));
        let cx = Context {
            scene,
            assembly: &assembly,
            opts,
            factors: &factors,
        };
        let solved = solve_with_noise_model(&cx, &mut report);
        let identifiable = check
            .join()
            .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
        (identifiable, solved)
    });
    (report.unique, report.conditioning) = identifiable?;
    let (solutions, lambda_trace) = solved?;
    let forces = collect_forces(scene, &assembly, &solutions);
    report.finish(
        scene,
        &assembly,
        &solutions,
        &forces,
        lambda_trace,
        start.elapsed().as_secs_f64(),
    );
    Ok(Inference { forces, report })
}

/// How much looser than the final solve's share of the noise the
/// reweighting passes before it may stop the interior point: only their
/// weights are kept (measured in docs/bench.md, round 6).
const WEIGHTING_PASS_LOOSENING: f64 = 30.0;

/// The chosen method's solve under the chosen stress-noise model.
fn solve_with_noise_model(
    cx: &Context,
    report: &mut InferenceReport,
) -> Result<(Vec<Vec<f64>>, Option<LambdaTrace>)> {
    let (scene, assembly) = (cx.scene, cx.assembly);
    Ok(match cx.opts.stress_noise {
        StressNoise::Absolute => solve_method(cx, report)?,
        StressNoise::Columns => {
            let weights = noise::column_weights(scene, assembly)?;
            let weighted = noise::weight_stress_rows(assembly, &weights);
            solve_method(
                &Context {
                    assembly: &weighted,
                    ..*cx
                },
                report,
            )?
        }
        StressNoise::Relative => {
            // The passes before the last only set weights: at the data's
            // accuracy they stop at a looser share of their noise.
            let mut looser = cx.opts.clone();
            looser.conic.noise_share = looser
                .conic
                .noise_share
                .map(|share| share * WEIGHTING_PASS_LOOSENING);
            let mut solved = solve_method(
                &Context {
                    opts: &looser,
                    ..*cx
                },
                report,
            )?;
            for step in 0..noise::IRLS_STEPS {
                let weights = noise::relative_weights(assembly, &solved.0);
                let weighted = noise::weight_stress_rows(assembly, &weights);
                let last = step + 1 == noise::IRLS_STEPS;
                solved = solve_method(
                    &Context {
                        assembly: &weighted,
                        opts: if last { cx.opts } else { &looser },
                        ..*cx
                    },
                    report,
                )?;
            }
            report.relative_stress_residual = Some(noise::relative_residual(assembly, &solved.0));
            solved
        }
    })
}

/// The chosen method's solve on an assembly (its stress rows possibly weighted).
fn solve_method(
    cx: &Context,
    report: &mut InferenceReport,
) -> Result<(Vec<Vec<f64>>, Option<LambdaTrace>)> {
    let (assembly, opts) = (cx.assembly, cx.opts);
    Ok(match opts.method {
        Method::Qs => (qs::solve_all(cx, 0.0, report)?, None),
        Method::Tikhonov if opts.lambda.is_none() => {
            let (lam, trace, xs) = lambda::search(cx, report)?;
            report.lambda = Some(lam * assembly.scales.length);
            (xs, Some(trace))
        }
        // `ls` (λ given or 0) and Tikhonov at a given λ.
        Method::Ls | Method::Tikhonov => (
            qs::solve_all(cx, qs::scaled_lambda(opts, assembly), report)?,
            None,
        ),
        Method::Scaled => {
            let (x, s) = scaled::solve(cx, report)?;
            report.stress_scale = Some(s);
            (vec![x], None)
        }
        Method::Dynamic | Method::Soft => (dynamic::solve(cx, report)?, None),
    })
}

/// Whether the data determine the forces (N(K_st) ∩ N(K_eq) = {0} in every
/// cluster), and the smallest σ_min/σ_max of the clusters' equilibrated
/// [K_st; K_eq].
fn check_identifiability(
    assembly: &Assembly,
    opts: &InferOptions,
) -> Result<(Option<bool>, Option<f64>)> {
    let n: usize = assembly.systems.iter().map(|s| s.n).sum();
    if n > opts.identifiability_limit {
        return Ok((None, None));
    }
    let mut unique = true;
    let mut conditioning = 1.0f64;
    for s in &assembly.systems {
        let ordering = cascade::ordering(s.dim, opts.ordering);
        let check = sparse_ls::identifiability_with(&s.stress, &s.momentum, ordering)?;
        unique &= check.unique;
        conditioning = conditioning.min(check.sigma_min_relative);
    }
    Ok((Some(unique), Some(conditioning)))
}

pub(crate) fn collect_forces(
    scene: &Scene,
    assembly: &Assembly,
    solutions: &[Vec<f64>],
) -> Vec<Option<Vec3>> {
    let mut forces = vec![None; scene.contacts.len()];
    for (system, x) in assembly.systems.iter().zip(solutions) {
        for (c, f) in system.forces(x) {
            forces[c] = Some(f);
        }
    }
    for &c in &assembly.zero_contacts {
        forces[c] = Some([0.0; 3]);
    }
    forces
}

pub use crate::scene::wall_totals;
