//! CSV reading and writing of scene folders and forces.csv, exactly as the data
//! contract says. Every error names the file, line and column; every write goes
//! to a temporary file first and is renamed into place, so a failed run leaves
//! no half-written output.

use super::{Body, Contact, Grain, Inertia, Scene, Settings, Sym, Vec3, Wall};
use crate::error::{Error, Result};
use std::collections::{BTreeMap, BTreeSet, HashMap, HashSet};
use std::io::Write;
use std::path::{Path, PathBuf};

/// A parsed CSV file: header and records with their line numbers.
struct Table {
    path: PathBuf,
    columns: HashMap<String, usize>,
    rows: Vec<(usize, csv::StringRecord)>,
}

/// A CSV's header map and its data rows with their line numbers.
pub(crate) type CsvRows = (HashMap<String, usize>, Vec<(usize, csv::StringRecord)>);

/// Reads a CSV the way every grainforce table is read: trimmed cells, `#`
/// comments, blank rows skipped, errors located by file and line.
pub(crate) fn read_csv(path: &Path) -> Result<CsvRows> {
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .comment(Some(b'#'))
        .from_reader(std::io::BufReader::new(file));
    let headers = reader.headers().map_err(|e| csv_error(path, e))?.clone();
    let columns = read_header(path, &headers)?;
    let mut rows = Vec::new();
    for record in reader.records() {
        let record = record.map_err(|e| csv_error(path, e))?;
        let line = record.position().map(|p| p.line() as usize).unwrap_or(0);
        if record.iter().all(str::is_empty) {
            continue;
        }
        rows.push((line, record));
    }
    Ok((columns, rows))
}

/// The header's column positions by name (empty names ignored).
fn read_header(path: &Path, headers: &csv::StringRecord) -> Result<HashMap<String, usize>> {
    let mut columns = HashMap::new();
    for (i, name) in headers.iter().enumerate() {
        if name.is_empty() {
            continue;
        }
        if columns.insert(name.to_owned(), i).is_some() {
            return Err(Error::data(
                path,
                Some(1),
                Some(name),
                "column appears twice in the header",
            ));
        }
    }
    Ok(columns)
}

/// A required, non-empty cell.
pub(crate) fn csv_cell<'a>(
    path: &Path,
    columns: &HashMap<String, usize>,
    record: &'a csv::StringRecord,
    line: usize,
    column: &str,
) -> Result<&'a str> {
    let Some(&i) = columns.get(column) else {
        return Err(Error::data(
            path,
            Some(1),
            Some(column),
            format!("required column `{column}` is missing from the header"),
        ));
    };
    match record.get(i) {
        Some(s) if !s.is_empty() => Ok(s),
        _ => Err(Error::data(path, Some(line), Some(column), "empty value")),
    }
}

/// A required finite number.
pub(crate) fn csv_number(
    path: &Path,
    columns: &HashMap<String, usize>,
    record: &csv::StringRecord,
    line: usize,
    column: &str,
) -> Result<f64> {
    parse_number(
        path,
        line,
        column,
        csv_cell(path, columns, record, line, column)?,
    )
}

/// A finite number, or an error naming the file, line and column.
pub(crate) fn parse_number(path: &Path, line: usize, column: &str, s: &str) -> Result<f64> {
    let value: f64 = s.parse().map_err(|_| {
        Error::data(
            path,
            Some(line),
            Some(column),
            format!("`{s}` is not a number"),
        )
    })?;
    if !value.is_finite() {
        return Err(Error::data(
            path,
            Some(line),
            Some(column),
            format!("`{s}` is not a finite number"),
        ));
    }
    Ok(value)
}

/// Reads the header of a CSV (the column names).
pub(crate) fn csv_header(path: &Path) -> Result<Vec<String>> {
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .comment(Some(b'#'))
        .from_reader(std::io::BufReader::new(file));
    let headers = reader.headers().map_err(|e| csv_error(path, e))?;
    Ok(headers.iter().map(str::to_owned).collect())
}

impl Table {
    fn read(path: &Path) -> Result<Table> {
        let (columns, rows) = read_csv(path)?;
        Ok(Table {
            path: path.to_owned(),
            columns,
            rows,
        })
    }

