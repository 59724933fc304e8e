//! `grainforce bench`: the speed/accuracy matrix (sizes × noise × methods) on
//! synthetic packings with exact forces. Each case runs in a child process
//! (`grainforce bench --single …`) so its peak memory is its own.

use grainforce::bench::{self, CaseResult, MethodSpec, Noise, PackingSpec};
use grainforce::error::{Error, Result};
use grainforce::scene::{self, Forces};
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

#[derive(clap::Args)]
#[command(
    long_about = "Measures time, peak memory, relative error against exact forces, worst Coulomb \
violation and solver iterations of each method on synthetic packings (jittered polydisperse \
lattices with walls and exact, admissible forces; see src/bench/generate.rs). Every case runs in \
its own child process. Prints a Markdown table, the constrained/ls time ratios and the scaling \
exponent of each method; optionally writes a CSV and a PNG plot of relerr vs time.\n\n\
The default run (2D, 10³ and 10⁴ grains, no noise and stress noise, the default methods) takes a \
few minutes in release. Larger sizes: --sizes 1e3,1e4,1e5,1e6 (2D) or --dim 3 --sizes 1e3,1e4,1e5."
)]
pub struct Args {
    /// Numbers of grains, comma-separated (1e3 notation accepted).
    #[arg(long, value_delimiter = ',', default_value = "1e3,1e4")]
    pub sizes: Vec<String>,
    /// Dimensions to run: 2, 3 or 2,3.
    #[arg(long, value_delimiter = ',', default_value = "2")]
    pub dim: Vec<usize>,
    /// Methods, comma-separated: ls, qs, qs-ip, qs-relaxed, tikhonov,
    /// tikhonov-ip, tikhonov-relaxed, tikhonov-search (automatic λ),
    /// tikhonov-coarse (automatic λ, --lambda-precision coarse), scaled,
    /// qs-pyr4 / qs-pyr8 / qs-pyr16 (3D). Default: all but the automatic λ
    /// and scaled, plus the pyramids in 3D. Plain names use the active-set solver; -ip the
    /// interior point (clarabel, tolerance 1e-8); -relaxed the interior point at
    /// tolerance 1e-4; a -nocheck suffix (e.g. ls-nocheck) skips the uniqueness check.
    #[arg(long, value_delimiter = ',')]
    pub methods: Option<Vec<String>>,
    /// Noise levels, comma-separated: none; stress (eq. 2.16: ×(1.15 + N(0, 0.1))
    /// per component); geometry (centroids ±0.5 % R, contact points ±1 % R,
    /// normals ±0.01 rad, Gaussian).
    #[arg(long, value_delimiter = ',', default_value = "none,stress")]
    pub noise: Vec<String>,
    /// Repeats of each case (the table shows the median time).
    #[arg(long, default_value_t = 1)]
    pub repeats: usize,
    /// Tikhonov λ of the fixed-λ variants, relative to the grain radius R₀.
    #[arg(long, default_value_t = 0.1)]
    pub lambda_rel: f64,
    /// Seed of the packings and the noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Share of the frictional contacts generated exactly at the Coulomb
    /// limit (|f_t| = μ f_n), as in a sheared packing. Default: 0.3 in 3D
    /// (so friction binds under noise, as on real sheared packings), 0 in 2D.
    #[arg(long)]
    pub sliding: Option<f64>,
    /// Wall-clock limit of one case in seconds; a slower case is killed and
    /// reported as a timeout.
    #[arg(long, default_value_t = 900.0)]
    pub timeout: f64,
    /// Write every case (one row per repeat) as CSV.
    #[arg(long, value_name = "TABLE.csv", alias = "out")]
    pub csv: Option<PathBuf>,
    /// Write the Markdown table and the ratios to this file as well.
    #[arg(long, value_name = "TABLE.md")]
    pub markdown: Option<PathBuf>,
    /// Write a PNG of relerr vs time (one curve per method) at the noisiest level run;
    /// with `-tolX` methods also BENCH-distance.png, each stop's distance to the
    /// tightest solve against time.
    #[arg(long, value_name = "BENCH.png")]
    pub plot: Option<PathBuf>,
    /// Also time the researcher's alternative on each scene: a Python script with
    /// cvxpy + Clarabel (benches/cvxpy/gem_cvxpy.py, run in its own venv, which
    /// it creates on first use with pip), against `grainforce infer --method qs`,
    /// both end-to-end (process start to forces written).
    #[arg(long)]
    pub cvxpy: bool,
    /// Largest size for which the cvxpy comparison runs.
    #[arg(long, default_value = "1e4")]
    pub cvxpy_max: String,
    /// The cvxpy script (default: benches/cvxpy/gem_cvxpy.py of the source tree).
    #[arg(long, value_name = "SCRIPT.py")]
    pub cvxpy_script: Option<PathBuf>,
    /// Do not run anything: merge these CSV files of earlier runs (--csv) and
    /// print/write their table, ratios and plot.
    #[arg(long, value_delimiter = ',', value_name = "A.csv,B.csv")]
    pub from: Option<Vec<PathBuf>>,
    /// Keep the generated scenes in this folder (default: a temporary folder).
    #[arg(long, value_name = "DIR")]
    pub keep: Option<PathBuf>,
    /// Run on these scene folders instead of generated packings, each with its
    /// exact forces in its forces.csv (as `grainforce dem` writes them, e.g. a
    /// sheared `dem box --deviator` packing); the noise levels are applied as
    /// to generated ones, and the fixed-λ variants use the scene's median
    /// grain radius.
    #[arg(long, value_delimiter = ',', value_name = "DIR,DIR", conflicts_with_all = ["sizes", "dim", "sliding"])]
    pub scenes: Option<Vec<PathBuf>>,

