//! What every constrained solve returns: the answer, the stage that produced
//! it ([`SolveStatus`]) and each stage tried on the way ([`Attempt`]), typed so
//! that a report can keep their numbers (the JSON report writes them as
//! numbers) and print them as text.

use super::active_set::StopReason;
use super::sparse_interior_point::InteriorPointStop;
use ::clarabel::solver::SolverStatus;
use std::fmt;

/// How a solve ended: the route that produced the answer. Reports print and
/// serialise it as the names they always used (`ActiveSet`, `Solved+polished`…).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SolveStatus {
    /// Nothing was solved (no cluster carried load).
    #[default]
    NotRun,
    /// The least-squares answer: no inequalities, or friction met as it is.
    LeastSquares,
    /// The active set on the sparse factorisation converged.
    ActiveSet,
    /// The interior point on the sparse factorisation converged (the active
    /// set could not settle).
    SparseInteriorPoint { polished: bool },
    /// The interior point (clarabel) converged to its tolerance.
    Solved { polished: bool },
    /// The interior point reached only reduced accuracy.
    AlmostSolved { polished: bool },
}

impl SolveStatus {
    /// An interior-point answer, which polishing may sharpen.
    pub fn is_interior_point(self) -> bool {
        matches!(
            self,
            SolveStatus::SparseInteriorPoint { .. }
                | SolveStatus::Solved { .. }
                | SolveStatus::AlmostSolved { .. }
        )
    }

    /// The same status after polishing (interior-point answers only).
    pub fn polished(self) -> SolveStatus {
        match self {
            SolveStatus::SparseInteriorPoint { .. } => {
                SolveStatus::SparseInteriorPoint { polished: true }
            }
            SolveStatus::Solved { .. } => SolveStatus::Solved { polished: true },
            SolveStatus::AlmostSolved { .. } => SolveStatus::AlmostSolved { polished: true },
            other => other,
        }
    }

    /// 0 not run, 1 converged, 2 reduced accuracy: a report of several solves
    /// shows the worst.
    pub(crate) fn severity(self) -> u8 {
        match self {
            SolveStatus::NotRun => 0,
            SolveStatus::AlmostSolved { .. } => 2,
            _ => 1,
        }
    }
}

impl std::fmt::Display for SolveStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (name, polished) = match *self {
            SolveStatus::NotRun => ("not run", false),
            SolveStatus::LeastSquares => ("LeastSquares", false),
            SolveStatus::ActiveSet => ("ActiveSet", false),
            SolveStatus::SparseInteriorPoint { polished } => ("SparseInteriorPoint", polished),
            SolveStatus::Solved { polished } => ("Solved", polished),
            SolveStatus::AlmostSolved { polished } => ("AlmostSolved", polished),
        };
        f.write_str(name)?;
        if polished {
            f.write_str("+polished")?;
        }
        Ok(())
    }
}

impl std::str::FromStr for SolveStatus {
    type Err = String;

    /// Reads the names [`fmt::Display`] writes (a bench table read back).
    fn from_str(text: &str) -> Result<Self, String> {
        let (name, polished) = match text.strip_suffix("+polished") {
            Some(name) => (name, true),
            None => (text, false),
        };
        let status = match name {
            "not run" => SolveStatus::NotRun,
            "LeastSquares" => SolveStatus::LeastSquares,
            "ActiveSet" => SolveStatus::ActiveSet,
            "SparseInteriorPoint" => SolveStatus::SparseInteriorPoint { polished },
            "Solved" => SolveStatus::Solved { polished },
            "AlmostSolved" => SolveStatus::AlmostSolved { polished },
            _ => return Err(format!("not a solver status: {text:?}")),
        };
        if polished && !status.is_interior_point() {
            return Err(format!("not a solver status: {text:?}"));
        }
        Ok(status)
    }
}

impl<'de> serde::Deserialize<'de> for SolveStatus {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let text = String::deserialize(d)?;
        text.parse().map_err(serde::de::Error::custom)
    }
}

impl serde::Serialize for SolveStatus {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

/// The answer of a constrained solve and how it was reached.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Solution {
    pub x: Vec<f64>,
    /// The stage that produced `x`.
    pub status: SolveStatus,
    pub iterations: u32,
    pub solve_time: f64,
    /// What was tried, in order.
    pub attempts: Vec<Attempt>,
    /// True when the solution comes from clarabel's softened-equality attempt.
    pub softened: bool,
    pub warnings: Vec<String>,
}

