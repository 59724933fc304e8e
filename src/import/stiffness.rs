//! Single-crystal elasticity for 3DXRD strains: `--stiffness SPEC` of
//! `grainforce import gff`.
//!
//! SPEC is one of
//! - `cubic:C11,C12,C44`, `hexagonal:C11,C12,C13,C33,C44` or
//!   `trigonal:C11,C12,C13,C14,C33,C44` (classes 32, 3m, −3m), in GPa, in the
//!   standard (IEEE) crystal frame: z ∥ c, x ∥ a for hexagonal and trigonal;
//! - a named crystal: `quartz` (α-quartz, trigonal) or `zirconium` (α-Zr,
//!   hexagonal), constants below with their sources;
//! - a file holding the 6×6 stiffness in Voigt order (11, 22, 33, 23, 13, 12;
//!   engineering shear strains), GPa, whitespace or comma separated, `#`
//!   comments; it is used in the crystal frame of the grains' U as it stands.
//!
//! The grain orientation U (FitAllB, ImageD11: xfab's Busing–Levy Cartesian
//! crystal frame, x ∥ a*, z ∥ c) maps crystal to sample: T_sample = U T_crystal
//! Uᵀ. For hexagonal and cubic constants the standard frame and the Busing–Levy
//! frame give the same stiffness; for trigonal ones they do not (a is 30° from
//! a* about c, and C14 becomes a C15 term), so symbolic and named trigonal
//! constants are rotated by −30° about c into the Busing–Levy frame first.
//!
//! Hooke's law: σ = C ε with ε in Voigt form (ε11, ε22, ε33, 2ε23, 2ε13, 2ε12).

use crate::error::{Error, Result};
use crate::scene::{sym, Sym};
use std::path::Path;

pub type Mat3 = [[f64; 3]; 3];
pub type Voigt = [[f64; 6]; 6];

/// Voigt index → tensor (row, column), order 11, 22, 33, 23, 13, 12.
const VOIGT_PAIRS: [(usize, usize); 6] = [(0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1)];

/// α-quartz at 25 °C, GPa: H. J. McSkimin, P. Andreatch and R. N. Thurston,
/// "Elastic moduli of quartz versus hydrostatic pressure at 25 and −195.8 °C",
/// J. Appl. Phys. 36, 1624 (1965). C11, C12, C13, C14, C33, C44; the sign of
/// C14 is that of the IEEE 1949 axes for right-handed quartz.
pub(crate) const QUARTZ: [f64; 6] = [86.74, 6.99, 11.91, -17.91, 107.2, 57.94];

/// α-zirconium at 298 K, GPa: E. S. Fisher and C. J. Renken, "Single-crystal
/// elastic moduli and the hcp → bcc transformation in Ti, Zr, and Hf",
/// Phys. Rev. 135, A482 (1964). C11, C12, C13, C33, C44.
pub(crate) const ZIRCONIUM: [f64; 5] = [143.4, 72.8, 65.3, 164.8, 32.0];

/// A crystal's stiffness in Pa, in the crystal frame U maps from.
#[derive(Debug, Clone, PartialEq)]
pub struct Stiffness {
    /// What SPEC named, for messages.
    pub label: String,
    /// Voigt stiffness, Pa, in the frame of `constants_to_crystal`'s source.
    pub voigt: Voigt,
    /// Rotation from the frame of the constants to the crystal frame of U.
    pub constants_to_crystal: Mat3,
}