    // Internal: one case in this process (used by the child processes).
    #[arg(long, hide = true)]
    pub single: bool,
    #[arg(long, hide = true)]
    pub scene: Option<PathBuf>,
    #[arg(long, hide = true)]
    pub truth: Option<PathBuf>,
    #[arg(long, hide = true)]
    pub method: Option<String>,
    #[arg(long, hide = true)]
    pub lambda: Option<f64>,
    #[arg(long, hide = true)]
    pub forces_out: Option<PathBuf>,
}

/// `--sliding` in 3D unless given: the share of contacts at the Coulomb
/// limit that makes the `ls` answer violate friction by ≥ 0.05 of the mean
/// normal force under stress noise, as real sheared packings do.
const DEFAULT_SLIDING_3D: f64 = 0.3;

fn parse_size(s: &str) -> Result<usize> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| Error::Invalid(format!("--sizes: `{s}` is not a number")))?;
    if !(2.0..=1e8).contains(&v) {
        return Err(Error::Invalid(format!(
            "--sizes: {s} grains is out of range (2 … 1e8)"
        )));
    }
    Ok(v.round() as usize)
}

pub fn run(args: Args) -> Result<()> {
    if args.single {
        return run_single(&args);
    }
    if let Some(files) = &args.from {
        let mut results = Vec::new();
        for f in files {
            results.extend(bench::read_csv(f)?);
        }
        let mut dims: Vec<usize> = results.iter().map(|r| r.dim).collect();
        dims.dedup();
        dims.sort_unstable();
        dims.dedup();
        let mut noises: Vec<Noise> = Vec::new();
        for r in &results {
            if let Some(n) = Noise::parse(&r.noise) {
                if !noises.contains(&n) {
                    noises.push(n);
                }
            }
        }
        return finish(&args, &results, &dims, &noises, &[]);
    }
    let sizes: Vec<usize> = args
        .sizes
        .iter()
        .map(|s| parse_size(s))
        .collect::<Result<_>>()?;
    let noises: Vec<Noise> = args
        .noise
        .iter()
        .map(|s| {
            Noise::parse(s.trim()).ok_or_else(|| {
                Error::Invalid(format!(
                    "--noise: unknown level `{s}` (none, stress, geometry)"
                ))
            })
        })
        .collect::<Result<_>>()?;
    for &d in &args.dim {
        if d != 2 && d != 3 {
            return Err(Error::Invalid(format!("--dim must be 2 or 3, got {d}")));
        }
    }
    if args.repeats == 0 {
        return Err(Error::Invalid("--repeats must be at least 1".into()));
    }
    if !(args.lambda_rel >= 0.0 && args.lambda_rel.is_finite()) {
        return Err(Error::Invalid("--lambda-rel must be finite and ≥ 0".into()));
    }
    if args.timeout.is_nan() || args.timeout <= 0.0 {
        return Err(Error::Invalid("--timeout must be positive".into()));
    }
    let cvxpy_max = parse_size(&args.cvxpy_max)?;
    // Read the given scenes and validate every method name before any long work.
    let given: Vec<GivenScene> = match &args.scenes {
        Some(dirs) => dirs
            .iter()
            .map(|d| GivenScene::read(d))
            .collect::<Result<_>>()?,
        None => Vec::new(),
    };
    let dims: Vec<usize> = if args.scenes.is_some() {
        let mut d: Vec<usize> = given.iter().map(|g| g.scene.dim).collect();
        d.sort_unstable();
        d.dedup();
        d
    } else {
        args.dim.clone()
    };
    for &dim in &dims {
        for m in methods_for(&args, dim) {
            bench::method_spec(&m, 1.0)?;
        }
    }
    let temp;
    let root = match &args.keep {
        Some(dir) => {
            std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
            dir.clone()
        }
        None => {
            temp = tempfile::tempdir().map_err(|e| Error::io("temporary folder", e))?;
            temp.path().to_path_buf()
        }
    };
    let exe = std::env::current_exe().map_err(|e| Error::io("grainforce executable", e))?;
    let mut results = Vec::new();
    let mut comparisons: Vec<CvxpyLine> = Vec::new();
    if args.cvxpy {
        cvxpy_setup(&script_path(&args))?;
    }
    let mut packings: Vec<GivenScene> = given;
    if args.scenes.is_none() {
        for &dim in &args.dim {
            for &size in &sizes {
                let mut spec = PackingSpec::new(dim, size);
                spec.seed = args.seed;
                spec.sliding =
                    args.sliding
                        .unwrap_or(if dim == 3 { DEFAULT_SLIDING_3D } else { 0.0 });
                let t = Instant::now();
                let packing = bench::generate(&spec)?;
                status!(
                    "{dim}D {size}: generated {} grains, {} contacts in {:.1} s ({} contacts at the Coulomb limit, {} with raised μ, equilibrium residual {:.1e})",
                    packing.scene.grains.len(),
                    packing.scene.contacts.len(),
                    t.elapsed().as_secs_f64(),
                    packing.sliding,
                    packing.raised_mu,
                    packing.equilibrium_residual
                );
                packings.push(GivenScene {
                    label: format!("{dim}d-{size}"),
                    scene: packing.scene,
                    truth: packing.truth,
                    radius: spec.radius,
                });
            }
        }
    }
    for packing in &packings {
        let (dim, size) = (packing.scene.dim, packing.scene.grains.len());
        {
            let lambda = args.lambda_rel * packing.radius;
            for &noise in &noises {
                let dir = root.join(format!("{}-{}", packing.label, noise.name()));
                let scene = bench::perturb(&packing.scene, noise, args.seed + 17);
                scene::write_scene(&dir, &scene)?;
                let truth_path = dir.join("truth.csv");
                scene::write_forces(&truth_path, &Forces::from_scene(&scene, &packing.truth))?;
                let first_case = results.len();
                for method in methods_for(&args, dim) {
                    for _ in 0..args.repeats {
                        let r = run_child(
                            &exe,
                            &dir,
                            &truth_path,
                            &method,
                            lambda,
                            noise,
                            dim,
                            size,
                            args.timeout,
                        );
                        status!("  {}", one_line(&r));
                        results.push(r);
                        // Keep the CSV current so an interrupted run keeps its cases.
                        if let Some(path) = &args.csv {
                            scene::write_file_atomically(path, bench::csv(&results)?.as_bytes())?;
                        }
                    }
                }
                fill_distances(&mut results[first_case..], &scene, &dir)?;
                drop(scene);
                if args.cvxpy && size <= cvxpy_max {
                    let c =
                        compare_cvxpy(&exe, &script_path(&args), &dir, &truth_path, args.timeout)?;
                    status!("  {}", c.line(dim, size, noise.name()));
                    comparisons.push((dim, size, noise.name(), c));
                }
            }
        }
    }
    finish(&args, &results, &dims, &noises, &comparisons)
}

