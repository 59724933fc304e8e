//! grainforce: contact forces inside granular materials from measured grain
//! stresses — the Granular Element Method (GEM), 2D and 3D, static and dynamic.
//!
//! The data flow: [`scene`] (model, CSV I/O, validation) → [`assemble`] (the
//! sparse GEM system) → [`infer`] (formulations, λ selection) → [`solver`]
//! (clarabel for QP/SOCP, faer for sparse least squares) → [`report`] (metrics,
//! plots). Beside it: [`dem`] (synthetic ground truth), [`image`] (measurements
//! from photographs), [`import`] and [`export`] (other tools' formats).
//!
//! # A tour
//!
//! **Scene → assembly → inference → score.** A scene folder holds
//! grains.csv, contacts.csv and optionally walls.csv and scene.json (see the
//! README); [`assemble`] turns it into the sparse GEM system, [`infer`]
//! solves it, [`report`] compares forces with the truth.
//!
//! ```
//! use grainforce::assemble::{assemble, AssembleOptions};
//! use grainforce::infer::{infer, InferOptions};
//! use grainforce::report::metrics::score;
//! use grainforce::scene::{read_forces, read_scene};
//! use std::path::Path;
//!
//! # fn main() -> grainforce::Result<()> {
//! let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/oedometer");
//! let scene = read_scene(&dir)?;
//!
//! // In 2D a Coulomb contact has two unknowns, the others one.
//! let assembly = assemble(&scene, &AssembleOptions::default())?;
//! let [frictionless, coulomb, normal_only] = assembly.friction_counts;
//! let unknowns: usize = assembly.systems.iter().map(|s| s.n).sum();
//! assert_eq!(unknowns, frictionless + 2 * coulomb + normal_only);
//!
//! let result = infer(&scene, &InferOptions::default())?;
//! println!("{}", result.report); // sizes, residuals, λ, solver status
//! let forces = result.forces_or_zero(); // force on `a` by `b`, in contact order
//!
//! let truth_file = dir.join("forces.csv"); // the DEM's exact forces
//! let truth = read_forces(&truth_file)?.for_scene(&scene, &truth_file)?;
//! assert!(score(&scene, &truth, &forces)?.relerr() < 1e-6);
//! # Ok(())
//! # }
//! ```
//!
//! **Ground truth: the DEM.** [`dem`] runs the presets (`oedometer`, `box`,
//! `impact`, `bed-impact`) and returns their frames with the exact forces.
//!
//! ```
//! use grainforce::dem::{simulate, DemConfig, Preset};
//! use grainforce::infer::{infer, InferOptions};
//! use grainforce::report::relative_error;
//!
//! # fn main() -> grainforce::Result<()> {
//! let run = simulate(&DemConfig::preset(Preset::Oedometer, 2).grains(30).seed(1))?;
//! assert!(run.report.passed, "the quasi-static gate was reached");
//! let frame = &run.frames[0];
//! let inferred = infer(frame, &InferOptions::default())?.forces_or_zero();
//! // A static packing with exact stresses: the forces come back exactly.
//! assert!(relative_error(&run.forces[0], &inferred) < 1e-6);
//! # Ok(())
//! # }
//! ```
//!
//! **Measurements from photographs.** [`image`] finds disks, contacts and
//! strains in pictures; here two bright disks on a dark background.
//!
//! ```
//! use grainforce::image::{detect_disks, DetectOptions, FloatImage};
//!
//! # fn main() -> grainforce::Result<()> {
//! let centres = [(60.0, 60.0), (140.0, 62.0)];
//! let image = FloatImage::from_fn(200, 120, |x, y| {
//!     let inside = centres.iter().any(|&(cx, cy): &(f64, f64)| {
//!         (x as f64 - cx).hypot(y as f64 - cy) < 30.0
//!     });
//!     image::Luma([if inside { 0.8 } else { 0.1 }])
//! });
//! let disks = detect_disks(&image, &DetectOptions::new(20.0, 40.0))?;
//! assert_eq!(disks.len(), 2);
//! for (d, &(cx, cy)) in disks.iter().zip(&centres) {
//!     assert!((d.x - cx).hypot(d.y - cy) < 1.0 && (d.r - 30.0).abs() < 1.0);
//! }
//! # Ok(())
//! # }
//! ```
//!
//! The command line (`src/cli`) is a thin layer of verbs over these modules.

pub mod assemble;
pub mod bench;
pub mod dem;
pub mod error;
pub mod export;
pub mod image;
pub mod import;
pub mod infer;
pub mod report;
pub mod scene;
pub mod solver;
pub mod stats;

pub use error::{Error, Result};
