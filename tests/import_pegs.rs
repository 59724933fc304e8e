//! The PeGS importer on PeGS2-like files written by scipy.io.savemat from a
//! known scene (fixtures/import/pegs/make_pegs_fixture.py: the 2D oedometer
//! DEM fixture drawn at 10000 px/m in a 760 px high image, disks 5 mm thick).

mod common;
use common::grainforce;
use grainforce::import::pegs::{import, Options, ScaleSource};
use grainforce::import::{mat5, ImportedScene};
use grainforce::scene::{self, read_forces, read_scene, Body, Scene, Vec3};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

const PX_PER_M: f64 = 10000.0;
const HEIGHT: u32 = 760;
const THICKNESS: f64 = 0.005;

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures/import/pegs")
        .join(name)
}

fn truth() -> (Scene, Vec<Vec3>) {
    common::fixture("oedometer")
}

fn solved(name: &str) -> ImportedScene {
    let options = Options {
        centres: Some(fixture("box_centers.txt")),
        image_height: Some(HEIGHT),
        thickness: Some(THICKNESS),
        ..Options::default()
    };
    let (imported, conversion) = import(&fixture(name), &options).unwrap();
    assert_eq!(conversion.scale_source, ScaleSource::File);
    assert_eq!(conversion.px_per_m, PX_PER_M);
    imported
}

fn close(a: Vec3, b: Vec3, tol: f64) -> bool {
    scene::norm(scene::sub(a, b)) <= tol
}

/// Truth contacts by (PeGS id of a, PeGS id or wall of b): PeGS ids are the
/// truth ids + 1.
fn truth_contacts(t: &Scene, f: &[Vec3]) -> HashMap<(String, String), (usize, Vec3)> {
    let pegs_id = |g: usize| (t.grains[g].id.parse::<usize>().unwrap() + 1).to_string();
    t.contacts
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let b = match c.b {
                Body::Grain(b) => pegs_id(b),
                Body::Wall(w) => t.walls[w].name.clone(),
            };
            ((pegs_id(c.a), b), (k, f[k]))
        })
        .collect()
}

#[test]
fn solved_files_give_the_scene_they_were_made_from() {
    let (t, tf) = truth();
    let plain = solved("box_solved.mat");
    let mut compressed = solved("box_solved_compressed.mat");
    compressed.frames[0].settings.description = plain.frames[0].settings.description.clone();
    assert!(plain == compressed, "compressed and plain files differ");
    assert!(plain.warnings.is_empty(), "{:?}", plain.warnings);
    let s = &plain.frames[0];
    let forces = &plain.forces.as_ref().expect("solved file has forces")[0];
    assert_eq!(s.dim, 2);
    assert_eq!(s.settings.thickness, Some(THICKNESS));
    assert_eq!(s.grains.len(), t.grains.len());
    for (g, tg) in s.grains.iter().zip(&t.grains) {
        let r = tg.radius.unwrap();
        assert_eq!(g.id, (tg.id.parse::<usize>().unwrap() + 1).to_string());
        assert!(close(g.position, tg.position, 1e-9 * r), "grain {}", g.id);
        assert!((g.radius.unwrap() - r).abs() <= 1e-9 * r, "grain {}", g.id);
        assert!((g.volume - tg.volume).abs() <= 1e-9 * tg.volume);
    }

    let want = truth_contacts(&t, &tf);
    assert_eq!(s.contacts.len(), want.len());
    let mut wall_contacts = 0;
    for (c, f) in s.contacts.iter().zip(forces) {
        let a = s.grains[c.a].id.clone();
        let b = match c.b {
            Body::Grain(b) => s.grains[b].id.clone(),
            Body::Wall(w) => s.walls[w].name.clone(),
        };
        // The truth may list the pair the other way round.
        let (k, tfk, sign) = match (
            want.get(&(a.clone(), b.clone())),
            want.get(&(b.clone(), a.clone())),
        ) {
            (Some(&(k, f)), _) => (k, f, 1.0),
            (None, Some(&(k, f))) => (k, f, -1.0),
            _ => panic!("contact {a}-{b} is not in the truth"),
        };
        let tc = &t.contacts[k];
        let size = tf.iter().map(|x| scene::norm(*x)).fold(0.0, f64::max);
        assert!(
            close(*f, tfk.map(|x| sign * x), 1e-9 * size),
            "force of {a}-{b}: {f:?} vs {tfk:?}"
        );
        assert!(
            close(c.normal, tc.normal.map(|x| sign * x), 1e-9),
            "normal of {a}-{b}"
        );
        let r = s.grains[c.a].radius.unwrap();
        match c.b {
            Body::Grain(_) => assert!(close(c.point, tc.point, 1e-9 * r), "point of {a}-{b}"),
            Body::Wall(_) => {
                wall_contacts += 1;
                // PeGS has no overlap: the point is on the rim, the DEM's
                // in the middle of the overlap, δ/2 (< 0.3 % of R) away.
                let rim = scene::norm(scene::sub(c.point, s.grains[c.a].position));
                assert!((rim - r).abs() <= 1e-9 * r);
                assert!(close(c.point, tc.point, 3e-3 * r), "point of {a}-{b}");
            }
        }
    }
    assert_eq!(wall_contacts, 20);
    for name in ["left", "right", "bottom", "top"] {
        assert!(s.wall_index(name).is_some(), "wall {name}");
    }

    // Stresses follow from the forces: away from the walls they are the
    // truth's (whose wall contact points differ by δ/2).
    let touches_wall: Vec<bool> = (0..s.grains.len())
        .map(|g| {
            s.contacts
                .iter()
                .any(|c| c.a == g && matches!(c.b, Body::Wall(_)))
        })
        .collect();
    for (g, (sg, tg)) in s.grains.iter().zip(&t.grains).enumerate() {
        if touches_wall[g] {
            continue;
        }
        let size = tg.stress.iter().map(|x| x.abs()).fold(0.0, f64::max);
        for k in 0..6 {
            assert!(
                (sg.stress[k] - tg.stress[k]).abs() <= 1e-9 * size,
                "stress of {}",
                sg.id
            );
        }
    }
}

