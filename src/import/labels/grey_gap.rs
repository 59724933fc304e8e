//! The gap between two grains from the grey image: each kept surface face
//! moved to where the grey level crosses half-way from void to solid along
//! the face's axis (sub-voxel, from the partial volume), a sphere fitted to
//! those points on each side, and the distance between the two spheres
//! along the line of their centres with its standard deviation.

use super::volume::SliceSource;
use super::{gauss_newton, FitSettings, GrainGeometry, Side, Sphere, Zone};
use crate::error::Result;
use crate::scene;
use rayon::prelude::*;

/// Per zone and side, for each kept face: where the grey crosses `level`
/// along the face's axis, in voxels from the face (NaN: no crossing within
/// the face's two voxels and one more either side). Grain–grain zones only.
/// One pass over the grey image in z order, four slices held.
pub(super) fn crossings(
    grey: &mut dyn SliceSource,
    faces: &[[Vec<[u16; 3]>; 2]],
    zones: &[Zone],
    level: f32,
) -> Result<Vec<[Vec<f32>; 2]>> {
    let [nz, ny, nx] = grey.shape();
    let is_pair = |k: usize| matches!(zones[k].b, Side::Grain(_));
    let mut out: Vec<[Vec<f32>; 2]> = faces
        .iter()
        .enumerate()
        .map(|(k, f)| {
            if is_pair(k) {
                [vec![f32::NAN; f[0].len()], vec![f32::NAN; f[1].len()]]
            } else {
                Default::default()
            }
        })
        .collect();
    // (the slice of the face's lower voxel, zone·2 + side, face)
    let mut wanted: Vec<(u32, u32, u32)> = Vec::new();
    for (k, f) in faces.iter().enumerate().filter(|(k, _)| is_pair(*k)) {
        for (side, list) in f.iter().enumerate() {
            for (i, p) in list.iter().enumerate() {
                wanted.push((u32::from(p[2] / 2), (2 * k + side) as u32, i as u32));
            }
        }
    }
    if wanted.is_empty() {
        return Ok(out);
    }
    wanted.sort_unstable();
    let mut ring = vec![vec![0f32; ny * nx]; 4];
    let mut next = 0;
    let mut answer = |ring: &[Vec<f32>], read: usize, upto: usize, next: &mut usize| {
        while *next < wanted.len() && wanted[*next].0 as usize <= upto {
            let (_, ks, i) = wanted[*next];
            let (k, side) = (ks as usize / 2, ks as usize % 2);
            let p = faces[k][side][i as usize];
            let sample = |at: [i64; 3]| -> Option<f32> {
                let inside = at[0] >= 0
                    && at[1] >= 0
                    && at[2] >= 0
                    && (at[0] as usize) < nx
                    && (at[1] as usize) < ny
                    && (at[2] as usize) <= read
                    && at[2] as usize + 4 > read;
                inside
                    .then(|| ring[at[2] as usize % 4][at[1] as usize * nx + at[0] as usize] - level)
            };
            out[k][side][i as usize] = crossing(p, sample);
            *next += 1;
        }
    };
    for z in 0..nz {
        grey.greys(z, &mut ring[z % 4])?;
        grey.release(z, z + 1);
        // Profiles whose lower voxel is in slice z − 2 have every slice.
        if z >= 2 {
            answer(&ring, z, z - 2, &mut next);
        }
    }
    answer(&ring, nz - 1, usize::MAX, &mut next);
    Ok(out)
}