/// A packing to run the matrix on, with its exact forces (per contact).
struct GivenScene {
    /// Names the case folders.
    label: String,
    scene: grainforce::scene::Scene,
    truth: Vec<grainforce::scene::Vec3>,
    /// Grain radius the fixed-λ variants scale with [m].
    radius: f64,
}

impl GivenScene {
    /// A scene folder and the exact forces in its forces.csv.
    fn read(dir: &Path) -> Result<Self> {
        let scene = scene::read_scene(dir)?;
        let truth_path = dir.join("forces.csv");
        if !truth_path.is_file() {
            return Err(Error::Invalid(format!(
                "--scenes: {} has no forces.csv with the exact forces to score against",
                dir.display()
            )));
        }
        let truth = scene::read_forces(&truth_path)?.for_scene(&scene, &truth_path)?;
        let mut radii: Vec<f64> = scene
            .grains
            .iter()
            .map(|g| g.radius.unwrap_or_else(|| g.equivalent_radius(scene.dim)))
            .filter(|r| r.is_finite() && *r > 0.0)
            .collect();
        if radii.is_empty() {
            return Err(Error::Invalid(format!(
                "--scenes: {} has no grain with a positive radius",
                dir.display()
            )));
        }
        radii.sort_by(f64::total_cmp);
        let name = dir
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "scene".into());
        Ok(GivenScene {
            label: format!("{}d-{}-{name}", scene.dim, scene.grains.len()),
            radius: radii[radii.len() / 2],
            scene,
            truth,
        })
    }
}