    /// Reads the rows whose frame `keep` accepts (rows without a frame
    /// column or cell are kept); the others are only scanned for their frame
    /// cell, so memory holds the kept frames only.
    fn read_frames(path: &Path, keep: &dyn Fn(i64) -> bool) -> Result<Table> {
        let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
        let mut reader = csv::ReaderBuilder::new()
            .trim(csv::Trim::All)
            .comment(Some(b'#'))
            .from_reader(std::io::BufReader::new(file));
        let header = reader.headers().map_err(|e| csv_error(path, e))?.clone();
        let columns = read_header(path, &header)?;
        let mut table = Table {
            path: path.to_owned(),
            columns,
            rows: Vec::new(),
        };
        let frame_column = table.columns.get("frame").copied();
        let mut record = csv::StringRecord::new();
        while reader
            .read_record(&mut record)
            .map_err(|e| csv_error(path, e))?
        {
            let line = record.position().map(|p| p.line() as usize).unwrap_or(0);
            if record.iter().all(str::is_empty) {
                continue;
            }
            let wanted = match frame_column.and_then(|i| record.get(i)) {
                Some(cell) if !cell.is_empty() => match table.frame(&record, line)? {
                    Some(k) => keep(k),
                    None => true,
                },
                _ => true,
            };
            if wanted {
                table.rows.push((line, record.clone()));
            }
        }
        Ok(table)
    }

    fn has(&self, column: &str) -> bool {
        self.columns.contains_key(column)
    }

    fn require(&self, column: &str) -> Result<usize> {
        self.columns.get(column).copied().ok_or_else(|| {
            Error::data(
                &self.path,
                Some(1),
                Some(column),
                format!("required column `{column}` is missing from the header"),
            )
        })
    }

    fn text<'a>(
        &self,
        record: &'a csv::StringRecord,
        line: usize,
        column: &str,
    ) -> Result<&'a str> {
        csv_cell(&self.path, &self.columns, record, line, column)
    }

    /// A finite number; `None` when the column is absent or the cell empty.
    fn optional_number(
        &self,
        record: &csv::StringRecord,
        line: usize,
        column: &str,
    ) -> Result<Option<f64>> {
        let Some(&i) = self.columns.get(column) else {
            return Ok(None);
        };
        let s = record.get(i).unwrap_or("");
        if s.is_empty() {
            return Ok(None);
        }
        parse_number(&self.path, line, column, s).map(Some)
    }

    fn number(&self, record: &csv::StringRecord, line: usize, column: &str) -> Result<f64> {
        self.require(column)?;
        self.optional_number(record, line, column)?
            .ok_or_else(|| Error::data(&self.path, Some(line), Some(column), "empty value"))
    }

    fn vector(&self, record: &csv::StringRecord, line: usize, names: &[&str]) -> Result<Vec3> {
        let mut v = [0.0; 3];
        for (k, name) in names.iter().enumerate() {
            v[k] = self.number(record, line, name)?;
        }
        Ok(v)
    }

    /// A vector whose columns are all absent (None) or all present.
    fn optional_vector(
        &self,
        record: &csv::StringRecord,
        line: usize,
        names: &[&str],
    ) -> Result<Option<Vec3>> {
        if !names.iter().any(|n| self.has(n)) {
            return Ok(None);
        }
        let mut v = [0.0; 3];
        let mut present = 0;
        for (k, name) in names.iter().enumerate() {
            if !self.has(name) {
                return Err(Error::data(
                    &self.path,
                    Some(1),
                    Some(name),
                    format!(
                        "column `{name}` is missing while {} are given",
                        names.join(", ")
                    ),
                ));
            }
            if let Some(x) = self.optional_number(record, line, name)? {
                v[k] = x;
                present += 1;
            }
        }
        match present {
            0 => Ok(None),
            n if n == names.len() => Ok(Some(v)),
            _ => Err(Error::data(
                &self.path,
                Some(line),
                Some(names[0]),
                format!("some but not all of {} are given", names.join(", ")),
            )),
        }
    }

    /// Like [`Table::optional_vector`] for any number of columns.
    fn optional_numbers(
        &self,
        record: &csv::StringRecord,
        line: usize,
        names: &[&str],
    ) -> Result<Option<Vec<f64>>> {
        if !names.iter().any(|n| self.has(n)) {
            return Ok(None);
        }
        let mut values = Vec::with_capacity(names.len());
        for name in names {
            if !self.has(name) {
                return Err(Error::data(
                    &self.path,
                    Some(1),
                    Some(name),
                    format!(
                        "column `{name}` is missing while {} are given",
                        names.join(", ")
                    ),
                ));
            }
            if let Some(x) = self.optional_number(record, line, name)? {
                values.push(x);
            }
        }
        match values.len() {
            0 => Ok(None),
            n if n == names.len() => Ok(Some(values)),
            _ => Err(Error::data(
                &self.path,
                Some(line),
                Some(names[0]),
                format!("some but not all of {} are given", names.join(", ")),
            )),
        }
    }

    fn frame(&self, record: &csv::StringRecord, line: usize) -> Result<Option<i64>> {
        let Some(&i) = self.columns.get("frame") else {
            return Ok(None);
        };
        let s = record.get(i).unwrap_or("");
        s.parse::<i64>().map(Some).map_err(|_| {
            Error::data(
                &self.path,
                Some(line),
                Some("frame"),
                format!("`{s}` is not an integer frame number"),
            )
        })
    }
}