fn identity() -> Mat3 {
    [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
}

/// Rotation by `degrees` about z.
fn about_z(degrees: f64) -> Mat3 {
    let (s, c) = degrees.to_radians().sin_cos();
    [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
}

/// Hexagonal (C14 = 0) or trigonal Voigt stiffness, GPa → Pa.
fn trigonal(c11: f64, c12: f64, c13: f64, c14: f64, c33: f64, c44: f64) -> Voigt {
    let c66 = 0.5 * (c11 - c12);
    let m = [
        [c11, c12, c13, c14, 0.0, 0.0],
        [c12, c11, c13, -c14, 0.0, 0.0],
        [c13, c13, c33, 0.0, 0.0, 0.0],
        [c14, -c14, 0.0, c44, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, c44, c14],
        [0.0, 0.0, 0.0, 0.0, c14, c66],
    ];
    m.map(|row| row.map(|x| x * 1e9))
}

fn cubic(c11: f64, c12: f64, c44: f64) -> Voigt {
    let mut m = [[0.0; 6]; 6];
    for i in 0..3 {
        for j in 0..3 {
            m[i][j] = if i == j { c11 } else { c12 } * 1e9;
        }
        m[i + 3][i + 3] = c44 * 1e9;
    }
    m
}

impl Stiffness {
    /// Parses SPEC (see the module documentation).
    pub fn parse(spec: &str) -> Result<Stiffness> {
        let bad = |msg: String| Error::Invalid(format!("--stiffness {spec}: {msg}"));
        let named = spec.trim().to_ascii_lowercase();
        let (voigt, rotate) = match named.as_str() {
            "quartz" | "alpha-quartz" | "α-quartz" => {
                let [c11, c12, c13, c14, c33, c44] = QUARTZ;
                (trigonal(c11, c12, c13, c14, c33, c44), true)
            }
            "zirconium" | "zr" => {
                let [c11, c12, c13, c33, c44] = ZIRCONIUM;
                (trigonal(c11, c12, c13, 0.0, c33, c44), false)
            }
            _ => match spec.split_once(':') {
                Some((class, values)) => {
                    let v: Vec<f64> = values
                        .split(',')
                        .map(|x| {
                            x.trim()
                                .parse::<f64>()
                                .ok()
                                .filter(|x| x.is_finite())
                                .ok_or_else(|| bad(format!("`{}` is not a number", x.trim())))
                        })
                        .collect::<Result<_>>()?;
                    let need = |n: usize, names: &str| {
                        if v.len() == n {
                            Ok(())
                        } else {
                            Err(bad(format!(
                                "{class} needs {n} constants in GPa ({names}), got {}",
                                v.len()
                            )))
                        }
                    };
                    match class.trim().to_ascii_lowercase().as_str() {
                        "cubic" => {
                            need(3, "C11,C12,C44")?;
                            (cubic(v[0], v[1], v[2]), false)
                        }
                        "hexagonal" => {
                            need(5, "C11,C12,C13,C33,C44")?;
                            (trigonal(v[0], v[1], v[2], 0.0, v[3], v[4]), false)
                        }
                        "trigonal" => {
                            need(6, "C11,C12,C13,C14,C33,C44")?;
                            (trigonal(v[0], v[1], v[2], v[3], v[4], v[5]), true)
                        }
                        other => {
                            return Err(bad(format!(
                                "unknown symmetry `{other}` (cubic, hexagonal, trigonal, \
                                 quartz, zirconium, or a 6×6 file)"
                            )))
                        }
                    }
                }
                None => (read_matrix(Path::new(spec))?, false),
            },
        };
        check_positive_definite(&voigt).map_err(bad)?;
        Ok(Stiffness {
            label: spec.to_owned(),
            voigt,
            constants_to_crystal: if rotate { about_z(-30.0) } else { identity() },
        })
    }

    /// Sample-frame stress (Pa, [`Sym`] order) of a sample-frame strain, for a
    /// grain of orientation `u` (crystal → sample).
    pub fn stress(&self, u: &Mat3, strain_sample: &Sym) -> Sym {
        // Orientation of the constants' frame in the sample.
        let a = mul(u, &self.constants_to_crystal);
        let eps = rotate_into(&a, &tensor(strain_sample));
        let mut e = [0.0; 6];
        for (k, (i, j)) in VOIGT_PAIRS.iter().enumerate() {
            e[k] = if i == j {
                eps[*i][*j]
            } else {
                2.0 * eps[*i][*j]
            };
        }
        let mut s = [[0.0; 3]; 3];
        for (k, (i, j)) in VOIGT_PAIRS.iter().enumerate() {
            let v: f64 = (0..6).map(|l| self.voigt[k][l] * e[l]).sum();
            s[*i][*j] = v;
            s[*j][*i] = v;
        }
        from_tensor(&rotate_out_of(&a, &s))
    }

    /// The 6×6 Jacobian ∂σ_sample/∂ε_sample in [`Sym`] order (shear entries per
    /// tensor component ε_ij, i ≠ j): the map is linear, so columns are the
    /// stresses of unit strains.
    pub fn jacobian(&self, u: &Mat3) -> [[f64; 6]; 6] {
        let mut j = [[0.0; 6]; 6];
        for k in 0..6 {
            let mut unit = [0.0; 6];
            unit[k] = 1.0;
            let col = self.stress(u, &unit);
            for (i, row) in j.iter_mut().enumerate() {
                row[k] = col[i];
            }
        }
        j
    }
}

fn read_matrix(path: &Path) -> Result<Voigt> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let mut values = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("");
        for cell in line.split(|c: char| c == ',' || c.is_whitespace()) {
            if cell.is_empty() {
                continue;
            }
            match cell.parse::<f64>() {
                Ok(x) if x.is_finite() => values.push(x),
                _ => {
                    return Err(Error::data(
                        path,
                        Some(i + 1),
                        None,
                        format!("`{cell}` is not a number (a 6×6 stiffness in GPa)"),
                    ))
                }
            }
        }
    }
    if values.len() != 36 {
        return Err(Error::data(
            path,
            None,
            None,
            format!("a 6×6 stiffness needs 36 numbers, found {}", values.len()),
        ));
    }
    let mut m = [[0.0; 6]; 6];
    for (k, v) in values.into_iter().enumerate() {
        m[k / 6][k % 6] = v * 1e9;
    }
    let scale = m.iter().flatten().fold(0.0_f64, |a, x| a.max(x.abs()));
    for i in 0..6 {
        for j in 0..i {
            if (m[i][j] - m[j][i]).abs() > 1e-6 * scale {
                return Err(Error::data(
                    path,
                    Some(i + 1),
                    None,
                    format!(
                        "the stiffness is not symmetric: C{}{} = {} GPa but C{}{} = {} GPa",
                        i + 1,
                        j + 1,
                        m[i][j] / 1e9,
                        j + 1,
                        i + 1,
                        m[j][i] / 1e9
                    ),
                ));
            }
        }
    }
    Ok(m)
}

