//! One solve on a factor (or a border around it) and iterative refinement
//! against the unregularised KKT system.

use super::active_rows::{ActiveRows, Changes};
use super::border::{border_columns, BorderColumn, Bordered, BORDER_MAX_ROWS};
use super::compressed::{abs_mul_scaled, abs_mul_t_scaled, mul_scaled, mul_t_scaled};
use super::krylov;
use super::numeric::{thread_count, Numeric};
use super::{
    Bordering, EqualityLeastSquares, ADD_FACTOR, CONVERGED_TOL, MAX_REFINEMENT_STEPS, STALL_STEPS,
};
use crate::solver::Triplets;
use crate::{Error, Result};

/// Outcome of one factorisation + refinement.
pub(super) struct Attempt {
    pub(super) x: Vec<f64>,
    pub(super) equality_multipliers: Vec<f64>,
    pub(super) multipliers: Vec<f64>,
    pub(super) dual: f64,
    pub(super) primal: f64,
    pub(super) steps: usize,
    pub(super) reused_factor: bool,
}

impl Attempt {
    pub(super) fn rho(&self) -> f64 {
        self.dual.max(self.primal)
    }
}

/// Krylov steps between two checks of the true KKT residual on a stale factor.
const KRYLOV_RESTART: usize = 30;
/// Largest reduction of the residual (2-norm) one restart aims for.
const KRYLOV_TOL: f64 = 1e-8;
/// Solves that GMRES on a factor holding stale rows is expected to cost:
/// 5–15 steps measured on 3D packings of 2·10³–10⁵ spheres, 30 % sliding.
/// At 2·10³ a factorisation costs ~12 solves, so reuse there is a wash
/// (0.13–0.19 s against 0.14–0.22 s a solve); from 10⁴ on it is a gain.
const STALE_SOLVES: f64 = 8.0;
/// A factor of the same A, C and δ at a λ at most this many decades away
/// preconditions GMRES on the system at λ (no active rows): the λ scan's
/// close steps. Preconditioned, the system differs from the identity by at
/// most (λ² − λ₀²)/λ₀², 0.26 at 0.05 decades.
const NEARBY_LAMBDA_DECADES: f64 = 0.05;
/// Solves that GMRES on a factor of a nearby λ is expected to cost.
const NEARBY_LAMBDA_SOLVES: f64 = 12.0;