fn csv_error(path: &Path, e: csv::Error) -> Error {
    let line = e.position().map(|p| p.line() as usize);
    let message = match e.kind() {
        csv::ErrorKind::UnequalLengths {
            expected_len, len, ..
        } => {
            format!("this row has {len} fields where the header has {expected_len}")
        }
        _ => e.to_string(),
    };
    Error::data(path, line, None, message)
}

fn coordinate_names(dim: usize, prefix: &str) -> Vec<String> {
    ["x", "y", "z"][..dim]
        .iter()
        .map(|c| format!("{prefix}{c}"))
        .collect()
}

fn names(v: &[String]) -> Vec<&str> {
    v.iter().map(String::as_str).collect()
}

/// Reads one scene; a folder holding several frames is an error here (use
/// [`read_sequence`]).
pub fn read_scene(dir: &Path) -> Result<Scene> {
    let mut frames = read_sequence(dir)?;
    if frames.len() != 1 {
        return Err(Error::Invalid(format!(
            "{}: holds a sequence of {} frames where one scene was expected",
            dir.display(),
            frames.len()
        )));
    }
    Ok(frames.remove(0))
}

/// Reads a scene folder: one frame, or a sequence when the files carry `frame`.
pub fn read_sequence(dir: &Path) -> Result<Vec<Scene>> {
    read_sequence_where(dir, None)
}

/// Reads the frames numbered `first..=last` of a sequence folder (all of a
/// scene without frame numbers). Rows of other frames are scanned for their
/// frame number only: neither parsed nor kept, so a block of a long
/// sequence costs the memory of the block.
pub fn read_sequence_frames(dir: &Path, first: i64, last: i64) -> Result<Vec<Scene>> {
    read_sequence_where(dir, Some((first, last)))
}

/// Whether a sequence folder's grains.csv has acceleration columns (read
/// from its header only).
pub fn sequence_has_acceleration_columns(dir: &Path) -> Result<bool> {
    check_folder(dir)?;
    let header = csv_header(&dir.join("grains.csv"))?;
    Ok(header
        .iter()
        .any(|c| matches!(c.as_str(), "a_x" | "alpha" | "alpha_x")))
}

fn check_folder(dir: &Path) -> Result<()> {
    if !dir.is_dir() {
        return Err(Error::io(
            dir,
            std::io::Error::new(std::io::ErrorKind::NotFound, "scene folder not found"),
        ));
    }
    Ok(())
}

