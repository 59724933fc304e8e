//! Scenes built in memory get the same clear errors as files: no panic in
//! inference, whatever the values.

use grainforce::bench::{generate, PackingSpec};
use grainforce::infer::{infer, InferOptions};
use grainforce::scene::{Body, Scene};
use grainforce::Error;

fn packing() -> Scene {
    generate(&PackingSpec::new(2, 16)).unwrap().scene
}

/// Each defect is rejected by `validate` and by `infer`, with a message
/// naming what is wrong.
fn rejected(scene: &Scene, words: &[&str]) {
    for result in [
        scene.validate().map(|_| ()),
        infer(scene, &InferOptions::default()).map(|_| ()),
    ] {
        match result {
            Err(Error::Invalid(message)) => {
                for w in words {
                    assert!(message.contains(w), "`{message}` lacks `{w}`");
                }
            }
            other => panic!("expected Error::Invalid naming {words:?}, got {other:?}"),
        }
    }
}

#[test]
fn a_good_scene_passes() {
    packing().validate().unwrap();
}

#[test]
fn bad_scenes_are_named() {
    let good = packing();
    let first_grain = good.grains[0].id.clone();
    let first_contact = good.contacts[0].id.clone();

    rejected(
        &Scene {
            dim: 4,
            ..good.clone()
        },
        &["dimension", "4"],
    );
    rejected(
        &Scene {
            grains: Vec::new(),
            ..good.clone()
        },
        &["no grains"],
    );

    let mut s = good.clone();
    s.grains[0].volume = 0.0;
    rejected(&s, &[&first_grain, "volume"]);
    let mut s = good.clone();
    s.grains[0].stress[1] = f64::NAN;
    rejected(&s, &[&first_grain, "stress"]);
    let mut s = good.clone();
    s.grains[0].position[2] = 1.0;
    rejected(&s, &[&first_grain, "position"]);
    let mut s = good.clone();
    s.grains[0].mass = Some(-1.0);
    rejected(&s, &[&first_grain, "mass"]);
    let mut s = good.clone();
    s.grains[1].id = first_grain.clone();
    rejected(&s, &[&first_grain, "twice"]);

    let mut s = good.clone();
    s.contacts[0].a = 999;
    rejected(&s, &[&first_contact, "999", "out of range"]);
    let mut s = good.clone();
    s.contacts[0].b = Body::Grain(999);
    rejected(&s, &[&first_contact, "999"]);
    let mut s = good.clone();
    s.contacts[0].b = Body::Wall(99);
    rejected(&s, &[&first_contact, "wall index 99"]);
    let mut s = good.clone();
    s.contacts[0].b = Body::Grain(s.contacts[0].a);
    rejected(&s, &[&first_contact, "itself"]);
    let mut s = good.clone();
    s.contacts[0].normal = [2.0, 0.0, 0.0];
    rejected(&s, &[&first_contact, "unit vector"]);
    let mut s = good.clone();
    s.contacts[0].mu = Some(f64::INFINITY);
    rejected(&s, &[&first_contact, "friction"]);
    let mut s = good.clone();
    s.contacts[1].id = first_contact.clone();
    rejected(&s, &[&first_contact, "twice"]);

    let mut s = good.clone();
    s.settings.gravity = Some(vec![0.0, f64::NAN]);
    rejected(&s, &["gravity"]);
    let mut s = good;
    s.settings.thickness = Some(0.0);
    rejected(&s, &["thickness"]);
}
