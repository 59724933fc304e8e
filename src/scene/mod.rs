//! The scene: grains, contacts, walls and settings, as the data contract
//! (`docs/scene-format.md`) describes them. One type serves 2D and 3D: vectors
//! are `[f64; 3]` with z = 0 in 2D, and [`Scene::dim`] says which.

mod io;
pub mod noise;
mod select;
mod sums;
mod validate;

pub use io::{
    body_name, read_forces, read_scene, read_sequence, read_sequence_frames,
    sequence_has_acceleration_columns, write_file_atomically, write_forces, write_scene,
    write_sequence, ForceRow, Forces,
};
/// The CSV reading every grainforce table shares (importers use it too).
pub(crate) use io::{csv_cell, csv_number, parse_number, read_csv};
pub use select::{select_subassembly, Selection};
pub use sums::{contact_sums, wall_totals, ContactSums};

/// A point or vector; z is 0 in 2D.
pub type Vec3 = [f64; 3];

/// A symmetric tensor in the contract's column order: xx, yy, zz, xy, xz, yz.
/// In 2D only xx, yy and xy are used (zz, xz, yz stay 0).
pub type Sym = [f64; 6];

/// Index of each component of [`Sym`].
pub mod sym {
    pub const XX: usize = 0;
    pub const YY: usize = 1;
    pub const ZZ: usize = 2;
    pub const XY: usize = 3;
    pub const XZ: usize = 4;
    pub const YZ: usize = 5;
    /// (row, column) of each component.
    pub const PAIRS: [(usize, usize); 6] = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)];
    /// The components present in 2D, in the order the stress rows use.
    pub const COMPONENTS_2D: [usize; 3] = [XX, YY, XY];
    pub const COMPONENTS_3D: [usize; 6] = [XX, YY, ZZ, XY, XZ, YZ];
    pub fn components(dim: usize) -> &'static [usize] {
        if dim == 2 {
            &COMPONENTS_2D
        } else {
            &COMPONENTS_3D
        }
    }
}

/// Rotational inertia about the centroid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Inertia {
    /// 2D (about z), or isotropic in 3D.
    Scalar(f64),
    /// 3D tensor, in [`Sym`] order.
    Tensor(Sym),
}

impl Inertia {
    /// I·α.
    pub fn apply(&self, alpha: Vec3) -> Vec3 {
        match *self {
            Inertia::Scalar(i) => [i * alpha[0], i * alpha[1], i * alpha[2]],
            Inertia::Tensor(t) => sym_apply(&t, alpha),
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct Grain {
    pub id: String,
    pub position: Vec3,
    /// Area in 2D, volume in 3D.
    pub volume: f64,
    /// Volume-averaged Cauchy stress, tension positive.
    pub stress: Sym,
    pub mass: Option<f64>,
    /// Measured (kinematic) centroid acceleration.
    pub acceleration: Option<Vec3>,
    pub inertia: Option<Inertia>,
    /// Angular acceleration (2D: z component only).
    pub angular_acceleration: Option<Vec3>,
    /// Optional `radius` column (an extension the DEM writes); otherwise derived from volume.
    pub radius: Option<f64>,
    /// Optional standard error of each stress component (`sd_s_xx` … extension
    /// columns, e.g. from 3DXRD), in [`Sym`] order; lets inference weight rows.
    pub stress_sd: Option<Sym>,
}

impl Grain {
    pub fn new(id: impl Into<String>, position: Vec3, volume: f64, stress: Sym) -> Self {
        Grain {
            id: id.into(),
            position,
            volume,
            stress,
            mass: None,
            acceleration: None,
            inertia: None,
            angular_acceleration: None,
            radius: None,
            stress_sd: None,
        }
    }

    /// The radius: the `radius` column when given, else that of a disk (2D) or
    /// sphere (3D) of the same area/volume.
    pub fn equivalent_radius(&self, dim: usize) -> f64 {
        self.radius.unwrap_or_else(|| {
            if dim == 2 {
                (self.volume / std::f64::consts::PI).sqrt()
            } else {
                (3.0 * self.volume / (4.0 * std::f64::consts::PI)).cbrt()
            }
        })
    }
}

/// The second body of a contact.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Body {
    /// Index into [`Scene::grains`].
    Grain(usize),
    /// Index into [`Scene::walls`].
    Wall(usize),
}

#[derive(Debug, Clone, PartialEq)]
pub struct Contact {
    pub id: String,
    /// Index into [`Scene::grains`] of the first body.
    pub a: usize,
    pub b: Body,
    pub point: Vec3,
    /// Unit normal from `a` towards `b`.
    pub normal: Vec3,
    /// Per-contact friction coefficient; overrides the scene-wide value.
    pub mu: Option<f64>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Wall {
    pub name: String,
    /// Total force the wall exerts on the grains (load cell), when measured.
    pub measured_force: Option<Vec3>,
}

/// scene.json.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Settings {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gravity: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mu: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub thickness: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub description: Option<String>,
}

/// One frame of a scene (a static scene is a single frame without a number).
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    pub dim: usize,
    pub frame: Option<i64>,
    pub grains: Vec<Grain>,
    pub contacts: Vec<Contact>,
    pub walls: Vec<Wall>,
    pub settings: Settings,
}

impl Scene {
    /// An empty scene; [`Scene::validate`] (run by the readers and by
    /// assembly) rejects a dimension other than 2 or 3.
    pub fn new(dim: usize) -> Self {
        Scene {
            dim,
            frame: None,
            grains: Vec::new(),
            contacts: Vec::new(),
            walls: Vec::new(),
            settings: Settings::default(),
        }
    }