fn read_sequence_where(dir: &Path, range: Option<(i64, i64)>) -> Result<Vec<Scene>> {
    check_folder(dir)?;
    let settings = read_settings(&dir.join("scene.json"))?;
    let read = |path: &Path| match range {
        None => Table::read(path),
        Some((first, last)) => Table::read_frames(path, &|k| (first..=last).contains(&k)),
    };
    let grains = read(&dir.join("grains.csv"))?;
    let contacts = read(&dir.join("contacts.csv"))?;
    let walls_path = dir.join("walls.csv");
    let walls = if walls_path.exists() {
        Some(read(&walls_path)?)
    } else {
        None
    };
    let dim = if grains.has("z") { 3 } else { 2 };
    let sequence = grains.has("frame");
    if sequence && !contacts.has("frame") {
        return Err(Error::data(
            &contacts.path,
            Some(1),
            Some("frame"),
            "grains.csv has a `frame` column, so contacts.csv must have one too",
        ));
    }
    if !sequence && contacts.has("frame") {
        return Err(Error::data(
            &grains.path,
            Some(1),
            Some("frame"),
            "contacts.csv has a `frame` column, so grains.csv must have one too",
        ));
    }

    let mut frames: BTreeMap<Option<i64>, Scene> = BTreeMap::new();
    let mut ids: HashMap<Option<i64>, HashMap<String, usize>> = HashMap::new();
    for (line, record) in &grains.rows {
        let frame = grains.frame(record, *line)?;
        let grain = parse_grain(&grains, record, *line, dim)?;
        let scene = frames.entry(frame).or_insert_with(|| {
            let mut s = Scene::new(dim);
            s.frame = frame;
            s.settings = settings.clone();
            s
        });
        let frame_ids = ids.entry(frame).or_default();
        if frame_ids
            .insert(grain.id.clone(), scene.grains.len())
            .is_some()
        {
            return Err(Error::data(
                &grains.path,
                Some(*line),
                Some("id"),
                format!("duplicate grain id `{}`", grain.id),
            ));
        }
        scene.grains.push(grain);
    }
    if frames.is_empty() {
        return Err(match range {
            Some((first, last)) if sequence => Error::Invalid(format!(
                "{}: no frame of the sequence lies in the range {first}..{last}",
                dir.display()
            )),
            _ => Error::data(&grains.path, None, None, "no grains"),
        });
    }

    let mut wall_loads: HashMap<(Option<i64>, String), Vec3> = HashMap::new();
    // Sorted: walls a frame's contacts do not name join it in an order that
    // does not depend on the run (nor on the frames read).
    let mut wall_names: BTreeSet<String> = BTreeSet::new();
    if let Some(walls) = &walls {
        walls.require("wall")?;
        for (line, record) in &walls.rows {
            let name = walls.text(record, *line, "wall")?.to_owned();
            let frame = walls.frame(record, *line)?;
            let f = walls.vector(record, *line, &names(&coordinate_names(dim, "f_")))?;
            if wall_loads.insert((frame, name.clone()), f).is_some() {
                return Err(Error::data(
                    &walls.path,
                    Some(*line),
                    Some("wall"),
                    format!("wall `{name}` is listed twice"),
                ));
            }
            wall_names.insert(name);
        }
    }

    let point = coordinate_names(dim, "");
    let normal = coordinate_names(dim, "n_");
    let mut contact_ids: HashMap<Option<i64>, HashSet<String>> = HashMap::new();
    for (line, record) in &contacts.rows {
        let line = *line;
        let frame = contacts.frame(record, line)?;
        let id = contacts.text(record, line, "id")?.to_owned();
        let Some(scene) = frames.get_mut(&frame) else {
            return Err(Error::data(
                &contacts.path,
                Some(line),
                Some("frame"),
                format!(
                    "frame {} has no grains in grains.csv",
                    frame.unwrap_or_default()
                ),
            ));
        };
        if !contact_ids.entry(frame).or_default().insert(id.clone()) {
            return Err(Error::data(
                &contacts.path,
                Some(line),
                Some("id"),
                format!("duplicate contact id `{id}`"),
            ));
        }
        let frame_ids = &ids[&frame];
        let a_name = contacts.text(record, line, "a")?;
        let Some(&a) = frame_ids.get(a_name) else {
            return Err(Error::data(
                &contacts.path,
                Some(line),
                Some("a"),
                format!("grain `{a_name}` is not in grains.csv"),
            ));
        };
        let b_name = contacts.text(record, line, "b")?;
        let b = if let Some(&b) = frame_ids.get(b_name) {
            if b == a {
                return Err(Error::data(
                    &contacts.path,
                    Some(line),
                    Some("b"),
                    "a contact of a grain with itself",
                ));
            }
            Body::Grain(b)
        } else if wall_names.contains(b_name) || b_name.parse::<f64>().is_err() {
            Body::Wall(scene.wall_or_insert(b_name))
        } else {
            return Err(Error::data(
                &contacts.path,
                Some(line),
                Some("b"),
                format!(
                    "`{b_name}` is neither a grain in grains.csv nor a wall (walls have names, or appear in walls.csv)"
                ),
            ));
        };
        let x = contacts.vector(record, line, &names(&point))?;
        let mut n = contacts.vector(record, line, &names(&normal))?;
        let length = super::norm(n);
        if length == 0.0 {
            return Err(Error::data(
                &contacts.path,
                Some(line),
                Some("n_x"),
                "the normal is zero",
            ));
        }
        if (length - 1.0).abs() > 1e-2 {
            return Err(Error::data(
                &contacts.path,
                Some(line),
                Some("n_x"),
                format!("the normal is not a unit vector (its length is {length})"),
            ));
        }
        for c in &mut n {
            *c /= length;
        }
        let mu = contacts.optional_number(record, line, "mu")?;
        if let Some(m) = mu {
            if m < 0.0 {
                return Err(Error::data(
                    &contacts.path,
                    Some(line),
                    Some("mu"),
                    "friction coefficient is negative",
                ));
            }
        }
        scene.contacts.push(Contact {
            id,
            a,
            b,
            point: x,
            normal: n,
            mu,
        });
    }

    for scene in frames.values_mut() {
        for name in &wall_names {
            scene.wall_or_insert(name);
        }
        for wall in &mut scene.walls {
            wall.measured_force = wall_loads
                .get(&(scene.frame, wall.name.clone()))
                .or_else(|| wall_loads.get(&(None, wall.name.clone())))
                .copied();
        }
    }
    let frames: Vec<Scene> = frames.into_values().collect();
    // The rows were checked one by one above; this catches what spans rows.
    for scene in &frames {
        scene
            .validate()
            .map_err(|e| Error::Invalid(format!("{}: {e}", dir.display())))?;
    }
    Ok(frames)
}