impl EqualityLeastSquares {
    /// One factorisation with static regularisation δ (or a border of the
    /// kept one, or the kept one holding stale rows), first solve,
    /// refinement. A border or stale factor that does not refine to
    /// [`CONVERGED_TOL`] is replaced by a factorisation: taking a row or a
    /// spring out cancels its penalty, which could cost the accuracy
    /// refinement needs, and stale rows may be too far off.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn attempt(
        &mut self,
        a: &Triplets,
        c: &Triplets,
        b: &[f64],
        d: &[f64],
        lambda: f64,
        delta: f64,
        g: &Triplets,
        springs: &Triplets,
    ) -> Result<Attempt> {
        match self.attempt_on(a, c, b, d, lambda, delta, g, springs, true) {
            Ok(att) if !att.reused_factor || att.rho() <= CONVERGED_TOL => Ok(att),
            Ok(_) | Err(Error::Solver(_)) => {
                self.attempt_on(a, c, b, d, lambda, delta, g, springs, false)
            }
            Err(e) => Err(e),
        }
    }

    /// [`attempt`](Self::attempt), bordering the changed rows only when
    /// `may_border`.
    #[allow(clippy::too_many_arguments)]
    fn attempt_on(
        &mut self,
        a: &Triplets,
        c: &Triplets,
        b: &[f64],
        d: &[f64],
        lambda: f64,
        delta: f64,
        g: &Triplets,
        springs: &Triplets,
        may_border: bool,
    ) -> Result<Attempt> {
        let n = self.n;
        let clock = std::time::Instant::now();
        let (changes, built, other_lambda) =
            self.reusable(a, c, lambda, delta, g, springs, may_border);
        let changes = match changes {
            Some(changes) => changes,
            None => {
                self.factorise(a, c, lambda, delta, g, springs)?;
                Changes::unchanged(g.nrows)
            }
        };
        let border = changes.count() > 0;
        let stale = changes.any_stale() || other_lambda;
        let previous = self.numeric.as_mut().and_then(|n| n.last_border.take());
        let num = self.numeric.as_ref().expect("factorised above");
        let factor = num.factor(
            self.symbolic
                .as_ref()
                .expect("non-empty KKT has a symbolic factor"),
        );
        let size = factor.rows();
        let mg = num.active.len();
        let bordered = if border {
            let columns = built.unwrap_or_else(|| border_columns(num, &changes, delta));
            Some(Bordered::new(columns, &factor, previous.as_ref())?)
        } else {
            None
        };
        let kept: Vec<f64> = changes
            .kept
            .iter()
            .map(|&k| if k { 1.0 } else { 0.0 })
            .collect();
        let any_kept = changes.kept.iter().any(|&k| k);
        // The rows as the factor holds them (stale ones with their old
        // entries), so that the solve below inverts the factored matrix exactly.
        let held = (!changes.stale.is_empty()).then(|| {
            let (mut csr, mut scale) = (num.active.csr.clone(), num.active.row_scale.clone());
            for &(i, j) in &changes.stale {
                let (from, to) = (num.in_factor.csr.range(j), csr.range(i));
                csr.val[to].copy_from_slice(&num.in_factor.csr.val[from]);
                scale[i] = num.in_factor.row_scale[j];
            }
            (csr, scale)
        });
        let (held_rows, held_scale) = match &held {
            Some((csr, scale)) => (csr, scale.as_slice()),
            None => (&num.active.csr, num.active.row_scale.as_slice()),
        };
        let mut border_rhs = vec![0.0; changes.count()];
        // Solves the regularised augmented system in place: the active rows
        // the factor holds are eliminated through their penalty, the others
        // bordered around it, between the two halves of the factor's solve.
        let mut kkt_solve = |rhs: &mut [f64]| {
            let (head, r3) = rhs.split_at_mut(size);
            if any_kept {
                let shifted: Vec<f64> = (r3.iter().zip(held_scale))
                    .map(|(r, t)| r * t / delta)
                    .collect();
                let lift = mul_t_scaled(held_rows, &kept, &num.base.col_scale, &shifted, n);
                for (h, l) in head.iter_mut().zip(&lift) {
                    *h += l;
                }
            }
            factor.solve_with(head, |v| {
                if let Some(bordered) = &bordered {
                    for (slot, &i) in border_rhs.iter_mut().zip(&changes.added) {
                        *slot = r3[i];
                    }
                    let t = bordered.correct(&factor, v, &border_rhs);
                    for (&i, ti) in changes.added.iter().zip(t.iter()) {
                        r3[i] = *ti;
                    }
                }
            });
            if any_kept {
                let gy = mul_scaled(held_rows, held_scale, &num.base.col_scale, &head[..n]);
                for ((r, gyi), &k) in r3.iter_mut().zip(&gy).zip(&changes.kept) {
                    if k {
                        *r = (gyi - *r) / delta;
                    }
                }
            }
        };

        // λ² s², in the factor's scaling, of the system solved.
        let lambda2_s2: std::borrow::Cow<[f64]> = if other_lambda {
            (num.base.col_scale.iter())
                .map(|s| lambda * lambda * s * s)
                .collect()
        } else {
            std::borrow::Cow::Borrowed(&num.base.lambda2_s2)
        };
        let ones_a = vec![1.0; a.nrows];
        let d_hat: Vec<f64> = d
            .iter()
            .zip(&num.base.c_row_scale)
            .map(|(v, t)| v * t)
            .collect();
        // The right-hand side (the residual at z = 0): (S Aᵀb, T d, 0).
        let mut z = mul_t_scaled(&self.a_csr, &ones_a, &num.base.col_scale, b, n);
        z.extend_from_slice(&d_hat);
        z.resize(size + mg, 0.0);
        kkt_solve(&mut z);
        let (r, dual, primal) = self.kkt_residual(num, &lambda2_s2, &ones_a, b, &d_hat, &z);
        if !(dual.is_finite() && primal.is_finite()) {
            return Err(Error::Solver(
                "the first KKT solve produced non-finite values (factor growth; the data are too badly scaled \
                 for the normal-equations KKT)"
                    .into(),
            ));
        }
        let residual = |z: &[f64]| self.kkt_residual(num, &lambda2_s2, &ones_a, b, &d_hat, z);
        let first = (r, dual, primal);
        let stale_solves = stale.then_some(num.factor_solves);
        let (best, steps) = self.refine(z, first, stale_solves, &mut kkt_solve, &residual);
        if super::profiling() {
            eprintln!(
                "ls-profile attempt δ {delta:e} {:.4} s, {steps} refinement steps to {:.1e}",
                clock.elapsed().as_secs_f64(),
                best.0
            );
        }
        let (x, equality_multipliers, multipliers) = unscale(&best.3, num, n, size)?;
        if let Some(num) = self.numeric.as_mut() {
            num.last_border = bordered.or(previous);
        }
        Ok(Attempt {
            x,
            equality_multipliers,
            multipliers,
            dual: best.1,
            primal: best.2,
            steps,
            reused_factor: border || stale,
        })
    }

    /// Iterative refinement from z (its residual `first`): `kkt_solve`
    /// steps, or on a stale factor (`stale_solves`: what factorising costs,
    /// in solves) GMRES preconditioned by it, until the relative KKT
    /// residual meets the target or stalls. Returns the best point
    /// (residual, dual, primal, z) and the steps.
    #[allow(clippy::type_complexity)]
    fn refine(
        &self,
        mut z: Vec<f64>,
        first: (Vec<f64>, f64, f64),
        stale_solves: Option<f64>,
        kkt_solve: &mut impl FnMut(&mut [f64]),
        residual: &impl Fn(&[f64]) -> (Vec<f64>, f64, f64),
    ) -> ((f64, f64, f64, Vec<f64>), usize) {
        let stale = stale_solves.is_some();
        // On a stale factor, refinement is GMRES preconditioned by the
        // factor; stop it before it costs more than the factorisation it saves.
        // (`Always` runs it to the end.)
        let max_steps = if stale && self.bordering == Bordering::Auto {
            (stale_solves.unwrap_or_default() as usize).clamp(4, MAX_REFINEMENT_STEPS)
        } else {
            MAX_REFINEMENT_STEPS
        };
        let (mut r, mut dual, mut primal) = first;
        let mut best = (dual.max(primal), dual, primal, z.clone());
        let mut steps = 0;
        let mut stalled = 0;
        // K v = r(0) − r(v), for the Krylov steps on a stale factor.
        let at_zero = stale.then(|| residual(&vec![0.0; z.len()]).0);
        while steps < max_steps && best.0 > self.refine_to && stalled < STALL_STEPS {
            match &at_zero {
                Some(r0) => {
                    let mut apply = |v: &[f64]| {
                        let rv = residual(v).0;
                        r0.iter().zip(&rv).map(|(a, b)| a - b).collect()
                    };
                    let budget = (max_steps - steps).min(KRYLOV_RESTART);
                    // Only the reduction still needed (with a margin): the
                    // relative KKT residual is not GMRES's 2-norm.
                    let aim = (0.1 * self.refine_to / best.0).clamp(KRYLOV_TOL, 0.5);
                    steps += krylov::gmres(&mut r, budget, aim, kkt_solve, &mut apply).max(1);
                }
                None => {
                    kkt_solve(&mut r);
                    steps += 1;
                }
            }
            for (zi, ri) in z.iter_mut().zip(&r) {
                *zi += ri;
            }
            (r, dual, primal) = residual(&z);
            let rho = dual.max(primal);
            if !rho.is_finite() {
                break;
            }
            stalled = if rho < 0.9 * best.0 { 0 } else { stalled + 1 };
            if rho < best.0 {
                best = (rho, dual, primal, z.clone());
            }
        }
        (best, steps)
    }

    /// Whether the factor in hand serves these rows: on a factor of the same
    /// A, C, λ and δ, the rows that changed (bordered around it), or a nearby
    /// λ (GMRES on the exact system). Returns the changes (`None`: factorise
    /// anew), the border's columns when the choice built them, and whether
    /// the factor holds another λ.
    #[allow(clippy::too_many_arguments, clippy::type_complexity)]
    fn reusable(
        &mut self,
        a: &Triplets,
        c: &Triplets,
        lambda: f64,
        delta: f64,
        g: &Triplets,
        springs: &Triplets,
        may_border: bool,
    ) -> (Option<Changes>, Option<Vec<BorderColumn>>, bool) {
        let n = self.n;
        // On a factor of the same A, C, λ and δ, the rows that changed since
        // it was computed (rows added, rows it holds that are no longer
        // active) are bordered around it — one sparse forward solve each —
        // instead of a new numeric factorisation, when those solves are
        // modelled to cost less than it.
        let mut changes = None;
        // The border's columns, when the choice below already built them.
        let mut built = None;
        // The factor holds another, nearby λ: GMRES on the exact system.
        let mut other_lambda = false;
        if let (Some(num), Some(symbolic)) = (self.numeric.as_mut(), self.symbolic.as_ref()) {
            // Only to the converged tolerance: to round-off GMRES took as
            // many solves as the factorisation (10⁴ spheres: 30 steps).
            let cheap = self.refine_to >= CONVERGED_TOL;
            let bordering = self.bordering;
            if may_border && cheap && nearby_lambda(num, bordering, a, c, lambda, delta, g, springs)
            {
                other_lambda = true;
                changes = Some(Changes::unchanged(0));
            } else if num.same_values(a, c, lambda, delta) {
                if !num.active.same(g, springs) {
                    num.active = ActiveRows::new(n, g, springs, &num.base.col_scale);
                }
                let diff = Changes::between(&num.in_factor, &num.active, &num.base.col_scale);
                let k = diff.count();
                // GMRES on a factor holding stale rows costs many solves.
                let gmres_solves = if diff.any_stale() { STALE_SOLVES } else { 0.0 };
                let reuse = match self.bordering {
                    Bordering::Never => k == 0 && !diff.any_stale(),
                    Bordering::Always => k <= BORDER_MAX_ROWS,
                    Bordering::Auto if k == 0 => gmres_solves < num.factor_solves,
                    Bordering::Auto if k > BORDER_MAX_ROWS => false,
                    Bordering::Auto => {
                        // Only the columns the last border did not solve cost solves.
                        let columns = border_columns(num, &diff, delta);
                        let factor = num.factor(symbolic);
                        let fresh = (columns.iter())
                            .filter(|col| !num.last_border.as_ref().is_some_and(|b| b.holds(col)))
                            .map(|(entries, _)| entries.as_slice());
                        let share = factor.reach_share(fresh)
                            + factor.schur_share(columns.iter().map(|(e, _)| e.as_slice()));
                        let solves = share / thread_count(self.par) as f64;
                        built = Some(columns);
                        solves + gmres_solves < num.factor_solves
                    }
                };
                // Without `may_border` (the retry after a border or stale
                // factor that did not refine) only the very same rows reuse it.
                if reuse && (may_border || (k == 0 && !diff.any_stale())) {
                    changes = Some(diff);
                }
            }
        }
        (changes, built, other_lambda)
    }

    /// Residual of the unregularised equilibrated KKT system at z = (y, μ, w), and
    /// the relative sizes of the dual (stationarity, normwise) and primal (C x = d
    /// and G x = 0, per row) parts.
    fn kkt_residual(
        &self,
        num: &Numeric,
        lambda2_s2: &[f64],
        ones_a: &[f64],
        b: &[f64],
        d_hat: &[f64],
        z: &[f64],
    ) -> (Vec<f64>, f64, f64) {
        let n = self.n;
        let mc = d_hat.len();
        let (y, rest) = z.split_at(n);
        let (mu, w) = rest.split_at(mc);
        let (s, t) = (&num.base.col_scale, &num.base.c_row_scale);
        let (g_csr, tg) = (&num.active.csr, &num.active.row_scale);
        let ay = mul_scaled(&self.a_csr, ones_a, s, y);
        let ra: Vec<f64> = b.iter().zip(&ay).map(|(bi, ai)| bi - ai).collect();
        let atr = mul_t_scaled(&self.a_csr, ones_a, s, &ra, n);
        let ctmu = mul_t_scaled(&self.c_csr, t, s, mu, n);
        let gtw = mul_t_scaled(g_csr, tg, s, w, n);
        let springs = &num.active.springs;
        let ones_r = vec![1.0; springs.nmajor];
        let ry = mul_scaled(springs, &ones_r, s, y);
        let rtry = mul_t_scaled(springs, &ones_r, s, &ry, n);
        let rtry_bound = abs_mul_t_scaled(
            springs,
            &ones_r,
            s,
            &abs_mul_scaled(springs, &ones_r, s, y),
            n,
        );
        let cy = mul_scaled(&self.c_csr, t, s, y);
        let gy = mul_scaled(g_csr, tg, s, y);

        let abs_ay = abs_mul_scaled(&self.a_csr, ones_a, s, y);
        let b_bound: Vec<f64> = b
            .iter()
            .zip(&abs_ay)
            .map(|(bi, ai)| bi.abs() + ai)
            .collect();
        let dual_bound = abs_mul_t_scaled(&self.a_csr, ones_a, s, &b_bound, n);
        let ctmu_bound = abs_mul_t_scaled(&self.c_csr, t, s, mu, n);
        let gtw_bound = abs_mul_t_scaled(g_csr, tg, s, w, n);
        let primal_bound = abs_mul_scaled(&self.c_csr, t, s, y);
        let g_bound = abs_mul_scaled(g_csr, tg, s, y);

        let mut r = Vec::with_capacity(z.len());
        let (mut dual_num, mut dual_den) = (0.0f64, 0.0f64);
        for j in 0..n {
            let reg = lambda2_s2[j] * y[j];
            let g = atr[j] - reg - ctmu[j] - gtw[j] - rtry[j];
            dual_num = dual_num.max(g.abs());
            dual_den = dual_den
                .max(dual_bound[j] + reg.abs() + ctmu_bound[j] + gtw_bound[j] + rtry_bound[j]);
            r.push(g);
        }
        // Constraints are checked row by row (componentwise): each equation must
        // hold to round-off relative to its own terms. A row whose terms are
        // themselves round-off of the solution (d_i = 0 and C_i y ≈ 0, e.g. one
        // entry pinning y_j = 0) cannot do better than |y_j| ~ u‖y‖, and the pure
        // componentwise ratio would then read 1 forever; such rows are measured
        // against ‖C_i‖∞‖y‖∞ as well (Arioli, Demmel & Duff, SIMAX 1989).
        let ratio = |num: f64, den: f64| {
            if num == 0.0 {
                0.0
            } else {
                (num / den).min(1.0)
            }
        };
        let y_max = y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let roundoff_level = ADD_FACTOR * z.len() as f64 * f64::EPSILON;
        let mut primal = 0.0f64;
        let mut row_check = |rc: f64, own: f64, rhs: f64, row_max: f64| {
            let own_terms = own + rhs.abs();
            let normwise = row_max * y_max;
            let den = if own_terms > roundoff_level * (normwise + rhs.abs()) {
                own_terms
            } else {
                own_terms + normwise
            };
            primal = primal.max(ratio(rc.abs(), den));
        };
        for i in 0..mc {
            let rc = d_hat[i] - cy[i];
            row_check(rc, primal_bound[i], d_hat[i], num.base.c_row_max[i]);
            r.push(rc);
        }
        for i in 0..gy.len() {
            row_check(gy[i], g_bound[i], 0.0, num.active.row_max[i]);
            r.push(-gy[i]);
        }
        (r, ratio(dual_num, dual_den), primal)
    }
}

