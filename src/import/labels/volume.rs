//! Voxel volumes read one z-slice at a time: in-memory arrays, NumPy `.npy`
//! (memory-mapped), raw files (memory-mapped) and multi-page TIFF (one page per
//! slice, any compression the `tiff` crate decodes). Arrays are C-ordered
//! `[z][y][x]`, as NumPy and TIFF stacks hold them.

use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// A voxel value that can be a label (a non-negative integer below 2³²).
pub trait LabelValue: Copy + Send + Sync {
    /// The label, or `None` for a negative or too large value.
    fn label(self) -> Option<u32>;
    /// The value as a grey level.
    fn grey(self) -> f32;
}

macro_rules! label_value {
    ($($t:ty),*) => {$(
        impl LabelValue for $t {
            #[inline]
            fn label(self) -> Option<u32> {
                u32::try_from(self).ok()
            }
            #[inline]
            fn grey(self) -> f32 {
                self as f32
            }
        }
    )*};
}
label_value!(u8, u16, u32, u64, i8, i16, i32, i64);

impl LabelValue for f32 {
    /// Whole non-negative values only.
    fn label(self) -> Option<u32> {
        (self >= 0.0 && self.fract() == 0.0 && self <= u32::MAX as f32).then_some(self as u32)
    }
    fn grey(self) -> f32 {
        self
    }
}

/// The element type of a file volume.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DType {
    U8,
    U16,
    U32,
    U64,
    I8,
    I16,
    I32,
    I64,
    F32,
    F64,
}

impl DType {
    pub fn size(self) -> usize {
        match self {
            DType::U8 | DType::I8 => 1,
            DType::U16 | DType::I16 => 2,
            DType::U32 | DType::I32 | DType::F32 => 4,
            DType::U64 | DType::I64 | DType::F64 => 8,
        }
    }

    /// `u8`, `uint16`, `i32`, `float32`… (NumPy's names too).
    pub fn parse(text: &str) -> Result<DType> {
        Ok(match text.to_ascii_lowercase().as_str() {
            "u8" | "uint8" => DType::U8,
            "u16" | "uint16" => DType::U16,
            "u32" | "uint32" => DType::U32,
            "u64" | "uint64" => DType::U64,
            "i8" | "int8" => DType::I8,
            "i16" | "int16" => DType::I16,
            "i32" | "int32" => DType::I32,
            "i64" | "int64" => DType::I64,
            "f32" | "float32" => DType::F32,
            "f64" | "float64" => DType::F64,
            _ => {
                return Err(Error::Invalid(format!(
                    "unknown data type `{text}` (u8, u16, u32, u64, i8, i16, i32, i64, f32, f64)"
                )))
            }
        })
    }

    fn is_float(self) -> bool {
        matches!(self, DType::F32 | DType::F64)
    }
}

/// One element of a byte buffer as f64 (exact for every integer type up to 2⁵³).
#[inline]
fn element(bytes: &[u8], dtype: DType, little: bool) -> f64 {
    macro_rules! get {
        ($t:ty, $n:expr) => {{
            let mut b = [0u8; $n];
            b.copy_from_slice(&bytes[..$n]);
            if little {
                <$t>::from_le_bytes(b) as f64
            } else {
                <$t>::from_be_bytes(b) as f64
            }
        }};
    }
    match dtype {
        DType::U8 => bytes[0] as f64,
        DType::I8 => bytes[0] as i8 as f64,
        DType::U16 => get!(u16, 2),
        DType::I16 => get!(i16, 2),
        DType::U32 => get!(u32, 4),
        DType::I32 => get!(i32, 4),
        DType::U64 => get!(u64, 8),
        DType::I64 => get!(i64, 8),
        DType::F32 => get!(f32, 4),
        DType::F64 => get!(f64, 8),
    }
}