fn parse_grain(t: &Table, record: &csv::StringRecord, line: usize, dim: usize) -> Result<Grain> {
    let id = t.text(record, line, "id")?.to_owned();
    let position = t.vector(record, line, &names(&coordinate_names(dim, "")))?;
    let volume = t.number(record, line, "volume")?;
    if volume <= 0.0 {
        return Err(Error::data(
            &t.path,
            Some(line),
            Some("volume"),
            format!("volume must be positive, got {volume}"),
        ));
    }
    let mut stress: Sym = [0.0; 6];
    for &k in super::sym::components(dim) {
        stress[k] = t.number(record, line, STRESS_COLUMNS[k])?;
    }
    let mass = t.optional_number(record, line, "mass")?;
    if let Some(m) = mass {
        if m <= 0.0 {
            return Err(Error::data(
                &t.path,
                Some(line),
                Some("mass"),
                format!("mass must be positive, got {m}"),
            ));
        }
    }
    let acceleration = t.optional_vector(record, line, &names(&coordinate_names(dim, "a_")))?;
    let (inertia, angular_acceleration) = if dim == 2 {
        let i = t
            .optional_number(record, line, "inertia")?
            .map(Inertia::Scalar);
        let alpha = t
            .optional_number(record, line, "alpha")?
            .map(|a| [0.0, 0.0, a]);
        (i, alpha)
    } else {
        let tensor_names: Vec<&str> = STRESS_COLUMNS.iter().map(|s| &s[2..]).collect();
        let tensor_cols: Vec<String> = tensor_names.iter().map(|c| format!("i_{c}")).collect();
        let i = if let Some(tensor) = t.optional_vector(record, line, &names(&tensor_cols[..3]))? {
            let mut full = [tensor[0], tensor[1], tensor[2], 0.0, 0.0, 0.0];
            if let Some(off) = t.optional_vector(record, line, &names(&tensor_cols[3..]))? {
                full[3..].copy_from_slice(&off);
            }
            Some(Inertia::Tensor(full))
        } else {
            t.optional_number(record, line, "inertia")?
                .map(Inertia::Scalar)
        };
        let alpha = t.optional_vector(record, line, &["alpha_x", "alpha_y", "alpha_z"])?;
        (i, alpha)
    };
    let radius = t.optional_number(record, line, "radius")?;
    let sd_names: Vec<&str> = super::sym::components(dim)
        .iter()
        .map(|&k| SD_COLUMNS[k])
        .collect();
    let stress_sd = t.optional_numbers(record, line, &sd_names)?.map(|values| {
        let mut sd: Sym = [0.0; 6];
        for (&k, v) in super::sym::components(dim).iter().zip(values) {
            sd[k] = v;
        }
        sd
    });
    if let Some(sd) = &stress_sd {
        if let Some(k) = sd.iter().position(|&x| x < 0.0) {
            return Err(Error::data(
                &t.path,
                Some(line),
                Some(SD_COLUMNS[k]),
                "a standard error cannot be negative",
            ));
        }
    }
    Ok(Grain {
        id,
        position,
        volume,
        stress,
        mass,
        acceleration,
        inertia,
        angular_acceleration,
        radius,
        stress_sd,
    })
}

