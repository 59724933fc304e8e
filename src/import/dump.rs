//! Reader for LAMMPS-style text dumps (`dump custom` of atoms and `dump local`
//! of entries), the format LIGGGHTS writes too. Columns are found by the names
//! in the `ITEM: ATOMS …` / `ITEM: ENTRIES …` header; every value must be a
//! number, and errors name the file, line and column.

use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// One snapshot of a dump file.
#[derive(Debug, Clone, PartialEq)]
pub struct DumpFrame {
    pub timestep: i64,
    /// Whether each box dimension is periodic (`pp` in `ITEM: BOX BOUNDS`).
    pub periodic: [bool; 3],
    /// Box bounds (lo, hi) per dimension, when given.
    pub bounds: Option<[[f64; 2]; 3]>,
    pub columns: Vec<String>,
    /// Line number of the `ITEM: ATOMS`/`ENTRIES` header.
    pub header_line: usize,
    pub rows: Vec<DumpRow>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct DumpRow {
    pub line: usize,
    pub values: Vec<f64>,
}

impl DumpFrame {
    pub fn column(&self, name: &str) -> Option<usize> {
        self.columns.iter().position(|c| c == name)
    }

    /// Index of a column that must exist, or an error at the header line.
    pub(crate) fn require(&self, path: &Path, name: &str) -> Result<usize> {
        self.column(name).ok_or_else(|| {
            Error::data(
                path,
                Some(self.header_line),
                Some(name),
                format!(
                    "column `{name}` is missing (the header has: {})",
                    self.columns.join(" ")
                ),
            )
        })
    }
}

/// Which kind of dump: per-atom (`ITEM: ATOMS`) or local (`ITEM: ENTRIES`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DumpKind {
    Atoms,
    Local,
}

impl DumpKind {
    fn count_item(self) -> &'static str {
        match self {
            DumpKind::Atoms => "NUMBER OF ATOMS",
            DumpKind::Local => "NUMBER OF ENTRIES",
        }
    }
    fn table_item(self) -> &'static str {
        match self {
            DumpKind::Atoms => "ATOMS",
            DumpKind::Local => "ENTRIES",
        }
    }
}

struct Lines {
    path: PathBuf,
    lines: Vec<String>,
    next: usize,
}

impl Lines {
    /// The next line and its 1-based number.
    fn take(&mut self, what: &str) -> Result<(usize, String)> {
        if self.next >= self.lines.len() {
            return Err(Error::data(
                &self.path,
                Some(self.lines.len()),
                None,
                format!("the file ends where {what} was expected"),
            ));
        }
        self.next += 1;
        Ok((self.next, self.lines[self.next - 1].trim().to_owned()))
    }
}

