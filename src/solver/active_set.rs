//! Friction-constrained least squares by a damped semismooth Newton
//! (primal–dual active-set) method on the sparse factorisation:
//!
//! ```text
//!     minimise ‖A x − b‖² + λ²‖x‖²   subject to   C x = d,   x_c ∈ K_c
//! ```
//!
//! with K_c each contact's cone (f_n ≥ 0, the 2D wedge, the 3D Coulomb cone).
//! The optimality conditions per contact read x_c = Π_K(x_c − ρ_c v_c), with
//! v_c the force the cone exerts (its multipliers) and Π_K the projection onto
//! the cone. Each iteration reads from that projection which piece of the cone
//! is active at every contact — interior (free), the boundary (sliding: the
//! face of the wedge; for the 3D cone its tangent plane plus the curvature of
//! the projection, a spring across the sliding direction), or the apex (open,
//! f_c = 0) — and solves the equality-constrained least squares with those rows
//! by [`EqualityLeastSquares`] on its *fixed* symbolic analysis: one numeric
//! factorisation per iteration, or, when few rows changed since the last one,
//! those rows bordered around it. That solve is the Newton step of the
//! fixed-point equations; the step is halved until their residual decreases.
//!
//! Started from the unconstrained answer it settles in a handful of solves;
//! the first active set is guessed by cheap Gauss–Seidel sweeps (`predict`),
//! which leaves two or three (2D, 10⁵ grains, stress noise: 2–3 solves
//! instead of 6–11; 3D, 10³ spheres, 30 % sliding, stress noise: 6 instead
//! of 8). The same sweeps run again after the first solve, around its answer
//! and exact cone forces, to place the contacts for the second (3D, 30 %
//! sliding, stress noise: 3 solves instead of 5 from 2 197 to 10⁵ spheres;
//! 2 factorised instead of 3 at 2 197 and 10⁴).
//! Convergence is declared only when every contact meets its fixed-point
//! condition to `tolerance` and the linear solve converged; the answer then
//! satisfies the KKT conditions of the convex problem and *is* the optimum.
//! Otherwise (no descent, stalling, too many solves) the caller falls back to
//! the interior-point solver. Pyramids are not handled (their facets meet in
//! edges; the interior point takes them).

mod predict;

use super::sparse_ls::{EqualityLeastSquares, CONVERGED_TOL};
use super::Cone;
use super::{LeastSquares, Triplets};
use crate::error::{Error, Result};

/// Smallest damping of a Newton step before the method gives up.
const MIN_STEP: f64 = 1.0 / 1024.0;

/// ρ relative to the inverse Hessian diagonal. Measured on noisy packings:
/// 3D, μ = 0.1, 10³ grains: 1 stalls, 0.1 converges in 22 solves, 0.01 and
/// 0.001 in 18; 2D 10⁴: 5 solves for all; 2D 10⁵: 0.01 in 6, 1 in 7 (only
/// with full steps forced against the line search). A small ρ lets the
/// forces, not the multipliers, decide the pieces.
const RHO_FACTOR: f64 = 0.01;

/// Smallest κ kept, so that a spring stays finite.
const KAPPA_MIN: f64 = 1e-12;

/// Solves without a decrease of the best residual by this factor before the
/// method gives up (cycling between active sets).
const STALL_FACTOR: f64 = 0.9;
const MAX_STALLED: usize = 8;

/// Settings of [`solve`].
#[derive(Debug, Clone, Copy)]
pub struct ActiveSetSettings {
    /// Linear solves before giving up.
    pub max_iterations: usize,
    /// Fixed-point residual ‖x_c − Π_K(x_c − ρ v_c)‖ accepted, relative to the
    /// largest unknown.
    pub tolerance: f64,
    /// Guess the first active set by Gauss–Seidel sweeps on the relaxed
    /// correction (see `predict`) instead of projecting the start.
    pub predict: bool,
    /// Guess the pieces again after a cold first solve (not one on a
    /// nearby problem's pieces), by the same sweeps around its forces and
    /// cone forces, instead of reading them off the Newton step (3D, 30 %
    /// sliding, stress noise: 2 197 and 10⁴ spheres 3 solves instead of 5,
    /// one factorisation fewer).
    pub reguess: bool,
}

