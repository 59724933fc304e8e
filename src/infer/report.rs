//! What an inference did: sizes, residuals, λ, solver status, warnings — printed
//! as a short summary and serialisable as JSON.

use super::{wall_totals, InferOptions, LambdaTrace, Method};
use crate::assemble::{Assembly, Friction};
use crate::scene::{Scene, Vec3};
use crate::solver::SolveStatus;
use crate::solver::{Attempt, Solution};

#[derive(Debug, Clone, serde::Serialize)]
pub struct WallReport {
    pub wall: String,
    pub measured: Option<Vec<f64>>,
    pub inferred: Vec<f64>,
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct InferenceReport {
    pub method: Method,
    pub dim: usize,
    pub frame: Option<i64>,
    pub grains: usize,
    pub grains_with_equations: usize,
    pub contacts: usize,
    pub modelled_contacts: usize,
    pub unknowns: usize,
    pub clusters: usize,
    pub rattlers: usize,
    pub loaded_rattlers: Vec<String>,
    pub zero_force_contacts: usize,
    /// How friction was modelled.
    pub friction: String,
    pub force_scale: f64,
    pub length_scale: f64,
    /// ‖K_st f − b_st‖ / ‖b_st‖ over all modelled grains.
    pub stress_residual: f64,
    /// `--stress-noise relative`: rms of (K_st f − b)/(|K_st f| + floor), the
    /// relative noise level the answer implies.
    pub relative_stress_residual: Option<f64>,
    /// Largest momentum-row residual relative to the mean contact force.
    pub momentum_residual: f64,
    /// Largest (|f_t| − μ f_n)₊ relative to the mean contact force.
    pub coulomb_violation: f64,
    /// Tikhonov λ in the units of the equation (length), when used.
    pub lambda: Option<f64>,
    pub lambda_trace: Option<LambdaTrace>,
    /// Dimensionless weight of the momentum rows (method `dynamic`); None = hard.
    pub momentum_weight: Option<f64>,
    /// The variance-component iteration that chose the momentum weight.
    pub variance_steps: Vec<super::dynamic::VarianceStep>,
    /// The swept Pareto front (dynamic, rule knee).
    pub pareto: Option<super::Front>,
    /// Estimated global stress scale (method `scaled`): true ≈ s · measured.
    pub stress_scale: Option<f64>,
    /// The hard-balance answer collapsed (data out of balance): the diagnosis.
    pub collapse: Option<super::Collapse>,
    /// Whether the forces are uniquely determined by the data (None: not checked).
    pub unique: Option<bool>,
    /// Estimate of σ_min/σ_max of the equilibrated [K_st; K_eq] (smallest
    /// over clusters; None: not checked): a relative error η in the data can
    /// move the forces by up to ~η/σ.
    pub conditioning: Option<f64>,
    pub solver_status: SolveStatus,
    /// How each solve went (algorithm, iterations, fallbacks) and how the λ
    /// search went, as text, deduplicated.
    pub solver_attempts: Vec<String>,
    /// The solves' stages of `solver_attempts`, typed: their numbers (the
    /// interior point's iterations, gap, distance to the optimum and noise)
    /// are numbers in the JSON report.
    pub solver_stages: Vec<Attempt>,
    pub iterations: u32,
    pub solver_time: f64,
    pub walls: Vec<WallReport>,
    pub warnings: Vec<String>,
    pub time: f64,
}

impl InferenceReport {
    pub(crate) fn new(scene: &Scene, opts: &InferOptions, assembly: &Assembly) -> Self {
        let [frictionless, coulomb, normal_only] = assembly.friction_counts;
        let friction = match opts.method {
            Method::Ls => "none imposed (ls: equalities only)".to_owned(),
            _ if normal_only > 0 && coulomb == 0 => format!(
                "normal force ≥ 0 only: no μ given (Coulomb abandoned) for {normal_only} contacts{}",
                if frictionless > 0 { format!(", {frictionless} frictionless") } else { String::new() }
            ),
            _ => format!("Coulomb on {coulomb} contacts, {frictionless} frictionless, {normal_only} normal-only"),
        };
        let mut warnings = Vec::new();
        if normal_only > 0 && opts.method != Method::Ls {
            warnings.push(format!(
                "{normal_only} contacts have no friction coefficient (no mu column in contacts.csv, no `mu`, no mu in scene.json): only f_n ≥ 0 imposed"
            ));
        }
        let loaded_rattlers: Vec<String> = assembly
            .loaded_rattlers
            .iter()
            .map(|&p| scene.grains[p].id.clone())
            .collect();
        // A loaded "rattler" either has no contact in the file or lost its
        // only one(s) to pruning (a grain with a single contact and nothing to
        // balance must have a zero force there when balance is exact).
        let pruned = assembly
            .loaded_rattlers
            .iter()
            .filter(|&&p| {
                scene
                    .contacts
                    .iter()
                    .any(|c| c.a == p || c.b == crate::scene::Body::Grain(p))
            })
            .count();
        let bare = loaded_rattlers.len() - pruned;
        if bare > 0 {
            warnings.push(format!(
                "{bare} grains report load (stress or acceleration) but have no contacts in the file; their data are ignored"
            ));
        }
        if pruned > 0 {
            warnings.push(format!(
                "{pruned} grains report stress but their contacts were all fixed to zero by pruning (a grain left with \
                 one contact and no load to balance carries no force when momentum balance is exact), so their \
                 stresses are ignored: the data are missing contacts (detectors miss weak ones); `method` = soft uses them"
            ));
        }
        InferenceReport {
            method: opts.method,
            dim: scene.dim,
            frame: scene.frame,
            grains: scene.grains.len(),
            grains_with_equations: assembly.systems.iter().map(|s| s.grains.len()).sum(),
            contacts: scene.contacts.len(),
            modelled_contacts: assembly.systems.iter().map(|s| s.unknowns.len()).sum(),
            unknowns: assembly.systems.iter().map(|s| s.n).sum(),
            clusters: assembly.systems.len(),
            rattlers: assembly.rattlers.len(),
            loaded_rattlers,
            zero_force_contacts: assembly.zero_contacts.len(),
            friction,
            force_scale: assembly.scales.force,
            length_scale: assembly.scales.length,
            stress_residual: 0.0,
            relative_stress_residual: None,
            momentum_residual: 0.0,
            coulomb_violation: 0.0,
            lambda: opts
                .lambda
                .filter(|_| matches!(opts.method, Method::Tikhonov | Method::Ls)),
            lambda_trace: None,
            momentum_weight: None,
            variance_steps: Vec::new(),
            pareto: None,
            stress_scale: None,
            collapse: None,
            unique: None,
            conditioning: None,
            solver_status: SolveStatus::NotRun,
            solver_attempts: Vec::new(),
            solver_stages: Vec::new(),
            iterations: 0,
            solver_time: 0.0,
            walls: Vec::new(),
            warnings,
            time: 0.0,
        }
    }

