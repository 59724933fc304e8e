//! `detect` at its defaults (only the radius range) on real photographs of
//! photoelastic disk packings, scored against the experimenters' own PeGS
//! answers. The photographs are not part of grainforce: they are read from
//! `$GRAINFORCE_TEST_DATA/real-photos` (each folder's SOURCE.md says what the
//! reference is), and the test says it skips when the variable is unset.
//!
//! Scoring follows the data's `match.py`: a detected disk matches a
//! reference disk when its centre lies within half the reference radius,
//! nearest pairs first, one to one; reference centres are MATLAB pixels
//! (1-based). PeGS lists force-bearing contacts only (G² above a threshold on
//! both disks), so its contacts are scored by recall.

#[path = "real_photos/variants.rs"]
mod variants;

use grainforce::image::{detect_images, ContactBody, DetectSettings, DetectedFrame};
use std::collections::HashSet;
use std::path::{Path, PathBuf};

struct Case {
    folder: &'static str,
    image: &'static str,
    stem: &'static str,
    /// The radius range a user gives: the experimenters' radii, widened ~10 %.
    radius: (f64, f64),
    /// What is asserted: centre offset from PeGS (median, 90th percentile) in
    /// radii, and the recall of PeGS's force-bearing contacts.
    centre: (f64, f64),
    contacts: f64,
}

/// The targets where they are met; the measured figure with a
/// little room where not, each with the reason in docs/image.md.
const CASES: [Case; 5] = [
    Case {
        folder: "pegs2-step09",
        image: "Step09-0001.tif",
        stem: "Step09-0001",
        radius: (45.0, 80.0),
        centre: (0.035, 0.075),
        contacts: 0.9,
    },
    Case {
        folder: "jlin-fixed48",
        image: "image2.jpg",
        stem: "image2",
        radius: (28.0, 42.0),
        // PeGS's own radii here spread over 31–38 px for disks of one size
        // (ours: 35.3 ± 0.4 px): its Hough centres are ~2 px off.
        centre: (0.06, 0.11),
        contacts: 0.9,
    },
    Case {
        folder: "jlin-narrow21",
        image: "image.jpg",
        stem: "image",
        radius: (59.0, 78.0),
        centre: (0.035, 0.075),
        contacts: 0.75,
    },
    Case {
        folder: "jlin-step83",
        image: "image3.jpg",
        stem: "image3",
        radius: (27.0, 39.0),
        centre: (0.035, 0.1),
        contacts: 0.85,
    },
    Case {
        folder: "jlin-iphone83",
        image: "image4.jpg",
        stem: "image4",
        radius: (66.0, 90.0),
        centre: (0.035, 0.075),
        contacts: 0.9,
    },
];

fn real_photos() -> Option<PathBuf> {
    match std::env::var_os("GRAINFORCE_TEST_DATA") {
        Some(root) => Some(PathBuf::from(root).join("real-photos")),
        None => {
            println!(
                "skipped: GRAINFORCE_TEST_DATA is not set (it names the folder holding real-photos/)"
            );
            None
        }
    }
}

fn rows(path: &Path, skip: usize) -> Vec<Vec<f64>> {
    std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .lines()
        .skip(skip)
        .filter(|l| !l.trim().is_empty())
        .map(|l| l.split(',').map(|v| v.trim().parse().unwrap()).collect())
        .collect()
}

fn percentile(v: &mut [f64], p: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    // numpy's linear interpolation, as match.py reports it.
    let x = p / 100.0 * (v.len() - 1) as f64;
    let (i, f) = (x.floor() as usize, x.fract());
    v[i] + f * (v[(i + 1).min(v.len() - 1)] - v[i])
}

/// How one detection compares with PeGS.
struct Scored {
    recall: f64,
    precision: f64,
    /// Centre offset from PeGS [radii]: median and 90th percentile.
    median: f64,
    p90: f64,
    /// PeGS's force-bearing contacts among ours.
    contacts: f64,
    /// The channel G² was read in.
    signal: Option<String>,
    line: String,
}

