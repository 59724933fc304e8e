//! A small reader for MATLAB's Level 5 MAT-files (what `save` writes by
//! default, `-v6` and `-v7`; not `-v7.3`, which is HDF5): numeric arrays of
//! every class (widened to f64), logical, char, cell and struct arrays,
//! zlib-compressed elements (miCOMPRESSED, through `flate2`), both byte
//! orders. Sparse arrays, function handles and opaque objects are recognised
//! and skipped.
//!
//! Written here because the crates.io readers in 2026 either cannot read
//! struct arrays (`matfile`, `mat5`), reject MATLAB's own PeGS files
//! (`matreader` 0.1.0) or panic on a truncated compressed file (`matrw`
//! 0.1.4 unwraps the inflate error). Every length below is checked against the
//! bytes that are there, counts are never trusted for allocation, nesting is
//! bounded and inflation is capped, so a corrupt file gives an error saying
//! where it went wrong, never a panic.

use crate::error::{Error, Result};
use std::io::Read;
use std::path::Path;

/// One MATLAB array.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// Numeric or logical array, column-major; `imag` for complex arrays.
    Numeric {
        dims: Vec<usize>,
        real: Numbers,
        imag: Option<Numbers>,
        class: &'static str,
    },
    Char {
        dims: Vec<usize>,
        text: String,
    },
    Cell {
        dims: Vec<usize>,
        items: Vec<Value>,
    },
    /// Struct array (or object): `values[element * fields.len() + field]`.
    Struct {
        dims: Vec<usize>,
        fields: Vec<String>,
        values: Vec<Value>,
    },
    /// An array class this reader skips (sparse, function handle, opaque).
    Unsupported {
        class: &'static str,
    },
}

/// Numeric data as stored (MATLAB narrows the storage type when the values
/// fit), widened to f64 only when asked: a big uint8 image costs its bytes,
/// not eight times as many.
#[derive(Debug, Clone)]
pub struct Numbers {
    kind: u32,
    big: bool,
    bytes: Vec<u8>,
}

impl Numbers {
    fn size(kind: u32) -> Option<usize> {
        match kind {
            MI_INT8 | MI_UINT8 => Some(1),
            MI_INT16 | MI_UINT16 => Some(2),
            MI_INT32 | MI_UINT32 | MI_SINGLE => Some(4),
            MI_DOUBLE | MI_INT64 | MI_UINT64 => Some(8),
            _ => None,
        }
    }

    pub fn len(&self) -> usize {
        Self::size(self.kind).map_or(0, |s| self.bytes.len() / s)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The values widened to f64 (int64 beyond 2⁵³ rounds).
    pub fn to_f64(&self) -> Vec<f64> {
        let Some(size) = Self::size(self.kind) else {
            return Vec::new();
        };
        let big = self.big;
        self.bytes
            .chunks_exact(size)
            .map(|c| {
                let mut b = [0u8; 8];
                if big {
                    // Right-aligned so that from_be_bytes reads the value.
                    b[8 - size..].copy_from_slice(c);
                } else {
                    b[..size].copy_from_slice(c);
                }
                let word = if big {
                    u64::from_be_bytes(b)
                } else {
                    u64::from_le_bytes(b)
                };
                match self.kind {
                    MI_INT8 => word as u8 as i8 as f64,
                    MI_UINT8 => word as u8 as f64,
                    MI_INT16 => word as u16 as i16 as f64,
                    MI_UINT16 => word as u16 as f64,
                    MI_INT32 => word as u32 as i32 as f64,
                    MI_UINT32 => word as u32 as f64,
                    MI_SINGLE => f32::from_bits(word as u32) as f64,
                    MI_DOUBLE => f64::from_bits(word),
                    MI_INT64 => word as i64 as f64,
                    _ => word as f64,
                }
            })
            .collect()
    }
}

/// Equal when the same values are stored in the same type, whatever the byte
/// order of the file.
impl PartialEq for Numbers {
    fn eq(&self, other: &Self) -> bool {
        self.kind == other.kind
            && self
                .to_f64()
                .iter()
                .map(|x| x.to_bits())
                .eq(other.to_f64().iter().map(|x| x.to_bits()))
    }
}

/// A named variable of the file.
#[derive(Debug, Clone, PartialEq)]
pub struct Variable {
    pub name: String,
    pub value: Value,
}

impl Value {
    /// The real values of a numeric or logical array, as f64.
    pub fn numbers(&self) -> Option<Vec<f64>> {
        match self {
            Value::Numeric { real, .. } => Some(real.to_f64()),
            _ => None,
        }
    }