/// A volume read slice by slice, in z order (a second pass restarts it).
pub trait SliceSource {
    /// `[nz, ny, nx]`.
    fn shape(&self) -> [usize; 3];
    /// Slice `z` as labels (`out.len() == ny·nx`); an error names the voxel
    /// that is not a label.
    fn labels(&mut self, z: usize, out: &mut [u32]) -> Result<()>;
    /// Slice `z` as grey levels.
    fn greys(&mut self, z: usize, out: &mut [f32]) -> Result<()>;
    /// The same volume readable from several threads at once (arrays and
    /// memory-mapped files), so that passes can split it into z-slabs.
    fn shared(&self) -> Option<&dyn SharedSource> {
        None
    }
    /// Slices `z0..z1` will not be read again in this pass (a memory-mapped
    /// file gives their pages back, so that resident memory stays O(slab)).
    fn release(&mut self, _z0: usize, _z1: usize) {}
}

/// A volume whose slices can be read in any order from any thread.
pub trait SharedSource: Sync {
    /// As [`SliceSource::labels`].
    fn labels_at(&self, z: usize, out: &mut [u32]) -> Result<()>;
    /// As [`SliceSource::greys`].
    fn greys_at(&self, z: usize, out: &mut [f32]) -> Result<()>;
    /// As [`SliceSource::release`]; called when no thread is reading.
    fn release_at(&self, _z0: usize, _z1: usize) {}
}

fn not_a_label(origin: &Path, z: usize, index: usize, nx: usize, value: f64) -> Error {
    Error::data(
        origin,
        None,
        Some(&format!("voxel z={z} y={} x={}", index / nx, index % nx)),
        format!("`{value}` is not a label (labels are integers 0 … 4294967295; 0 is void)"),
    )
}

/// A volume held in memory, `data[(z·ny + y)·nx + x]`.
pub struct ArraySource<'a, T: LabelValue> {
    data: &'a [T],
    shape: [usize; 3],
}

impl<'a, T: LabelValue> ArraySource<'a, T> {
    pub fn new(data: &'a [T], shape: [usize; 3]) -> Result<Self> {
        let n = shape.iter().try_fold(1usize, |a, &s| a.checked_mul(s));
        if n != Some(data.len()) || shape.contains(&0) {
            return Err(Error::Invalid(format!(
                "a {}×{}×{} volume needs {} voxels, the array has {}",
                shape[0],
                shape[1],
                shape[2],
                n.map_or("too many".into(), |n| n.to_string()),
                data.len()
            )));
        }
        Ok(ArraySource { data, shape })
    }
}

impl<T: LabelValue> SliceSource for ArraySource<'_, T> {
    fn shape(&self) -> [usize; 3] {
        self.shape
    }

    fn labels(&mut self, z: usize, out: &mut [u32]) -> Result<()> {
        self.labels_at(z, out)
    }

    fn greys(&mut self, z: usize, out: &mut [f32]) -> Result<()> {
        self.greys_at(z, out)
    }

    fn shared(&self) -> Option<&dyn SharedSource> {
        Some(self)
    }
}

impl<T: LabelValue> SharedSource for ArraySource<'_, T> {
    fn greys_at(&self, z: usize, out: &mut [f32]) -> Result<()> {
        let n = self.shape[1] * self.shape[2];
        for (o, v) in out.iter_mut().zip(&self.data[z * n..(z + 1) * n]) {
            *o = v.grey();
        }
        Ok(())
    }

    fn labels_at(&self, z: usize, out: &mut [u32]) -> Result<()> {
        let n = self.shape[1] * self.shape[2];
        let slice = &self.data[z * n..(z + 1) * n];
        for (i, (o, v)) in out.iter_mut().zip(slice).enumerate() {
            *o = v.label().ok_or_else(|| {
                not_a_label(Path::new("<array>"), z, i, self.shape[2], v.grey() as f64)
            })?;
        }
        Ok(())
    }
}

/// A memory-mapped file of C-ordered elements after a header (`.npy`, raw).
pub struct MappedSource {
    path: PathBuf,
    map: memmap2::Mmap,
    offset: usize,
    dtype: DType,
    little: bool,
    shape: [usize; 3],
}