/// Runs `detect` with only the radius range on `image` and scores it against
/// PeGS's centres (`reference`: 0-based x, y, r per disk) and force-bearing
/// contacts (1-based pairs of reference lines).
fn detect_and_score(
    image: &Path,
    radius: (f64, f64),
    reference: &[[f64; 3]],
    theirs: &[Vec<f64>],
) -> Scored {
    let settings = DetectSettings::new(radius.0, radius.1, 1.0);
    let started = std::time::Instant::now();
    let detection = detect_images(&[image.to_owned()], &settings, &mut |_, _, _, _| Ok(()))
        .unwrap_or_else(|e| panic!("{}: {e}", image.display()));
    let elapsed = started.elapsed().as_secs_f64();
    let frame: &DetectedFrame = &detection.frames[0];
    // Nearest pairs within half the reference radius, one to one.
    let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
    for (i, r) in reference.iter().enumerate() {
        for (j, d) in frame.disks.iter().enumerate() {
            let offset = (d.x - r[0]).hypot(d.y - r[1]);
            if offset < 0.5 * r[2] {
                pairs.push((offset, i, j));
            }
        }
    }
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (mut to_detected, mut taken) = (vec![None; reference.len()], HashSet::new());
    let mut offsets = Vec::new();
    for (offset, i, j) in pairs {
        if to_detected[i].is_none() && !taken.contains(&j) {
            to_detected[i] = Some(j);
            taken.insert(j);
            offsets.push(offset / reference[i][2]);
        }
    }
    let matched = offsets.len();
    let recall = matched as f64 / reference.len() as f64;
    let precision = matched as f64 / frame.disks.len().max(1) as f64;
    let (median, p90) = if offsets.is_empty() {
        (f64::INFINITY, f64::INFINITY)
    } else {
        (
            percentile(&mut offsets, 50.0),
            percentile(&mut offsets, 90.0),
        )
    };
    let ours: HashSet<(usize, usize)> = frame
        .contacts
        .iter()
        .filter_map(|c| match c.b {
            ContactBody::Disk(b) => Some((c.a.min(b), c.a.max(b))),
            ContactBody::Wall(_) => None,
        })
        .collect();
    let found = theirs
        .iter()
        .filter(|p| {
            let (a, b) = (
                to_detected[p[0] as usize - 1],
                to_detected[p[1] as usize - 1],
            );
            matches!((a, b), (Some(a), Some(b)) if ours.contains(&(a.min(b), a.max(b))))
        })
        .count();
    let contacts = found as f64 / theirs.len() as f64;
    let line = format!(
        "disks {matched}/{} (+{} false), recall {recall:.3} precision {precision:.3}; \
         centre offset from PeGS {median:.3} R median, {p90:.3} R p90; \
         PeGS's force-bearing contacts found {found}/{} ({contacts:.2}), \
         {} contacts in all; searched the {}; {elapsed:.1} s",
        reference.len(),
        frame.disks.len() - matched,
        theirs.len(),
        frame.contacts.len(),
        frame.choice.describe()
    );
    Scored {
        recall,
        precision,
        median,
        p90,
        contacts,
        signal: frame.choice.signal.clone(),
        line,
    }
}

impl Scored {
    /// Notes in `failed` what falls short of: disk recall and precision, centre
    /// offset (median, p90) [R], PeGS's contacts found.
    fn check(
        &self,
        name: &str,
        (disks, centre, contacts): (f64, (f64, f64), f64),
        failed: &mut Vec<String>,
    ) {
        if self.recall < disks || self.precision < disks {
            failed.push(format!(
                "{name}: recall {} precision {}",
                self.recall, self.precision
            ));
        }
        if self.median > centre.0 || self.p90 > centre.1 {
            failed.push(format!(
                "{name}: centre offset {} / {} R",
                self.median, self.p90
            ));
        }
        if self.contacts < contacts {
            failed.push(format!("{name}: PeGS's contacts found {}", self.contacts));
        }
    }
}

/// PeGS's centres of a case, 0-based.
fn reference(dir: &Path, case: &Case) -> Vec<[f64; 3]> {
    rows(&dir.join(format!("{}_centers.txt", case.stem)), 0)
        .iter()
        .map(|r| [r[0] - 1.0, r[1] - 1.0, r[2]])
        .collect()
}

fn pegs_contacts(dir: &Path, case: &Case) -> Vec<Vec<f64>> {
    rows(&dir.join(format!("{}_contacts_ref.csv", case.stem)), 1)
}