    /// Gravity as a vector (zero unless scene.json gives it).
    pub fn gravity(&self) -> Vec3 {
        let mut g = [0.0; 3];
        if let Some(v) = &self.settings.gravity {
            for (k, x) in v.iter().take(3).enumerate() {
                g[k] = *x;
            }
        }
        g
    }

    /// The friction coefficient of a contact: its own, else the scene's, else none.
    pub fn contact_mu(&self, contact: &Contact) -> Option<f64> {
        contact.mu.or(self.settings.mu)
    }

    pub fn wall_index(&self, name: &str) -> Option<usize> {
        self.walls.iter().position(|w| w.name == name)
    }

    /// Index of the wall with this name, adding it (unmeasured) when new.
    pub fn wall_or_insert(&mut self, name: &str) -> usize {
        match self.wall_index(name) {
            Some(i) => i,
            None => {
                self.walls.push(Wall {
                    name: name.to_owned(),
                    measured_force: None,
                });
                self.walls.len() - 1
            }
        }
    }

    /// Whether any grain carries dynamic data (accelerations).
    pub fn has_accelerations(&self) -> bool {
        self.grains
            .iter()
            .any(|g| g.acceleration.is_some() || g.angular_acceleration.is_some())
    }

    /// The net load a grain's contacts must supply: force m (a − g) and moment
    /// I α (zero for whatever the scene does not give).
    pub fn momentum_target(&self, grain: &Grain) -> (Vec3, Vec3) {
        self.momentum_target_with(grain, self.gravity())
    }

    /// [`Scene::momentum_target`] under the given gravity.
    pub fn momentum_target_with(&self, grain: &Grain, g: Vec3) -> (Vec3, Vec3) {
        let mut force = [0.0; 3];
        if let Some(m) = grain.mass {
            let a = grain.acceleration.unwrap_or([0.0; 3]);
            for k in 0..3 {
                force[k] = m * (a[k] - g[k]);
            }
        }
        let moment = match (grain.inertia, grain.angular_acceleration) {
            (Some(i), Some(alpha)) => i.apply(alpha),
            _ => [0.0; 3],
        };
        (force, moment)
    }
}

pub fn dot(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

pub fn sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

pub fn norm(a: Vec3) -> f64 {
    dot(a, a).sqrt()
}

pub fn cross(a: Vec3, b: Vec3) -> Vec3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// sym(r ⊗ f) in [`Sym`] order.
pub fn sym_outer(r: Vec3, f: Vec3) -> Sym {
    let mut s = [0.0; 6];
    for (k, &(i, j)) in sym::PAIRS.iter().enumerate() {
        s[k] = 0.5 * (r[i] * f[j] + r[j] * f[i]);
    }
    s
}

/// A symmetric tensor times a vector.
pub fn sym_apply(t: &Sym, v: Vec3) -> Vec3 {
    [
        t[0] * v[0] + t[3] * v[1] + t[4] * v[2],
        t[3] * v[0] + t[1] * v[1] + t[5] * v[2],
        t[4] * v[0] + t[5] * v[1] + t[2] * v[2],
    ]
}

/// Tangent basis of a unit normal: one vector in 2D (n rotated by +90°), two in 3D.
pub fn tangents(dim: usize, n: Vec3) -> (Vec3, Vec3) {
    if dim == 2 {
        ([-n[1], n[0], 0.0], [0.0; 3])
    } else {
        // Pick the axis least aligned with n for a well-conditioned basis.
        let axis = if n[0].abs() <= n[1].abs() && n[0].abs() <= n[2].abs() {
            [1.0, 0.0, 0.0]
        } else if n[1].abs() <= n[2].abs() {
            [0.0, 1.0, 0.0]
        } else {
            [0.0, 0.0, 1.0]
        };
        let t1 = cross(n, axis);
        let l = norm(t1);
        let t1 = [t1[0] / l, t1[1] / l, t1[2] / l];
        (t1, cross(n, t1))
    }
}

/// Volume of the assembly Ω: the bounding box of the grains (centroid ± radius),
/// an area in 2D.
pub fn assembly_volume(scene: &Scene) -> f64 {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for g in &scene.grains {
        let r = g.equivalent_radius(scene.dim);
        for k in 0..scene.dim {
            lo[k] = lo[k].min(g.position[k] - r);
            hi[k] = hi[k].max(g.position[k] + r);
        }
    }
    (0..scene.dim).map(|k| (hi[k] - lo[k]).max(0.0)).product()
}

/// Macroscopic stress (eq. 2.1) ⟨σ⟩ = (1/Ω) Σ_c sym(f ⊗ d) of a force field,
/// with d the branch vector between centroids (for a wall contact, the arm from
/// the grain's centroid to the contact point), tension positive.
pub fn macroscopic_stress(scene: &Scene, forces: &[Vec3], volume: f64) -> Sym {
    let mut s = [0.0; 6];
    for (c, f) in scene.contacts.iter().zip(forces) {
        let a = scene.grains[c.a].position;
        // f acts on a; the branch vector points from b to a so that compression is negative.
        let d = match c.b {
            Body::Grain(b) => sub(a, scene.grains[b].position),
            Body::Wall(_) => sub(a, c.point),
        };
        let t = sym_outer(d, *f);
        for k in 0..6 {
            s[k] -= t[k] / volume;
        }
    }
    s
}
