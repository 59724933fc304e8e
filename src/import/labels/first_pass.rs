//! Pass 1 over the volume: each grain's voxel moments and bounding box, the
//! faces between labels and the grey sums, in fixed z-slabs (on threads when
//! the source can be read from several) merged in z order. The moments are
//! integers and the faces keep their scan order, so the result is the serial
//! pass's to the bit whatever the number of threads.

use super::volume::{SharedSource, SliceSource};
use super::{Face, Moments, Scan, MAX_LABEL, SLAB};
use crate::error::{Error, Result};
use rayon::prelude::*;
use std::collections::hash_map::Entry;
use std::collections::HashMap;

/// One slab's share: grains in order of first appearance, faces by label.
#[derive(Default)]
struct Partial {
    index: Vec<u32>,
    labels: Vec<u32>,
    moments: Vec<Moments>,
    /// Grain–grain faces by (lower label, higher label).
    pairs: HashMap<(u32, u32), Vec<Face>>,
    /// Grain–container faces by grain label.
    container: HashMap<u32, Vec<Face>>,
    grey_solid: (f64, u64),
    grey_void: (f64, u64),
}

impl Partial {
    fn grain(&mut self, label: u32, at: [usize; 3], shape: [usize; 3]) -> Result<usize> {
        if label >= MAX_LABEL {
            return Err(Error::Invalid(format!(
                "label {label} at voxel z={} y={} x={}: labels above {} are not supported; \
                 relabel the volume sequentially",
                at[2],
                at[1],
                at[0],
                MAX_LABEL - 1
            )));
        }
        let l = label as usize;
        if l >= self.index.len() {
            self.index.resize((l + 1).max(self.index.len() * 2), 0);
        }
        if self.index[l] == 0 {
            self.labels.push(label);
            self.moments.push(Moments {
                reference: [at[0] as i64, at[1] as i64, at[2] as i64],
                n: 0,
                sum: [0; 3],
                sq: [0; 6],
                lo: at,
                hi: at,
                cut: false,
            });
            self.index[l] = self.labels.len() as u32;
        }
        let g = self.index[l] as usize - 1;
        let m = &mut self.moments[g];
        for k in 0..3 {
            m.lo[k] = m.lo[k].min(at[k]);
            m.hi[k] = m.hi[k].max(at[k]);
        }
        if at[1] == 0 || at[2] == 0 || at[1] + 1 == shape[1] || at[2] + 1 == shape[0] {
            m.cut = true;
        }
        Ok(g)
    }

    /// Records the face between voxel `p` (label `lp`) and its +axis
    /// neighbour (label `lq`), with the mean grey of the two.
    fn interface(
        &mut self,
        container: u32,
        (lp, lq): (u32, u32),
        p: [usize; 3],
        axis: i8,
        grey: f32,
    ) {
        if lp == 0 || lq == 0 {
            return;
        }
        let mut centre = [2 * p[0] as i32, 2 * p[1] as i32, 2 * p[2] as i32];
        centre[axis as usize - 1] += 1;
        if lp == container || lq == container {
            let (l, dir) = if lp == container {
                (lq, -axis)
            } else {
                (lp, axis)
            };
            self.container.entry(l).or_default().push(Face {
                p: centre,
                axis: dir,
                grey,
            });
            return;
        }
        let (a, b, dir) = if lp < lq {
            (lp, lq, axis)
        } else {
            (lq, lp, -axis)
        };
        self.pairs.entry((a, b)).or_default().push(Face {
            p: centre,
            axis: dir,
            grey,
        });
    }
}

impl Moments {
    /// Adds another slab's moments of the same grain, moved to this
    /// reference (integer arithmetic: exact).
    fn absorb(&mut self, other: &Moments) {
        let d: [i64; 3] = std::array::from_fn(|k| other.reference[k] - self.reference[k]);
        let n = other.n as i64;
        for (k, &(i, j)) in crate::scene::sym::PAIRS.iter().enumerate() {
            self.sq[k] += other.sq[k] + d[j] * other.sum[i] + d[i] * other.sum[j] + n * d[i] * d[j];
        }
        for k in 0..3 {
            self.sum[k] += other.sum[k] + n * d[k];
            self.lo[k] = self.lo[k].min(other.lo[k]);
            self.hi[k] = self.hi[k].max(other.hi[k]);
        }
        self.n += other.n;
        self.cut |= other.cut;
    }
}