impl Default for ActiveSetSettings {
    fn default() -> Self {
        ActiveSetSettings {
            max_iterations: 40,
            tolerance: 1e-10,
            predict: true,
            reguess: true,
        }
    }
}

/// Outcome of [`solve`].
#[derive(Debug, Clone)]
pub struct ActiveSetSolution {
    pub x: Vec<f64>,
    /// True when the KKT conditions hold to the tolerance: x is the optimum.
    pub converged: bool,
    /// Linear solves done (numeric factorisations or borders).
    pub iterations: usize,
    /// Contacts on their friction limit and open contacts at the end.
    pub sliding: usize,
    pub open: usize,
    /// Largest fixed-point residual at the end, relative to the largest unknown.
    pub residual: f64,
    /// Why it stopped when not converged.
    pub reason: Option<StopReason>,
    /// One entry per linear solve.
    pub history: Vec<ActiveSetStep>,
    /// The pieces (interior, sliding, open) of the last solve: a warm start
    /// for a nearby problem (the next λ of a search), see [`solve_from`].
    pub pieces: ActivePieces,
}

impl ActiveSetSolution {
    /// Solves that needed a new numeric factorisation (the others were
    /// bordered around, or held stale in, the last one).
    pub fn factorisations(&self) -> usize {
        self.history
            .iter()
            .filter(|step| !step.reused_factor)
            .count()
    }
}

/// Which piece of its cone each contact was on — an opaque warm start.
#[derive(Debug, Clone, Default)]
pub struct ActivePieces(Vec<Piece>);

/// One iteration of [`solve`].
#[derive(Debug, Clone, Copy)]
pub struct ActiveSetStep {
    /// Rows imposed in this solve.
    pub active_rows: usize,
    /// Damping of the Newton step taken (1 = full).
    pub step: f64,
    /// Contacts whose piece changed for the next solve.
    pub changed: usize,
    /// Largest fixed-point residual after the step, relative to the largest unknown.
    pub residual: f64,
    /// Wall-clock time of the linear solve (factorisation and refinement) [s].
    pub seconds: f64,
    /// No new factorisation: the last one served, the rows that changed
    /// since bordered around it or held stale (see
    /// [`ActiveLsSolution::reused_factor`](super::sparse_ls::ActiveLsSolution::reused_factor)).
    pub reused_factor: bool,
}

/// Which piece of its cone a contact's force lies on.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Piece {
    Interior,
    /// On the boundary: the unit tangential direction of sliding (1D: ±1) and,
    /// for the 3D cone, κ = μα/τ, the projection's contraction across the
    /// sliding direction (its curvature term).
    Boundary {
        dir: [f64; 2],
        kappa: f64,
    },
    Apex,
}

/// A cone in a uniform view: the normal unknown, up to two tangential ones, μ.
struct Contact {
    normal: usize,
    tangents: Vec<usize>,
    mu: f64,
}

impl Contact {
    fn of(cone: &Cone) -> Option<Contact> {
        match *cone {
            Cone::NonNegative { normal } => Some(Contact {
                normal,
                tangents: Vec::new(),
                mu: 0.0,
            }),
            Cone::Wedge {
                normal,
                tangent,
                mu,
            } => Some(Contact {
                normal,
                tangents: vec![tangent],
                mu,
            }),
            Cone::Circular { normal, t1, t2, mu } => Some(Contact {
                normal,
                tangents: vec![t1, t2],
                mu,
            }),
            Cone::Pyramid { .. } => None,
        }
    }

    /// (normal, tangential) components of a vector over all unknowns.
    fn split(&self, x: &[f64]) -> (f64, [f64; 2]) {
        let mut t = [0.0; 2];
        for (k, &j) in self.tangents.iter().enumerate() {
            t[k] = x[j];
        }
        (x[self.normal], t)
    }