const STRESS_COLUMNS: [&str; 6] = ["s_xx", "s_yy", "s_zz", "s_xy", "s_xz", "s_yz"];
/// Standard errors of the stress components (extension columns).
const SD_COLUMNS: [&str; 6] = [
    "sd_s_xx", "sd_s_yy", "sd_s_zz", "sd_s_xy", "sd_s_xz", "sd_s_yz",
];

fn read_settings(path: &Path) -> Result<Settings> {
    if !path.exists() {
        return Ok(Settings::default());
    }
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let settings: Settings = serde_json::from_str(&text).map_err(|e| {
        Error::data(
            path,
            Some(e.line()),
            None,
            format!("invalid scene.json: {e}"),
        )
    })?;
    if let Some(g) = &settings.gravity {
        if g.len() < 2 || g.len() > 3 || g.iter().any(|x| !x.is_finite()) {
            return Err(Error::data(
                path,
                None,
                Some("gravity"),
                "gravity must be 2 or 3 finite numbers",
            ));
        }
    }
    if let Some(mu) = settings.mu {
        if !(mu >= 0.0 && mu.is_finite()) {
            return Err(Error::data(
                path,
                None,
                Some("mu"),
                "mu must be a finite non-negative number",
            ));
        }
    }
    Ok(settings)
}

/// Writes `contents` to `path` through a temporary file in the same folder.
fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> Result<()> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let mut tmp = tempfile::NamedTempFile::new_in(dir).map_err(|e| Error::io(path, e))?;
    {
        let mut buffered = std::io::BufWriter::new(tmp.as_file_mut());
        write(&mut buffered).map_err(|e| Error::io(path, e))?;
        buffered.flush().map_err(|e| Error::io(path, e))?;
    }
    // Temporary files are private (0600); the output is an ordinary file.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(tmp.path(), std::fs::Permissions::from_mode(0o644))
            .map_err(|e| Error::io(path, e))?;
    }
    tmp.persist(path).map_err(|e| Error::io(path, e.error))?;
    Ok(())
}

/// Writes bytes to `path` atomically (temporary file in the same folder, then rename).
pub fn write_file_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomically(path, |out| out.write_all(bytes))
}

/// Shortest text that reads back to the same f64.
fn num(x: f64) -> String {
    format!("{x}")
}

fn csv_line(out: &mut dyn Write, cells: &[String]) -> std::io::Result<()> {
    let escaped: Vec<String> = cells
        .iter()
        .map(|c| {
            if c.contains([',', '"', '\n']) {
                format!("\"{}\"", c.replace('"', "\"\""))
            } else {
                c.clone()
            }
        })
        .collect();
    writeln!(out, "{}", escaped.join(","))
}

/// Writes one scene to a folder (created if needed).
pub fn write_scene(dir: &Path, scene: &Scene) -> Result<()> {
    write_sequence(dir, std::slice::from_ref(scene))
}

