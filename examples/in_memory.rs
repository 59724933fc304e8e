//! Library use without files: build a scene in memory, infer, read the forces.
//!
//!     cargo run --example in_memory
//!
//! Two disks stacked between a floor and a lid, pressed with 250 N/m: the
//! stresses they would report are computed from that load, and inference
//! recovers it.

use grainforce::infer::{infer, InferOptions, Method};
use grainforce::scene::{Body, Contact, Grain, Scene};

fn main() -> grainforce::Result<()> {
    let r = 0.01; // disk radius [m]
    let area = std::f64::consts::PI * r * r;
    // A disk squeezed along y by P carries V σ_yy = −2 r P (two contacts, arm r).
    let p = 250.0;
    let s_yy = -2.0 * r * p / area;

    let mut scene = Scene::new(2);
    scene.settings.mu = Some(0.5);
    scene.grains.push(Grain::new(
        "lower",
        [0.0, r, 0.0],
        area,
        [0.0, s_yy, 0.0, 0.0, 0.0, 0.0],
    ));
    scene.grains.push(Grain::new(
        "upper",
        [0.0, 3.0 * r, 0.0],
        area,
        [0.0, s_yy, 0.0, 0.0, 0.0, 0.0],
    ));
    let floor = scene.wall_or_insert("floor");
    let lid = scene.wall_or_insert("lid");
    let contact = |id: &str, a, b, y: f64, ny: f64| Contact {
        id: id.into(),
        a,
        b,
        point: [0.0, y, 0.0],
        normal: [0.0, ny, 0.0],
        mu: None,
    };
    scene
        .contacts
        .push(contact("floor", 0, Body::Wall(floor), 0.0, -1.0));
    scene
        .contacts
        .push(contact("middle", 0, Body::Grain(1), 2.0 * r, 1.0));
    scene
        .contacts
        .push(contact("lid", 1, Body::Wall(lid), 4.0 * r, 1.0));

    let result = infer(
        &scene,
        &InferOptions {
            method: Method::Qs,
            ..InferOptions::default()
        },
    )?;
    eprint!("{}", result.report);
    for (c, f) in scene.contacts.iter().zip(&result.forces) {
        let f = f.expect("every contact is modelled");
        println!(
            "{:>7}: force on `{}` = ({:+.3}, {:+.3}) N/m",
            c.id, scene.grains[c.a].id, f[0], f[1]
        );
    }
    Ok(())
}