#[inline]
fn add_run(m: &mut Moments, x0: usize, x1: usize, y: usize, z: usize) {
    let len = (x1 - x0) as i64;
    let a = x0 as i64 - m.reference[0];
    let b = x1 as i64 - 1 - m.reference[0];
    // Σ dx and Σ dx² over dx = a … b (a sum of consecutive integers is an
    // integer: a + b and the length have opposite parities).
    let s1 = (a + b) * len / 2;
    let sq = |k: i64| k * (k + 1) * (2 * k + 1) / 6;
    let s2 = if a >= 0 {
        sq(b) - sq(a - 1)
    } else if b < 0 {
        sq(-a) - sq(-b - 1)
    } else {
        sq(b) + sq(-a)
    };
    let dy = y as i64 - m.reference[1];
    let dz = z as i64 - m.reference[2];
    m.n += len as u64;
    m.sum[0] += s1;
    m.sum[1] += dy * len;
    m.sum[2] += dz * len;
    m.sq[0] += s2;
    m.sq[1] += dy * dy * len;
    m.sq[2] += dz * dz * len;
    m.sq[3] += s1 * dy;
    m.sq[4] += s1 * dz;
    m.sq[5] += dy * dz * len;
}

type ReadSlice<'r> = dyn FnMut(usize, &mut [u32], &mut [f32]) -> Result<()> + 'r;

/// Slices `z0..z1` (slice `z0 − 1` is read for the faces below `z0`).
fn slab(
    (z0, z1): (usize, usize),
    shape: [usize; 3],
    container: u32,
    with_grey: bool,
    read: &mut ReadSlice,
) -> Result<Partial> {
    let [nz, ny, nx] = shape;
    let n = ny * nx;
    let mut part = Partial::default();
    let mut prev = vec![0u32; n];
    let mut cur = vec![0u32; n];
    let mut gprev = vec![0f32; if with_grey { n } else { 0 }];
    let mut gcur = gprev.clone();
    if z0 > 0 {
        read(z0 - 1, &mut prev, &mut gprev)?;
    }
    let grey_of = |g: &[f32], i: usize, h: &[f32], j: usize| {
        if g.is_empty() {
            0.0
        } else {
            0.5 * (g[i] + h[j])
        }
    };
    for z in z0..z1 {
        read(z, &mut cur, &mut gcur)?;
        for y in 0..ny {
            let row = &cur[y * nx..(y + 1) * nx];
            let mut x = 0;
            while x < nx {
                let l = row[x];
                let mut end = x + 1;
                while end < nx && row[end] == l {
                    end += 1;
                }
                if l != 0 && l != container {
                    let g = part.grain(l, [x, y, z], shape)?;
                    part.grain(l, [end - 1, y, z], shape)?;
                    let m = &mut part.moments[g];
                    if z == 0 || x == 0 || end == nx {
                        m.cut = true;
                    }
                    add_run(m, x, end, y, z);
                }
                x = end;
            }
            if with_grey {
                for (i, &l) in row.iter().enumerate() {
                    let v = gcur[y * nx + i] as f64;
                    if l == 0 {
                        part.grey_void.0 += v;
                        part.grey_void.1 += 1;
                    } else if l != container {
                        part.grey_solid.0 += v;
                        part.grey_solid.1 += 1;
                    }
                }
            }
        }
        // Faces towards −x, −y (this slice) and −z (the slice below).
        for y in 0..ny {
            for x in 0..nx {
                let i = y * nx + x;
                let l = cur[i];
                if x > 0 && cur[i - 1] != l {
                    let g = grey_of(&gcur, i - 1, &gcur, i);
                    part.interface(container, (cur[i - 1], l), [x - 1, y, z], 1, g);
                }
                if y > 0 && cur[i - nx] != l {
                    let g = grey_of(&gcur, i - nx, &gcur, i);
                    part.interface(container, (cur[i - nx], l), [x, y - 1, z], 2, g);
                }
                if z > 0 && prev[i] != l {
                    let g = grey_of(&gprev, i, &gcur, i);
                    part.interface(container, (prev[i], l), [x, y, z - 1], 3, g);
                }
            }
        }
        std::mem::swap(&mut prev, &mut cur);
        std::mem::swap(&mut gprev, &mut gcur);
    }
    debug_assert!(z1 <= nz);
    part.index = Vec::new();
    Ok(part)
}