#[test]
fn real_photographs_at_the_defaults() {
    let Some(root) = real_photos() else {
        return;
    };
    let mut failed = Vec::new();
    for case in &CASES {
        let dir = root.join(case.folder);
        let s = detect_and_score(
            &dir.join(case.image),
            case.radius,
            &reference(&dir, case),
            &pegs_contacts(&dir, case),
        );
        println!("{}: {}", case.folder, s.line);
        s.check(case.folder, (0.98, case.centre, case.contacts), &mut failed);
    }
    assert!(failed.is_empty(), "{failed:#?}");
}

/// Big disks (radius 100–240 px, as a 21-megapixel camera sees them): real
/// photographs upscaled in memory, PeGS's centres moved likewise. The
/// disks, centres (in radii) and contacts must come out as at the original
/// size (the same targets and floors).
#[test]
fn big_disks_in_upscaled_photographs() {
    let Some(root) = real_photos() else {
        return;
    };
    let dir_out = tempfile::tempdir().unwrap();
    let mut failed = Vec::new();
    // (case, factor, disk recall and precision, PeGS's contacts found: the
    // target on pegs2-step09, jlin-narrow21's floor at its own size)
    for (k, factor, disks, contacts) in [(2usize, 2.0, 0.98, 0.75), (0, 2.5, 0.98, 0.9)] {
        let case = &CASES[k];
        let dir = root.join(case.folder);
        let photo = image::open(dir.join(case.image)).unwrap().to_rgb8();
        let big = variants::upscaled(&photo, factor);
        let path = dir_out
            .path()
            .join(format!("{}-x{factor}.png", case.folder));
        big.save(&path).unwrap();
        let (w, h) = (photo.width(), photo.height());
        let scaled: Vec<[f64; 3]> = reference(&dir, case)
            .iter()
            .map(|r| {
                [
                    variants::scaled_coordinate(r[0], w, big.width()),
                    variants::scaled_coordinate(r[1], h, big.height()),
                    factor * r[2],
                ]
            })
            .collect();
        let radius = (factor * case.radius.0, factor * case.radius.1);
        let s = detect_and_score(&path, radius, &scaled, &pegs_contacts(&dir, case));
        println!("{} ×{factor}: {}", case.folder, s.line);
        let name = format!("{} ×{factor}", case.folder);
        s.check(&name, (disks, case.centre, contacts), &mut failed);
    }
    assert!(failed.is_empty(), "{failed:#?}");
}

/// The photographs as under red light (the DSLR photograph's: green and
/// blue a few per cent) and orange backlight, with sensor noise: the
/// defaults must find the disks whatever the light's colour.
#[test]
fn coloured_light_at_the_defaults() {
    let Some(root) = real_photos() else {
        return;
    };
    let dir_out = tempfile::tempdir().unwrap();
    let mut failed = Vec::new();
    // Disk recall and precision asserted per photo: the target, or (jlin-
    // fixed48 under red light: 47 of 48, its disk against the container's
    // corner keeps too few outline rays in the noise) the level measured, as
    // a floor.
    for (case, disks) in CASES.iter().zip([0.98, 0.97, 0.98, 0.98, 0.98]) {
        let dir = root.join(case.folder);
        let photo = image::open(dir.join(case.image)).unwrap().to_rgb8();
        for (light, gains) in [
            ("red", variants::RED_LIGHT),
            ("orange", variants::ORANGE_LIGHT),
        ] {
            let path = dir_out.path().join(format!("{}-{light}.png", case.folder));
            variants::lit(&photo, gains, 0.01, 7).save(&path).unwrap();
            let s = detect_and_score(
                &path,
                case.radius,
                &reference(&dir, case),
                &pegs_contacts(&dir, case),
            );
            println!("{} under {light} light: {}", case.folder, s.line);
            let name = format!("{} under {light} light", case.folder);
            // Green is a few per cent of red under red light: G² is read in red.
            if light == "red" && s.signal.as_deref() != Some("red") {
                failed.push(format!("{name}: G² read in {:?}", s.signal));
            }
            s.check(&name, (disks, (0.1, 0.15), 0.0), &mut failed);
        }
    }
    assert!(failed.is_empty(), "{failed:#?}");
}