type CvxpyLine<'a> = (usize, usize, &'a str, Comparison);

/// Table, ratios, CSV and plot of finished results.
fn finish(
    args: &Args,
    results: &[CaseResult],
    dims: &[usize],
    noises: &[Noise],
    comparisons: &[CvxpyLine],
) -> Result<()> {
    let agg = bench::aggregate(results);
    let mut text = bench::markdown_table(&agg);
    text.push('\n');
    text.push_str(&ratios_text(&agg, dims, noises));
    for (dim, size, noise, c) in comparisons {
        text.push_str(&format!("- {}\n", c.line(*dim, *size, noise)));
    }
    print!("{text}");
    if let Some(path) = &args.csv {
        scene::write_file_atomically(path, bench::csv(results)?.as_bytes())?;
    }
    if let Some(path) = &args.markdown {
        scene::write_file_atomically(path, text.as_bytes())?;
    }
    if let Some(path) = &args.plot {
        let noise = [Noise::Stress, Noise::Geometry, Noise::None]
            .into_iter()
            .find(|n| noises.contains(n))
            .unwrap_or(Noise::None);
        let title = format!(
            "relerr vs time, {} noise (one point per size)",
            noise.name()
        );
        match bench::plot(&agg, noise.name(), &title) {
            Some(img) => grainforce::report::chart::save_png(path, &img)?,
            None => eprintln!("no successful case to plot"),
        }
        let title = format!(
            "distance to the tightest solve vs time, {} noise",
            noise.name()
        );
        if let Some(img) = bench::plot_distances(&agg, noise.name(), &title) {
            let stem = path.file_stem().unwrap_or_default().to_string_lossy();
            let distance_path = path.with_file_name(format!("{stem}-distance.png"));
            grainforce::report::chart::save_png(&distance_path, &img)?;
            status!("wrote {}", distance_path.display());
        }
    }
    Ok(())
}

