//! Writes a real photograph as another camera or light would have taken it
//! (the variants `tests/image_real_photos.rs` checks), with the PeGS centres
//! moved likewise, to time and score the CLI on them:
//!
//!     cargo run --release --example real_photo_variants -- PHOTO CENTRES OUT_DIR
//!
//! OUT_DIR gets `x2.38.jpg` (the phone photograph upscaled to 21 MP: disks
//! of radius ~160–200 px), `red.jpg`, `orange.jpg` and a `*_centers.txt`
//! for each (the PeGS list's format: 1-based x, y, r).

#[path = "../tests/real_photos/variants.rs"]
mod variants;

use image::codecs::jpeg::JpegEncoder;
use image::RgbImage;
use std::path::Path;

fn save(photo: &RgbImage, path: &Path) {
    let file = std::fs::File::create(path).expect("writable output folder");
    let mut encoder = JpegEncoder::new_with_quality(std::io::BufWriter::new(file), 95);
    encoder.encode_image(photo).expect("encodes");
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [photo, centres, out] = &args[..] else {
        eprintln!("usage: real_photo_variants PHOTO CENTRES OUT_DIR");
        std::process::exit(2);
    };
    let out = Path::new(out);
    std::fs::create_dir_all(out).expect("output folder");
    let photo = image::open(photo).expect("a photograph").to_rgb8();
    let centres = std::fs::read_to_string(centres).expect("a centres file");
    let write_centres = |name: &str, f: f64, resized: (u32, u32)| {
        let mut text = String::new();
        for line in centres.lines().filter(|l| !l.trim().is_empty()) {
            let v: Vec<f64> = line.split(',').map(|s| s.trim().parse().unwrap()).collect();
            let x = variants::scaled_coordinate(v[0] - 1.0, photo.width(), resized.0) + 1.0;
            let y = variants::scaled_coordinate(v[1] - 1.0, photo.height(), resized.1) + 1.0;
            text += &format!("{x:.3},{y:.3},{:.3}", v[2] * f);
            for extra in &v[3..] {
                text += &format!(",{extra}");
            }
            text += "\n";
        }
        std::fs::write(out.join(name), text).unwrap();
    };
    for factor in [2.0, 2.38, 3.0] {
        let big = variants::upscaled(&photo, factor);
        save(&big, &out.join(format!("x{factor}.jpg")));
        write_centres(
            &format!("x{factor}_centers.txt"),
            factor,
            (big.width(), big.height()),
        );
    }
    for (name, gains) in [
        ("red", variants::RED_LIGHT),
        ("orange", variants::ORANGE_LIGHT),
    ] {
        save(
            &variants::lit(&photo, gains, 0.01, 7),
            &out.join(format!("{name}.jpg")),
        );
        write_centres(&format!("{name}_centers.txt"), 1.0, photo.dimensions());
    }
}