    /// Projection of (n, t) onto the cone and the piece it lands on.
    fn project(&self, n: f64, t: [f64; 2]) -> (Piece, f64, [f64; 2]) {
        let tau = t[0].hypot(t[1]);
        if self.tangents.is_empty() {
            return if n > 0.0 {
                (Piece::Interior, n, t)
            } else {
                (Piece::Apex, 0.0, [0.0; 2])
            };
        }
        if tau <= self.mu * n {
            return (Piece::Interior, n, t);
        }
        if self.mu * tau <= -n {
            return (Piece::Apex, 0.0, [0.0; 2]);
        }
        // Onto the generator (1, μ ĉ) of the boundary.
        let dir = [t[0] / tau, t[1] / tau];
        let alpha = (n + self.mu * tau) / (1.0 + self.mu * self.mu);
        let kappa = (self.mu * alpha / tau).clamp(KAPPA_MIN, 1.0);
        (
            Piece::Boundary { dir, kappa },
            alpha,
            [alpha * self.mu * dir[0], alpha * self.mu * dir[1]],
        )
    }

    /// Unit rows a·x = 0 imposing a piece, oriented so that a·x ≥ 0 is the
    /// feasible side (a multiplier > 0 then holds the force back).
    fn rows(&self, piece: Piece) -> Vec<Vec<(usize, f64)>> {
        match piece {
            Piece::Interior => Vec::new(),
            Piece::Apex => std::iter::once(self.normal)
                .chain(self.tangents.iter().copied())
                .map(|j| vec![(j, 1.0)])
                .collect(),
            Piece::Boundary { dir, .. } => {
                // μ f_n − ĉ·f_t ≥ 0: the face of the wedge, the tangent plane of the cone.
                let norm = (1.0 + self.mu * self.mu).sqrt();
                let mut row = vec![(self.normal, self.mu / norm)];
                for (k, &j) in self.tangents.iter().enumerate() {
                    row.push((j, -dir[k] / norm));
                }
                vec![row]
            }
        }
    }
}

impl Contact {
    /// The natural residual ‖x_c − Π_K(x_c − ρ v_c)‖ of the contact's force
    /// x_c = (n, t) against its cone's force v_c, and the piece that
    /// projection lands on (with κ for the 3D spring).
    fn natural(
        &self,
        (xn, xt): (f64, [f64; 2]),
        (vn, vt): (f64, [f64; 2]),
        rho: f64,
    ) -> (f64, Piece) {
        let (piece, pn, pt) =
            self.project(xn - rho * vn, [xt[0] - rho * vt[0], xt[1] - rho * vt[1]]);
        ((pn - xn).hypot((pt[0] - xt[0]).hypot(pt[1] - xt[1])), piece)
    }

    /// The Newton linearisation of the 3D cone's projection on its boundary
    /// adds, besides the tangent plane, a spring on the tangential component
    /// across the sliding direction: v⊥ = −k x⊥ with k = (1 − κ)/(κρ). Returned
    /// as the row √k e⊥ of the extra term ‖R x‖² (= ½ k x⊥² in the halved
    /// objective), with k.
    fn spring(&self, piece: Piece, rho: f64) -> Option<(Vec<(usize, f64)>, f64)> {
        match (piece, self.tangents.as_slice()) {
            (Piece::Boundary { dir, kappa }, &[t1, t2]) if kappa < 1.0 => {
                let k = (1.0 - kappa) / (kappa * rho);
                let r = k.sqrt();
                Some((vec![(t1, -dir[1] * r), (t2, dir[0] * r)], k))
            }
            _ => None,
        }
    }
}