impl MappedSource {
    /// A raw file: `shape` `[nz, ny, nx]` elements of `dtype` from byte `offset`.
    pub fn raw(
        path: &Path,
        shape: [usize; 3],
        dtype: DType,
        little: bool,
        offset: usize,
    ) -> Result<Self> {
        let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
        // SAFETY: the map is read-only; a file truncated by another process
        // while we read it is outside what any reader can guard against.
        let map = unsafe { memmap2::Mmap::map(&file) }.map_err(|e| Error::io(path, e))?;
        let needed = shape
            .iter()
            .try_fold(dtype.size(), |a, &s| a.checked_mul(s))
            .and_then(|n| n.checked_add(offset));
        if shape.contains(&0) || needed != Some(map.len()) {
            return Err(Error::data(
                path,
                None,
                None,
                format!(
                    "a {}×{}×{} volume of {}-byte values after a {offset}-byte header is {} bytes; \
                     the file has {}",
                    shape[0],
                    shape[1],
                    shape[2],
                    dtype.size(),
                    needed.map_or("too many".into(), |n| n.to_string()),
                    map.len()
                ),
            ));
        }
        Ok(MappedSource {
            path: path.to_owned(),
            map,
            offset,
            dtype,
            little,
            shape,
        })
    }

    /// A NumPy `.npy` file (format 1.0–3.0, C order, a 3D integer or float array).
    pub fn npy(path: &Path) -> Result<Self> {
        let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
        // SAFETY: as in `raw`.
        let map = unsafe { memmap2::Mmap::map(&file) }.map_err(|e| Error::io(path, e))?;
        let header = parse_npy_header(&map).map_err(|m| Error::data(path, None, None, m))?;
        drop(map);
        Self::raw(
            path,
            header.shape,
            header.dtype,
            header.little,
            header.data_offset,
        )
    }

    fn slice_bytes(&self, z: usize) -> &[u8] {
        let n = self.shape[1] * self.shape[2] * self.dtype.size();
        &self.map[self.offset + z * n..self.offset + (z + 1) * n]
    }

    /// Drops the mapped pages of slices `z0..z1` from this process (they
    /// stay in the page cache): without it a pass over a 2 GB file leaves
    /// 2 GB resident.
    fn drop_pages(&self, z0: usize, z1: usize) {
        #[cfg(unix)]
        {
            // 64 KiB: a multiple of every page size in use, so both ends are
            // page-aligned whatever the machine's.
            const ALIGN: usize = 1 << 16;
            let n = self.shape[1] * self.shape[2] * self.dtype.size();
            let start = (self.offset + z0 * n).div_ceil(ALIGN) * ALIGN;
            let end =
                ((self.offset + z1.min(self.shape[0]) * n) / ALIGN * ALIGN).min(self.map.len());
            if end > start {
                // SAFETY: a read-only map of a file: MADV_DONTNEED only makes
                // the next read fault the same bytes in again from the page
                // cache. Every read copies out of the map and returns before
                // a range is released, so no borrow of it is alive.
                let _ = unsafe {
                    self.map.unchecked_advise_range(
                        memmap2::UncheckedAdvice::DontNeed,
                        start,
                        end - start,
                    )
                };
            }
        }
        #[cfg(not(unix))]
        let _ = (z0, z1);
    }
}

impl SliceSource for MappedSource {
    fn shape(&self) -> [usize; 3] {
        self.shape
    }

    fn labels(&mut self, z: usize, out: &mut [u32]) -> Result<()> {
        self.labels_at(z, out)
    }

    fn greys(&mut self, z: usize, out: &mut [f32]) -> Result<()> {
        self.greys_at(z, out)
    }

    fn shared(&self) -> Option<&dyn SharedSource> {
        Some(self)
    }

    fn release(&mut self, z0: usize, z1: usize) {
        self.drop_pages(z0, z1);
    }
}

impl SharedSource for MappedSource {
    fn greys_at(&self, z: usize, out: &mut [f32]) -> Result<()> {
        let size = self.dtype.size();
        let bytes = self.slice_bytes(z);
        for (o, b) in out.iter_mut().zip(bytes.chunks_exact(size)) {
            *o = element(b, self.dtype, self.little) as f32;
        }
        Ok(())
    }

    fn release_at(&self, z0: usize, z1: usize) {
        self.drop_pages(z0, z1);
    }