#[test]
fn without_the_centres_file_radii_are_the_rounded_ones() {
    let (t, _) = truth();
    let options = Options {
        image_height: Some(HEIGHT),
        ..Options::default()
    };
    let (imported, conversion) = import(&fixture("box_solved.mat"), &options).unwrap();
    assert_eq!(conversion.px_per_m, PX_PER_M);
    let s = &imported.frames[0];
    for (g, tg) in s.grains.iter().zip(&t.grains) {
        let px = tg.radius.unwrap() * PX_PER_M;
        let r = g.radius.unwrap() * PX_PER_M;
        assert!((r - px.round()).abs() < 1e-9, "grain {}: {r} px", g.id);
        assert!(close(g.position, tg.position, 1e-9));
    }
    // Without --thickness the forces are PeGS's newtons, per metre.
    let (_, tf) = truth();
    let f = &imported.forces.as_ref().unwrap()[0];
    let total: f64 = f.iter().map(|x| scene::norm(*x)).sum();
    let want: f64 = tf.iter().map(|x| scene::norm(*x)).sum::<f64>() * THICKNESS;
    assert!((total - want).abs() <= 1e-9 * want);
    assert_eq!(s.settings.thickness, None);
}

#[test]
fn explicit_scale_and_missing_height() {
    let options = Options {
        px_per_m: Some(2.0 * PX_PER_M),
        ..Options::default()
    };
    let (imported, conversion) = import(&fixture("box_solved.mat"), &options).unwrap();
    assert_eq!(conversion.scale_source, ScaleSource::Given);
    assert!(!conversion.height_given);
    // The lowest disk edge becomes y = ½ px above the scene's zero.
    let s = &imported.frames[0];
    let lowest = s
        .grains
        .iter()
        .map(|g| g.position[1] - g.radius.unwrap())
        .fold(f64::INFINITY, f64::min);
    assert!((0.0..1.5 / (2.0 * PX_PER_M)).contains(&lowest), "{lowest}");
}