    /// Accounts for one solver call.
    pub(crate) fn absorb(&mut self, sol: &Solution) {
        self.iterations += sol.iterations;
        self.solver_time += sol.solve_time;
        if sol.status.severity() >= self.solver_status.severity() {
            self.solver_status = sol.status;
        }
        for a in &sol.attempts {
            let text = a.to_string();
            if !self.solver_attempts.contains(&text) {
                self.solver_attempts.push(text);
                self.solver_stages.push(a.clone());
            }
        }
        for w in &sol.warnings {
            if !self.warnings.contains(w) {
                self.warnings.push(w.clone());
            }
        }
    }

    pub(crate) fn finish(
        &mut self,
        scene: &Scene,
        assembly: &Assembly,
        solutions: &[Vec<f64>],
        forces: &[Option<Vec3>],
        trace: Option<LambdaTrace>,
        time: f64,
    ) {
        let (mut r2, mut b2, mut worst_momentum) = (0.0, 0.0, 0.0f64);
        let mut magnitudes = 0.0;
        let mut count = 0usize;
        for (system, x) in assembly.systems.iter().zip(solutions) {
            let scale = self.stress_scale.unwrap_or(1.0);
            let kx = system.stress.mul(x);
            for (k, b) in kx.iter().zip(&system.stress_rhs) {
                r2 += (k - scale * b).powi(2);
                b2 += (scale * b).powi(2);
            }
            let mx = system.momentum.mul(x);
            for (m, b) in mx.iter().zip(&system.momentum_rhs) {
                worst_momentum = worst_momentum.max((m - b).abs());
            }
            for (_, f) in system.forces(x) {
                magnitudes += crate::scene::norm(f) / assembly.scales.force;
                count += 1;
            }
        }
        let mean = if count > 0 {
            magnitudes / count as f64
        } else {
            0.0
        };
        self.stress_residual = if b2 > 0.0 {
            (r2 / b2).sqrt()
        } else {
            r2.sqrt()
        };
        self.momentum_residual = if mean > 0.0 {
            worst_momentum / mean
        } else {
            worst_momentum
        };
        let mut worst_coulomb = 0.0f64;
        for system in &assembly.systems {
            for u in &system.unknowns {
                if let (Friction::Coulomb(mu), Some(f)) = (u.friction, forces[u.contact]) {
                    let n = scene.contacts[u.contact].normal;
                    let fn_ = -crate::scene::dot(f, n);
                    let ft = crate::scene::norm([
                        f[0] + fn_ * n[0],
                        f[1] + fn_ * n[1],
                        f[2] + fn_ * n[2],
                    ]);
                    worst_coulomb = worst_coulomb.max(ft - mu * fn_);
                }
            }
        }
        self.coulomb_violation = if mean > 0.0 {
            worst_coulomb / (mean * assembly.scales.force)
        } else {
            0.0
        };
        let totals = wall_totals(scene, forces);
        self.walls = scene
            .walls
            .iter()
            .zip(&totals)
            .map(|(w, t)| WallReport {
                wall: w.name.clone(),
                measured: w.measured_force.map(|m| m[..scene.dim].to_vec()),
                inferred: t[..scene.dim].to_vec(),
            })
            .collect();
        if let Some(t) = &trace {
            if t.at_edge {
                self.warnings.push(
                    "the best λ lies at an end of the search range; widen it (`lambda_range`) or give `lambda`".into(),
                );
            }
        }
        self.lambda_trace = trace;
        self.time = time;
    }
}

fn fmt_vec(v: &[f64]) -> String {
    let parts: Vec<String> = v.iter().map(|x| format!("{x:.4e}")).collect();
    format!("({})", parts.join(", "))
}

impl std::fmt::Display for InferenceReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if let Some(frame) = self.frame {
            writeln!(f, "frame {frame}")?;
        }
        writeln!(f, "method      {} ({}D)", self.method, self.dim)?;
        writeln!(
            f,
            "size        {} grains ({} with equations, {} rattlers), {} contacts ({} modelled, {} zero by pruning), {} unknowns, {} clusters",
            self.grains,
            self.grains_with_equations,
            self.rattlers,
            self.contacts,
            self.modelled_contacts,
            self.zero_force_contacts,
            self.unknowns,
            self.clusters
        )?;
        writeln!(f, "friction    {}", self.friction)?;
        writeln!(
            f,
            "residuals   stress {:.3e} (relative), momentum {:.3e} (of mean force), Coulomb violation {:.3e}",
            self.stress_residual, self.momentum_residual, self.coulomb_violation
        )?;
        if let Some(l) = self.lambda {
            writeln!(
                f,
                "lambda      {:.4e} (dimensionless {:.4e})",
                l,
                l / self.length_scale
            )?;
        }
        if matches!(self.method, Method::Dynamic | Method::Soft) {
            match self.momentum_weight {
                Some(w) => writeln!(f, "momentum    weight λ = {w:.4e} (dimensionless)")?,
                None => writeln!(f, "momentum    exact (hard constraint)")?,
            }
        }
        if let Some(s) = self.stress_scale {
            writeln!(
                f,
                "stress      scale estimated from walls: {s:.5} (measured stresses × {s:.5})"
            )?;
        }
        if let Some(c) = &self.collapse {
            write!(f, "{c}")?;
        }
        let conditioning = match self.conditioning {
            Some(c) => format!(
                " (condition ≈ {:.1}: relative errors in the data can grow about that much in the forces)",
                1.0 / c
            ),
            None => String::new(),
        };
        match self.unique {
            Some(true) if self.collapse.is_some() && self.method != Method::Soft => writeln!(
                f,
                "unique      the equations have one solution, but it is the collapse above, not the forces"
            )?,
            Some(true) => writeln!(f, "unique      yes: the data determine every force{conditioning}")?,
            Some(false) => writeln!(
                f,
                "unique      NO: N(K_st) ∩ N(K_eq) ≠ {{0}}, other force fields fit the data equally well{conditioning}"
            )?,
            None => writeln!(f, "unique      not checked")?,
        }
        for w in &self.walls {
            match &w.measured {
                Some(m) => writeln!(
                    f,
                    "wall        {}: inferred {} measured {}",
                    w.wall,
                    fmt_vec(&w.inferred),
                    fmt_vec(m)
                )?,
                None => writeln!(
                    f,
                    "wall        {}: inferred {}",
                    w.wall,
                    fmt_vec(&w.inferred)
                )?,
            }
        }
        writeln!(
            f,
            "solver      {} in {} iterations, {:.3} s solver time, {:.3} s total",
            self.solver_status, self.iterations, self.solver_time, self.time
        )?;
        for w in &self.warnings {
            writeln!(f, "warning     {w}")?;
        }
        Ok(())
    }
}
