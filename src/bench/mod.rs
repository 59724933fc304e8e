//! The speed/accuracy benchmark: synthetic packings ([`generate`]), noise
//! ([`noise`]), one case = one method on one scene ([`run_case`]), and the
//! table, CSV and plot of a whole matrix of cases.
//!
//! The `grainforce bench` verb runs each case in a child process so that its
//! peak memory (VmHWM) is its own; this module only measures in-process.

pub mod generate;
pub mod measured;
pub use crate::scene::noise;

pub use generate::{generate, Packing, PackingSpec};
pub use noise::{perturb, Noise};

use crate::error::{Error, Result};
use crate::infer::{
    infer, ConeModel, ConstrainedSolver, InferConfig, InferOptions, LambdaPrecision, Method,
};
use crate::report::chart::{Chart, Scale};
use crate::report::metrics::relative_error;
use crate::scene::{Scene, Vec3};
use crate::solver::SolveStatus;
use image::RgbImage;
use std::time::Instant;

/// Relaxed clarabel tolerance for the `-relaxed` variants.
pub const RELAXED_TOLERANCE: f64 = 1e-4;

/// One benchmarked configuration of the inference.
#[derive(Debug, Clone)]
pub struct MethodSpec {
    pub name: String,
    pub options: InferOptions,
}

/// Names accepted by [`method_spec`]: `ls`, `qs`, `qs-ip`, `qs-relaxed`,
/// `tikhonov`, `tikhonov-ip`, `tikhonov-relaxed`, `tikhonov-search` (λ
/// matched to the walls at [`LambdaPrecision::Fine`]), `tikhonov-coarse` (the
/// same at [`LambdaPrecision::Coarse`], the default), `scaled`, and in 3D `qs-pyr4`, `qs-pyr8`,
/// `qs-pyr16` (any `qs-pyrK`, `K` ≥ 3). `qs` and `tikhonov` use the
/// active-set solver, `-ip` the interior point (clarabel, tolerance 1e-8),
/// `-relaxed` the interior point at tolerance 1e-4; any name
/// may end in `-nocheck` to skip the identifiability (uniqueness) check, and
/// (before that) in `-tolX` to solve to tolerance X rather than the data's
/// accuracy (e.g. `qs-tol1e-4`: the active set, then the sparse interior
/// point to 10⁻⁴), and
/// (before that) in `-relative` to weight the stress rows by the relative
/// noise model (`--stress-noise relative`); `soft` is momentum as a penalty.
pub const METHOD_NAMES: &str =
    "ls, qs, qs-ip, qs-relaxed, tikhonov, tikhonov-ip, tikhonov-relaxed, tikhonov-search, tikhonov-coarse, scaled, qs-pyrK (3D: K facets, e.g. qs-pyr8), soft, each optionally with -tolX (a tolerance, e.g. qs-tol1e-4), then -relative, then -nocheck";

/// The default matrix: the floor, the constrained formulations by active set
/// and by interior point at both tolerances and, in 3D, pyramids of 4, 8 and 16 facets.
pub fn default_methods(dim: usize) -> Vec<&'static str> {
    let mut m = vec![
        "ls",
        "qs",
        "qs-ip",
        "qs-relaxed",
        "tikhonov",
        "tikhonov-ip",
        "tikhonov-relaxed",
    ];
    if dim == 3 {
        m.extend(["qs-pyr4", "qs-pyr8", "qs-pyr16"]);
    }
    m
}