/// Adds a slab's share to the scan (slabs in z order).
fn merge(scan: &mut Scan, part: Partial) {
    for (&label, m) in part.labels.iter().zip(&part.moments) {
        let l = label as usize;
        if l >= scan.index.len() {
            scan.index.resize((l + 1).max(scan.index.len() * 2), 0);
        }
        if scan.index[l] == 0 {
            scan.labels.push(label);
            scan.moments.push(*m);
            scan.index[l] = scan.labels.len() as u32;
        } else {
            scan.moments[scan.index[l] as usize - 1].absorb(m);
        }
    }
    let idx = |l: u32| scan.index[l as usize] - 1;
    for ((a, b), mut faces) in part.pairs {
        match scan.pairs.entry((idx(a), idx(b))) {
            Entry::Vacant(e) => {
                e.insert(faces);
            }
            Entry::Occupied(mut e) => e.get_mut().append(&mut faces),
        }
    }
    for (a, mut faces) in part.container {
        match scan.container.entry(idx(a)) {
            Entry::Vacant(e) => {
                e.insert(faces);
            }
            Entry::Occupied(mut e) => e.get_mut().append(&mut faces),
        }
    }
    scan.grey_solid.0 += part.grey_solid.0;
    scan.grey_solid.1 += part.grey_solid.1;
    scan.grey_void.0 += part.grey_void.0;
    scan.grey_void.1 += part.grey_void.1;
}

/// Pass 1. Sources readable from several threads run `SLAB`-slice slabs on
/// rayon's threads; others the same slabs one after another.
pub(super) fn scan<'g>(
    labels: &mut dyn SliceSource,
    mut grey: Option<&mut (dyn SliceSource + 'g)>,
    container: u32,
) -> Result<Scan> {
    let shape = labels.shape();
    let nz = shape[0];
    let mut scan = Scan {
        index: Vec::new(),
        labels: Vec::new(),
        moments: Vec::new(),
        pairs: HashMap::new(),
        container: HashMap::new(),
        grey_solid: (0.0, 0),
        grey_void: (0.0, 0),
    };
    let slabs: Vec<(usize, usize)> = (0..nz)
        .step_by(SLAB)
        .map(|z0| (z0, (z0 + SLAB).min(nz)))
        .collect();
    let with_grey = grey.is_some();
    let shared_grey: Option<Option<&dyn SharedSource>> = match grey.as_deref() {
        None => Some(None),
        Some(g) => g.shared().map(Some),
    };
    if let (Some(shared), Some(shared_grey)) = (labels.shared(), shared_grey) {
        for batch in slabs.chunks(rayon::current_num_threads().max(1)) {
            let parts: Vec<Result<Partial>> = batch
                .par_iter()
                .map(|&range| {
                    let mut read = |z: usize, l: &mut [u32], g: &mut [f32]| {
                        shared.labels_at(z, l)?;
                        match shared_grey {
                            Some(s) => s.greys_at(z, g),
                            None => Ok(()),
                        }
                    };
                    slab(range, shape, container, with_grey, &mut read)
                })
                .collect();
            for p in parts {
                merge(&mut scan, p?);
            }
            // No thread reads now; the next batch reads one slice lower.
            if let (Some(&(z0, _)), Some(&(_, z1))) = (batch.first(), batch.last()) {
                let (a, b) = (z0.saturating_sub(1), if z1 == nz { nz } else { z1 - 1 });
                shared.release_at(a, b);
                if let Some(s) = shared_grey {
                    s.release_at(a, b);
                }
            }
        }
        return Ok(scan);
    }
    // In z order: each slice read once, the last of a slab kept for the
    // faces below the next.
    let mut kept: (usize, Vec<u32>, Vec<f32>) = (usize::MAX, Vec::new(), Vec::new());
    for &range in &slabs {
        let mut read = |z: usize, l: &mut [u32], g: &mut [f32]| -> Result<()> {
            if z == kept.0 {
                l.copy_from_slice(&kept.1);
                g.copy_from_slice(&kept.2);
                return Ok(());
            }
            labels.labels(z, l)?;
            labels.release(z, z + 1);
            if let Some(s) = grey.as_deref_mut() {
                s.greys(z, g)?;
                s.release(z, z + 1);
            }
            if (z + 1) % SLAB == 0 {
                kept = (z, l.to_vec(), g.to_vec());
            }
            Ok(())
        };
        let part = slab(range, shape, container, with_grey, &mut read)?;
        merge(&mut scan, part);
    }
    Ok(scan)
}