/// Each contact is fitted on both disks; the reference is the mean of disk
/// a's fit and minus disk b's. Disks 1-2-3 in a row along x (pixels):
/// disk 1 fits f = 2, α = 0 at β = 0 → (−2, 0); disk 2 fits f = 1, α = 0.1 at
/// β = π, i.e. on disk 2 −(cos(π − 0.1), sin(π − 0.1)) in pixels (y down).
#[test]
fn the_two_fits_of_a_contact_are_averaged() {
    let (imported, conversion) = import(&fixture("two_fits.mat"), &Options::default()).unwrap();
    assert_eq!(conversion.scale_source, ScaleSource::Pixels);
    let f = &imported.forces.as_ref().unwrap()[0];
    let (c, s) = (0.1f64.cos(), 0.1f64.sin());
    // On disk 2 by 1, scene frame (y up): (c, s); on 1 by 2: (−c, −s).
    let want = [
        [-(2.0 + c) / 2.0, -s / 2.0, 0.0],
        [-(c + 3.0) / 2.0, s / 2.0, 0.0],
    ];
    for (k, w) in want.iter().enumerate() {
        assert!(close(f[k], *w, 1e-12), "contact {k}: {:?} vs {w:?}", f[k]);
    }
    let ids: Vec<&str> = imported.frames[0]
        .contacts
        .iter()
        .map(|c| c.id.as_str())
        .collect();
    assert_eq!(ids, ["1-2", "2-3"]);
    assert!(
        imported.warnings.iter().any(|w| w.contains("100.4 %")),
        "{:?}",
        imported.warnings
    );
}

#[test]
fn pegs1_neighbours_by_index_are_recognised() {
    let (imported, _) = import(&fixture("pegs1_indices.mat"), &Options::default()).unwrap();
    let ids: Vec<&str> = imported.frames[0]
        .contacts
        .iter()
        .map(|c| c.id.as_str())
        .collect();
    assert_eq!(ids, ["10-20", "20-30"]);
    assert!(imported.warnings.iter().any(|w| w.contains("indices")));
}

#[test]
fn contact_detect_output_has_contacts_but_no_forces() {
    let (imported, _) = import(&fixture("box_contacts.mat"), &Options::default()).unwrap();
    assert!(imported.forces.is_none());
    assert_eq!(imported.frames[0].contacts.len(), 93);
    assert!(imported.warnings.iter().any(|w| w.contains("strain")));
}

/// Every truncation of a compressed and of a plain file is an error, never a
/// panic, and names where it went wrong; so is every single flipped byte
/// (those may also still read).
#[test]
fn corrupt_bytes_give_errors_not_panics() {
    for name in ["box_solved_compressed.mat", "two_fits.mat"] {
        let bytes = std::fs::read(fixture(name)).unwrap();
        assert!(mat5::parse(&bytes, mat5::MAX_INFLATED).is_ok());
        for cut in 0..bytes.len() {
            match mat5::parse(&bytes[..cut], mat5::MAX_INFLATED) {
                // The header alone is a valid file without variables.
                Ok(v) if cut == 128 && v.is_empty() => {}
                Ok(_) => panic!("{name} cut at {cut} read"),
                Err(e) => assert!(e.contains("byte") || e.contains("header"), "{e}"),
            }
        }
        let mut flipped = bytes.clone();
        for (k, &original) in bytes.iter().enumerate().take(3000) {
            flipped[k] ^= 0xa5;
            let _ = mat5::parse(&flipped, 1 << 20);
            flipped[k] = original;
        }
    }
}

/// A zip bomb is refused at the cap instead of filling memory.
#[test]
fn inflation_is_capped() {
    let bytes = std::fs::read(fixture("box_solved_compressed.mat")).unwrap();
    let e = mat5::parse(&bytes, 1000).unwrap_err();
    assert!(e.contains("inflates to more than 1000 bytes"), "{e}");
}

// The command line: import → infer → score, and bad files.

fn s(p: &Path) -> String {
    p.to_str().unwrap().to_owned()
}