/// The configuration a bench method name stands for: a named preset of
/// [`InferConfig`] (names in [`METHOD_NAMES`]). `lambda` is the Tikhonov λ
/// [m] of the fixed-λ names.
pub fn preset(name: &str, lambda: f64) -> Result<InferConfig> {
    let mut c = InferConfig::default();
    let mut base = name;
    let mut name_rest = name;
    if let Some(b) = name.strip_suffix("-nocheck") {
        c.uniqueness_limit = 0;
        base = b;
        name_rest = b;
    }
    if let Some(b) = base.strip_suffix("-relative") {
        c.stress_noise = crate::infer::StressNoise::Relative;
        base = b;
        name_rest = b;
    }
    if let Some((b, tolerance)) = split_tolerance(base) {
        // Our cascade (active set, then the sparse interior point) solved to
        // this tolerance instead of the data's accuracy.
        c.tolerance = Some(tolerance);
        base = b;
        name_rest = b;
    }
    if let Some(b) = base.strip_suffix("-relaxed") {
        // A tolerance is a knob of the interior point only.
        c.tolerance = Some(RELAXED_TOLERANCE);
        c.solver = ConstrainedSolver::InteriorPoint;
        base = b;
    } else if let Some(b) = base.strip_suffix("-ip") {
        c.solver = ConstrainedSolver::InteriorPoint;
        base = b;
    }
    let method = match base {
        "ls" if base == name_rest => Method::Ls,
        "qs" => Method::Qs,
        "tikhonov" => {
            c.lambda = Some(lambda);
            Method::Tikhonov
        }
        "tikhonov-search" if base == name_rest => {
            c.lambda_precision = LambdaPrecision::Fine;
            Method::Tikhonov
        }
        "tikhonov-coarse" if base == name_rest => {
            c.lambda_precision = LambdaPrecision::Coarse;
            Method::Tikhonov
        }
        "scaled" if base == name_rest => Method::Scaled,
        "soft" if base == name_rest => Method::Soft,
        _ => {
            let facets = base
                .strip_prefix("qs-pyr")
                .and_then(|k| k.parse::<usize>().ok())
                .filter(|&k| k >= 3);
            let Some(k) = facets else {
                return Err(Error::Invalid(format!(
                    "unknown bench method `{name}`; known: {METHOD_NAMES}"
                )));
            };
            c.cone = ConeModel::Pyramid(k);
            Method::Qs
        }
    };
    c.method = Some(method);
    Ok(c)
}

/// A method name ending in `-tolX` (X a tolerance in (0, 1), e.g.
/// `qs-tol1e-4`): the rest of the name and X.
pub fn split_tolerance(name: &str) -> Option<(&str, f64)> {
    let (base, tolerance) = name.rsplit_once("-tol")?;
    let tolerance: f64 = tolerance.parse().ok()?;
    (tolerance > 0.0 && tolerance < 1.0).then_some((base, tolerance))
}

/// The solver's options of a named method ([`preset`]).
pub fn method_spec(name: &str, lambda: f64) -> Result<MethodSpec> {
    let (options, _) = preset(name, lambda)?.options()?;
    Ok(MethodSpec {
        name: name.to_owned(),
        options,
    })
}

/// What one case measured.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CaseResult {
    pub dim: usize,
    pub grains: usize,
    pub contacts: usize,
    pub unknowns: usize,
    pub noise: String,
    pub method: String,
    /// Wall-clock time of `infer` (assembly + solve + report) [s].
    pub time: f64,
    /// Reading the scene and truth from disk [s] (0 when generated in memory).
    pub load_time: f64,
    /// Peak resident memory of the process [bytes], when known.
    pub peak_memory: Option<u64>,
    /// ‖f − f*‖ / ‖f*‖ (eq. 2.15); NaN when the case failed.
    #[serde(deserialize_with = "f64_or_nan")]
    pub relerr: f64,
    /// Worst (|f_t| − μ f_n)₊ relative to the mean contact force.
    #[serde(deserialize_with = "f64_or_nan")]
    pub coulomb_violation: f64,
    pub iterations: u32,
    /// The solve's status; `None` (written "failed") when the case failed.
    #[serde(with = "status_or_failed")]
    pub status: Option<SolveStatus>,
    /// The error, when the inference failed or timed out.
    pub error: Option<String>,
    /// ‖f − f_tight‖ / ‖f_tight‖ to the same method's solve at its tightest
    /// tolerance on the same scene (its `-tolX` variants, when run): how far
    /// each stop lies from the optimum ([`distances_to_tightest`]).
    #[serde(default)]
    pub distance: Option<f64>,
    /// CPU seconds of `infer`, all threads (Linux): steadier than `time` on a
    /// shared machine.
    #[serde(default)]
    pub cpu_time: Option<f64>,
}

impl CaseResult {
    pub fn failed(
        dim: usize,
        grains: usize,
        noise: &str,
        method: &str,
        time: f64,
        error: String,
    ) -> Self {
        CaseResult {
            dim,
            grains,
            contacts: 0,
            unknowns: 0,
            noise: noise.to_owned(),
            method: method.to_owned(),
            time,
            load_time: 0.0,
            peak_memory: None,
            relerr: f64::NAN,
            coulomb_violation: f64::NAN,
            iterations: 0,
            status: None,
            error: Some(error),
            distance: None,
            cpu_time: None,
        }
    }

    pub fn ok(&self) -> bool {
        self.error.is_none()
    }
}