/// Why the active set stopped without converging (the interior point then
/// takes over).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StopReason {
    /// Pyramidal cones have no pieces this method knows.
    PyramidalCones,
    /// The line search found no decrease of the natural residual.
    NoDescent { residual: f64 },
    /// Several solves in a row without a 10 % decrease.
    Stalled { residual: f64, solves: usize },
    /// A full step that changed no piece and did not converge.
    NoProgress {
        residual: f64,
        linear_solve_converged: bool,
    },
    /// The solve budget ran out.
    IterationLimit { solves: usize },
}

impl std::fmt::Display for StopReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            StopReason::PyramidalCones => {
                write!(f, "pyramidal cones are left to the interior-point solver")
            }
            StopReason::NoDescent { residual } => write!(
                f,
                "no descent of the natural residual ({residual:.1e}) along the Newton step"
            ),
            StopReason::Stalled { residual, solves } => write!(
                f,
                "the natural residual stalled at {residual:.1e} ({solves} solves without a 10 % decrease)"
            ),
            StopReason::NoProgress {
                residual,
                linear_solve_converged,
            } => write!(
                f,
                "no progress at fixed-point residual {residual:.1e} (linear solve converged: {linear_solve_converged})"
            ),
            StopReason::IterationLimit { solves } => {
                write!(f, "the active set did not settle in {solves} solves")
            }
        }
    }
}

/// Solves the friction-constrained least squares, starting from `start` (the
/// unconstrained answer, or any guess). `ls` is reused: its symbolic analysis is
/// kept across iterations. Returns `Ok` with `converged: false` (and the reason)
/// when the method does not settle; errors only on invalid input.
pub fn solve(
    ls: &mut EqualityLeastSquares,
    problem: &LeastSquares,
    cones: &[Cone],
    start: &[f64],
    settings: &ActiveSetSettings,
) -> Result<ActiveSetSolution> {
    solve_from(ls, problem, cones, start, None, settings)
}

/// As [`solve`], with the first solve on `warm`'s pieces (those of a nearby
/// problem's answer, e.g. the previous λ of a search) instead of the pieces
/// `start` suggests. Ignored when it has another number of contacts.
pub fn solve_from(
    ls: &mut EqualityLeastSquares,
    problem: &LeastSquares,
    cones: &[Cone],
    start: &[f64],
    warm: Option<&ActivePieces>,
    settings: &ActiveSetSettings,
) -> Result<ActiveSetSolution> {
    let a = problem.a;
    if settings.max_iterations == 0 || !(settings.tolerance > 0.0 && settings.tolerance < 1.0) {
        return Err(Error::Invalid(format!(
            "active set: need at least one solve and a tolerance in (0, 1), got {} and {}",
            settings.max_iterations, settings.tolerance
        )));
    }
    if start.len() != a.ncols {
        return Err(Error::Invalid(format!(
            "active set: the start has {} entries for {} unknowns",
            start.len(),
            a.ncols
        )));
    }
    let Some(contacts) = cones.iter().map(Contact::of).collect::<Option<Vec<_>>>() else {
        return Ok(fail(start.to_vec(), Vec::new(), StopReason::PyramidalCones));
    };
    let (diag, rho) = diagonal_and_rho(problem, &contacts);

    // Each solve only needs the accuracy at which convergence is declared.
    ls.set_refinement_target(CONVERGED_TOL);
    let warm = warm.filter(|w| w.0.len() == contacts.len());
    let initial = match warm {
        Some(w) => Some(w.0.clone()),
        None if settings.predict => predict::pieces(problem, &contacts, start, None, &diag, &rho),
        None => None,
    };
    // A nearby problem's pieces start close: after them the second guess
    // cost more sweeps than it saved (λ search, 2 197 spheres: 15 solves
    // instead of 20, 11.2–12.4 s against 9.2–11.0 s).
    let settings = &ActiveSetSettings {
        reguess: settings.reguess && warm.is_none(),
        ..*settings
    };
    let outcome = iterate(
        ls, problem, cones, &contacts, &diag, &rho, start, initial, settings,
    );
    ls.set_refinement_target(0.0);
    outcome
}