    /// Number of elements (product of the dimensions).
    pub fn len(&self) -> usize {
        match self {
            Value::Numeric { real, .. } => real.len(),
            Value::Char { dims, .. } | Value::Cell { dims, .. } | Value::Struct { dims, .. } => {
                dims.iter().product()
            }
            Value::Unsupported { .. } => 0,
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Field `name` of struct element `index`.
    pub fn field(&self, index: usize, name: &str) -> Option<&Value> {
        match self {
            Value::Struct { fields, values, .. } => {
                let k = fields.iter().position(|f| f == name)?;
                values.get(index * fields.len() + k)
            }
            _ => None,
        }
    }

    /// A short description for error messages, e.g. "a 1×3 cell array".
    pub fn describe(&self) -> String {
        let dims = |d: &[usize]| {
            d.iter()
                .map(|x| x.to_string())
                .collect::<Vec<_>>()
                .join("×")
        };
        match self {
            Value::Numeric { dims: d, class, .. } => format!("a {} {class} array", dims(d)),
            Value::Char { text, .. } => format!("the text `{text}`"),
            Value::Cell { dims: d, .. } => format!("a {} cell array", dims(d)),
            Value::Struct { dims: d, .. } => format!("a {} struct array", dims(d)),
            Value::Unsupported { class } => format!("a {class} array"),
        }
    }
}

/// Largest inflated size of one compressed element: far above any PeGS file
/// (a few MB), low enough that a zip bomb is refused before memory runs out.
pub const MAX_INFLATED: usize = 1 << 30;
/// Deepest nesting of cells/structs accepted (PeGS uses 2).
const MAX_DEPTH: usize = 64;

// Data types (miXXX) and array classes (mxXXX) of the format.
const MI_INT8: u32 = 1;
const MI_UINT8: u32 = 2;
const MI_INT16: u32 = 3;
const MI_UINT16: u32 = 4;
const MI_INT32: u32 = 5;
const MI_UINT32: u32 = 6;
const MI_SINGLE: u32 = 7;
const MI_DOUBLE: u32 = 9;
const MI_INT64: u32 = 12;
const MI_UINT64: u32 = 13;
const MI_MATRIX: u32 = 14;
const MI_COMPRESSED: u32 = 15;
const MI_UTF8: u32 = 16;
const MI_UTF16: u32 = 17;
const MI_UTF32: u32 = 18;

/// Reads every variable of a MAT v5 file; errors name the file and the byte.
pub fn read(path: &Path) -> Result<Vec<Variable>> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse(&bytes, MAX_INFLATED).map_err(|m| Error::data(path, None, None, m))
}

/// Parses the bytes of a MAT v5 file; `max_inflated` caps each compressed
/// element's inflated size.
pub fn parse(bytes: &[u8], max_inflated: usize) -> std::result::Result<Vec<Variable>, String> {
    if bytes.len() < 128 {
        return Err(format!(
            "not a MAT-file: {} bytes, shorter than the 128-byte MAT v5 header",
            bytes.len()
        ));
    }
    let text = String::from_utf8_lossy(&bytes[..116]);
    if text.starts_with("MATLAB 7.3") || bytes.get(512..520) == Some(b"\x89HDF\r\n\x1a\n") {
        return Err(
            "a MAT v7.3 file (HDF5), which this reader does not take: re-save it in MATLAB \
             with save(name, 'particle', '-v7')"
                .into(),
        );
    }
    let big =
        match &bytes[126..128] {
            b"IM" => false,
            b"MI" => true,
            _ => return Err(
                "not a MAT v5 file: the header has no `IM`/`MI` byte-order mark at bytes 126–127 \
                 (a MAT v4 file, or not a MAT-file at all)"
                    .into(),
            ),
        };
    if !text.starts_with("MATLAB") {
        return Err("not a MAT v5 file: the header does not start with `MATLAB`".into());
    }
    let mut reader = Reader {
        buf: &bytes[128..],
        pos: 0,
        big,
        offset: 128,
        context: String::new(),
        max_inflated,
    };
    let mut variables = Vec::new();
    // MATLAB may pad the end of the file with zeros.
    while reader.pos < reader.buf.len() && reader.buf[reader.pos..].iter().any(|b| *b != 0) {
        variables.extend(reader.variable(0)?);
    }
    Ok(variables)
}

struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
    big: bool,
    /// File offset of `buf[0]`, or of the compressed element it came from.
    offset: usize,
    /// "in the compressed element at byte N, " when inside one.
    context: String,
    max_inflated: usize,
}

/// One data element: its type and payload.
struct Element<'a> {
    kind: u32,
    data: &'a [u8],
    /// Where its tag starts, for messages.
    at: usize,
}