/// Runs one method on one scene against its exact forces. An inference error
/// is recorded in the result, not returned.
pub fn run_case(scene: &Scene, truth: &[Vec3], noise: Noise, spec: &MethodSpec) -> CaseResult {
    run_case_with_forces(scene, truth, noise, spec).0
}

/// [`run_case`], also returning the forces inferred (none when it failed).
pub fn run_case_with_forces(
    scene: &Scene,
    truth: &[Vec3],
    noise: Noise,
    spec: &MethodSpec,
) -> (CaseResult, Option<Vec<Vec3>>) {
    let start = Instant::now();
    let cpu_start = cpu_seconds();
    let result = infer(scene, &spec.options);
    let time = start.elapsed().as_secs_f64();
    let cpu_time = cpu_start.zip(cpu_seconds()).map(|(a, b)| b - a);
    match result {
        Ok(inference) => {
            let forces = inference.forces_or_zero();
            let r = &inference.report;
            let case = CaseResult {
                dim: scene.dim,
                grains: scene.grains.len(),
                contacts: scene.contacts.len(),
                unknowns: r.unknowns,
                noise: noise.name().into(),
                method: spec.name.clone(),
                time,
                load_time: 0.0,
                peak_memory: peak_memory(),
                relerr: relative_error(truth, &forces),
                coulomb_violation: r.coulomb_violation,
                iterations: r.iterations,
                status: Some(r.solver_status),
                error: None,
                distance: None,
                cpu_time,
            };
            (case, Some(forces))
        }
        Err(e) => {
            let mut c = CaseResult::failed(
                scene.dim,
                scene.grains.len(),
                noise.name(),
                &spec.name,
                time,
                e.to_string(),
            );
            c.contacts = scene.contacts.len();
            c.peak_memory = peak_memory();
            c.cpu_time = cpu_time;
            (c, None)
        }
    }
}

/// For each (method name, its forces) run on one scene: the relative
/// distance ‖f − f_tight‖ / ‖f_tight‖ to the forces of the same method at its
/// tightest `-tolX` variant among them (`qs`, `qs-tol1e-2`, … `qs-tol1e-8`
/// are measured against `qs-tol1e-8`). `None` for a method run at no
/// tolerance variant, or failed.
pub fn distances_to_tightest(cases: &[(&str, Option<&[Vec3]>)]) -> Vec<Option<f64>> {
    let family = |name: &str| split_tolerance(name).map_or(name.to_owned(), |t| t.0.to_owned());
    cases
        .iter()
        .map(|(name, forces)| {
            let forces = (*forces)?;
            let own = family(name);
            let tightest = cases
                .iter()
                .filter_map(|(other, f)| {
                    let (base, tolerance) = split_tolerance(other)?;
                    (base == own).then_some((tolerance, (*f)?))
                })
                .min_by(|a, b| a.0.total_cmp(&b.0))?;
            Some(relative_error(tightest.1, forces))
        })
        .collect()
}

/// Peak resident set size of this process (VmHWM) in bytes; Linux only.
pub fn peak_memory() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// CPU seconds this process has used so far, all threads (utime + stime
/// from /proc/self/stat); Linux only. On a shared machine wall time alone
/// says little.
pub fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields 14 and 15 (utime, stime) are the 12th and 13th after the ")"
    // that ends the command name.
    let after: Vec<&str> = stat.rsplit_once(')')?.1.split_whitespace().collect();
    let ticks: f64 = after.get(11)?.parse::<f64>().ok()? + after.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// Median of the repeats of each (dim, grains, noise, method), keeping the
/// first failure if any repeat failed.
pub fn aggregate(results: &[CaseResult]) -> Vec<CaseResult> {
    let mut out: Vec<CaseResult> = Vec::new();
    let mut groups: Vec<Vec<&CaseResult>> = Vec::new();
    for r in results {
        let key = |c: &CaseResult| (c.dim, c.grains, c.noise.clone(), c.method.clone());
        match groups.iter_mut().find(|g| key(g[0]) == key(r)) {
            Some(g) => g.push(r),
            None => groups.push(vec![r]),
        }
    }
    for g in groups {
        if let Some(f) = g.iter().find(|c| !c.ok()) {
            out.push((*f).clone());
            continue;
        }
        let mut times: Vec<f64> = g.iter().map(|c| c.time).collect();
        times.sort_by(f64::total_cmp);
        let mut c = g[0].clone();
        c.time = times[times.len() / 2];
        let mut cpu: Vec<f64> = g.iter().filter_map(|c| c.cpu_time).collect();
        cpu.sort_by(f64::total_cmp);
        c.cpu_time = cpu.get(cpu.len() / 2).copied();
        c.peak_memory = g.iter().filter_map(|c| c.peak_memory).max();
        out.push(c);
    }
    out
}