/// Writes frames to a folder; a `frame` column is written when any frame has a number.
pub fn write_sequence(dir: &Path, frames: &[Scene]) -> Result<()> {
    let Some(first) = frames.first() else {
        return Err(Error::Invalid("no frames to write".into()));
    };
    for scene in frames {
        scene.validate()?;
    }
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let dim = first.dim;
    let framed = frames.iter().any(|s| s.frame.is_some());
    let all_grains = || frames.iter().flat_map(|s| s.grains.iter());
    let has_mass = all_grains().any(|g| g.mass.is_some());
    let has_acc = all_grains().any(|g| g.acceleration.is_some());
    let has_inertia = all_grains().any(|g| g.inertia.is_some());
    let has_alpha = all_grains().any(|g| g.angular_acceleration.is_some());
    let has_radius = all_grains().any(|g| g.radius.is_some());
    let has_sd = all_grains().any(|g| g.stress_sd.is_some());
    let coords = coordinate_names(dim, "");
    let opt = |x: Option<f64>| x.map(num).unwrap_or_default();

    write_atomically(&dir.join("grains.csv"), |out| {
        let mut header: Vec<String> = vec!["id".into()];
        if framed {
            header.insert(0, "frame".into());
        }
        header.extend(coords.iter().cloned());
        header.push("volume".into());
        header.extend(
            super::sym::components(dim)
                .iter()
                .map(|&k| STRESS_COLUMNS[k].to_owned()),
        );
        if has_radius {
            header.push("radius".into());
        }
        if has_sd {
            header.extend(
                super::sym::components(dim)
                    .iter()
                    .map(|&k| SD_COLUMNS[k].to_owned()),
            );
        }
        if has_mass {
            header.push("mass".into());
        }
        if has_acc {
            header.extend(coordinate_names(dim, "a_"));
        }
        if has_inertia {
            header.push("inertia".into());
        }
        if has_alpha {
            if dim == 2 {
                header.push("alpha".into());
            } else {
                header.extend(["alpha_x".into(), "alpha_y".into(), "alpha_z".into()]);
            }
        }
        csv_line(out, &header)?;
        for scene in frames {
            for g in &scene.grains {
                let mut row = vec![g.id.clone()];
                if framed {
                    row.insert(0, scene.frame.unwrap_or(0).to_string());
                }
                row.extend(g.position[..dim].iter().map(|&x| num(x)));
                row.push(num(g.volume));
                row.extend(
                    super::sym::components(dim)
                        .iter()
                        .map(|&k| num(g.stress[k])),
                );
                if has_radius {
                    row.push(opt(g.radius));
                }
                if has_sd {
                    for &k in super::sym::components(dim) {
                        row.push(g.stress_sd.map(|sd| num(sd[k])).unwrap_or_default());
                    }
                }
                if has_mass {
                    row.push(opt(g.mass));
                }
                if has_acc {
                    match g.acceleration {
                        Some(a) => row.extend(a[..dim].iter().map(|&x| num(x))),
                        None => row.extend(std::iter::repeat_n(String::new(), dim)),
                    }
                }
                if has_inertia {
                    row.push(match g.inertia {
                        Some(Inertia::Scalar(i)) => num(i),
                        // Written as the isotropic mean; full tensors are rare in 2D/3D DEM output.
                        Some(Inertia::Tensor(t)) => num((t[0] + t[1] + t[2]) / 3.0),
                        None => String::new(),
                    });
                }
                if has_alpha {
                    let n = if dim == 2 { 1 } else { 3 };
                    match g.angular_acceleration {
                        Some(a) if dim == 2 => row.push(num(a[2])),
                        Some(a) => row.extend(a.iter().map(|&x| num(x))),
                        None => row.extend(std::iter::repeat_n(String::new(), n)),
                    }
                }
                csv_line(out, &row)?;
            }
        }
        Ok(())
    })?;

    let has_mu = frames
        .iter()
        .flat_map(|s| &s.contacts)
        .any(|c| c.mu.is_some());
    write_atomically(&dir.join("contacts.csv"), |out| {
        let mut header: Vec<String> = vec!["id".into(), "a".into(), "b".into()];
        if framed {
            header.insert(0, "frame".into());
        }
        header.extend(coords.iter().cloned());
        header.extend(coordinate_names(dim, "n_"));
        if has_mu {
            header.push("mu".into());
        }
        csv_line(out, &header)?;
        for scene in frames {
            for c in &scene.contacts {
                let mut row = vec![
                    c.id.clone(),
                    scene.grains[c.a].id.clone(),
                    body_name(scene, c.b),
                ];
                if framed {
                    row.insert(0, scene.frame.unwrap_or(0).to_string());
                }
                row.extend(c.point[..dim].iter().map(|&x| num(x)));
                row.extend(c.normal[..dim].iter().map(|&x| num(x)));
                if has_mu {
                    row.push(opt(c.mu));
                }
                csv_line(out, &row)?;
            }
        }
        Ok(())
    })?;

    let measured: Vec<(Option<i64>, &Wall)> = frames
        .iter()
        .flat_map(|s| {
            s.walls
                .iter()
                .filter(|w| w.measured_force.is_some())
                .map(move |w| (s.frame, w))
        })
        .collect();
    if !measured.is_empty() {
        write_atomically(&dir.join("walls.csv"), |out| {
            let mut header: Vec<String> = vec!["wall".into()];
            if framed {
                header.insert(0, "frame".into());
            }
            header.extend(coordinate_names(dim, "f_"));
            csv_line(out, &header)?;
            for (frame, w) in &measured {
                let mut row = vec![w.name.clone()];
                if framed {
                    row.insert(0, frame.unwrap_or(0).to_string());
                }
                let f = w.measured_force.unwrap_or_default();
                row.extend(f[..dim].iter().map(|&x| num(x)));
                csv_line(out, &row)?;
            }
            Ok(())
        })?;
    }
    if first.settings != Settings::default() {
        let text = serde_json::to_string_pretty(&first.settings)
            .map_err(|e| Error::Invalid(e.to_string()))?;
        write_atomically(&dir.join("scene.json"), |out| writeln!(out, "{text}"))?;
    }
    Ok(())
}