fn methods_for(args: &Args, dim: usize) -> Vec<String> {
    match &args.methods {
        Some(m) => m
            .iter()
            .map(|s| s.trim().to_owned())
            .filter(|s| dim == 3 || !s.starts_with("qs-pyr"))
            .collect(),
        None => bench::default_methods(dim)
            .into_iter()
            .map(str::to_owned)
            .collect(),
    }
}

fn one_line(r: &CaseResult) -> String {
    match &r.error {
        None => format!(
            "{} {:>8.3} s  relerr {:.2e}  violation {:.1e}  {} it  {:.0} MB",
            r.method,
            r.time,
            r.relerr,
            r.coulomb_violation,
            r.iterations,
            r.peak_memory.unwrap_or(0) as f64 / 1048576.0
        ),
        Some(e) => format!("{} failed after {:.1} s: {e}", r.method, r.time),
    }
}

/// Constrained-vs-floor ratios per size and the scaling exponent of each method.
fn ratios_text(agg: &[CaseResult], dims: &[usize], noises: &[Noise]) -> String {
    let mut s = String::new();
    for &dim in dims {
        for noise in noises {
            let noise = noise.name();
            let mut methods: Vec<&str> = Vec::new();
            for r in agg.iter().filter(|r| r.dim == dim && r.noise == noise) {
                if !methods.contains(&r.method.as_str()) {
                    methods.push(&r.method);
                }
            }
            for m in &methods {
                if let Some(e) = bench::scaling_exponent(agg, dim, noise, m) {
                    s.push_str(&format!("- {dim}D, {noise} noise, {m}: time ∝ N^{e:.2}\n"));
                }
            }
        }
    }
    s
}

fn run_single(args: &Args) -> Result<()> {
    let (Some(dir), Some(truth_path), Some(method)) = (&args.scene, &args.truth, &args.method)
    else {
        return Err(Error::Invalid(
            "--single needs --scene, --truth and --method".into(),
        ));
    };
    let noise = args
        .noise
        .first()
        .and_then(|n| Noise::parse(n))
        .unwrap_or(Noise::None);
    let spec: MethodSpec = bench::method_spec(method, args.lambda.unwrap_or(0.0))?;
    let t = Instant::now();
    let scene = scene::read_scene(dir)?;
    let truth = scene::read_forces(truth_path)?.for_scene(&scene, truth_path)?;
    let load_time = t.elapsed().as_secs_f64();
    let (mut r, forces) = bench::run_case_with_forces(&scene, &truth, noise, &spec);
    if let (Some(path), Some(forces)) = (&args.forces_out, forces) {
        scene::write_forces(path, &Forces::from_scene(&scene, &forces))?;
    }
    r.load_time = load_time;
    r.peak_memory = bench::peak_memory();
    println!(
        "{}",
        serde_json::to_string(&r).map_err(|e| Error::Invalid(e.to_string()))?
    );
    Ok(())
}