#[test]
fn import_infer_score() {
    let dir = tempfile::tempdir().unwrap();
    // A PNG named .jpg: the size is read from the bytes, not the name (the
    // PeGS2 test image Step09-0001.jpg is a TIFF).
    let png = dir.path().join("photo.png");
    image::GrayImage::new(800, HEIGHT).save(&png).unwrap();
    let photo = dir.path().join("photo.jpg");
    std::fs::rename(&png, &photo).unwrap();
    let out = dir.path().join("scene");
    let (ok, _, err) = grainforce(&[
        "import",
        "pegs",
        &s(&fixture("box_solved_compressed.mat")),
        &s(&fixture("box_centers.txt")),
        "-o",
        &s(&out),
        "--image",
        &s(&photo),
        "--thickness",
        "0.005",
    ]);
    assert!(ok, "{err}");
    assert!(err.contains("58 grains, 93 contacts"), "{err}");
    let frame = grainforce::image::PixelFrame::read(&out.join("image-frame.json")).unwrap();
    assert_eq!(
        (frame.px_per_m, frame.width, frame.height),
        (PX_PER_M, 800, HEIGHT)
    );
    // The written scene is the truth's, placed as detect would place it.
    let (t, _) = truth();
    let written = read_scene(&out).unwrap();
    for (g, tg) in written.grains.iter().zip(&t.grains) {
        assert!(close(g.position, tg.position, 1e-12), "grain {}", g.id);
    }

    let inferred = dir.path().join("inferred.csv");
    let (ok, _, err) = grainforce(&["infer", &s(&out), "-o", &s(&inferred), "-q"]);
    assert!(ok, "{err}");
    let report = dir.path().join("score.json");
    let (ok, stdout, err) = grainforce(&[
        "score",
        &s(&out.join("forces.csv")),
        &s(&inferred),
        "--scene",
        &s(&out),
        "--report",
        &s(&report),
    ]);
    assert!(ok, "{err}");
    assert!(stdout.contains("contacts scored: 93"), "{stdout}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    // PeGS's forces here balance every disk, so the stresses they imply
    // determine them: infer recovers them.
    let relerr = json["overall"]["error"]["relative"].as_f64().unwrap();
    assert!(relerr < 1e-6, "relative error {relerr}");
}

/// A bad file: non-zero exit, the file named, nothing written.
fn refused(inputs: &[&Path], needle: &str) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("scene");
    let mut args = vec!["import".to_owned(), "pegs".to_owned()];
    args.extend(inputs.iter().map(|p| s(p)));
    args.extend(["-o".to_owned(), s(&out)]);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let (ok, _, err) = grainforce(&args);
    assert!(!ok, "{inputs:?} was accepted");
    let named = inputs.iter().any(|p| err.contains(&s(p)));
    assert!(named, "the error does not name the file: {err}");
    assert!(err.contains(needle), "expected `{needle}` in: {err}");
    assert!(!out.exists(), "output written for {inputs:?}");
}

#[test]
fn bad_files_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let good = std::fs::read(fixture("box_solved_compressed.mat")).unwrap();
    let plain = std::fs::read(fixture("box_solved.mat")).unwrap();
    let write = |name: &str, bytes: &[u8]| {
        let p = dir.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    };
    let truncated = write("truncated.mat", &good[..good.len() / 2]);
    refused(&[&truncated], "runs past the end");
    let mut scrambled = good.clone();
    for b in &mut scrambled[300..340] {
        *b ^= 0x5a;
    }
    let scrambled = write("scrambled.mat", &scrambled);
    refused(&[&scrambled], "does not inflate");
    let truncated_plain = write("truncated_plain.mat", &plain[..plain.len() / 2]);
    refused(&[&truncated_plain], "runs past the end");
    let mut magic = good.clone();
    magic[126..128].copy_from_slice(b"XX");
    let magic = write("magic.mat", &magic);
    refused(&[&magic], "not a MAT v5 file");
    let mut v73 = good.clone();
    v73[..10].copy_from_slice(b"MATLAB 7.3");
    let v73 = write("v73.mat", &v73);
    refused(&[&v73], "v7.3");
    refused(&[&fixture("missing_betas.mat")], "not `betas`");
    // Centres file first: not a MAT-file.
    refused(&[&fixture("box_centers.txt")], "not a MAT");
    // The centres of another image.
    refused(
        &[&fixture("two_fits.mat"), &fixture("box_centers.txt")],
        "same image",
    );
    let bad_row = write("centres.txt", b"1,2,3,4\n5,6,x,8\n");
    refused(&[&fixture("two_fits.mat"), &bad_row], "line 2");
}

#[test]
fn other_formats_still_need_two_files() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("scene");
    let (ok, _, err) = grainforce(&[
        "import",
        "yade",
        &s(&fixture("box_centers.txt")),
        "-o",
        &s(&out),
    ]);
    assert!(!ok && err.contains("needs two input files, got 1"), "{err}");
    assert!(!out.exists());
}