/// diag(AᵀA + λ²I), and each contact's ρ_c = RHO_FACTOR / (mean of that
/// diagonal over its unknowns): the step that turns a multiplier (a
/// gradient) into a force.
fn diagonal_and_rho(problem: &LeastSquares, contacts: &[Contact]) -> (Vec<f64>, Vec<f64>) {
    let LeastSquares { a, lambda, .. } = *problem;
    let mut diag = vec![lambda * lambda; a.ncols];
    for k in 0..a.nnz() {
        diag[a.cols[k]] += a.vals[k] * a.vals[k];
    }
    let rho = contacts
        .iter()
        .map(|ct| {
            let idx = std::iter::once(ct.normal).chain(ct.tangents.iter().copied());
            let h = idx.clone().map(|j| diag[j]).sum::<f64>() / idx.count() as f64;
            if h > 0.0 && h.is_finite() {
                RHO_FACTOR / h
            } else {
                1.0
            }
        })
        .collect();
    (diag, rho)
}

/// An unconverged outcome.
fn fail(x: Vec<f64>, history: Vec<ActiveSetStep>, reason: StopReason) -> ActiveSetSolution {
    ActiveSetSolution {
        pieces: ActivePieces::default(),
        x,
        converged: false,
        iterations: history.len(),
        sliding: 0,
        open: 0,
        residual: history.last().map_or(f64::INFINITY, |h| h.residual),
        reason: Some(reason),
        history,
    }
}

