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

use grainforce::image::{detect_images, ContactBody, DetectSettings};
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

#[test]
fn real_photographs_at_the_defaults() {
    let Some(root) = real_photos() else {
        return;
    };
    for case in &CASES {
        let dir = root.join(case.folder);
        let settings = DetectSettings::new(case.radius.0, case.radius.1, 1.0);
        let started = std::time::Instant::now();
        let detection =
            detect_images(&[dir.join(case.image)], &settings, &mut |_, _, _, _| Ok(())).unwrap();
        let elapsed = started.elapsed().as_secs_f64();
        let frame = &detection.frames[0];
        let reference = rows(&dir.join(format!("{}_centers.txt", case.stem)), 0);
        // Nearest pairs within half the reference radius, one to one.
        let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
        for (i, r) in reference.iter().enumerate() {
            for (j, d) in frame.disks.iter().enumerate() {
                let offset = (d.x - (r[0] - 1.0)).hypot(d.y - (r[1] - 1.0));
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
        let precision = matched as f64 / frame.disks.len() as f64;
        let median = percentile(&mut offsets, 50.0);
        let p90 = percentile(&mut offsets, 90.0);
        // PeGS's force-bearing contacts among ours (contacts.csv's pairs).
        let ours: HashSet<(usize, usize)> = frame
            .contacts
            .iter()
            .filter_map(|c| match c.b {
                ContactBody::Disk(b) => Some((c.a.min(b), c.a.max(b))),
                ContactBody::Wall(_) => None,
            })
            .collect();
        let theirs = rows(&dir.join(format!("{}_contacts_ref.csv", case.stem)), 1);
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
        let contact_recall = found as f64 / theirs.len() as f64;
        println!(
            "{}: disks {matched}/{} (+{} false), recall {recall:.3} precision {precision:.3}; \
             centre offset from PeGS {median:.3} R median, {p90:.3} R p90; \
             PeGS's force-bearing contacts found {found}/{} ({contact_recall:.2}), \
             {} contacts in all; searched the {}; {elapsed:.1} s",
            case.folder,
            reference.len(),
            frame.disks.len() - matched,
            theirs.len(),
            frame.contacts.len(),
            frame.choice.describe()
        );
        assert!(recall >= 0.98 && precision >= 0.98, "{}", case.folder);
        assert!(
            median <= case.centre.0 && p90 <= case.centre.1,
            "{}: centre offset {median} / {p90} R",
            case.folder
        );
        assert!(contact_recall >= case.contacts, "{}", case.folder);
    }
}