/// One stage of the cascade as it was tried.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(tag = "stage", rename_all = "snake_case")]
pub enum Attempt {
    /// The least squares without inequalities on the sparse factorisation.
    LeastSquares,
    /// The active set on the sparse factorisation converged.
    ActiveSet {
        solves: usize,
        sliding: usize,
        open: usize,
    },
    /// The active set did not deliver; the sparse interior point converged.
    SparseInteriorPoint {
        active_set: ActiveSetMiss,
        iterations: usize,
        gap: f64,
        /// Certified distance to the optimum (fit norm), when `noise` is known.
        distance: Option<f64>,
        /// The same distance estimated from the last steps' contraction,
        /// when `noise` is known and the steps contracted; at the data's
        /// accuracy the stop takes the smaller of the two.
        estimate: Option<f64>,
        /// What the noise moves the answer by (fit norm), when estimated.
        noise: Option<f64>,
        /// Stopped at the data's accuracy, before the tolerance.
        at_data_accuracy: bool,
        /// Refinement steps of its Newton solves in all (what their
        /// accuracy cost) and the largest relative KKT residual one was
        /// answered with (not in the text).
        refinement_steps: usize,
        solve_residual: f64,
    },
    /// The active set did not deliver, nor did the sparse interior point
    /// (clarabel follows).
    SparseInteriorPointFailed {
        active_set: ActiveSetMiss,
        failure: InteriorPointFailure,
    },
    /// One clarabel attempt at `tolerance`.
    Clarabel {
        tolerance: f64,
        #[serde(serialize_with = "debug_name")]
        status: SolverStatus,
    },
    /// clarabel with the hard equalities as penalties of `weight`.
    ClarabelSoftened {
        weight: f64,
        #[serde(serialize_with = "debug_name")]
        status: SolverStatus,
    },
}

/// Why the active set did not deliver.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ActiveSetMiss {
    /// It ran out without a reason of its own.
    NotConverged,
    /// It stopped unconverged, for this reason.
    Stopped(#[serde(serialize_with = "display_text")] StopReason),
    /// Not tried: it did not settle at a nearby λ.
    Skipped,
}

/// How the sparse interior point failed.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum InteriorPointFailure {
    /// It stopped short of its tolerance.
    Stopped {
        #[serde(serialize_with = "display_text")]
        stop: InteriorPointStop,
        iterations: usize,
        gap: f64,
        primal_residual: f64,
        dual_residual: f64,
    },
    /// It could not run (e.g. its own analysis failed).
    Error(String),
}

fn debug_name<S: serde::Serializer>(status: &SolverStatus, s: S) -> Result<S::Ok, S::Error> {
    s.collect_str(&format_args!("{status:?}"))
}

fn display_text<T: fmt::Display, S: serde::Serializer>(v: &T, s: S) -> Result<S::Ok, S::Error> {
    s.collect_str(v)
}

impl fmt::Display for ActiveSetMiss {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ActiveSetMiss::NotConverged => f.write_str("not converged"),
            ActiveSetMiss::Stopped(reason) => write!(f, "{reason}"),
            ActiveSetMiss::Skipped => f.write_str("skipped (it did not settle at a nearby λ)"),
        }
    }
}

impl fmt::Display for InteriorPointFailure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            InteriorPointFailure::Stopped {
                stop,
                iterations,
                gap,
                primal_residual,
                dual_residual,
            } => {
                if stop.has_measures() {
                    write!(
                        f,
                        "{stop}: gap {gap:.1e}, primal residual {primal_residual:.1e}, dual residual {dual_residual:.1e}"
                    )?;
                } else {
                    write!(f, "{stop}")?;
                }
                write!(f, " after {iterations} iterations")
            }
            InteriorPointFailure::Error(message) => f.write_str(message),
        }
    }
}