/// The damped semismooth Newton iteration of [`solve`].
#[allow(clippy::too_many_arguments)]
fn iterate(
    ls: &mut EqualityLeastSquares,
    problem: &LeastSquares,
    cones: &[Cone],
    contacts: &[Contact],
    diag: &[f64],
    rho: &[f64],
    start: &[f64],
    initial: Option<Vec<Piece>>,
    settings: &ActiveSetSettings,
) -> Result<ActiveSetSolution> {
    let LeastSquares { a, b, c, d, lambda } = *problem;
    let n = a.ncols;
    // The natural residual of each contact at (x, v): x_c − Π_K(x_c − ρ_c v_c),
    // and the piece that projection lands on.
    let natural = |x: &[f64], v: &[(f64, [f64; 2])], k: usize| -> (f64, Piece) {
        let ct = &contacts[k];
        ct.natural(ct.split(x), v[k], rho[k])
    };
    let merit = |x: &[f64], v: &[(f64, [f64; 2])]| -> f64 {
        (0..contacts.len())
            .map(|k| natural(x, v, k).0.powi(2))
            .sum()
    };

    let mut x = start.to_vec();
    let mut history = Vec::new();
    let (mut best_merit, mut stalled) = (f64::INFINITY, 0);
    let mut v = vec![(0.0, [0.0; 2]); contacts.len()];
    let mut pieces: Vec<Piece> = match initial {
        Some(p) => p,
        None => (0..contacts.len()).map(|k| natural(&x, &v, k).1).collect(),
    };
    for iteration in 1..=settings.max_iterations {
        let rows = ActiveRows::of(contacts, &pieces, rho, n);
        let (g, springs) = (&rows.g, &rows.springs);
        let clock = std::time::Instant::now();
        let sol = ls.solve_with_active(a, c, b, d, lambda, g, springs)?;
        history.push(ActiveSetStep {
            active_rows: g.nrows,
            step: 0.0,
            changed: 0,
            residual: f64::NAN,
            seconds: clock.elapsed().as_secs_f64(),
            reused_factor: sol.reused_factor,
        });
        let x_full = sol.solution.x;
        let v_full = rows.dual(contacts, &pieces, &sol.multipliers, &x_full);
        // Damped step: the full Newton step can overshoot far from the
        // solution; halve it until the natural residual decreases.
        let before = merit(&x, &v);
        let (step, x_new, v_new, after) = damped_step(&x, &v, x_full, v_full, before, &merit);
        if after > (1.0 - 1e-4 * step) * before {
            return Ok(fail(
                x,
                history,
                StopReason::NoDescent {
                    residual: before.sqrt(),
                },
            ));
        }
        x = x_new;
        v = v_new;
        if after < STALL_FACTOR * best_merit {
            best_merit = after;
            stalled = 0;
        } else {
            stalled += 1;
            if stalled >= MAX_STALLED {
                return Ok(fail(
                    x,
                    history,
                    StopReason::Stalled {
                        residual: after.sqrt(),
                        solves: MAX_STALLED,
                    },
                ));
            }
        }
        let scale = x
            .iter()
            .fold(0.0f64, |m, v| m.max(v.abs()))
            .max(f64::MIN_POSITIVE);
        let tol = settings.tolerance * scale;
        // The pieces of this solve, when a re-guess may replace the next ones.
        let reguess = iteration == 1 && settings.reguess;
        let solved_on = reguess.then(|| pieces.clone());
        let (worst, mut changed) =
            update_pieces(contacts.len(), &natural, &x, &v, tol, &mut pieces);
        // The first solve's cone forces are the first exact ones: the
        // sweeps around its answer place the contacts better than the
        // Newton step's projection, whose sliding directions turned too
        // far for the next factor to hold them (10⁴ spheres: 294 rows and
        // springs to border after it, past the 256 a border takes).
        if let Some(solved_on) = solved_on.filter(|_| worst > tol) {
            if let Some(guess) = predict::pieces(problem, contacts, &x, Some(&v), diag, rho) {
                changed = (guess.iter().zip(&solved_on))
                    .filter(|(next, last)| next != last)
                    .count();
                pieces = guess;
            }
        }
        let residual = worst / scale;
        if let Some(last) = history.last_mut() {
            (last.step, last.changed, last.residual) = (step, changed, residual);
        }
        if worst <= tol && step == 1.0 && sol.solution.converged {
            for cone in cones {
                cone.project(&mut x);
            }
            let sliding = pieces
                .iter()
                .filter(|p| matches!(p, Piece::Boundary { .. }))
                .count();
            let open = pieces.iter().filter(|p| **p == Piece::Apex).count();
            return Ok(ActiveSetSolution {
                pieces: ActivePieces(pieces),
                x,
                converged: true,
                iterations: iteration,
                sliding,
                open,
                residual,
                reason: None,
                history,
            });
        }
        if changed == 0 && step == 1.0 {
            return Ok(fail(
                x,
                history,
                StopReason::NoProgress {
                    residual,
                    linear_solve_converged: sol.solution.converged,
                },
            ));
        }
    }
    Ok(fail(
        x,
        history,
        StopReason::IterationLimit {
            solves: settings.max_iterations,
        },
    ))
}

/// A contact's dual force (normal, tangential).
type Dual = (f64, [f64; 2]);

/// The rows of the contacts' current pieces: equalities `g` (owned by
/// `owner[row]`) and the springs of sliding contacts (contact, stiffness).
struct ActiveRows {
    g: Triplets,
    springs: Triplets,
    owner: Vec<usize>,
    spring_of: Vec<(usize, f64)>,
}

impl ActiveRows {
    fn of(contacts: &[Contact], pieces: &[Piece], rho: &[f64], n: usize) -> Self {
        let mut g = Triplets::new(0, n);
        let mut springs = Triplets::new(0, n);
        let mut owner = Vec::new();
        let mut spring_of = Vec::new();
        for (k, (ct, piece)) in contacts.iter().zip(pieces).enumerate() {
            for row in ct.rows(*piece) {
                g.nrows += 1;
                for (j, val) in row {
                    g.push(g.nrows - 1, j, val);
                }
                owner.push(k);
            }
            if let Some((row, stiffness)) = ct.spring(*piece, rho[k]) {
                springs.nrows += 1;
                for (j, val) in row {
                    springs.push(springs.nrows - 1, j, val);
                }
                spring_of.push((k, stiffness));
            }
        }
        ActiveRows {
            g,
            springs,
            owner,
            spring_of,
        }
    }