/// Name of a contact's second body as written in contacts.csv.
pub fn body_name(scene: &Scene, body: Body) -> String {
    match body {
        Body::Grain(i) => scene.grains[i].id.clone(),
        Body::Wall(w) => scene.walls[w].name.clone(),
    }
}

/// One row of forces.csv.
#[derive(Debug, Clone, PartialEq)]
pub struct ForceRow {
    pub contact: String,
    pub frame: Option<i64>,
    /// Force on grain `a` by `b`.
    pub force: Vec3,
    /// Standard deviation per component, when uncertainty was estimated.
    pub sd: Option<Vec3>,
}

/// The contents of a forces.csv.
#[derive(Debug, Clone, PartialEq)]
pub struct Forces {
    pub dim: usize,
    pub rows: Vec<ForceRow>,
}

impl Forces {
    /// Builds the rows of one frame from per-contact forces in scene order.
    pub fn from_scene(scene: &Scene, forces: &[Vec3]) -> Forces {
        Forces {
            dim: scene.dim,
            rows: scene
                .contacts
                .iter()
                .zip(forces)
                .map(|(c, f)| ForceRow {
                    contact: c.id.clone(),
                    frame: scene.frame,
                    force: *f,
                    sd: None,
                })
                .collect(),
        }
    }

    /// The forces of one frame, in the order of that scene's contacts; a contact
    /// missing from the file is an error naming it.
    pub fn for_scene(&self, scene: &Scene, path: &Path) -> Result<Vec<Vec3>> {
        let map: HashMap<&str, Vec3> = self
            .rows
            .iter()
            .filter(|r| r.frame == scene.frame || r.frame.is_none())
            .map(|r| (r.contact.as_str(), r.force))
            .collect();
        scene
            .contacts
            .iter()
            .map(|c| {
                map.get(c.id.as_str()).copied().ok_or_else(|| {
                    Error::data(
                        path,
                        None,
                        Some("contact"),
                        format!("contact `{}` has no force", c.id),
                    )
                })
            })
            .collect()
    }
}

pub fn read_forces(path: &Path) -> Result<Forces> {
    let t = Table::read(path)?;
    t.require("contact")?;
    let dim = if t.has("f_z") { 3 } else { 2 };
    let comps = coordinate_names(dim, "f_");
    let sd_cols = coordinate_names(dim, "sd_");
    let mut seen = HashSet::new();
    let mut rows = Vec::with_capacity(t.rows.len());
    for (line, record) in &t.rows {
        let contact = t.text(record, *line, "contact")?.to_owned();
        let frame = t.frame(record, *line)?;
        if !seen.insert((frame, contact.clone())) {
            return Err(Error::data(
                path,
                Some(*line),
                Some("contact"),
                format!("contact `{contact}` is listed twice"),
            ));
        }
        let force = t.vector(record, *line, &names(&comps))?;
        let sd = t.optional_vector(record, *line, &names(&sd_cols))?;
        rows.push(ForceRow {
            contact,
            frame,
            force,
            sd,
        });
    }
    Ok(Forces { dim, rows })
}

pub fn write_forces(path: &Path, forces: &Forces) -> Result<()> {
    let dim = forces.dim;
    let framed = forces.rows.iter().any(|r| r.frame.is_some());
    let has_sd = forces.rows.iter().any(|r| r.sd.is_some());
    write_atomically(path, |out| {
        let mut header: Vec<String> = vec!["contact".into()];
        if framed {
            header.insert(0, "frame".into());
        }
        header.extend(coordinate_names(dim, "f_"));
        if has_sd {
            header.extend(coordinate_names(dim, "sd_"));
        }
        csv_line(out, &header)?;
        for r in &forces.rows {
            let mut row = vec![r.contact.clone()];
            if framed {
                row.insert(0, r.frame.unwrap_or(0).to_string());
            }
            row.extend(r.force[..dim].iter().map(|&x| num(x)));
            if has_sd {
                let sd = r.sd.unwrap_or_default();
                row.extend(sd[..dim].iter().map(|&x| num(x)));
            }
            csv_line(out, &row)?;
        }
        Ok(())
    })
}
