//! The options of one inference: the method, its solver and their settings.

use super::dynamic::DynamicOptions;
use super::{LambdaSearch, OnCollapse, StressNoise};
use crate::assemble::AssembleOptions;
use crate::solver::active_set::ActiveSetSettings;
use crate::solver::cascade::CascadeSettings;
use crate::solver::clarabel::ConicSettings;
use crate::solver::sparse_ls::Ordering;

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "snake_case")]
pub enum Method {
    Qs,
    Tikhonov,
    Scaled,
    Ls,
    Dynamic,
    /// Static data, momentum balance as a weighted penalty (data that do not
    /// balance, e.g. photoelastic frames with missed contacts).
    Soft,
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Method::Qs => "qs",
            Method::Tikhonov => "tikhonov",
            Method::Scaled => "scaled",
            Method::Ls => "ls",
            Method::Dynamic => "dynamic",
            Method::Soft => "soft",
        })
    }
}

/// How friction-constrained problems are solved.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "snake_case")]
pub enum ConstrainedSolver {
    /// Primal–dual active set on the sparse factorisation, warm-started from the
    /// unconstrained answer; when it does not settle, an interior point on the
    /// same sparse factorisation, then clarabel.
    ActiveSet,
    /// Clarabel's interior point (lifted QP/SOCP), then active-set polishing.
    InteriorPoint,
}

/// How the 3D Coulomb cone is modelled. Written `exact` or `pyramidK`
/// (K facets, at least 3) in a configuration; the CLI offers 4, 8 and 16.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(try_from = "String", into = "String")]
pub enum ConeModel {
    /// The exact second-order cone (SOCP).
    Exact,
    /// An inscribed pyramid with this many facets (a linear QP).
    Pyramid(usize),
}

impl std::fmt::Display for ConeModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ConeModel::Exact => f.write_str("exact"),
            ConeModel::Pyramid(k) => write!(f, "pyramid{k}"),
        }
    }
}

impl std::str::FromStr for ConeModel {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        if s == "exact" {
            return Ok(ConeModel::Exact);
        }
        s.strip_prefix("pyramid")
            .and_then(|k| k.parse::<usize>().ok())
            .filter(|&k| k >= 3)
            .map(ConeModel::Pyramid)
            .ok_or_else(|| format!("unknown cone `{s}`: expected exact or pyramidK (K ≥ 3 facets)"))
    }
}

impl TryFrom<String> for ConeModel {
    type Error = String;
    fn try_from(s: String) -> std::result::Result<Self, String> {
        s.parse()
    }
}

impl From<ConeModel> for String {
    fn from(c: ConeModel) -> String {
        c.to_string()
    }
}

#[cfg(feature = "cli")]
impl clap::ValueEnum for ConeModel {
    fn value_variants<'a>() -> &'a [Self] {
        &[
            ConeModel::Exact,
            ConeModel::Pyramid(4),
            ConeModel::Pyramid(8),
            ConeModel::Pyramid(16),
        ]
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        Some(clap::builder::PossibleValue::new(match self {
            ConeModel::Exact => "exact",
            ConeModel::Pyramid(4) => "pyramid4",
            ConeModel::Pyramid(8) => "pyramid8",
            ConeModel::Pyramid(16) => "pyramid16",
            ConeModel::Pyramid(_) => return None,
        }))
    }
}

#[derive(Debug, Clone)]
pub struct InferOptions {
    pub method: Method,
    pub assemble: AssembleOptions,
    /// Tikhonov λ in the units of the equation (a length: ‖K f − b‖ is force × length).
    pub lambda: Option<f64>,
    pub lambda_search: LambdaSearch,
    pub cone: ConeModel,
    pub conic: ConicSettings,
    /// Weight ω of the wall rows in `scaled`, relative to the stress rows.
    pub wall_weight: f64,
    /// On infeasible data, return the least-violation answer (momentum softened).
    pub allow_infeasible: bool,
    pub dynamic: DynamicOptions,
    /// Dynamic: sweep and report the Pareto front even when the rule is not `knee`.
    pub dynamic_front: bool,
    /// Solve the least squares without inequalities first (sparse LDLᵀ); when it
    /// satisfies friction it is the constrained optimum and the QP is skipped.
    pub exact_first: bool,
    /// Check uniqueness (N(K_st) ∩ N(K_eq) = {0}) up to this many unknowns.
    pub identifiability_limit: usize,
    /// Refine interior-point answers by solving exactly on their active set.
    pub polish: bool,
    /// Algorithm for the friction-constrained problems.
    pub solver: ConstrainedSolver,
    pub active_set: ActiveSetSettings,
    /// Fill-reducing ordering of the sparse factorisation; `None` picks by
    /// dimension ([`Ordering::for_dim`]). The answer is the same either way.
    pub ordering: Option<Ordering>,
    /// What a hard-balance method does when its forces collapse (data out of
    /// balance): fail, switch to `soft`, or accept (flagged in the report).
    pub on_collapse: OnCollapse,
    /// Noise model of the stress rows (how they are weighted).
    pub stress_noise: StressNoise,
}

impl InferOptions {
    /// The cascade's settings from these options.
    pub(crate) fn cascade(&self) -> CascadeSettings {
        CascadeSettings {
            active_set: self.solver == ConstrainedSolver::ActiveSet,
            exact_first: self.exact_first,
            ordering: self.ordering,
            active_set_settings: self.active_set,
            interior_point: self.conic,
        }
    }
}

impl Default for InferOptions {
    fn default() -> Self {
        InferOptions {
            method: Method::Qs,
            assemble: AssembleOptions::default(),
            lambda: None,
            lambda_search: LambdaSearch::default(),
            cone: ConeModel::Exact,
            conic: ConicSettings::default(),
            wall_weight: 100.0,
            allow_infeasible: false,
            dynamic: DynamicOptions::default(),
            dynamic_front: false,
            exact_first: true,
            identifiability_limit: 200_000,
            polish: true,
            solver: ConstrainedSolver::ActiveSet,
            active_set: ActiveSetSettings::default(),
            ordering: None,
            on_collapse: OnCollapse::Fail,
            stress_noise: StressNoise::Absolute,
        }
    }
}