/// Whether the kept factor, of the same A, C and δ at another λ within
/// [`NEARBY_LAMBDA_DECADES`] and holding no active rows, serves as the
/// preconditioner of a solve without active rows at `lambda` (3–7 GMRES
/// steps to [`CONVERGED_TOL`] on the λ scans measured).
#[allow(clippy::too_many_arguments)]
fn nearby_lambda(
    num: &Numeric,
    bordering: Bordering,
    a: &Triplets,
    c: &Triplets,
    lambda: f64,
    delta: f64,
    g: &Triplets,
    springs: &Triplets,
) -> bool {
    let base = &num.base;
    let close = base.lambda > 0.0
        && lambda > 0.0
        && base.lambda != lambda
        && (lambda / base.lambda).log10().abs() <= NEARBY_LAMBDA_DECADES;
    let worth = match bordering {
        Bordering::Never => false,
        Bordering::Always => true,
        Bordering::Auto => NEARBY_LAMBDA_SOLVES < num.factor_solves,
    };
    close
        && worth
        && g.nrows == 0
        && springs.nrows == 0
        && num.in_factor.len() == 0
        && num.in_factor.springs.nmajor == 0
        && base.delta == delta
        && base.a_vals == a.vals
        && base.c_vals == c.vals
}

/// The answer and the multipliers in the problem's units from the refined
/// z = (y, μ, w) of the equilibrated system.
fn unscale(
    z: &[f64],
    num: &Numeric,
    n: usize,
    size: usize,
) -> Result<(Vec<f64>, Vec<f64>, Vec<f64>)> {
    let x: Vec<f64> = z[..n]
        .iter()
        .zip(&num.base.col_scale)
        .map(|(y, s)| y * s)
        .collect();
    if x.iter().any(|v| !v.is_finite()) {
        return Err(Error::Solver(
            "the solution overflows after unscaling".into(),
        ));
    }
    // The refined system reads (AᵀA + λ²)x + … + Gᵀ(T w) = Aᵀb, so the
    // multiplier of G x ≥ 0 in ∇ = Cᵀν + Gᵀy is y = −T w.
    let equality_multipliers = z[n..size]
        .iter()
        .zip(&num.base.c_row_scale)
        .map(|(m, t)| -m * t)
        .collect();
    let multipliers = z[size..]
        .iter()
        .zip(&num.active.row_scale)
        .map(|(w, t)| -w * t)
        .collect();
    Ok((x, equality_multipliers, multipliers))
}

