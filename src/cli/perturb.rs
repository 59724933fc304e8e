//! `grainforce perturb`: measurement noise on a scene.

use grainforce::dem::perturb::{perturb, PerturbConfig};
use grainforce::scene;
use grainforce::Error;
use std::path::PathBuf;

const DETAILS: &str = "\
Adds measurement noise to a scene (or every frame of a sequence).

The stress model is exactly the original study's (eq. 2.16): every stress
component b becomes b + (BIAS + N(0, NOISE))·b, one draw per component;
`--stress-bias 0.15 --stress-noise 0.1` reproduces it. Other noises are
independent Gaussian: centroid coordinates (--position-noise, metres),
the tilt of each contact normal (--normal-noise, degrees), each
acceleration component (--accel-noise, m/s²); --drop-contacts removes each
contact with that probability.

forces.csv in SCENE (the ground truth) is copied unchanged into OUT, so the
noisy scene can be scored against the true forces; dem_report.json too.";

#[derive(clap::Args)]
#[command(after_help = DETAILS)]
pub struct Args {
    /// Scene folder to perturb.
    scene: PathBuf,
    /// Output scene folder (created if needed).
    #[arg(short, long)]
    output: PathBuf,
    /// Systematic relative stress error (0.15 in the original study).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    stress_bias: f64,
    /// Standard deviation of the random relative stress error (0.1 there).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    stress_noise: f64,
    /// Standard deviation of each centroid coordinate [m].
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    position_noise: f64,
    /// Standard deviation of the tilt of each contact normal [degrees].
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    normal_noise: f64,
    /// Standard deviation of each acceleration component [m/s²].
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    accel_noise: f64,
    /// Probability that a contact is missed (removed).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    drop_contacts: f64,
    /// Random seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

pub fn run(args: Args) -> grainforce::Result<()> {
    let config = PerturbConfig {
        stress_bias: args.stress_bias,
        stress_noise: args.stress_noise,
        position_noise: args.position_noise,
        normal_noise_deg: args.normal_noise,
        accel_noise: args.accel_noise,
        drop_contacts: args.drop_contacts,
        seed: args.seed,
    };
    config.validate().map_err(|e| match e {
        // The library names its fields; here they are flags.
        Error::Invalid(m) => Error::Invalid(
            m.replace("`normal_noise_deg`", "--normal-noise")
                .replace("`stress_bias`", "--stress-bias")
                .replace("`stress_noise`", "--stress-noise")
                .replace("`position_noise`", "--position-noise")
                .replace("`accel_noise`", "--accel-noise")
                .replace("`drop_contacts`", "--drop-contacts"),
        ),
        e => e,
    })?;
    if args.scene == args.output {
        return Err(Error::Invalid(
            "the output folder must differ from the scene folder".into(),
        ));
    }
    let frames = scene::read_sequence(&args.scene)?;
    let noisy = perturb(&frames, &config)?;
    scene::write_sequence(&args.output, &noisy)?;
    let mut copied = Vec::new();
    for name in ["forces.csv", "dem_report.json"] {
        let from = args.scene.join(name);
        if from.exists() {
            let to = args.output.join(name);
            std::fs::copy(&from, &to).map_err(|e| Error::io(&to, e))?;
            copied.push(name);
        }
    }
    let contacts: usize = noisy.iter().map(|s| s.contacts.len()).sum();
    status!(
        "{}: {} frame(s), {} contacts kept{}",
        args.output.display(),
        noisy.len(),
        contacts,
        if copied.is_empty() {
            String::new()
        } else {
            format!("; copied {} unchanged", copied.join(", "))
        }
    );
    Ok(())
}