fn check_positive_definite(m: &Voigt) -> std::result::Result<(), String> {
    let matrix = nalgebra::SMatrix::<f64, 6, 6>::from_fn(|i, j| m[i][j]);
    if matrix.cholesky().is_none() {
        return Err("the stiffness is not positive definite (no stable crystal has it)".into());
    }
    Ok(())
}

/// Symmetric tensor of a [`Sym`].
pub(crate) fn tensor(s: &Sym) -> Mat3 {
    let mut t = [[0.0; 3]; 3];
    for (k, (i, j)) in sym::PAIRS.iter().enumerate() {
        t[*i][*j] = s[k];
        t[*j][*i] = s[k];
    }
    t
}

/// [`Sym`] of a symmetric tensor.
pub(crate) fn from_tensor(t: &Mat3) -> Sym {
    let mut s = [0.0; 6];
    for (k, (i, j)) in sym::PAIRS.iter().enumerate() {
        s[k] = t[*i][*j];
    }
    s
}

fn mul(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut c = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            c[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

fn transpose(a: &Mat3) -> Mat3 {
    let mut t = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            t[i][j] = a[j][i];
        }
    }
    t
}

/// Aᵀ T A: a sample-frame tensor in the frame A maps from.
pub(crate) fn rotate_into(a: &Mat3, t: &Mat3) -> Mat3 {
    mul(&transpose(a), &mul(t, a))
}

/// A T Aᵀ: a tensor in the frame A maps from, in the sample frame.
pub(crate) fn rotate_out_of(a: &Mat3, t: &Mat3) -> Mat3 {
    mul(a, &mul(t, &transpose(a)))
}
