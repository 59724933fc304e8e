//! The twelve position-noise draws on `impact` (0.1 % of a diameter) that the
//! dynamic examples compare pipelines on: relerr of the forces and the impulse
//! check of the moving grains, against the measured Δv and the noise-free one.

use grainforce::dem::perturb::{perturb, PerturbConfig};
use grainforce::dem::{simulate, DemConfig, DemRun, Preset};
use grainforce::infer::kinematics::{impulse_check, ImpulseCheck, ImpulseOptions};
use grainforce::report::metrics::relative_error;
use grainforce::scene::{Scene, Vec3};

pub const DRAWS: u64 = 12;

pub struct ImpactDraws {
    pub run: DemRun,
    pub fps: f64,
    /// Position noise of every draw [m].
    pub position_noise: f64,
    exact: ImpulseCheck,
}

/// What the draws measured.
#[derive(Default)]
pub struct Tally {
    relerrs: Vec<f64>,
    /// Disagreement of each moving grain-draw with the measured Δv.
    moving: Vec<f64>,
    /// The same inferred Δv against the noise-free tracks' Δv.
    vs_true: Vec<f64>,
}

impl ImpactDraws {
    pub fn new() -> grainforce::Result<Self> {
        Self::of(Preset::Impact)
    }

    /// The same draws on another dynamic preset (2D, DEM seed 1).
    pub fn of(preset: Preset) -> grainforce::Result<Self> {
        let config = DemConfig::preset(preset, 2).seed(1);
        let fps = config.frame_rate;
        let run = simulate(&config)?;
        let diameter = 2.0 * run.frames[0].grains[0].radius.unwrap_or(0.0);
        let exact = impulse_check(
            &run.frames,
            &run.force_sets(),
            fps,
            run.frames[0].gravity(),
            &ImpulseOptions::default(),
        )?;
        Ok(ImpactDraws {
            run,
            fps,
            position_noise: 1e-3 * diameter,
            exact,
        })
    }

    /// Infers each noisy draw with `infer` (seeds 1…12), printing a line per draw.
    pub fn tally(
        &self,
        mut infer: impl FnMut(Vec<Scene>) -> grainforce::Result<(Vec<Scene>, Vec<Vec<Option<Vec3>>>)>,
    ) -> grainforce::Result<Tally> {
        let mut tally = Tally::default();
        let truth: Vec<Vec3> = self.run.forces.iter().flatten().copied().collect();
        for seed in 1..=DRAWS {
            let config = PerturbConfig {
                position_noise: self.position_noise,
                seed,
                ..Default::default()
            };
            let (noisy, forces) = infer(perturb(&self.run.frames, &config)?)?;
            let inferred: Vec<Vec3> = forces
                .iter()
                .flatten()
                .map(|x| x.unwrap_or([0.0; 3]))
                .collect();
            let e = relative_error(&truth, &inferred);
            tally.relerrs.push(e);
            let gravity = noisy[0].gravity();
            let check = impulse_check(
                &noisy,
                &forces,
                self.fps,
                gravity,
                &ImpulseOptions::default(),
            )?;
            let mut line =
                format!("seed {seed:2}: relerr {e:.4}; disagreement (vs measured/noise-free Δv)");
            for (r, x) in check.rows.iter().zip(&self.exact.rows) {
                let gap = (r.inferred[0] - x.measured[0]).hypot(r.inferred[1] - x.measured[1]);
                let d = gap / x.measured[0].hypot(x.measured[1]);
                let mark = if r.moves { "" } else { "~" };
                line.push_str(&format!(" {mark}{:.3}/{d:.3}", r.disagreement));
                if r.moves {
                    tally.moving.push(r.disagreement);
                    tally.vs_true.push(d);
                }
            }
            println!("{line}");
        }
        Ok(tally)
    }
}

impl Tally {
    /// Prints the summary under `label`.
    pub fn print(mut self, label: &str) {
        let summary = |v: &mut Vec<f64>| {
            v.sort_by(f64::total_cmp);
            let within = v.iter().filter(|&&d| d <= 0.10).count();
            format!(
                "median {:.3}, 90th percentile {:.3}, worst {:.3}, {within}/{} within 10 %",
                v[v.len() / 2],
                v[(v.len() * 9) / 10],
                v[v.len() - 1],
                v.len()
            )
        };
        self.relerrs.sort_by(f64::total_cmp);
        println!(
            "{label}: relerr {:.4}..{:.4}",
            self.relerrs[0],
            self.relerrs[self.relerrs.len() - 1]
        );
        println!(
            "moving grains (~: not moving), vs measured Δv:   {}",
            summary(&mut self.moving)
        );
        println!(
            "moving grains, vs noise-free Δv: {}",
            summary(&mut self.vs_true)
        );
    }
}