/// Reads every frame of a dump file.
pub(crate) fn read_dump(path: &Path, kind: DumpKind) -> Result<Vec<DumpFrame>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let mut lines = Lines {
        path: path.to_owned(),
        lines: text.lines().map(str::to_owned).collect(),
        next: 0,
    };
    let mut frames = Vec::new();
    let mut timestep: Option<i64> = None;
    let mut count: Option<usize> = None;
    let mut periodic = [false; 3];
    let mut bounds = None;
    while lines.next < lines.lines.len() {
        let (line_no, line) = lines.take("an ITEM line")?;
        if line.is_empty() {
            continue;
        }
        let Some(item) = line.strip_prefix("ITEM:") else {
            return Err(Error::data(
                path,
                Some(line_no),
                None,
                format!("expected an `ITEM:` line, found `{}`", short(&line)),
            ));
        };
        let item = item.trim();
        if item == "TIMESTEP" {
            let (n, v) = lines.take("the timestep")?;
            timestep = Some(v.parse().map_err(|_| {
                Error::data(path, Some(n), None, format!("`{v}` is not a timestep"))
            })?);
            count = None;
            bounds = None;
            periodic = [false; 3];
        } else if item == kind.count_item() {
            let (n, v) = lines.take("a count")?;
            count =
                Some(v.parse().map_err(|_| {
                    Error::data(path, Some(n), None, format!("`{v}` is not a count"))
                })?);
        } else if let Some(flags) = item.strip_prefix("BOX BOUNDS") {
            let flags: Vec<&str> = flags.split_whitespace().collect();
            for (k, f) in flags.iter().take(3).enumerate() {
                periodic[k] = f.contains('p');
            }
            let mut b = [[0.0; 2]; 3];
            for row in &mut b {
                let (n, v) = lines.take("box bounds")?;
                let nums: Vec<f64> = v
                    .split_whitespace()
                    .map(str::parse)
                    .collect::<std::result::Result<_, _>>()
                    .map_err(|_| {
                        Error::data(path, Some(n), None, format!("bad box bounds `{v}`"))
                    })?;
                if nums.len() < 2 {
                    return Err(Error::data(
                        path,
                        Some(n),
                        None,
                        "box bounds need lo and hi",
                    ));
                }
                *row = [nums[0], nums[1]];
            }
            bounds = Some(b);
        } else if let Some(names) = item.strip_prefix(kind.table_item()) {
            let header_line = line_no;
            let columns: Vec<String> = names.split_whitespace().map(str::to_owned).collect();
            let Some(ts) = timestep else {
                return Err(Error::data(
                    path,
                    Some(header_line),
                    None,
                    "`ITEM: TIMESTEP` must come before the table",
                ));
            };
            let Some(n_rows) = count else {
                return Err(Error::data(
                    path,
                    Some(header_line),
                    None,
                    format!("`ITEM: {}` must come before the table", kind.count_item()),
                ));
            };
            // The count is data: a huge one must give "the file ends" below,
            // not reserve memory for rows that are not there.
            let mut rows = Vec::with_capacity(n_rows.min(lines.lines.len() - lines.next));
            for _ in 0..n_rows {
                let (n, v) = lines.take("a table row")?;
                let cells: Vec<&str> = v.split_whitespace().collect();
                if cells.len() != columns.len() {
                    return Err(Error::data(
                        path,
                        Some(n),
                        None,
                        format!(
                            "this row has {} values where the header names {} columns",
                            cells.len(),
                            columns.len()
                        ),
                    ));
                }
                let mut values = Vec::with_capacity(cells.len());
                for (cell, name) in cells.iter().zip(&columns) {
                    let x = crate::scene::parse_number(path, n, name, cell)?;
                    values.push(x);
                }
                rows.push(DumpRow { line: n, values });
            }
            frames.push(DumpFrame {
                timestep: ts,
                periodic,
                bounds,
                columns,
                header_line,
                rows,
            });
        } else if item.starts_with("ATOMS")
            || item.starts_with("ENTRIES")
            || item.starts_with("NUMBER OF")
        {
            let expected = match kind {
                DumpKind::Atoms => "a per-atom dump (dump custom)",
                DumpKind::Local => "a local dump (dump local)",
            };
            return Err(Error::data(
                path,
                Some(line_no),
                None,
                format!("`ITEM: {item}` does not belong in {expected}; were the files swapped?"),
            ));
        } else {
            // Other items (UNITS, TIME, …): skip their value lines.
            while lines.next < lines.lines.len()
                && !lines.lines[lines.next].trim_start().starts_with("ITEM:")
            {
                lines.next += 1;
            }
        }
    }
    if frames.is_empty() {
        return Err(Error::data(
            path,
            None,
            None,
            "no snapshot found in the dump",
        ));
    }
    Ok(frames)
}

fn short(s: &str) -> String {
    if s.len() > 40 {
        format!(
            "{}…",
            &s[..s.char_indices().nth(40).map_or(s.len(), |(i, _)| i)]
        )
    } else {
        s.to_owned()
    }
}

/// The snapshots of an atoms dump paired by timestep with those of its local
/// (contact) dump, and the dimension: given, or detected from the atoms.
pub(crate) fn paired_snapshots(
    atoms: &Path,
    local: &Path,
    dim: Option<usize>,
) -> Result<(usize, Vec<(DumpFrame, DumpFrame)>)> {
    let atom_frames = read_dump(atoms, DumpKind::Atoms)?;
    let mut local_frames = read_dump(local, DumpKind::Local)?;
    let dim = match dim {
        Some(d @ (2 | 3)) => d,
        Some(d) => return Err(Error::Invalid(format!("dimension must be 2 or 3, not {d}"))),
        None => super::lammps::detect_dim(&atom_frames[0]),
    };
    let mut pairs = Vec::with_capacity(atom_frames.len());
    for af in atom_frames {
        let Some(k) = local_frames.iter().position(|l| l.timestep == af.timestep) else {
            return Err(Error::data(
                local,
                None,
                None,
                format!(
                    "no snapshot for timestep {} (present in {})",
                    af.timestep,
                    atoms.display()
                ),
            ));
        };
        pairs.push((af, local_frames.swap_remove(k)));
    }
    Ok((dim, pairs))
}