/// PeGS's fits carry errors, independently on the two disks of a contact
/// (box_solved_noisy.mat: f off by 5 %, α by 0.05 rad, sd). The mean of the
/// two fits is the reference; `infer` on the stresses it implies, with every
/// disk balanced, lands closer to the DEM's forces than PeGS's own answer.
#[test]
fn balancing_noisy_fits_brings_them_closer_to_the_truth() {
    let (t, tf) = truth();
    let options = Options {
        centres: Some(fixture("box_centers.txt")),
        image_height: Some(HEIGHT),
        thickness: Some(THICKNESS),
        ..Options::default()
    };
    let (imported, _) = import(&fixture("box_solved_noisy.mat"), &options).unwrap();
    assert!(
        imported
            .warnings
            .iter()
            .any(|w| w.contains("the two fits of a contact differ")),
        "{:?}",
        imported.warnings
    );
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("scene");
    imported.write(&out).unwrap();
    let inferred_path = dir.path().join("inferred.csv");
    let (ok, _, err) = grainforce(&["infer", &s(&out), "-o", &s(&inferred_path), "-q"]);
    assert!(ok, "{err}");
    let scene = &imported.frames[0];
    let inferred = read_forces(&inferred_path)
        .unwrap()
        .for_scene(scene, &inferred_path)
        .unwrap();
    let pegs = &imported.forces.as_ref().unwrap()[0];
    // The truth, contact by contact in the imported order and orientation.
    let want = truth_contacts(&t, &tf);
    let truth: Vec<Vec3> = scene
        .contacts
        .iter()
        .map(|c| {
            let a = scene.grains[c.a].id.clone();
            let b = match c.b {
                Body::Grain(b) => scene.grains[b].id.clone(),
                Body::Wall(w) => scene.walls[w].name.clone(),
            };
            match want.get(&(a.clone(), b.clone())) {
                Some(&(_, f)) => f,
                None => want[&(b, a)].1.map(|x| -x),
            }
        })
        .collect();
    let relerr = |f: &[Vec3]| {
        let e: f64 = f
            .iter()
            .zip(&truth)
            .map(|(x, y)| scene::norm(scene::sub(*x, *y)).powi(2))
            .sum();
        let n: f64 = truth.iter().map(|y| scene::norm(*y).powi(2)).sum();
        (e / n).sqrt()
    };
    let (pegs_err, infer_err) = (relerr(pegs), relerr(&inferred));
    // Measured: 0.045 and 0.024.
    assert!(
        pegs_err > 0.02 && pegs_err < 0.08,
        "PeGS's relerr {pegs_err}"
    );
    assert!(
        infer_err < 0.75 * pegs_err,
        "infer {infer_err} vs PeGS {pegs_err}"
    );
}

/// `$GRAINFORCE_TEST_DATA/real-photos/NAME` (the experimenters' files, not
/// shipped with grainforce), or `None` with a skip message.
fn real_photos(name: &str) -> Option<PathBuf> {
    match std::env::var_os("GRAINFORCE_TEST_DATA") {
        Some(root) => Some(PathBuf::from(root).join("real-photos").join(name)),
        None => {
            println!("skipped: GRAINFORCE_TEST_DATA is not set (it names the folder holding real-photos/)");
            None
        }
    }
}

/// Lines `x,y,…` (or `a,b,…` after a header) of a small text table.
fn table(path: &Path, skip: usize) -> Vec<Vec<f64>> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .skip(skip)
        .filter(|l| !l.trim().is_empty())
        .map(|l| l.split(',').map(|v| v.trim().parse().unwrap()).collect())
        .collect()
}

