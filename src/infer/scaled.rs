//! `scaled`: min ‖K_st f − s b_st‖² + ω‖W f − F_walls‖² over f and a global
//! stress scale s — the measured wall forces pin down a global bias of the
//! stresses (e.g. a wrong Young's modulus). One system for the whole scene.

use super::context::{cones, Context};
use super::InferenceReport;
use crate::error::{Error, Result};
use crate::solver::cascade;
use crate::solver::{Cone, ConicProblem, Term, Triplets};

/// One system; unknowns [x, s].
pub(crate) fn solve(cx: &Context, report: &mut InferenceReport) -> Result<(Vec<f64>, f64)> {
    let (scene, assembly, opts) = (cx.scene, cx.assembly, cx.opts);
    let Some(system) = assembly.systems.first() else {
        return Err(Error::Invalid(
            "no contacts carry load: nothing to infer".into(),
        ));
    };
    let n = system.n;
    // Stress term K x − s b = 0 with s the (n+1)-th unknown.
    let mut stress = Triplets::new(system.stress.nrows, n + 1);
    for k in 0..system.stress.nnz() {
        stress.push(
            system.stress.rows[k],
            system.stress.cols[k],
            system.stress.vals[k],
        );
    }
    for (i, &b) in system.stress_rhs.iter().enumerate() {
        stress.push(i, n, -b);
    }
    let zeros = vec![0.0; system.stress.nrows];
    let dim = scene.dim;
    let mut walls = Triplets::new(0, n + 1);
    let mut wall_rhs = Vec::new();
    for w in &system.walls {
        let Some(measured) = scene.walls[w.wall].measured_force else {
            continue;
        };
        let base = walls.nrows;
        walls.nrows += dim;
        for k in 0..w.rows.nnz() {
            walls.push(base + w.rows.rows[k], w.rows.cols[k], w.rows.vals[k]);
        }
        wall_rhs.extend(measured[..dim].iter().map(|f| f / assembly.scales.force));
    }
    if wall_rhs.is_empty() {
        return Err(Error::Invalid(
            "`method` = scaled needs measured wall forces (walls.csv) for walls that touch the grains".into(),
        ));
    }
    let momentum = widen(&system.momentum, n + 1);
    let mut cone_list = cones(system, opts.cone);
    cone_list.push(Cone::NonNegative { normal: n });
    let problem = ConicProblem {
        n: n + 1,
        terms: vec![
            Term {
                matrix: &stress,
                rhs: &zeros,
                weight: 1.0,
            },
            Term {
                matrix: &walls,
                rhs: &wall_rhs,
                weight: opts.wall_weight,
            },
        ],
        equalities: vec![(&momentum, system.momentum_rhs.as_slice())],
        lambda: 0.0,
        regularized: 0,
        cones: cone_list,
    };
    let sol = cascade::solve(&problem, None, &opts.cascade())?.solution;
    report.absorb(&sol);
    let s = sol.x[n];
    if s <= 0.0 {
        return Err(Error::Invalid(
            "the wall forces and the stresses disagree in sign (estimated stress scale ≤ 0)".into(),
        ));
    }
    Ok((sol.x[..n].to_vec(), s))
}

fn widen(m: &Triplets, ncols: usize) -> Triplets {
    let mut w = m.clone();
    w.ncols = ncols;
    w
}
