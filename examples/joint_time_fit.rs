//! Prototype: momentum fitted over time instead of frame by frame. Unknowns
//! are every frame's contact forces plus each grain's position and velocity
//! per frame, tied by the integrator (hard rows); the objective weighs the
//! stress rows of every frame and the raw tracks (positions, not derived
//! accelerations); torque rows Σ r × f = Iα are hard. No friction. Prints
//! relerr and the impulse check on the twelve `impact` draws of
//! `impulse_draws`, to decide whether the product should do this.
//!
//!     cargo run --release --example joint_time_fit [STRESS_SD]
//!
//! Measured (stress sd 0.1 / 0.01 / 0.001): the impulse check holds for all
//! 60 moving grain-draws (worst 1.0 % / 2.2 % / 3.6 % against the measured
//! Δv), but the forces chase the position noise (nothing smooths them in
//! time): relerr 0.61–0.79 / 0.28–0.41 / 0.15–0.28, against 0.030–0.035
//! frame by frame. The missing piece is a prior in time (roughness of each
//! contact's force across frames, or the filtered accelerations kept as
//! momentum rows beside per-grain impulse rows).

#[path = "support/impact_draws.rs"]
mod impact_draws;

use grainforce::scene::{Body, Scene, Vec3};
use grainforce::solver::sparse_ls::EqualityLeastSquares;
use grainforce::solver::Triplets;
use impact_draws::{ImpactDraws, FPS};

fn main() -> grainforce::Result<()> {
    let stress_sd: f64 = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(0.1);
    let draws = ImpactDraws::new()?;
    let sigma_x = draws.position_noise;
    let tally = draws.tally(|noisy| {
        let forces = joint_fit(&noisy, 1.0 / FPS, sigma_x, stress_sd)?;
        Ok((noisy, forces))
    })?;
    tally.print(&format!("joint fit, stress sd {stress_sd}"));
    Ok(())
}

/// Appends one row Σ v·x[col] = rhs to (t, rhs).
fn push_row(t: &mut Triplets, rhs: &mut Vec<f64>, entries: &[(usize, f64)], value: f64) {
    t.nrows += 1;
    for &(col, v) in entries {
        t.push(t.nrows - 1, col, v);
    }
    rhs.push(value);
}

/// Contacts touching grain `p` of `frame`: (index, sign of the force on p, arm r).
fn arms(frame: &Scene, p: usize) -> impl Iterator<Item = (usize, f64, [f64; 2])> + '_ {
    let x = frame.grains[p].position;
    frame
        .contacts
        .iter()
        .enumerate()
        .filter_map(move |(i, ct)| {
            let sign = if ct.a == p {
                1.0
            } else if ct.b == Body::Grain(p) {
                -1.0
            } else {
                return None;
            };
            Some((i, sign, [ct.point[0] - x[0], ct.point[1] - x[1]]))
        })
}

