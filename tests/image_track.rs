//! Grain ids over a sequence: motion, grains leaving and entering.

use grainforce::image::{
    detect_images, render_sequence, save_gray, track_sequence, DetectSettings, Disk, Elasticity,
    PlaneCondition, RenderOptions, TrackOptions,
};
use grainforce::scene::{read_sequence, write_sequence, Grain, Scene};
use rand::seq::SliceRandom;
use rand::SeedableRng;

fn disk(x: f64, y: f64, r: f64) -> Disk {
    Disk {
        x,
        y,
        r,
        support: 1.0,
        visible: 1.0,
        contrast: 1.0,
        rms: 0.0,
    }
}

#[test]
fn ids_follow_moving_grains_through_entries_and_exits() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    // A 5×4 lattice of radius-20 disks, 45 px apart, moving right 15 px in
    // the first frame, then 30 px per frame: beyond the 20 px gate, so only
    // the predicted positions can follow them. A little jitter; grain 7
    // leaves after frame 2, a new grain appears in frame 3.
    let truth: Vec<([f64; 2], [f64; 2])> = (0..20)
        .map(|k| {
            let p = [50.0 + 45.0 * (k % 5) as f64, 50.0 + 45.0 * (k / 5) as f64];
            (p, [30.0, -4.0 + 0.5 * (k % 3) as f64])
        })
        .collect();
    let travel = |f: usize| {
        if f == 0 {
            0.0
        } else {
            15.0 + 30.0 * (f - 1) as f64
        }
    };
    let mut frames: Vec<Vec<(usize, Disk)>> = Vec::new();
    for f in 0..6 {
        let mut disks: Vec<(usize, Disk)> = truth
            .iter()
            .enumerate()
            .filter(|(k, _)| !(*k == 7 && f > 2))
            .map(|(k, (p, v))| {
                let jitter = 0.3 * ((k * 7 + f * 3) % 5) as f64 - 0.6;
                (
                    k,
                    disk(p[0] + travel(f) + jitter, p[1] + v[1] * f as f64, 20.0),
                )
            })
            .collect();
        if f >= 3 {
            disks.push((99, disk(100.0 + 10.0 * f as f64, 300.0, 25.0)));
        }
        disks.shuffle(&mut rng);
        frames.push(disks);
    }
    let lists: Vec<Vec<Disk>> = frames
        .iter()
        .map(|f| f.iter().map(|d| d.1).collect())
        .collect();
    let ids = track_sequence(&lists, &TrackOptions::new(20.0)).unwrap();
    let mut id_of = std::collections::HashMap::new();
    let mut seen = std::collections::HashSet::new();
    for (f, frame) in frames.iter().enumerate() {
        for (k, (grain, _)) in frame.iter().enumerate() {
            let id = ids[f][k];
            match id_of.get(grain) {
                Some(&known) => assert_eq!(known, id, "grain {grain} changed id in frame {f}"),
                None => {
                    assert!(seen.insert(id), "id {id} reused for grain {grain}");
                    id_of.insert(*grain, id);
                }
            }
        }
        let unique: std::collections::HashSet<_> = ids[f].iter().collect();
        assert_eq!(unique.len(), ids[f].len(), "ids unique within frame {f}");
    }
    assert_eq!(id_of.len(), 21);
    assert_eq!(id_of[&99], 20, "the newcomer gets the next id");
}

#[test]
fn tracking_gate_must_be_positive() {
    let mut o = TrackOptions::new(20.0);
    o.max_jump_px = 0.0;
    assert!(track_sequence(&[vec![]], &o).is_err());
}

#[test]
fn detected_sequence_keeps_ids_and_writes_frames() {
    let elasticity = Elasticity::new(5.5e6, 0.4, PlaneCondition::Stress).unwrap();
    let base: Vec<([f64; 2], f64)> = vec![
        ([0.06, 0.06], 0.04),
        ([0.16, 0.07], 0.045),
        ([0.27, 0.06], 0.04),
        ([0.10, 0.16], 0.035),
        ([0.21, 0.17], 0.04),
    ];
    // Three frames; the grains drift 4 px per frame, grain 2 leaves in frame 2.
    let frames: Vec<Scene> = (0..3)
        .map(|f| {
            let mut s = Scene::new(2);
            for (k, (p, r)) in base.iter().enumerate() {
                if k == 2 && f == 2 {
                    continue;
                }
                let mut g = Grain::new(
                    format!("g{k}"),
                    [p[0] + 0.004 * f as f64, p[1] - 0.002 * f as f64, 0.0],
                    std::f64::consts::PI * r * r,
                    [0.0; 6],
                );
                g.radius = Some(*r);
                s.grains.push(g);
            }
            s
        })
        .collect();
    let mut render = RenderOptions::new(1000.0, elasticity);
    render.margin_px = 30.0;
    let rendered = render_sequence(&frames, &render).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let paths: Vec<_> = rendered
        .deformed
        .iter()
        .enumerate()
        .map(|(k, image)| {
            let path = dir.path().join(format!("frame{k}.png"));
            save_gray(&path, image, 8).unwrap();
            path
        })
        .collect();
    let mut settings = DetectSettings::new(25.0, 55.0, 1000.0);
    settings.frame = Some(rendered.frame);
    let detection = detect_images(&paths, &settings, &mut |_, _, _, _| Ok(())).unwrap();
    // Map each truth grain to its detected id in every frame.
    let id_at = |f: usize, p: [f64; 3]| -> String {
        let scene = &detection.frames[f].scene;
        let g = scene
            .grains
            .iter()
            .find(|g| (g.position[0] - p[0]).hypot(g.position[1] - p[1]) < 0.5e-3)
            .expect("every grain is found");
        g.id.clone()
    };
    for truth in &frames[0].grains {
        let first = id_at(0, truth.position);
        for (f, frame) in frames.iter().enumerate().skip(1) {
            if let Some(t) = frame.grains.iter().find(|g| g.id == truth.id) {
                assert_eq!(id_at(f, t.position), first, "{} in frame {f}", truth.id);
            }
        }
    }
    assert_eq!(detection.frames[2].scene.grains.len(), 4);
    let out = dir.path().join("scene");
    let scenes: Vec<Scene> = detection.frames.iter().map(|f| f.scene.clone()).collect();
    write_sequence(&out, &scenes).unwrap();
    let back = read_sequence(&out).unwrap();
    assert_eq!(back.len(), 3);
    assert_eq!(back[2].frame, Some(2));
}