    /// Each contact's dual force from the solve's multipliers.
    fn dual(
        &self,
        contacts: &[Contact],
        pieces: &[Piece],
        multipliers: &[f64],
        x_full: &[f64],
    ) -> Vec<Dual> {
        let (g, owner) = (&self.g, &self.owner);
        // v_c = Σ y_i a_i over the contact's rows.
        let mut v_full = vec![(0.0, [0.0; 2]); contacts.len()];
        for k in 0..g.nnz() {
            let (row, j, val) = (g.rows[k], g.cols[k], g.vals[k]);
            let ct = &contacts[owner[row]];
            let y = multipliers[row] * val;
            let vc = &mut v_full[owner[row]];
            if j == ct.normal {
                vc.0 += y;
            } else if let Some(p) = ct.tangents.iter().position(|&t| t == j) {
                vc.1[p] += y;
            }
        }
        // The springs' force, v = −k (e⊥·x) e⊥.
        for &(k, stiffness) in &self.spring_of {
            let Piece::Boundary { dir, .. } = pieces[k] else {
                continue;
            };
            let ct = &contacts[k];
            let (_, xt) = ct.split(x_full);
            let across = -dir[1] * xt[0] + dir[0] * xt[1];
            let force = -stiffness * across;
            v_full[k].1[0] += force * -dir[1];
            v_full[k].1[1] += force * dir[0];
        }
        v_full
    }
}

/// Halves the step from (x, v) towards the Newton point (x_full, v_full)
/// until the merit decreases enough (or the step is below [`MIN_STEP`]). Both
/// ends satisfy the (linear) stationarity and momentum rows, so every point
/// between them does too. Returns the step, the point and its merit.
fn damped_step(
    x: &[f64],
    v: &[Dual],
    x_full: Vec<f64>,
    v_full: Vec<Dual>,
    before: f64,
    merit: &impl Fn(&[f64], &[Dual]) -> f64,
) -> (f64, Vec<f64>, Vec<Dual>, f64) {
    let mut step = 1.0;
    let (mut x_new, mut v_new) = (x_full.clone(), v_full.clone());
    let mut after = merit(&x_new, &v_new);
    while after > (1.0 - 1e-4 * step) * before && step > MIN_STEP {
        step *= 0.5;
        x_new = x
            .iter()
            .zip(&x_full)
            .map(|(a, b)| a + step * (b - a))
            .collect();
        v_new = v
            .iter()
            .zip(&v_full)
            .map(|(a, b)| {
                (
                    a.0 + step * (b.0 - a.0),
                    [
                        a.1[0] + step * (b.1[0] - a.1[0]),
                        a.1[1] + step * (b.1[1] - a.1[1]),
                    ],
                )
            })
            .collect();
        after = merit(&x_new, &v_new);
    }
    (step, x_new, v_new, after)
}

/// Moves each contact whose natural residual exceeds `tol` to the piece its
/// projection lands on; returns the worst residual and how many changed.
fn update_pieces(
    count: usize,
    natural: &impl Fn(&[f64], &[Dual], usize) -> (f64, Piece),
    x: &[f64],
    v: &[Dual],
    tol: f64,
    pieces: &mut [Piece],
) -> (f64, usize) {
    let mut worst = 0.0f64;
    let mut changed = 0;
    for k in 0..count {
        let (e, piece) = natural(x, v, k);
        worst = worst.max(e);
        if e > tol {
            if piece != pieces[k] {
                changed += 1;
            }
            pieces[k] = piece;
        } else if let (Piece::Boundary { .. }, Piece::Boundary { .. }) = (piece, pieces[k]) {
            // A sliding contact within tolerance still follows its
            // sliding direction: kept at an older one, such contacts
            // held the residual just below the tolerance (3D, 30 %
            // sliding: 1e-10 at the end instead of 2e-13), and the last
            // step was no longer Newton's.
            pieces[k] = piece;
        }
    }
    (worst, changed)
}
