//! Reporting: accuracy metrics against a ground truth ([`metrics`]), small PNG
//! charts with a built-in bitmap font ([`chart`], [`font`]), force-chain pictures
//! ([`forcechain`]) and Pareto fronts of the λ sweep ([`pareto`]).

pub mod chart;
pub mod draw;
pub mod font;
pub mod forcechain;
pub mod metrics;
pub mod pareto;

pub use chart::{save_png, Chart, Scale};
pub use forcechain::{draw_force_chains, ForceChainOptions, Plane};
pub use metrics::{relative_error, score, Score};
pub use pareto::{draw_pareto, read_pareto_csv, write_pareto_csv, ParetoPoint};