#[cfg(test)]
mod tests {
    use super::super::{Bordering, EqualityLeastSquares, CONVERGED_TOL};
    use crate::solver::Triplets;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A random overdetermined A (90 × 60) with 10 equality rows.
    fn problem() -> (Triplets, Triplets, Vec<f64>, Vec<f64>) {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let (n, m, mc) = (60, 90, 10);
        let mut a = Triplets::new(m, n);
        for i in 0..m {
            for _ in 0..5 {
                a.push(i, rng.gen_range(0..n), rng.gen_range(-1.0..1.0));
            }
        }
        let mut c = Triplets::new(mc, n);
        for i in 0..mc {
            for j in 0..4 {
                c.push(i, (6 * i + j) % n, rng.gen_range(0.5..1.5));
            }
        }
        let b = (0..m).map(|_| rng.gen_range(-1.0..1.0)).collect();
        let d = (0..mc).map(|_| rng.gen_range(-1.0..1.0)).collect();
        (a, c, b, d)
    }

    fn relative_gap(x: &[f64], y: &[f64]) -> f64 {
        let diff = x.iter().zip(y).map(|(a, b)| (a - b).powi(2)).sum::<f64>();
        (diff / y.iter().map(|v| v * v).sum::<f64>()).sqrt()
    }

    /// A factor of a λ 0.03 decades away preconditions GMRES to the answer
    /// a new factorisation gives; one 0.2 decades away, a solve to
    /// round-off, or `Bordering::Never` factorise anew.
    #[test]
    fn a_factor_of_a_nearby_lambda_preconditions_the_solve() {
        let (a, c, b, d) = problem();
        let none = Triplets::new(0, a.ncols);
        let (lambda0, near, far) = (0.3, 0.3 * 10f64.powf(0.03), 0.3 * 10f64.powf(0.2));
        let exact = |lambda: f64| {
            let mut ls = EqualityLeastSquares::new(&a, &c).unwrap();
            ls.solve(&a, &c, &b, &d, lambda).unwrap().x
        };
        let solve_after = |lambda: f64, bordering: Bordering, target: f64| {
            let mut ls = EqualityLeastSquares::new(&a, &c).unwrap();
            ls.set_bordering(bordering);
            ls.set_refinement_target(target);
            ls.solve(&a, &c, &b, &d, lambda0).unwrap();
            ls.solve_with_active(&a, &c, &b, &d, lambda, &none, &none)
                .unwrap()
        };
        let reused = solve_after(near, Bordering::Always, CONVERGED_TOL);
        assert!(reused.reused_factor && reused.solution.converged);
        let gap = relative_gap(&reused.solution.x, &exact(near));
        assert!(gap < 1e-9, "{gap:.2e} from a new factorisation's answer");
        assert!(relative_gap(&exact(near), &exact(lambda0)) > 1e-4);

        for (lambda, bordering, target) in [
            (far, Bordering::Always, CONVERGED_TOL),
            (near, Bordering::Never, CONVERGED_TOL),
            (near, Bordering::Always, 0.0),
        ] {
            let sol = solve_after(lambda, bordering, target);
            assert!(!sol.reused_factor, "{lambda} {bordering:?} {target}");
            assert!(relative_gap(&sol.solution.x, &exact(lambda)) < 1e-9);
        }
    }
}