    fn labels_at(&self, z: usize, out: &mut [u32]) -> Result<()> {
        let size = self.dtype.size();
        let bytes = self.slice_bytes(z);
        // The common cases without the per-element conversion.
        match (self.dtype, self.little == cfg!(target_endian = "little")) {
            (DType::U8, _) => {
                for (o, b) in out.iter_mut().zip(bytes) {
                    *o = *b as u32;
                }
                return Ok(());
            }
            (DType::U16, true) => {
                for (o, b) in out.iter_mut().zip(bytes.chunks_exact(2)) {
                    *o = u16::from_ne_bytes([b[0], b[1]]) as u32;
                }
                return Ok(());
            }
            (DType::U32, true) => {
                for (o, b) in out.iter_mut().zip(bytes.chunks_exact(4)) {
                    *o = u32::from_ne_bytes([b[0], b[1], b[2], b[3]]);
                }
                return Ok(());
            }
            _ => {}
        }
        for (i, (o, b)) in out.iter_mut().zip(bytes.chunks_exact(size)).enumerate() {
            let v = element(b, self.dtype, self.little);
            if self.dtype.is_float() || v < 0.0 || v > u32::MAX as f64 {
                return Err(if self.dtype.is_float() {
                    Error::data(
                        &self.path,
                        None,
                        None,
                        "a label volume must hold integers; this one holds floating-point values",
                    )
                } else {
                    not_a_label(&self.path, z, i, self.shape[2], v)
                });
            }
            *o = v as u32;
        }
        Ok(())
    }
}

pub(crate) struct NpyHeader {
    pub shape: [usize; 3],
    pub dtype: DType,
    pub little: bool,
    pub data_offset: usize,
}

/// The `.npy` header: magic, version, header length, then a Python dict
/// literal `{'descr': '<u2', 'fortran_order': False, 'shape': (z, y, x), }`.
pub(crate) fn parse_npy_header(bytes: &[u8]) -> std::result::Result<NpyHeader, String> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err("not a NumPy .npy file (no \\x93NUMPY magic)".into());
    }
    let major = bytes[6];
    let (len, start) = match major {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        _ => return Err(format!("unsupported .npy format version {major}")),
    };
    let text = bytes
        .get(start..start + len)
        .ok_or("the .npy header is cut short")?;
    let text = std::str::from_utf8(text).map_err(|_| "the .npy header is not text")?;
    let value = |key: &str| -> std::result::Result<&str, String> {
        let at = text
            .find(&format!("'{key}'"))
            .ok_or(format!("the .npy header has no '{key}'"))?;
        let rest = &text[at + key.len() + 2..];
        let colon = rest.find(':').ok_or("malformed .npy header")?;
        Ok(rest[colon + 1..].trim_start())
    };
    let descr = value("descr")?;
    let descr = descr
        .strip_prefix('\'')
        .and_then(|d| d.split('\'').next())
        .ok_or("malformed 'descr' in the .npy header")?;
    let (order, code) = descr.split_at(1.min(descr.len()));
    let little = match order {
        "<" | "|" | "=" => true,
        ">" => false,
        _ => return Err(format!("unsupported .npy dtype `{descr}`")),
    };
    let dtype = match code {
        "u1" => DType::U8,
        "u2" => DType::U16,
        "u4" => DType::U32,
        "u8" => DType::U64,
        "i1" => DType::I8,
        "i2" => DType::I16,
        "i4" => DType::I32,
        "i8" => DType::I64,
        "f4" => DType::F32,
        "f8" => DType::F64,
        "b1" => DType::U8,
        _ => return Err(format!("unsupported .npy dtype `{descr}`")),
    };
    if value("fortran_order")?.starts_with("True") {
        return Err(
            "the array is in Fortran order; save np.ascontiguousarray(volume) instead".into(),
        );
    }
    let shape = value("shape")?;
    let shape = shape
        .strip_prefix('(')
        .and_then(|s| s.split(')').next())
        .ok_or("malformed 'shape' in the .npy header")?;
    let dims: Vec<usize> = shape
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.trim_end_matches('L').parse::<usize>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| format!("malformed shape ({shape}) in the .npy header"))?;
    if dims.len() != 3 {
        return Err(format!(
            "a label volume is a 3D array; this one has shape ({shape})"
        ));
    }
    Ok(NpyHeader {
        shape: [dims[0], dims[1], dims[2]],
        dtype,
        little,
        data_offset: start + len,
    })
}