/// The crossing nearest the face (doubled coordinates `p`) of the profile
/// `sample` (grey − level) through its two voxels and one more either side.
fn crossing(p: [u16; 3], sample: impl Fn([i64; 3]) -> Option<f32>) -> f32 {
    let axis = (0..3).find(|&k| p[k] % 2 == 1).unwrap_or(0);
    let mut low = p.map(|v| i64::from(v / 2));
    low[axis] = i64::from((p[axis] - 1) / 2);
    let at = |j: i64| {
        let mut q = low;
        q[axis] += j;
        sample(q)
    };
    let (m1, s0, s1, s2) = (at(-1), at(0), at(1), at(2));
    // Segment from voxel j to j + 1: the crossing's offset from the face
    // (which sits at 0.5).
    let segment = |a: Option<f32>, b: Option<f32>, j: f32| -> Option<f32> {
        let (a, b) = (a?, b?);
        ((a <= 0.0) != (b <= 0.0)).then(|| j + a / (a - b) - 0.5)
    };
    if let Some(t) = segment(s0, s1, 0.0) {
        return t;
    }
    match (segment(m1, s0, -1.0), segment(s1, s2, 1.0)) {
        (Some(a), Some(b)) => {
            if a.abs() <= b.abs() {
                a
            } else {
                b
            }
        }
        (Some(a), None) => a,
        (None, Some(b)) => b,
        (None, None) => f32::NAN,
    }
}

/// Per grain–grain zone: the gap between the two grey-fitted spheres along
/// their centres' line and its standard deviation (voxels), from each side's
/// label-fitted sphere `solved` as start.
pub(super) fn gaps(
    faces: &[[Vec<[u16; 3]>; 2]],
    offsets: &[[Vec<f32>; 2]],
    solved: &[[Option<Sphere>; 2]],
    zones: &[Zone],
    grains: &[GrainGeometry],
    settings: &FitSettings,
) -> Vec<Option<(f64, f64)>> {
    (0..zones.len())
        .into_par_iter()
        .map(|k| {
            let Side::Grain(b) = zones[k].b else {
                return None;
            };
            let off = offsets.get(k)?;
            let grain = [zones[k].a as usize, b as usize];
            let mut fitted = [None; 2];
            for side in 0..2 {
                let points: Vec<[f64; 3]> = faces[k][side]
                    .iter()
                    .zip(&off[side])
                    .filter(|(_, o)| o.is_finite())
                    .map(|(p, &o)| {
                        let axis = (0..3).find(|&a| p[a] % 2 == 1).unwrap_or(0);
                        let mut q = p.map(|v| 0.5 * f64::from(v));
                        q[axis] += f64::from(o);
                        q
                    })
                    .collect();
                let prior = (
                    grains[grain[side]].radius_voxels,
                    settings.grey_radius_prior,
                );
                fitted[side] = gauss_newton(&points, solved[k][side]?, prior, settings);
            }
            let [Some(((ca, ra, _), cov_a)), Some(((cb, rb, _), cov_b))] = fitted else {
                return None;
            };
            let d = scene::sub(cb, ca);
            let dist = scene::norm(d);
            let u = d.map(|x| x / dist);
            // ∂gap/∂(c, r) is (−u, −1) for side a and (u, −1) for side b.
            let va = nalgebra::Vector4::new(-u[0], -u[1], -u[2], -1.0);
            let vb = nalgebra::Vector4::new(u[0], u[1], u[2], -1.0);
            let var = (va.transpose() * cov_a * va)[0] + (vb.transpose() * cov_b * vb)[0];
            (dist > 0.0).then(|| (dist - ra - rb, var.max(0.0).sqrt()))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::crossing;

    /// A straight edge of grey 1 → 0 across the voxels 0 | 1 of an x face,
    /// crossing ½ at x = 0.3 from the face: found at 0.3, and beyond the
    /// face's two voxels too.
    #[test]
    fn a_linear_edge_crosses_where_it_should() {
        let face = [1u16, 4, 6];
        for at in [-1.2f64, -0.7, -0.2, 0.0, 0.3, 0.45, 0.9, 1.4] {
            let edge = |q: [i64; 3]| Some((0.5 - 0.4 * (q[0] as f64 - 0.5 - at)) as f32 - 0.5);
            let got = crossing(face, edge) as f64;
            assert!((got - at).abs() < 1e-5, "{at}: {got}");
        }
        let flat = |_: [i64; 3]| Some(0.3f32);
        assert!(crossing(face, flat).is_nan());
        let outside = |q: [i64; 3]| (q[0] >= 0).then_some(1.0f32);
        assert!(crossing(face, outside).is_nan());
    }
}