impl<'a> Reader<'a> {
    fn err(&self, at: usize, message: impl std::fmt::Display) -> String {
        if self.context.is_empty() {
            format!("at byte {}: {message}", self.offset + at)
        } else {
            format!(
                "{}at byte {} of its inflated data: {message}",
                self.context, at
            )
        }
    }

    fn u32_at(&self, at: usize) -> Option<u32> {
        let b: [u8; 4] = self.buf.get(at..at.checked_add(4)?)?.try_into().ok()?;
        Some(if self.big {
            u32::from_be_bytes(b)
        } else {
            u32::from_le_bytes(b)
        })
    }

    /// The next data element (normal or small format).
    fn element(&mut self) -> std::result::Result<Element<'a>, String> {
        let at = self.pos;
        let truncated = |r: &Self| r.err(at, "the file ends inside a data element (truncated)");
        let word = self.u32_at(at).ok_or_else(|| truncated(self))?;
        if word >> 16 != 0 {
            // Small element: type and size share the first word, data in the second.
            let (kind, n) = (word & 0xffff, (word >> 16) as usize);
            if n > 4 {
                return Err(self.err(
                    at,
                    format!("a small data element claims {n} bytes (at most 4)"),
                ));
            }
            let data = self
                .buf
                .get(at + 4..at + 4 + n)
                .ok_or_else(|| truncated(self))?;
            self.pos = (at + 8).min(self.buf.len());
            return Ok(Element { kind, data, at });
        }
        let n = self.u32_at(at + 4).ok_or_else(|| truncated(self))? as usize;
        let start = at + 8;
        let end = start.checked_add(n).filter(|e| *e <= self.buf.len());
        let Some(end) = end else {
            return Err(self.err(
                at,
                format!(
                    "a data element of {n} bytes runs past the end ({} bytes left): the file is \
                     truncated or corrupt",
                    self.buf.len() - start.min(self.buf.len())
                ),
            ));
        };
        // Elements are padded to 8 bytes, except compressed ones.
        let padded = if word == MI_COMPRESSED {
            end
        } else {
            end.div_ceil(8) * 8
        };
        self.pos = padded.min(self.buf.len());
        Ok(Element {
            kind: word,
            data: &self.buf[start..end],
            at,
        })
    }

    /// A top-level variable, or `None` for a skipped element type.
    fn variable(&mut self, depth: usize) -> std::result::Result<Option<Variable>, String> {
        let e = self.element()?;
        match e.kind {
            MI_MATRIX => {
                let (name, value) = self.sub(e.data, e.at + 8).matrix(depth)?;
                Ok(Some(Variable { name, value }))
            }
            MI_COMPRESSED => {
                let inflated = self.inflate(&e)?;
                let mut inner = Reader {
                    buf: &inflated,
                    pos: 0,
                    big: self.big,
                    offset: 0,
                    context: format!(
                        "{}in the compressed element at byte {}, ",
                        self.context,
                        self.offset + e.at
                    ),
                    max_inflated: self.max_inflated,
                };
                if depth >= MAX_DEPTH {
                    return Err(self.err(e.at, "compressed elements nested too deep"));
                }
                inner.variable(depth + 1)
            }
            _ => Ok(None),
        }
    }

    fn inflate(&self, e: &Element) -> std::result::Result<Vec<u8>, String> {
        let mut out = Vec::new();
        let cap = self.max_inflated as u64;
        flate2::read::ZlibDecoder::new(e.data)
            .take(cap + 1)
            .read_to_end(&mut out)
            .map_err(|x| {
                self.err(
                    e.at,
                    format!("the compressed element does not inflate ({x}): the file is truncated or corrupt"),
                )
            })?;
        if out.len() as u64 > cap {
            return Err(self.err(
                e.at,
                format!("the compressed element inflates to more than {cap} bytes"),
            ));
        }
        Ok(out)
    }

    /// A reader over a sub-slice (the payload of an element at `offset`).
    fn sub(&self, buf: &'a [u8], offset: usize) -> Reader<'a> {
        Reader {
            buf,
            pos: 0,
            big: self.big,
            offset: self.offset + offset,
            context: self.context.clone(),
            max_inflated: self.max_inflated,
        }
    }

    fn expect(&mut self, kinds: &[u32], what: &str) -> std::result::Result<Element<'a>, String> {
        let e = self.element()?;
        if !kinds.contains(&e.kind) {
            return Err(self.err(e.at, format!("expected {what}, found data type {}", e.kind)));
        }
        Ok(e)
    }

    /// The payload of a miMATRIX element: name and value.
    fn matrix(&mut self, depth: usize) -> std::result::Result<(String, Value), String> {
        if depth > MAX_DEPTH {
            return Err(self.err(0, "cells or structs nested too deep"));
        }
        if self.buf.is_empty() {
            // MATLAB writes an empty field value as a bare miMATRIX tag.
            return Ok((
                String::new(),
                Value::Numeric {
                    dims: vec![0, 0],
                    real: Numbers {
                        kind: MI_DOUBLE,
                        big: self.big,
                        bytes: Vec::new(),
                    },
                    imag: None,
                    class: "double",
                },
            ));
        }
        let flags = self.expect(&[MI_UINT32], "the array flags (miUINT32)")?;
        let word = self
            .sub(flags.data, 0)
            .u32_at(0)
            .ok_or_else(|| self.err(flags.at, "array flags shorter than 4 bytes"))?;
        let class = (word & 0xff) as u8;
        let complex = word & 0x0800 != 0;
        let logical = word & 0x0200 != 0;
        let dims_e = self.expect(&[MI_INT32], "the dimensions (miINT32)")?;
        let dims = self.integers(&dims_e)?;
        if dims.iter().any(|d| *d < 0) {
            return Err(self.err(dims_e.at, format!("negative dimension in {dims:?}")));
        }
        let dims: Vec<usize> = dims.iter().map(|d| *d as usize).collect();
        let count = dims
            .iter()
            .try_fold(1usize, |a, d| a.checked_mul(*d))
            .ok_or_else(|| self.err(dims_e.at, format!("dimensions {dims:?} overflow")))?;
        let name_e = self.expect(&[MI_INT8, MI_UINT8], "the array name (miINT8)")?;
        let name = String::from_utf8_lossy(name_e.data).into_owned();
        let value = match class {
            1 => {
                let mut items = Vec::with_capacity(count.min(self.buf.len() / 8));
                for _ in 0..count {
                    items.push(self.child(depth)?);
                }
                Value::Cell { dims, items }
            }
            2 | 3 => {
                if class == 3 {
                    self.expect(&[MI_INT8, MI_UINT8], "the object's class name")?;
                }
                let len_e = self.expect(&[MI_INT32], "the field name length (miINT32)")?;
                let len = *self
                    .integers(&len_e)?
                    .first()
                    .ok_or_else(|| self.err(len_e.at, "empty field name length"))?;
                let names_e = self.expect(&[MI_INT8, MI_UINT8], "the field names (miINT8)")?;
                let fields = if names_e.data.is_empty() {
                    Vec::new()
                } else {
                    if len <= 0 || names_e.data.len() % len as usize != 0 {
                        return Err(self.err(
                            names_e.at,
                            format!(
                                "{} bytes of field names are not a whole number of {len}-byte names",
                                names_e.data.len()
                            ),
                        ));
                    }
                    names_e
                        .data
                        .chunks(len as usize)
                        .map(|c| {
                            let end = c.iter().position(|b| *b == 0).unwrap_or(c.len());
                            String::from_utf8_lossy(&c[..end]).into_owned()
                        })
                        .collect()
                };
                let total = count
                    .checked_mul(fields.len())
                    .ok_or_else(|| self.err(names_e.at, "struct array too large"))?;
                let mut values = Vec::with_capacity(total.min(self.buf.len() / 8));
                for _ in 0..total {
                    values.push(self.child(depth)?);
                }
                Value::Struct {
                    dims,
                    fields,
                    values,
                }
            }
            4 => {
                let e = self.element()?;
                Value::Char {
                    text: self.text(&e)?,
                    dims,
                }
            }
            5 => Value::Unsupported { class: "sparse" },
            6..=15 => {
                let class_name = if logical {
                    "logical"
                } else {
                    [
                        "double", "single", "int8", "uint8", "int16", "uint16", "int32", "uint32",
                        "int64", "uint64",
                    ][class as usize - 6]
                };
                let e = self.element()?;
                let real = self.numbers(&e, count)?;
                let imag = if complex {
                    let e = self.element()?;
                    Some(self.numbers(&e, count)?)
                } else {
                    None
                };
                Value::Numeric {
                    dims,
                    real,
                    imag,
                    class: class_name,
                }
            }
            16 => Value::Unsupported {
                class: "function handle",
            },
            17 => Value::Unsupported { class: "opaque" },
            other => {
                return Err(self.err(0, format!("unknown array class {other}")));
            }
        };
        Ok((name, value))
    }

    /// A cell or field value: a miMATRIX element.
    fn child(&mut self, depth: usize) -> std::result::Result<Value, String> {
        let e = self.expect(&[MI_MATRIX], "an array (miMATRIX) inside the cell/struct")?;
        Ok(self.sub(e.data, e.at + 8).matrix(depth + 1)?.1)
    }

    fn integers(&self, e: &Element) -> std::result::Result<Vec<i64>, String> {
        if e.data.len() % 4 != 0 {
            return Err(self.err(e.at, "miINT32 data is not a whole number of 4-byte values"));
        }
        let r = self.sub(e.data, 0);
        Ok((0..e.data.len() / 4)
            .filter_map(|k| r.u32_at(4 * k).map(|w| w as i32 as i64))
            .collect())
    }

    /// Numeric data of any stored type; `count` values expected.
    fn numbers(&self, e: &Element, count: usize) -> std::result::Result<Numbers, String> {
        let Some(size) = Numbers::size(e.kind) else {
            return Err(self.err(e.at, format!("data type {} cannot hold numbers", e.kind)));
        };
        if e.data.len() != count.saturating_mul(size) {
            return Err(self.err(
                e.at,
                format!(
                    "{} bytes of data where the dimensions need {count} values of {size} bytes",
                    e.data.len()
                ),
            ));
        }
        Ok(Numbers {
            kind: e.kind,
            big: self.big,
            bytes: e.data.to_vec(),
        })
    }

    fn text(&self, e: &Element) -> std::result::Result<String, String> {
        let r = self.sub(e.data, 0);
        let units = |size: usize| -> Vec<u32> {
            (0..e.data.len() / size)
                .map(|k| match size {
                    2 => {
                        let b = [e.data[2 * k], e.data[2 * k + 1]];
                        (if r.big {
                            u16::from_be_bytes(b)
                        } else {
                            u16::from_le_bytes(b)
                        }) as u32
                    }
                    _ => r.u32_at(4 * k).unwrap_or(0),
                })
                .collect()
        };
        Ok(match e.kind {
            MI_UTF8 | MI_UINT8 | MI_INT8 => String::from_utf8_lossy(e.data).into_owned(),
            MI_UINT16 | MI_UTF16 => {
                let u: Vec<u16> = units(2).into_iter().map(|x| x as u16).collect();
                String::from_utf16_lossy(&u)
            }
            MI_UTF32 | MI_UINT32 => units(4)
                .into_iter()
                .map(|c| char::from_u32(c).unwrap_or('\u{fffd}'))
                .collect(),
            other => return Err(self.err(e.at, format!("data type {other} cannot hold text"))),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn word(big: bool, x: u32) -> [u8; 4] {
        if big {
            x.to_be_bytes()
        } else {
            x.to_le_bytes()
        }
    }

    /// A normal data element, padded to 8 bytes.
    fn element(big: bool, kind: u32, data: &[u8]) -> Vec<u8> {
        let mut out = word(big, kind).to_vec();
        out.extend(word(big, data.len() as u32));
        out.extend(data);
        out.resize(out.len().div_ceil(8) * 8, 0);
        out
    }

    /// A small data element (≤ 4 bytes of data in the tag's second word).
    fn small(big: bool, kind: u32, data: &[u8]) -> Vec<u8> {
        let mut out = word(big, (data.len() as u32) << 16 | kind).to_vec();
        out.extend(data);
        out.resize(8, 0);
        out
    }

    fn ints(big: bool, values: &[i32]) -> Vec<u8> {
        values.iter().flat_map(|v| word(big, *v as u32)).collect()
    }

    fn matrix(big: bool, class: u32, dims: &[i32], name: &str, body: &[u8]) -> Vec<u8> {
        let mut b = element(big, MI_UINT32, &[word(big, class), word(big, 0)].concat());
        b.extend(element(big, MI_INT32, &ints(big, dims)));
        b.extend(if name.len() <= 4 {
            small(big, MI_INT8, name.as_bytes())
        } else {
            element(big, MI_INT8, name.as_bytes())
        });
        b.extend(body);
        element(big, MI_MATRIX, &b)
    }

    fn header(big: bool) -> Vec<u8> {
        let mut h = b"MATLAB 5.0 MAT-file, hand-built for the reader's tests".to_vec();
        h.resize(116, b' ');
        h.extend([0u8; 8]);
        h.extend(if big { [1u8, 0] } else { [0u8, 1] });
        h.extend(if big { b"MI" } else { b"IM" });
        h
    }

    /// A 1×2 struct s with fields x (double stored as int16, or as double),
    /// name (char as UTF-16 or UTF-8) and c (a cell holding a double and an
    /// empty array), then a compressed complex int32 array z.
    fn file(big: bool) -> Vec<u8> {
        let f64s = |v: f64| {
            if big {
                v.to_be_bytes()
            } else {
                v.to_le_bytes()
            }
        };
        let i16s = |v: i16| {
            if big {
                v.to_be_bytes()
            } else {
                v.to_le_bytes()
            }
        };
        let mut fields = Vec::new();
        // Element 1.
        fields.extend(matrix(
            big,
            6,
            &[1, 1],
            "",
            &small(big, MI_INT16, &i16s(-7)),
        ));
        let ab: Vec<u8> = "ab"
            .encode_utf16()
            .flat_map(|u| {
                if big {
                    u.to_be_bytes()
                } else {
                    u.to_le_bytes()
                }
            })
            .collect();
        fields.extend(matrix(big, 4, &[1, 2], "", &small(big, MI_UINT16, &ab)));
        let mut cell = matrix(big, 6, &[1, 1], "", &element(big, MI_DOUBLE, &f64s(1.5)));
        cell.extend(element(big, MI_MATRIX, &[]));
        fields.extend(matrix(big, 1, &[1, 2], "", &cell));
        // Element 2.
        fields.extend(matrix(
            big,
            6,
            &[1, 1],
            "",
            &element(big, MI_DOUBLE, &f64s(2.5)),
        ));
        fields.extend(matrix(
            big,
            4,
            &[1, 1],
            "",
            &small(big, MI_UTF8, "é".as_bytes()),
        ));
        fields.extend(matrix(big, 1, &[1, 0], "", &[]));
        let mut body = small(big, MI_INT32, &word(big, 8));
        let mut names = Vec::new();
        for n in ["x", "name", "c"] {
            let mut b = n.as_bytes().to_vec();
            b.resize(8, 0);
            names.extend(b);
        }
        body.extend(element(big, MI_INT8, &names));
        body.extend(fields);
        let mut out = header(big);
        out.extend(matrix(big, 2, &[1, 2], "s", &body));
        // z = [1, -2, 3] + [0, 0, 1]i as int32, compressed.
        let mut z = element(big, MI_INT32, &ints(big, &[1, -2, 3]));
        z.extend(element(big, MI_INT32, &ints(big, &[0, 0, 1])));
        let z = matrix(big, 12 | 0x0800, &[1, 3], "z", &z);
        let mut enc = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        enc.write_all(&z).unwrap();
        let packed = enc.finish().unwrap();
        out.extend(word(big, MI_COMPRESSED));
        out.extend(word(big, packed.len() as u32));
        out.extend(packed);
        out
    }

    #[test]
    fn both_byte_orders_read_the_same() {
        let little = parse(&file(false), MAX_INFLATED).unwrap();
        let big = parse(&file(true), MAX_INFLATED).unwrap();
        assert_eq!(little, big);
        assert_eq!(little.len(), 2);
        let s = &little[0];
        assert_eq!(s.name, "s");
        assert_eq!(s.value.len(), 2);
        assert_eq!(s.value.field(0, "x").unwrap().numbers(), Some(vec![-7.0]));
        assert_eq!(s.value.field(1, "x").unwrap().numbers(), Some(vec![2.5]));
        let text = |k| match s.value.field(k, "name").unwrap() {
            Value::Char { text, .. } => text.clone(),
            other => panic!("{other:?}"),
        };
        assert_eq!((text(0), text(1)), ("ab".to_owned(), "é".to_owned()));
        match s.value.field(0, "c").unwrap() {
            Value::Cell { dims, items } => {
                assert_eq!(dims, &[1, 2]);
                assert_eq!(items[0].numbers(), Some(vec![1.5]));
                assert!(items[1].is_empty());
            }
            other => panic!("{other:?}"),
        }
        assert!(s.value.field(1, "c").unwrap().is_empty());
        match &little[1].value {
            Value::Numeric {
                real, imag, class, ..
            } => {
                assert_eq!(real.to_f64(), [1.0, -2.0, 3.0]);
                assert_eq!(
                    imag.as_ref().map(Numbers::to_f64),
                    Some(vec![0.0, 0.0, 1.0])
                );
                assert_eq!(*class, "int32");
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn lengths_that_lie_are_errors() {
        let good = file(true);
        // The struct's element claims more bytes than the file has.
        let mut long = good.clone();
        long[128 + 4..128 + 8].copy_from_slice(&u32::MAX.to_be_bytes());
        let e = parse(&long, MAX_INFLATED).unwrap_err();
        assert!(
            e.contains("at byte 128") && e.contains("runs past the end"),
            "{e}"
        );
        // Dimensions that need more data than is stored.
        let mut dims = file(false);
        let at = dims
            .windows(8)
            .position(|w| w == [1, 0, 0, 0, 2, 0, 0, 0])
            .unwrap();
        dims[at + 4] = 0xff;
        assert!(parse(&dims, MAX_INFLATED).is_err());
    }
}
