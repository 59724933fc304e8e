//! The large-volume measurement of docs/tomography.md: writes an N³ u16
//! label volume (.npy, slice by slice: a simple cubic stack of touching
//! spheres of D voxels) and imports it from the memory-mapped file.
//!
//! cargo run --release --example labels_bench -- /tmp/labels.npy 1000 30
//! (then delete the file; run under `/usr/bin/time -v` for the peak memory).
//! RAYON_NUM_THREADS=1 runs the slabs one after another (the same answer);
//! LABELS_NORMALS=pca skips the surface fits (the first pass's cost).

use grainforce::import::labels::{self, FileFormat, Options};
use std::io::Write;

fn main() -> grainforce::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let path = std::path::PathBuf::from(args.get(1).map_or("/tmp/labels.npy", String::as_str));
    let n: usize = args.get(2).map_or(1000, |s| s.parse().expect("N"));
    let d: f64 = args.get(3).map_or(30.0, |s| s.parse().expect("D"));
    if !path.exists() {
        let t = std::time::Instant::now();
        let mut header =
            format!("{{'descr': '<u2', 'fortran_order': False, 'shape': ({n}, {n}, {n}), }}");
        let pad = (64 - (10 + header.len() + 1) % 64) % 64;
        header.push_str(&" ".repeat(pad));
        header.push('\n');
        let file = std::fs::File::create(&path).map_err(|e| grainforce::Error::io(&path, e))?;
        let mut out = std::io::BufWriter::new(file);
        let io = |e| grainforce::Error::io(&path, e);
        out.write_all(b"\x93NUMPY\x01\x00").map_err(io)?;
        out.write_all(&(header.len() as u16).to_le_bytes())
            .map_err(io)?;
        out.write_all(header.as_bytes()).map_err(io)?;
        let cells = (n as f64 / d).floor() as usize;
        let mut slice = vec![0u8; n * n * 2];
        for z in 0..n {
            for y in 0..n {
                for x in 0..n {
                    let cell = |v: usize| ((v as f64 + 0.5) / d).floor() as usize;
                    let (cx, cy, cz) = (cell(x), cell(y), cell(z));
                    let mut label = 0u16;
                    if cx < cells && cy < cells && cz < cells {
                        let c = |k: usize| (k as f64 + 0.5) * d - 0.5;
                        let r2 = (x as f64 - c(cx)).powi(2)
                            + (y as f64 - c(cy)).powi(2)
                            + (z as f64 - c(cz)).powi(2);
                        // Radius a little over D/2 so neighbours share faces.
                        if r2 <= (0.5 * d + 0.6).powi(2) {
                            label = (1 + cx + cells * (cy + cells * cz)) as u16;
                        }
                    }
                    let i = 2 * (y * n + x);
                    slice[i..i + 2].copy_from_slice(&label.to_le_bytes());
                }
            }
            out.write_all(&slice).map_err(io)?;
        }
        out.flush().map_err(io)?;
        eprintln!(
            "wrote {} in {:.1} s",
            path.display(),
            t.elapsed().as_secs_f64()
        );
    }
    // LABELS_ROBUST=k: robust restarts per side (the default's cost).
    let mut options = Options::default();
    if let Some(k) = std::env::var("LABELS_ROBUST")
        .ok()
        .and_then(|v| v.parse().ok())
    {
        options.fit.robust_samples = k;
    }
    // LABELS_NORMALS=pca: no surface fits, the first pass alone (nearly).
    if std::env::var("LABELS_NORMALS").is_ok_and(|v| v == "pca") {
        options.normals = labels::NormalMethod::Pca;
    }
    let t = std::time::Instant::now();
    let out = labels::import_file(&path, &FileFormat::Auto, None, &options)?;
    println!(
        "{n}³ u16: {} grains, {} contacts, import {:.1} s",
        out.scene.grains.len(),
        out.scene.contacts.len(),
        t.elapsed().as_secs_f64()
    );
    Ok(())
}
