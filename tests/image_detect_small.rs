//! Small disks (radius 6–12 px) at the defaults, on a dim dark field and
//! on a bright field: the scale at which real photographs were lost
//! (docs/image.md, round 12: `wc-slope-*` at half size, radii 6–15 px,
//! 0.70–0.82 of their disks). The packings are drawn here: disks placed at
//! random (fixed seed), each grown until it touches a neighbour, rendered
//! with 4 × 4 samples a pixel, blurred by the optics (σ 0.7 px), with
//! sensor noise (σ 2 grey levels).

use grainforce::image::{detect_images, DetectSettings, DetectedFrame};
use image::{GrayImage, Luma, Rgb, RgbImage};

const SIZE: usize = 260;

/// A small deterministic generator (64-bit LCG), uniform in [0, 1).
struct Random(u64);

impl Random {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }

    /// A standard normal deviate (Box–Muller).
    fn normal(&mut self) -> f64 {
        let (u, v) = (self.next().max(1e-12), self.next());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

/// Disks (x, y, r) of radius 6 or 9 placed at random without overlap until
/// 20 000 tries have been made, then each grown (up to 12 px) until it
/// touches its nearest neighbour or the picture's edge: a dense packing of
/// radii 6–12 with contacts.
fn packing(seed: u64) -> Vec<[f64; 3]> {
    let mut random = Random(seed);
    let mut disks: Vec<[f64; 3]> = Vec::new();
    let size = SIZE as f64;
    for _ in 0..20_000 {
        let r = if random.next() < 0.5 { 6.0 } else { 9.0 };
        let x = r + 1.0 + (size - 2.0 * r - 2.0) * random.next();
        let y = r + 1.0 + (size - 2.0 * r - 2.0) * random.next();
        if disks.iter().all(|d| (x - d[0]).hypot(y - d[1]) >= r + d[2]) {
            disks.push([x, y, r]);
        }
    }
    for i in 0..disks.len() {
        let [x, y, _] = disks[i];
        let nearest = (disks.iter().enumerate())
            .filter(|&(j, _)| j != i)
            .map(|(_, d)| (x - d[0]).hypot(y - d[1]) - d[2])
            .fold(f64::INFINITY, f64::min);
        let edge = x.min(y).min(size - 1.0 - x).min(size - 1.0 - y);
        disks[i][2] = nearest.min(edge).min(12.0);
    }
    disks
}

/// Pale teal disks with a darker rim (the outer 0.15 R) on a white
/// backlight.
fn teal_on_white(inside: Option<(usize, f64)>) -> [f64; 3] {
    match inside {
        None => [250.0; 3],
        Some((_, t)) if t > 0.85 => [70.0, 100.0, 80.0],
        Some(_) => [130.0, 170.0, 150.0],
    }
}

/// The picture, one value per channel and pixel: each of 4 × 4 samples a
/// pixel takes `shade(disk index and distance over radius, or None)`; then
/// the optics' blur (σ 0.7 px) and the sensor's noise (σ 2 grey levels).
fn render(
    disks: &[[f64; 3]],
    seed: u64,
    shade: impl Fn(Option<(usize, f64)>) -> [f64; 3],
) -> Vec<[f64; 3]> {
    const S: usize = 4;
    let n = SIZE * S;
    // Which disk each sample lies in (the disks do not overlap).
    let mut label: Vec<Option<(usize, f64)>> = vec![None; n * n];
    // Sample (i, j) is at pixel coordinates ((j + ½)/S − ½, …): pixel (x, y)
    // is centred on the point (x, y), as the detector reads it.
    let at = |k: usize| (k as f64 + 0.5) / S as f64 - 0.5;
    for (k, d) in disks.iter().enumerate() {
        let lo = |c: f64| (((c - d[2] + 0.5) * S as f64).floor().max(0.0)) as usize;
        let hi = |c: f64| ((((c + d[2] + 0.5) * S as f64).ceil()) as usize).min(n - 1);
        for i in lo(d[1])..=hi(d[1]) {
            for j in lo(d[0])..=hi(d[0]) {
                let t = (at(j) - d[0]).hypot(at(i) - d[1]) / d[2];
                if t <= 1.0 {
                    label[i * n + j] = Some((k, t));
                }
            }
        }
    }
    let mut picture = vec![[0.0; 3]; SIZE * SIZE];
    for (p, value) in picture.iter_mut().enumerate() {
        let (y, x) = (p / SIZE, p % SIZE);
        for i in y * S..(y + 1) * S {
            for j in x * S..(x + 1) * S {
                let v = shade(label[i * n + j]);
                (0..3).for_each(|c| value[c] += v[c] / (S * S) as f64);
            }
        }
    }
    let blurred = blur(&picture, 0.7);
    let mut random = Random(seed);
    blurred
        .into_iter()
        .map(|v| v.map(|c| c + 2.0 * random.normal()))
        .collect()
}

/// Separable Gaussian blur (kernel to ±3σ, edges extended).
fn blur(picture: &[[f64; 3]], sigma: f64) -> Vec<[f64; 3]> {
    let reach = (3.0 * sigma).ceil() as isize;
    let kernel: Vec<f64> = (-reach..=reach)
        .map(|k| (-(k * k) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let total: f64 = kernel.iter().sum();
    let pass = |input: &[[f64; 3]], step: (isize, isize)| -> Vec<[f64; 3]> {
        (0..SIZE * SIZE)
            .map(|p| {
                let (y, x) = ((p / SIZE) as isize, (p % SIZE) as isize);
                let mut sum = [0.0; 3];
                for (t, w) in kernel.iter().enumerate() {
                    let o = t as isize - reach;
                    let clamp = |v: isize| v.clamp(0, SIZE as isize - 1) as usize;
                    let q = clamp(y + o * step.1) * SIZE + clamp(x + o * step.0);
                    (0..3).for_each(|c| sum[c] += w * input[q][c] / total);
                }
                sum
            })
            .collect()
    };
    pass(&pass(picture, (1, 0)), (0, 1))
}

fn detect(path: &std::path::Path, radius: [f64; 2]) -> DetectedFrame {
    let settings = DetectSettings::new(radius[0], radius[1], 1000.0);
    let detection =
        detect_images(&[path.to_path_buf()], &settings, &mut |_, _, _, _| Ok(())).expect("detect");
    detection.frames.into_iter().next().expect("a frame")
}

/// The picture written as an 8-bit gray PNG (its first channel) in `dir`.
fn save_gray(picture: &[[f64; 3]], name: &str, dir: &tempfile::TempDir) -> std::path::PathBuf {
    let image = GrayImage::from_fn(SIZE as u32, SIZE as u32, |x, y| {
        Luma([picture[y as usize * SIZE + x as usize][0]
            .round()
            .clamp(0.0, 255.0) as u8])
    });
    let path = dir.path().join(name);
    image.save(&path).unwrap();
    path
}

/// The picture written as an 8-bit RGB PNG in `dir`.
fn save_rgb(picture: &[[f64; 3]], name: &str, dir: &tempfile::TempDir) -> std::path::PathBuf {
    let image = RgbImage::from_fn(SIZE as u32, SIZE as u32, |x, y| {
        let v = picture[y as usize * SIZE + x as usize];
        Rgb(v.map(|c| c.round().clamp(0.0, 255.0) as u8))
    });
    let path = dir.path().join(name);
    image.save(&path).unwrap();
    path
}

/// The share of the disks found within half a radius of their centre (one
/// to one, as `match.py` scores real photographs), the false ones, and the
/// median centre error in radii.
fn score(disks: &[[f64; 3]], found: &DetectedFrame) -> (f64, usize, f64) {
    let mut taken = vec![false; found.disks.len()];
    let mut errors = Vec::new();
    for d in disks {
        let best = (found.disks.iter().enumerate())
            .filter(|(k, _)| !taken[*k])
            .map(|(k, f)| ((f.x - d[0]).hypot(f.y - d[1]), k))
            .min_by(|a, b| a.0.total_cmp(&b.0));
        if let Some((e, k)) = best.filter(|b| b.0 < 0.5 * d[2]) {
            taken[k] = true;
            errors.push(e / d[2]);
        }
    }
    errors.sort_by(f64::total_cmp);
    let median = errors.get(errors.len() / 2).copied().unwrap_or(f64::NAN);
    let hits = errors.len();
    (
        hits as f64 / disks.len() as f64,
        found.disks.len() - hits,
        median,
    )
}

fn assert_found(disks: &[[f64; 3]], found: &DetectedFrame, what: &str, recall: f64) {
    let (share, false_ones, centre) = score(disks, found);
    println!(
        "{what}: {share:.3} of {} found, {false_ones} false, centres {centre:.3} R ({})",
        disks.len(),
        found.choice.describe()
    );
    assert!(share >= recall, "{what}: {share:.3} of the disks found");
    assert!(false_ones <= 1, "{what}: {false_ones} false");
    assert!(centre <= 0.05, "{what}: median centre error {centre} R");
}

/// A monochrome camera's dark field: interiors of 25–70 grey levels over a
/// background of 3, a brighter outer ring, no dark rim. Up-sampled to radii
/// of 12 px and more 218 of the 226 disks are found (0.965); searched in
/// its own pixels (the up-sampling turned off, `SMALL_DISK_RADIUS` 0) 213
/// (0.942); both searches merged (round 13) 222 (0.982): the floor fails
/// with either alone. The same
/// drawing in numpy, three seeds, scored by the release CLI: 0.934–0.956
/// before this round, 0.967–0.974 after.
#[test]
fn small_disks_on_a_dim_dark_field() {
    let disks = packing(1);
    let mut random = Random(7);
    let levels: Vec<f64> = disks.iter().map(|_| 25.0 + 45.0 * random.next()).collect();
    let picture = render(&disks, 2, |inside| match inside {
        None => [3.0; 3],
        Some((k, t)) => [levels[k] + if t > 0.88 { 40.0 } else { 0.0 }; 3],
    });
    let dir = tempfile::tempdir().unwrap();
    let path = save_gray(&picture, "dark.png", &dir);
    assert_found(&disks, &detect(&path, [6.0, 12.0]), "dark field", 0.975);
}

/// Pale teal disks with a darker rim on a white backlight: all 226 disks
/// up-sampled, 222 in its own pixels (0.982: fails the 0.99 floor). In numpy,
/// three seeds:
/// 0.979–0.996 before this round, 0.996–1.000 after.
#[test]
fn small_disks_on_a_bright_field() {
    let disks = packing(1);
    let picture = render(&disks, 3, teal_on_white);
    let dir = tempfile::tempdir().unwrap();
    let path = save_rgb(&picture, "bright.png", &dir);
    assert_found(&disks, &detect(&path, [6.0, 12.0]), "bright field", 0.99);
}

/// A hexagonal packing (centres `spacing` apart, disk k of radius
/// `radius(k)`) filling the picture: with touching disks no background
/// shows between them but the small triangles where three meet, so few
/// rays of a disk find an outline (docs/image.md, round 13).
fn hexagonal(spacing: f64, radius: impl Fn(usize) -> f64) -> Vec<[f64; 3]> {
    let mut disks = Vec::new();
    let size = SIZE as f64;
    let row = spacing * 3f64.sqrt() / 2.0;
    for i in 0.. {
        let y = spacing / 2.0 + row * i as f64;
        if y + spacing / 2.0 > size - 1.0 {
            break;
        }
        let shift = if i % 2 == 1 { spacing / 2.0 } else { 0.0 };
        for j in 0.. {
            let x = spacing / 2.0 + shift + spacing * j as f64;
            if x + spacing / 2.0 > size - 1.0 {
                break;
            }
            let r = radius(disks.len());
            disks.push([x, y, r]);
        }
    }
    disks
}

/// A dark field of touching disks: dim interiors, bright rims.
fn hex_dark(disks: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let mut random = Random(11);
    let levels: Vec<f64> = disks.iter().map(|_| 25.0 + 45.0 * random.next()).collect();
    render(disks, 4, |inside| match inside {
        None => [3.0; 3],
        Some((k, t)) => [levels[k] + if t > 0.88 { 40.0 } else { 0.0 }; 3],
    })
}

/// Touching disks of radius 10 in a dark field: only the triangles between
/// the disks show the background. The rims' bin (70 grey levels) was read
/// as the background, the most common of the brightest by a little (11 241
/// pixels against the dark triangles' 9 853), and 110 of 168 (0.655) were
/// found; now the dark triangles' (the nearly as full bin farther from the
/// median pixel, round 14), 165 (0.982), none false.
#[test]
fn hex_dark_field() {
    let disks = hexagonal(20.0, |_| 10.0);
    let dir = tempfile::tempdir().unwrap();
    let path = save_gray(&hex_dark(&disks), "hex-dark.png", &dir);
    assert_found(&disks, &detect(&path, [8.0, 12.0]), "hex dark", 0.97);
}

/// Touching teal disks of radius 10 with a darker rim on white: up-sampled
/// with the support's tolerance in the up-sampled pixels (half a
/// photograph's pixel) 26 of 168 (0.155, centres 0.08 R); in the picture's
/// own pixels 60 (0.357); now, the tolerance one photograph's pixel and
/// both searches merged, 134 (0.798).
#[test]
fn hex_bright_field() {
    let disks = hexagonal(20.0, |_| 10.0);
    let picture = render(&disks, 5, teal_on_white);
    let dir = tempfile::tempdir().unwrap();
    let path = save_rgb(&picture, "hex-bright.png", &dir);
    assert_found(&disks, &detect(&path, [8.0, 12.0]), "hex bright", 0.78);
}

/// A slightly polydisperse hexagonal packing in a dark field (radii
/// 9–10.5 px, centres 21 px apart): up-sampled 135 of 161 (0.839), in its
/// own pixels 145 (0.901), both merged 146 (0.907); with the dark
/// background between the disks read as the background (round 14, as in
/// [`hex_dark_field`]), 161 (1.000).
#[test]
fn hex_polydisperse_dark_field() {
    let mut random = Random(13);
    let radii: Vec<f64> = (0..400).map(|_| 9.0 + 1.5 * random.next()).collect();
    let disks = hexagonal(21.0, |k| radii[k]);
    let dir = tempfile::tempdir().unwrap();
    let path = save_gray(&hex_dark(&disks), "hex-poly.png", &dir);
    assert_found(&disks, &detect(&path, [8.0, 12.0]), "hex poly dark", 0.99);
}