/// The real PeGS 1.x files (Junyi Lin's runs of PeGSDiskPrep and
/// PeGSDiskSolve on his photographs): the disks and the contact lists come
/// out as the files hold them (checked against the tables the data's
/// SOURCE.md derived with scipy), and a solved file's forces are PeGS's.
#[test]
fn real_pegs1_preprocessing_and_solved_files() {
    let Some(root) = real_photos("") else {
        return;
    };
    // folder, file, centres table, contacts table, disk-wall contacts, solved
    let cases = [
        (
            "jlin-fixed48",
            "image2_preprocessing.mat",
            "image2_centers.txt",
            "image2_contacts_ref.csv",
            13,
            false,
        ),
        (
            "jlin-fixed48",
            "image2_solved.mat",
            "image2_centers.txt",
            "image2_contacts_ref.csv",
            13,
            true,
        ),
        (
            "jlin-narrow21",
            "image_preprocessing.mat",
            "image_centers.txt",
            "image_contacts_ref.csv",
            14,
            false,
        ),
        (
            "jlin-narrow21",
            "image_solved.mat",
            "image_solved_centers.txt",
            "image_solved_contacts_ref.csv",
            11,
            true,
        ),
        (
            "jlin-step83",
            "image3_preprocessing.mat",
            "image3_centers.txt",
            "image3_contacts_ref.csv",
            24,
            false,
        ),
        (
            "jlin-step83",
            "image3_solved.mat",
            "image3_solved_centers.txt",
            "image3_solved_contacts_ref.csv",
            13,
            true,
        ),
        (
            "jlin-iphone83",
            "image4_preprocessing.mat",
            "image4_centers.txt",
            "image4_contacts_ref.csv",
            25,
            false,
        ),
    ];
    for (folder, file, centres, pairs, walls, is_solved) in cases {
        let dir = root.join(folder);
        const HEIGHT: u32 = 2000;
        let options = Options {
            image_height: Some(HEIGHT),
            ..Options::default()
        };
        let (imported, conversion) = import(&dir.join(file), &options).unwrap();
        assert_eq!(conversion.scale_source, ScaleSource::File, "{file}");
        let s = conversion.px_per_m;
        let scene = &imported.frames[0];
        let centres = table(&dir.join(centres), 0);
        assert_eq!(scene.grains.len(), centres.len(), "{folder}/{file}");
        for (g, c) in scene.grains.iter().zip(&centres) {
            // Back to MATLAB pixels: x = X S + ½, y = H + ½ − Y S.
            let (x, y) = (
                g.position[0] * s + 0.5,
                HEIGHT as f64 + 0.5 - g.position[1] * s,
            );
            assert!(
                (x - c[0]).abs() < 1e-6 && (y - c[1]).abs() < 1e-6,
                "{file}: grain {} at ({x}, {y}), table {c:?}",
                g.id
            );
            assert!(
                (g.radius.unwrap() * s - c[2]).abs() < 1e-6,
                "{file}: radius"
            );
        }
        let mut found: Vec<(usize, usize)> = Vec::new();
        let mut wall_contacts = 0;
        for c in &scene.contacts {
            match c.b {
                Body::Grain(b) => {
                    let (a, b) = (
                        scene.grains[c.a].id.parse::<usize>().unwrap(),
                        scene.grains[b].id.parse::<usize>().unwrap(),
                    );
                    found.push((a.min(b), a.max(b)));
                }
                Body::Wall(_) => wall_contacts += 1,
            }
        }
        found.sort();
        let mut expected: Vec<(usize, usize)> = table(&dir.join(pairs), 1)
            .iter()
            .map(|p| (p[0] as usize, p[1] as usize))
            .collect();
        expected.sort();
        assert_eq!(found, expected, "{folder}/{file}: disk-disk contacts");
        assert_eq!(wall_contacts, walls, "{folder}/{file}: wall contacts");
        assert_eq!(imported.forces.is_some(), is_solved, "{folder}/{file}");
        if let Some(forces) = &imported.forces {
            // PeGS's fitted magnitudes (forces.csv of the data folder: id,
            // neighbour, beta, alpha, force, …): a wall contact is fitted once,
            // so its force is PeGS's exactly.
            let stem = file.trim_end_matches("_solved.mat");
            let rows = table(&dir.join(format!("{stem}_forces.csv")), 1);
            let mut checked = 0;
            for (c, f) in scene.contacts.iter().zip(&forces[0]) {
                if let Body::Wall(_) = c.b {
                    let id: f64 = scene.grains[c.a].id.parse().unwrap();
                    let magnitude = f[0].hypot(f[1]);
                    let row = rows
                        .iter()
                        .filter(|r| r[0] == id && r[1] < 0.0)
                        .min_by(|p, q| {
                            (p[4].abs() - magnitude)
                                .abs()
                                .total_cmp(&(q[4].abs() - magnitude).abs())
                        })
                        .unwrap();
                    assert!(
                        // The table holds 6 significant digits.
                        (row[4].abs() - magnitude).abs() <= 1e-5 * magnitude.max(1e-3),
                        "{file}: wall force {magnitude}, PeGS {}",
                        row[4]
                    );
                    checked += 1;
                }
            }
            assert_eq!(checked, walls, "{file}");
        }
        println!(
            "{folder}/{file}: {} disks, {} + {wall_contacts} contacts{}",
            scene.grains.len(),
            expected.len(),
            if is_solved { ", forces" } else { "" }
        );
    }
}