fn fmt_bytes(b: Option<u64>) -> String {
    match b {
        Some(b) if b >= 1 << 30 => format!("{:.2} GB", b as f64 / (1u64 << 30) as f64),
        Some(b) => format!("{:.0} MB", b as f64 / (1u64 << 20) as f64),
        None => "–".into(),
    }
}

fn fmt_time(t: f64) -> String {
    if t < 1.0 {
        format!("{:.0} ms", t * 1e3)
    } else {
        format!("{t:.2} s")
    }
}

/// A Markdown table of (aggregated) results, with each case's time relative to
/// the `ls` floor of the same scene when present.
pub fn markdown_table(results: &[CaseResult]) -> String {
    let mut s = String::from(
        "| dim | grains | unknowns | noise | method | time | cpu | × ls | peak memory | relerr | from the tightest solve | worst Coulomb violation | iterations | status |\n\
         |---|---:|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|\n",
    );
    for r in results {
        let floor = results
            .iter()
            .find(|f| {
                f.dim == r.dim
                    && f.grains == r.grains
                    && f.noise == r.noise
                    && f.method == "ls"
                    && f.ok()
            })
            .map(|f| f.time);
        let ratio = match (floor, r.ok()) {
            (Some(f), true) if f > 0.0 => format!("{:.1}", r.time / f),
            _ => "–".into(),
        };
        let status = match &r.error {
            Some(e) => format!("**failed**: {}", e.replace('|', "/")),
            None => status_or_failed::text(r.status),
        };
        s.push_str(&format!(
            "| {}D | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
            r.dim,
            r.grains,
            r.unknowns,
            r.noise,
            r.method,
            fmt_time(r.time),
            r.cpu_time.map_or("–".into(), fmt_time),
            ratio,
            fmt_bytes(r.peak_memory),
            if r.ok() {
                format!("{:.3e}", r.relerr)
            } else {
                "–".into()
            },
            r.distance.map_or("–".into(), |d| format!("{d:.1e}")),
            if r.ok() {
                format!("{:.1e}", r.coulomb_violation)
            } else {
                "–".into()
            },
            r.iterations,
            status
        ));
    }
    s
}

/// A number that JSON wrote as `null` (JSON has no NaN): a failed case's
/// relerr travels from the child process that way.
fn f64_or_nan<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<f64, D::Error> {
    use serde::Deserialize;
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// A case's status as the table writes it: the status's name, or "failed".
mod status_or_failed {
    use crate::solver::SolveStatus;
    use serde::{Deserialize, Deserializer, Serializer};

    const FAILED: &str = "failed";

    pub fn text(status: Option<SolveStatus>) -> String {
        status.map_or_else(|| FAILED.to_owned(), |s| s.to_string())
    }

    pub fn serialize<S: Serializer>(status: &Option<SolveStatus>, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(&text(*status))
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<SolveStatus>, D::Error> {
        let text = String::deserialize(d)?;
        if text == FAILED {
            return Ok(None);
        }
        text.parse().map(Some).map_err(serde::de::Error::custom)
    }
}

/// CSV of results (one row per case).
pub fn csv(results: &[CaseResult]) -> Result<String> {
    let mut w = ::csv::Writer::from_writer(Vec::new());
    for r in results {
        w.serialize(r)
            .map_err(|e| Error::Invalid(format!("writing the bench table: {e}")))?;
    }
    let bytes = w
        .into_inner()
        .map_err(|e| Error::Invalid(format!("writing the bench table: {e}")))?;
    String::from_utf8(bytes).map_err(|e| Error::Invalid(e.to_string()))
}

/// Reads results written by [`csv`].
pub fn read_csv(path: &std::path::Path) -> Result<Vec<CaseResult>> {
    let mut r = ::csv::Reader::from_path(path)
        .map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))?;
    let mut out = Vec::new();
    for (i, row) in r.deserialize().enumerate() {
        let row: CaseResult = row.map_err(|e| {
            Error::data(
                path,
                Some(i + 2),
                None,
                format!("not a bench result row: {e}"),
            )
        })?;
        out.push(row);
    }
    Ok(out)
}

