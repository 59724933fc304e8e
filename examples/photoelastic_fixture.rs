//! Writes `fixtures/photoelastic/`: the bundled example of `grainforce
//! photoelastic` — the 58-disk DEM oedometer (`fixtures/oedometer`, whose
//! forces.csv is the truth) drawn as a dark-field photoelastic photograph
//! under the conditions (r ≈ 40 px, blur 0.8 px, noise 2 %, uneven
//! lighting, JPEG q90), with its scene folder (disks thick 5 mm, the pixel
//! frame) so that
//!
//!     grainforce photoelastic fixtures/photoelastic/photo.jpg \
//!         --scene fixtures/photoelastic/scene -o forces.csv --fsigma 200 --blur 0.8
//!
//! fits forces to compare with `fixtures/oedometer/forces.csv`.
//!
//!     cargo run --release --example photoelastic_fixture

use grainforce::image::photoelastic::{render_photoelastic, save_jpeg, PhotoelasticOptions};
use grainforce::image::FRAME_FILE;
use grainforce::scene::{read_forces, read_scene, write_scene};
use grainforce::{Error, Result};
use std::path::Path;

/// f_σ [N/m] over the thickness [m]: the stress of one fringe order [Pa].
const FSIGMA: f64 = 200.0;
const THICKNESS: f64 = 0.005;

fn main() -> Result<()> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures");
    let mut scene = read_scene(&root.join("oedometer"))?;
    let rows = read_forces(&root.join("oedometer/forces.csv"))?.rows;
    let truth = scene
        .contacts
        .iter()
        .map(|c| match rows.iter().find(|r| r.contact == c.id) {
            Some(r) => Ok([r.force[0], r.force[1]]),
            None => Err(Error::Invalid(format!("no force for contact {}", c.id))),
        })
        .collect::<Result<Vec<_>>>()?;
    let mean_r =
        scene.grains.iter().filter_map(|g| g.radius).sum::<f64>() / scene.grains.len() as f64;
    let mut options = PhotoelasticOptions::new(40.0 / mean_r, FSIGMA / THICKNESS);
    options.blur_px = 0.8;
    options.noise = 0.02;
    options.uneven_lighting = 0.1;
    let (photo, frame) = render_photoelastic(&scene, &truth, &options)?;

    let out = root.join("photoelastic");
    scene.settings.thickness = Some(THICKNESS);
    scene.settings.description = Some(format!(
        "fixtures/oedometer's 58 disks as photo.jpg shows them (examples/photoelastic_fixture.rs): thickness {THICKNESS} m, f_σ {FSIGMA} N/m; the true forces are fixtures/oedometer/forces.csv"
    ));
    write_scene(&out.join("scene"), &scene)?;
    frame.write(&out.join("scene").join(FRAME_FILE))?;
    save_jpeg(&out.join("photo.jpg"), &photo, 90)?;
    println!(
        "wrote {} ({}×{} px) and its scene",
        out.join("photo.jpg").display(),
        frame.width,
        frame.height
    );
    Ok(())
}