/// Writes a C-ordered little-endian `.npy` (format 1.0) of u16 or u32 labels
/// (tests and measurements make volumes with it).
pub fn write_npy<T: NpyElement>(path: &Path, data: &[T], shape: [usize; 3]) -> Result<()> {
    let mut header = format!(
        "{{'descr': '{}', 'fortran_order': False, 'shape': ({}, {}, {}), }}",
        T::DESCR,
        shape[0],
        shape[1],
        shape[2]
    );
    // Data start aligned to 64 bytes, the header ends with a newline.
    let pad = (64 - (10 + header.len() + 1) % 64) % 64;
    header.push_str(&" ".repeat(pad));
    header.push('\n');
    let mut bytes = Vec::with_capacity(10 + header.len() + data.len() * T::SIZE);
    bytes.extend_from_slice(b"\x93NUMPY\x01\x00");
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    for v in data {
        v.extend_le(&mut bytes);
    }
    crate::scene::write_file_atomically(path, &bytes)
}

/// An element [`write_npy`] can write.
pub trait NpyElement: Copy {
    const DESCR: &'static str;
    const SIZE: usize;
    fn extend_le(self, out: &mut Vec<u8>);
}

macro_rules! npy_element {
    ($($t:ty => $d:expr),*) => {$(
        impl NpyElement for $t {
            const DESCR: &'static str = $d;
            const SIZE: usize = std::mem::size_of::<$t>();
            fn extend_le(self, out: &mut Vec<u8>) {
                out.extend_from_slice(&self.to_le_bytes());
            }
        }
    )*};
}
npy_element!(u8 => "|u1", u16 => "<u2", u32 => "<u4", f32 => "<f4");

/// A multi-page TIFF, one page per z-slice, read in order (restarting the
/// decoder for a second pass).
pub struct TiffSource {
    path: PathBuf,
    decoder: tiff::decoder::Decoder<std::io::BufReader<std::fs::File>>,
    /// The page the decoder is on.
    page: usize,
    shape: [usize; 3],
}

fn tiff_error(path: &Path, e: tiff::TiffError) -> Error {
    Error::data(path, None, None, format!("cannot read the TIFF: {e}"))
}

impl TiffSource {
    pub fn open(path: &Path) -> Result<Self> {
        let mut decoder = Self::decoder(path)?;
        let (w, h) = decoder.dimensions().map_err(|e| tiff_error(path, e))?;
        let mut pages = 1;
        while decoder.more_images() {
            decoder.next_image().map_err(|e| tiff_error(path, e))?;
            let d = decoder.dimensions().map_err(|e| tiff_error(path, e))?;
            if d != (w, h) {
                return Err(Error::data(
                    path,
                    None,
                    Some(&format!("page {pages}")),
                    format!("page is {}×{} where the first page is {w}×{h}", d.0, d.1),
                ));
            }
            pages += 1;
        }
        Ok(TiffSource {
            path: path.to_owned(),
            decoder: Self::decoder(path)?,
            page: 0,
            shape: [pages, h as usize, w as usize],
        })
    }

    fn decoder(path: &Path) -> Result<tiff::decoder::Decoder<std::io::BufReader<std::fs::File>>> {
        let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
        Ok(tiff::decoder::Decoder::new(std::io::BufReader::new(file))
            .map_err(|e| tiff_error(path, e))?
            .with_limits(tiff::decoder::Limits::unlimited()))
    }

