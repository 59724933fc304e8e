//! grainforce: contact forces inside granular materials from measured grain
//! stresses — the Granular Element Method (GEM), 2D and 3D, static and dynamic.
//!
//! The data flow: [`scene`] (model, CSV I/O, validation) → [`assemble`] (the
//! sparse GEM system) → [`infer`] (formulations, λ selection) → [`solver`]
//! (clarabel for QP/SOCP, faer for sparse least squares) → [`report`] (metrics,
//! plots). Beside it: [`dem`] (synthetic ground truth), [`image`] (measurements
//! from photographs), [`import`] and [`export`] (other tools' formats).

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