/// Least squares over all frames at once (2D, all grains tracked in every frame).
fn joint_fit(
    frames: &[Scene],
    dt: f64,
    sigma_x: f64,
    stress_sd: f64,
) -> grainforce::Result<Vec<Vec<Option<Vec3>>>> {
    let nf = frames.len();
    let ng = frames[0].grains.len();
    // Force and length units.
    let (f0, l0) = (100.0, 1e-4);
    // Columns: forces (2 per contact per frame), then per grain per frame x(2), v·dt(2).
    let mut force_col = Vec::new();
    let mut ncols = 0;
    for f in frames {
        force_col.push(ncols);
        ncols += 2 * f.contacts.len();
    }
    let kin0 = ncols;
    let kin = |p: usize, k: usize| kin0 + 4 * (p * nf + k);
    ncols += 4 * ng * nf;
    let (mut a, mut b) = (Triplets::new(0, ncols), Vec::new());
    let (mut c, mut d) = (Triplets::new(0, ncols), Vec::new());
    let g = frames[0].gravity();
    let origin: Vec<Vec3> = frames[0].grains.iter().map(|g| g.position).collect();
    let stress_scale = |frame: &Scene| {
        let sum: f64 = frame
            .grains
            .iter()
            .map(|g| {
                let s = g.stress;
                (g.volume * g.volume) * (s[0] * s[0] + s[1] * s[1] + 2.0 * s[3] * s[3])
            })
            .sum();
        (sum / ng as f64).sqrt()
    };
    let largest = frames.iter().map(stress_scale).fold(0.0, f64::max);
    for (k, frame) in frames.iter().enumerate() {
        // Stress rows, weighted by the frame's stress scale (floored: a frame
        // of zero stress is not exact).
        let w = 1.0 / (stress_sd * stress_scale(frame).max(1e-3 * largest));
        for (p, grain) in frame.grains.iter().enumerate() {
            let mut rows: [Vec<(usize, f64)>; 3] = Default::default();
            // Torque (hard): Σ r × f = Iα, as the frame-by-frame inference has.
            let mut torque = Vec::new();
            let size = 2.0 * grain.radius.unwrap_or(1.0);
            for (i, sign, r) in arms(frame, p) {
                let (cx, cy) = (force_col[k] + 2 * i, force_col[k] + 2 * i + 1);
                let v = sign * w * f0;
                rows[0].push((cx, v * r[0]));
                rows[1].push((cy, v * r[1]));
                rows[2].extend([(cx, 0.5 * v * r[1]), (cy, 0.5 * v * r[0])]);
                torque.extend([
                    (cy, sign * r[0] * f0 / size),
                    (cx, -sign * r[1] * f0 / size),
                ]);
            }
            for (row, s) in rows.iter().zip([0, 1, 3]) {
                push_row(&mut a, &mut b, row, w * grain.volume * grain.stress[s]);
            }
            let i_alpha = match (&grain.inertia, grain.angular_acceleration) {
                (Some(grainforce::scene::Inertia::Scalar(i)), Some(al)) => i * al[2],
                _ => 0.0,
            };
            push_row(&mut c, &mut d, &torque, i_alpha / size);
            // Track rows: measured positions.
            for axis in 0..2 {
                let value = (grain.position[axis] - origin[p][axis]) / sigma_x;
                push_row(&mut a, &mut b, &[(kin(p, k) + axis, l0 / sigma_x)], value);
            }
        }
    }
    // Integrator: x' = x + v dt + dt²(a0/3 + a1/6), v' = v + dt(a0 + a1)/2, a = N/m + g.
    for p in 0..ng {
        let Some(m) = frames[0].grains[p].mass else {
            return Err(grainforce::Error::Invalid(format!(
                "grain {} has no mass",
                frames[0].grains[p].id
            )));
        };
        // Net force on p in frame k, per axis: (column, ±1).
        let net = |k: usize, axis: usize| -> Vec<(usize, f64)> {
            arms(&frames[k], p)
                .map(|(i, sign, _)| (force_col[k] + 2 * i + axis, sign))
                .collect()
        };
        let h = dt * dt * f0 / m;
        for k in 0..nf - 1 {
            for axis in 0..2 {
                let (now, next) = (net(k, axis), net(k + 1, axis));
                let mut x_row = vec![
                    (kin(p, k + 1) + axis, l0),
                    (kin(p, k) + axis, -l0),
                    (kin(p, k) + 2 + axis, -l0),
                ];
                x_row.extend(now.iter().map(|&(col, s)| (col, -h * s / 3.0)));
                x_row.extend(next.iter().map(|&(col, s)| (col, -h * s / 6.0)));
                push_row(&mut c, &mut d, &x_row, dt * dt * g[axis] * 0.5);
                let mut v_row = vec![(kin(p, k + 1) + 2 + axis, l0), (kin(p, k) + 2 + axis, -l0)];
                v_row.extend(now.iter().chain(&next).map(|&(col, s)| (col, -0.5 * h * s)));
                push_row(&mut c, &mut d, &v_row, dt * dt * g[axis]);
            }
        }
    }
    let mut ls = EqualityLeastSquares::new(&a, &c)?;
    let sol = ls.solve(&a, &c, &b, &d, 0.0)?;
    if !sol.converged {
        return Err(grainforce::Error::Solver(format!(
            "joint fit did not converge (KKT residual {:e})",
            sol.kkt_residual
        )));
    }
    Ok(frames
        .iter()
        .enumerate()
        .map(|(k, f)| {
            (0..f.contacts.len())
                .map(|i| {
                    let col = force_col[k] + 2 * i;
                    Some([f0 * sol.x[col], f0 * sol.x[col + 1], 0.0])
                })
                .collect()
        })
        .collect())
}