    fn page(&mut self, z: usize) -> Result<tiff::decoder::DecodingResult> {
        if z < self.page {
            self.decoder = Self::decoder(&self.path)?;
            self.page = 0;
        }
        while self.page < z {
            self.decoder
                .next_image()
                .map_err(|e| tiff_error(&self.path, e))?;
            self.page += 1;
        }
        let at = |e| {
            Error::data(
                &self.path,
                None,
                Some(&format!("page {z}")),
                format!("cannot decode the page: {e}"),
            )
        };
        match self.decoder.colortype().map_err(at)? {
            tiff::ColorType::Gray(_) => {}
            other => {
                return Err(Error::data(
                    &self.path,
                    None,
                    Some(&format!("page {z}")),
                    format!(
                        "a label volume has one grey channel per voxel; this page is {other:?}"
                    ),
                ))
            }
        }
        self.decoder.read_image().map_err(at)
    }
}

impl SliceSource for TiffSource {
    fn shape(&self) -> [usize; 3] {
        self.shape
    }

    fn labels(&mut self, z: usize, out: &mut [u32]) -> Result<()> {
        use tiff::decoder::DecodingResult as D;
        let nx = self.shape[2];
        let page = self.page(z)?;
        macro_rules! ints {
            ($v:expr) => {{
                for (i, (o, v)) in out.iter_mut().zip($v.iter()).enumerate() {
                    *o = v
                        .label()
                        .ok_or_else(|| not_a_label(&self.path, z, i, nx, v.grey() as f64))?;
                }
            }};
        }
        match page {
            D::U8(v) => ints!(v),
            D::U16(v) => ints!(v),
            D::U32(v) => ints!(v),
            D::U64(v) => ints!(v),
            D::I8(v) => ints!(v),
            D::I16(v) => ints!(v),
            D::I32(v) => ints!(v),
            D::I64(v) => ints!(v),
            _ => {
                return Err(Error::data(
                    &self.path,
                    None,
                    Some(&format!("page {z}")),
                    "a label volume must hold integers; this page holds floating-point values",
                ))
            }
        }
        Ok(())
    }

    fn greys(&mut self, z: usize, out: &mut [f32]) -> Result<()> {
        use tiff::decoder::DecodingResult as D;
        let page = self.page(z)?;
        macro_rules! copy {
            ($v:expr) => {{
                for (o, v) in out.iter_mut().zip($v.iter()) {
                    *o = *v as f32;
                }
            }};
        }
        match page {
            D::U8(v) => copy!(v),
            D::U16(v) => copy!(v),
            D::U32(v) => copy!(v),
            D::U64(v) => copy!(v),
            D::I8(v) => copy!(v),
            D::I16(v) => copy!(v),
            D::I32(v) => copy!(v),
            D::I64(v) => copy!(v),
            D::F32(v) => copy!(v),
            D::F64(v) => copy!(v),
            D::F16(v) => {
                for (o, x) in out.iter_mut().zip(v.iter()) {
                    *o = f32::from(*x);
                }
            }
        }
        Ok(())
    }
}

/// How to read a volume file.
#[derive(Debug, Clone, PartialEq)]
pub enum FileFormat {
    /// By extension: `.npy`, `.tif`/`.tiff`.
    Auto,
    /// Raw C-ordered elements, `[nz, ny, nx]`, little-endian unless `big`.
    Raw {
        shape: [usize; 3],
        dtype: DType,
        big_endian: bool,
        header_bytes: usize,
    },
}

/// Opens a volume file as a slice source.
pub fn open(path: &Path, format: &FileFormat) -> Result<Box<dyn SliceSource>> {
    match format {
        FileFormat::Raw {
            shape,
            dtype,
            big_endian,
            header_bytes,
        } => Ok(Box::new(MappedSource::raw(
            path,
            *shape,
            *dtype,
            !big_endian,
            *header_bytes,
        )?)),
        FileFormat::Auto => {
            let ext = path
                .extension()
                .and_then(|e| e.to_str())
                .unwrap_or("")
                .to_ascii_lowercase();
            match ext.as_str() {
                "npy" => Ok(Box::new(MappedSource::npy(path)?)),
                "tif" | "tiff" => Ok(Box::new(TiffSource::open(path)?)),
                _ => Err(Error::data(
                    path,
                    None,
                    None,
                    "unknown volume format: name it .npy, .tif or .tiff, or give --shape and \
                     --dtype for a raw file",
                )),
            }
        }
    }
}