/// Runs `cmd` with a wall-clock limit; returns (stdout, stderr, success, seconds)
/// or None on timeout.
fn run_limited(mut cmd: Command, timeout: f64) -> Result<Option<(String, String, bool, f64)>> {
    let start = Instant::now();
    let mut child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| Error::io("child process", e))?;
    let mut out = child.stdout.take();
    let mut err = child.stderr.take();
    // Drain the pipes on threads so a chatty child cannot block.
    let out_thread = std::thread::spawn(move || {
        let mut s = String::new();
        if let Some(o) = out.as_mut() {
            let _ = o.read_to_string(&mut s);
        }
        s
    });
    let err_thread = std::thread::spawn(move || {
        let mut s = String::new();
        if let Some(e) = err.as_mut() {
            let _ = e.read_to_string(&mut s);
        }
        s
    });
    loop {
        if let Some(status) = child
            .try_wait()
            .map_err(|e| Error::io("child process", e))?
        {
            let secs = start.elapsed().as_secs_f64();
            let o = out_thread.join().unwrap_or_default();
            let e = err_thread.join().unwrap_or_default();
            return Ok(Some((o, e, status.success(), secs)));
        }
        if start.elapsed().as_secs_f64() > timeout {
            let _ = child.kill();
            let _ = child.wait();
            return Ok(None);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[allow(clippy::too_many_arguments)]
fn run_child(
    exe: &Path,
    dir: &Path,
    truth: &Path,
    method: &str,
    lambda: f64,
    noise: Noise,
    dim: usize,
    size: usize,
    timeout: f64,
) -> CaseResult {
    let mut cmd = Command::new(exe);
    cmd.arg("bench")
        .arg("--single")
        .arg("--scene")
        .arg(dir)
        .arg("--truth")
        .arg(truth)
        .arg("--method")
        .arg(method)
        .arg("--lambda")
        .arg(lambda.to_string())
        .arg("--noise")
        .arg(noise.name())
        .arg("--forces-out")
        .arg(case_forces_path(dir, method));
    let fail =
        |msg: String, secs: f64| CaseResult::failed(dim, size, noise.name(), method, secs, msg);
    match run_limited(cmd, timeout) {
        Ok(Some((out, err, ok, secs))) => {
            let parsed = out
                .lines()
                .rev()
                .find_map(|l| serde_json::from_str::<CaseResult>(l).ok());
            match (parsed, ok) {
                (Some(r), true) => r,
                (None, true) => fail(
                    format!(
                        "the case's result could not be read: `{}`",
                        out.trim().lines().last().unwrap_or("")
                    ),
                    secs,
                ),
                _ => fail(
                    format!(
                        "child process failed: {}",
                        err.trim().lines().last().unwrap_or("no message")
                    ),
                    secs,
                ),
            }
        }
        Ok(None) => fail(format!("timeout after {timeout:.0} s"), timeout),
        Err(e) => fail(e.to_string(), 0.0),
    }
}

/// Where the child running `method` on the case folder `dir` writes its forces.
fn case_forces_path(dir: &Path, method: &str) -> PathBuf {
    dir.join(format!("forces-{method}.csv"))
}

/// Each case's distance to its method's tightest-tolerance solve on the same
/// scene (the `-tolX` variants), from the forces the children wrote.
fn fill_distances(cases: &mut [CaseResult], scene: &scene::Scene, dir: &Path) -> Result<()> {
    let mut forces = Vec::with_capacity(cases.len());
    for case in cases.iter() {
        let path = case_forces_path(dir, &case.method);
        forces.push(if case.ok() && path.is_file() {
            Some(scene::read_forces(&path)?.for_scene(scene, &path)?)
        } else {
            None
        });
    }
    let named: Vec<(&str, Option<&[grainforce::scene::Vec3]>)> = cases
        .iter()
        .zip(&forces)
        .map(|(c, f)| (c.method.as_str(), f.as_deref()))
        .collect();
    let distances = bench::distances_to_tightest(&named);
    for (case, distance) in cases.iter_mut().zip(distances) {
        case.distance = distance;
    }
    Ok(())
}

fn script_path(args: &Args) -> PathBuf {
    args.cvxpy_script
        .clone()
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/cvxpy/gem_cvxpy.py"))
}

fn venv_python(script: &Path) -> PathBuf {
    script
        .parent()
        .unwrap_or(Path::new("."))
        .join(".venv/bin/python")
}

/// Creates the script's venv (pip install cvxpy clarabel) once, untimed.
fn cvxpy_setup(script: &Path) -> Result<()> {
    if !script.is_file() {
        return Err(Error::Invalid(format!(
            "cvxpy script {} not found (give --cvxpy-script)",
            script.display()
        )));
    }
    status!("setting up the cvxpy venv (first use installs cvxpy and clarabel with pip)…");
    let status = Command::new("python3")
        .arg(script)
        .arg("--setup")
        .status()
        .map_err(|e| Error::io("python3", e))?;
    if !status.success() {
        return Err(Error::Invalid(
            "the cvxpy script could not set up its venv (see its output above)".into(),
        ));
    }
    Ok(())
}

struct Comparison {
    grainforce_time: f64,
    grainforce_relerr: f64,
    cvxpy_time: Option<f64>,
    cvxpy_solve_time: Option<f64>,
    cvxpy_relerr: Option<f64>,
    cvxpy_note: String,
}

impl Comparison {
    fn line(&self, dim: usize, size: usize, noise: &str) -> String {
        match self.cvxpy_time {
            Some(t) => format!(
                "{dim}D {size} grains, {noise} noise, end-to-end: grainforce infer (qs) {:.2} s (relerr {:.2e}) vs Python cvxpy+Clarabel {:.2} s (solve {:.2} s, relerr {:.2e}): {:.1}× faster",
                self.grainforce_time,
                self.grainforce_relerr,
                t,
                self.cvxpy_solve_time.unwrap_or(f64::NAN),
                self.cvxpy_relerr.unwrap_or(f64::NAN),
                t / self.grainforce_time
            ),
            None => format!(
                "{dim}D {size} grains, {noise} noise: grainforce infer (qs) {:.2} s; cvxpy failed: {}",
                self.grainforce_time, self.cvxpy_note
            ),
        }
    }
}

fn relerr_of(scene_dir: &Path, truth: &Path, forces: &Path) -> Result<f64> {
    let scene = scene::read_scene(scene_dir)?;
    let t = scene::read_forces(truth)?.for_scene(&scene, truth)?;
    let f = scene::read_forces(forces)?.for_scene(&scene, forces)?;
    Ok(grainforce::report::metrics::relative_error(&t, &f))
}

fn compare_cvxpy(
    exe: &Path,
    script: &Path,
    dir: &Path,
    truth: &Path,
    timeout: f64,
) -> Result<Comparison> {
    let gf_out = dir.join("forces-grainforce.csv");
    let mut cmd = Command::new(exe);
    cmd.arg("infer")
        .arg(dir)
        .arg("-o")
        .arg(&gf_out)
        .arg("--method")
        .arg("qs")
        .arg("--quiet");
    let (gf_time, gf_relerr) = match run_limited(cmd, timeout)? {
        Some((_, _, true, secs)) => (secs, relerr_of(dir, truth, &gf_out)?),
        Some((_, err, false, _)) => {
            return Err(Error::Solver(format!(
                "grainforce infer failed: {}",
                err.trim()
            )))
        }
        None => (f64::NAN, f64::NAN),
    };
    let py_out = dir.join("forces-cvxpy.csv");
    let mut cmd = Command::new(venv_python(script));
    cmd.arg(script).arg(dir).arg("-o").arg(&py_out);
    let mut c = Comparison {
        grainforce_time: gf_time,
        grainforce_relerr: gf_relerr,
        cvxpy_time: None,
        cvxpy_solve_time: None,
        cvxpy_relerr: None,
        cvxpy_note: String::new(),
    };
    match run_limited(cmd, timeout)? {
        Some((out, _, true, secs)) => {
            c.cvxpy_time = Some(secs);
            c.cvxpy_solve_time = out.lines().rev().find_map(|l| {
                serde_json::from_str::<serde_json::Value>(l)
                    .ok()
                    .and_then(|v| v.get("solve_time").and_then(|t| t.as_f64()))
            });
            c.cvxpy_relerr = relerr_of(dir, truth, &py_out).ok();
        }
        Some((_, err, false, _)) => {
            c.cvxpy_note = err.trim().lines().last().unwrap_or("").to_owned()
        }
        None => c.cvxpy_note = format!("timeout after {timeout:.0} s"),
    }
    Ok(c)
}