/// The text the reports have always printed for each stage.
impl fmt::Display for Attempt {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Attempt::LeastSquares => f.write_str("equality-constrained least squares (faer)"),
            Attempt::ActiveSet {
                solves,
                sliding,
                open,
            } => write!(
                f,
                "active set on the sparse factorisation: {solves} solves, {sliding} sliding and {open} open contacts"
            ),
            Attempt::SparseInteriorPoint {
                active_set,
                iterations,
                gap,
                distance,
                estimate,
                noise,
                at_data_accuracy,
                ..
            } => {
                write!(
                    f,
                    "active set: {active_set}; interior point on the sparse factorisation: {iterations} iterations (gap {gap:.1e})"
                )?;
                if let (Some(distance), Some(noise)) = (distance, noise) {
                    write!(f, "; distance to the optimum ≤ {distance:.1e}")?;
                    if let Some(estimate) = estimate {
                        write!(f, " (estimated {estimate:.1e})")?;
                    }
                    write!(
                        f,
                        " against noise {noise:.1e} (fit norm){}",
                        if *at_data_accuracy {
                            ", the data's accuracy"
                        } else {
                            ""
                        }
                    )?;
                }
                Ok(())
            }
            Attempt::SparseInteriorPointFailed {
                active_set,
                failure,
            } => write!(
                f,
                "active set: {active_set}; interior point on the sparse factorisation: {failure}; solved by the interior point instead"
            ),
            Attempt::Clarabel { tolerance, status } => {
                write!(f, "tolerance {tolerance:.0e}: {status:?}")
            }
            Attempt::ClarabelSoftened { weight, status } => {
                write!(f, "equalities softened (weight {weight:.0e}): {status:?}")
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_status_reads_back_from_its_name() {
        for status in [
            SolveStatus::NotRun,
            SolveStatus::LeastSquares,
            SolveStatus::ActiveSet,
            SolveStatus::SparseInteriorPoint { polished: false },
            SolveStatus::SparseInteriorPoint { polished: true },
            SolveStatus::Solved { polished: false },
            SolveStatus::Solved { polished: true },
            SolveStatus::AlmostSolved { polished: false },
            SolveStatus::AlmostSolved { polished: true },
        ] {
            assert_eq!(status.to_string().parse::<SolveStatus>(), Ok(status));
        }
        for bad in [
            "",
            "failed",
            "ActiveSet+polished",
            "Solved+polished+polished",
        ] {
            assert!(bad.parse::<SolveStatus>().is_err(), "{bad:?} accepted");
        }
    }

    #[test]
    fn the_interior_points_figures_are_text_and_numbers() {
        let attempt = Attempt::SparseInteriorPoint {
            active_set: ActiveSetMiss::Skipped,
            iterations: 17,
            gap: 3.2e-9,
            distance: Some(1.26e-5),
            estimate: Some(2.04e-6),
            noise: Some(4.0e-3),
            at_data_accuracy: true,
            refinement_steps: 41,
            solve_residual: 8.5e-10,
        };
        assert_eq!(
            attempt.to_string(),
            "active set: skipped (it did not settle at a nearby λ); interior point on the sparse \
             factorisation: 17 iterations (gap 3.2e-9); distance to the optimum ≤ 1.3e-5 \
             (estimated 2.0e-6) against noise 4.0e-3 (fit norm), the data's accuracy"
        );
        let json = serde_json::to_value(&attempt).unwrap();
        assert_eq!(json["stage"], "sparse_interior_point");
        assert_eq!(json["distance"].as_f64(), Some(1.26e-5));
        assert_eq!(json["estimate"].as_f64(), Some(2.04e-6));
        assert_eq!(json["noise"].as_f64(), Some(4.0e-3));
        assert_eq!(json["active_set"], "skipped");
        assert_eq!(json["refinement_steps"].as_u64(), Some(41));
        assert_eq!(json["solve_residual"].as_f64(), Some(8.5e-10));
        // Without a noise estimate the text names neither figure.
        let tolerance_only = Attempt::SparseInteriorPoint {
            active_set: ActiveSetMiss::Skipped,
            iterations: 17,
            gap: 3.2e-9,
            distance: None,
            estimate: None,
            noise: None,
            at_data_accuracy: false,
            refinement_steps: 0,
            solve_residual: 0.0,
        };
        assert!(!tolerance_only.to_string().contains("distance"));
    }

    #[test]
    fn clarabel_attempts_print_as_before() {
        let a = Attempt::Clarabel {
            tolerance: 1e-8,
            status: SolverStatus::Solved,
        };
        assert_eq!(a.to_string(), "tolerance 1e-8: Solved");
        assert_eq!(serde_json::to_value(&a).unwrap()["status"], "Solved");
        let failure = InteriorPointFailure::Stopped {
            stop: InteriorPointStop::NoProgress { iterations: 8 },
            iterations: 40,
            gap: 1e-3,
            primal_residual: 2e-4,
            dual_residual: 5e-5,
        };
        assert_eq!(
            failure.to_string(),
            "no progress in 8 iterations: gap 1.0e-3, primal residual 2.0e-4, dual residual 5.0e-5 after 40 iterations"
        );
    }
}