/// Least-squares slope of log(time) against log(grains) over successful
/// cases of one method (the empirical scaling exponent), when ≥ 2 sizes exist.
pub fn scaling_exponent(
    results: &[CaseResult],
    dim: usize,
    noise: &str,
    method: &str,
) -> Option<f64> {
    let pts: Vec<(f64, f64)> = results
        .iter()
        .filter(|r| {
            r.ok() && r.dim == dim && r.noise == noise && r.method == method && r.time > 0.0
        })
        .map(|r| ((r.grains as f64).ln(), r.time.ln()))
        .collect();
    if pts.len() < 2 {
        return None;
    }
    let n = pts.len() as f64;
    let mx = pts.iter().map(|p| p.0).sum::<f64>() / n;
    let my = pts.iter().map(|p| p.1).sum::<f64>() / n;
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    (sxx > 0.0).then(|| sxy / sxx)
}

/// Distance to the tightest solve ([`CaseResult::distance`]) against CPU
/// time (wall time where unknown) at one noise level, one curve per method
/// and scene through its tolerances; `None` when no case has a distance.
pub fn plot_distances(results: &[CaseResult], noise: &str, title: &str) -> Option<RgbImage> {
    let mut curves: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
    for r in results
        .iter()
        .filter(|r| r.ok() && r.noise == noise && r.time > 0.0)
    {
        // The tightest solve itself lies at distance 0, off a log axis.
        let Some(d) = r.distance.filter(|d| *d > 0.0) else {
            continue;
        };
        let family = split_tolerance(&r.method).map_or(r.method.as_str(), |t| t.0);
        let name = format!("{}D {} ({} grains)", r.dim, family, r.grains);
        let time = r.cpu_time.filter(|t| *t > 0.0).unwrap_or(r.time);
        add_point(&mut curves, name, (time, d));
    }
    // In the order of the stops (loosest first): on a shared machine time
    // alone does not order them.
    for (_, pts) in &mut curves {
        pts.sort_by(|a, b| b.1.total_cmp(&a.1));
    }
    log_log_chart(
        curves,
        title,
        "time [s] (CPU where known)",
        "distance to the tightest solve (relative)",
    )
}

/// Adds a point to the named curve, starting the curve if it is new.
fn add_point(curves: &mut Vec<(String, Vec<(f64, f64)>)>, name: String, point: (f64, f64)) {
    match curves.iter_mut().find(|c| c.0 == name) {
        Some(c) => c.1.push(point),
        None => curves.push((name, vec![point])),
    }
}

/// The curves as lines on log–log axes, in the palette's colours; `None`
/// without a curve.
fn log_log_chart(
    curves: Vec<(String, Vec<(f64, f64)>)>,
    title: &str,
    x: &str,
    y: &str,
) -> Option<RgbImage> {
    if curves.is_empty() {
        return None;
    }
    let palette = crate::report::chart::PALETTE;
    let mut chart = Chart::new(1000, 640)
        .title(title)
        .x_axis(x, Scale::Log)
        .y_axis(y, Scale::Log);
    for (i, (name, pts)) in curves.iter().enumerate() {
        chart = chart.line(name, pts, palette[i % palette.len()]);
    }
    Some(chart.render())
}

/// relerr against time at one noise level, one curve per (dim, method)
/// through the sizes.
pub fn plot(results: &[CaseResult], noise: &str, title: &str) -> Option<RgbImage> {
    // A method run at several tolerances is one curve per scene through its
    // tolerances (time against accuracy); any other one curve through the sizes.
    let family = |method: &str| split_tolerance(method).map_or(method.to_owned(), |t| t.0.into());
    let tolerance_families: Vec<String> = results
        .iter()
        .filter_map(|r| split_tolerance(&r.method).map(|t| t.0.to_owned()))
        .collect();
    let mut curves: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
    for r in results
        .iter()
        .filter(|r| r.ok() && r.noise == noise && r.time > 0.0 && r.relerr > 0.0)
    {
        let name = if tolerance_families.contains(&family(&r.method)) {
            format!(
                "{}D {} ({} grains), tolerances",
                r.dim,
                family(&r.method),
                r.grains
            )
        } else {
            format!("{}D {}", r.dim, r.method)
        };
        add_point(&mut curves, name, (r.time, r.relerr));
    }
    for (_, pts) in &mut curves {
        pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    }
    log_log_chart(curves, title, "time [s]", "relative error vs ground truth")
}
