//! Merging the outputs of runs over blocks of a sequence (`infer --frames`,
//! one cluster task each) into the files one run over every frame writes:
//! tables with a leading `frame` column (forces.csv) byte for byte, and the
//! JSON reports (one entry per frame) entry for entry.

use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// One shard's rows: the frames they span and their bytes.
struct Block {
    path: PathBuf,
    frames: Option<(i64, i64)>,
    body: Vec<u8>,
}

/// Puts the blocks in frame order and checks that no frame is in two.
fn in_frame_order(mut blocks: Vec<Block>) -> Result<Vec<Block>> {
    blocks.retain(|b| b.frames.is_some());
    blocks.sort_by_key(|b| b.frames);
    for pair in blocks.windows(2) {
        if let (Some((_, last)), Some((next, _))) = (pair[0].frames, pair[1].frames) {
            if next <= last {
                return Err(Error::Invalid(format!(
                    "{} and {} both hold frame {next}: shards must cover disjoint frame ranges",
                    pair[0].path.display(),
                    pair[1].path.display()
                )));
            }
        }
    }
    Ok(blocks)
}

/// Concatenates CSV tables whose first column is `frame` (forces.csv of a
/// sequence, with or without sd columns): the shared header once, then the
/// shards' rows in frame order. Each shard's rows must be in frame order (as
/// `infer` writes them) and the shards' frames disjoint; the result is the
/// file one run over their frames writes, byte for byte.
pub fn merge_frame_tables(shards: &[PathBuf]) -> Result<Vec<u8>> {
    let mut header: Option<(PathBuf, Vec<u8>)> = None;
    let mut blocks = Vec::new();
    for path in shards {
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        let mut reader = csv::ReaderBuilder::new()
            .has_headers(false)
            .from_reader(bytes.as_slice());
        let mut record = csv::ByteRecord::new();
        let mut starts = Vec::new();
        let mut frames = Vec::new();
        loop {
            let start = reader.position().byte() as usize;
            let more = reader.read_byte_record(&mut record).map_err(|e| {
                Error::data(
                    path,
                    e.position().map(|p| p.line() as usize),
                    None,
                    e.to_string(),
                )
            })?;
            if !more {
                break;
            }
            let line = record.position().map_or(0, |p| p.line() as usize);
            let first = record.get(0).unwrap_or_default();
            if starts.is_empty() {
                if first != b"frame" {
                    return Err(Error::data(
                        path,
                        Some(1),
                        None,
                        "the first column is not `frame`: only a sequence's tables merge",
                    ));
                }
            } else {
                let frame = std::str::from_utf8(first)
                    .ok()
                    .and_then(|s| s.parse::<i64>().ok())
                    .ok_or_else(|| {
                        Error::data(
                            path,
                            Some(line),
                            Some("frame"),
                            "not an integer frame number",
                        )
                    })?;
                if frames.last().is_some_and(|&k| frame < k) {
                    return Err(Error::data(
                        path,
                        Some(line),
                        Some("frame"),
                        "the rows are not in frame order",
                    ));
                }
                frames.push(frame);
            }
            starts.push(start);
        }
        if starts.is_empty() {
            return Err(Error::data(path, None, None, "empty file: no header"));
        }
        let body_start = starts.get(1).copied().unwrap_or(bytes.len());
        let this_header = bytes[..body_start].to_vec();
        match &header {
            None => header = Some((path.clone(), this_header)),
            Some((first, h)) if *h != this_header => {
                return Err(Error::data(
                    path,
                    Some(1),
                    None,
                    format!("its header differs from that of {}", first.display()),
                ))
            }
            Some(_) => {}
        }
        blocks.push(Block {
            path: path.clone(),
            frames: frames.first().zip(frames.last()).map(|(&a, &b)| (a, b)),
            body: bytes[body_start..].to_vec(),
        });
    }
    let Some((_, mut out)) = header else {
        return Err(Error::Invalid("no shard to merge".into()));
    };
    for block in in_frame_order(blocks)? {
        out.extend_from_slice(&block.body);
    }
    Ok(out)
}

/// Merges `infer --report` files of blocks of one sequence into the report
/// one run over their frames writes: one entry per frame (a failed frame's
/// `{"frame", "error"}`), in frame order. A block of one frame holds a
/// single object; each entry is kept as its shard wrote it.
pub fn merge_reports(shards: &[PathBuf]) -> Result<Vec<u8>> {
    let mut blocks = Vec::new();
    for path in shards {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let bad = |e: serde_json::Error| {
            Error::data(
                path,
                Some(e.line()),
                None,
                format!("not a JSON report: {e}"),
            )
        };
        let entries: Vec<Box<serde_json::value::RawValue>> = if text.trim_start().starts_with('[') {
            serde_json::from_str(&text).map_err(bad)?
        } else {
            // A one-frame block: its report at the top level, indented as
            // an entry of a list.
            let raw: Box<serde_json::value::RawValue> = serde_json::from_str(&text).map_err(bad)?;
            let indented = raw.get().replace('\n', "\n  ");
            vec![serde_json::value::RawValue::from_string(indented).map_err(bad)?]
        };
        let mut frames = Vec::new();
        for entry in &entries {
            let value: serde_json::Value = serde_json::from_str(entry.get()).map_err(bad)?;
            if value.get("time_fit").is_some() {
                return Err(Error::data(
                    path,
                    None,
                    Some("time_fit"),
                    "a joint time fit is one problem over every frame: its report does not merge",
                ));
            }
            let frame = value
                .get("frame")
                .and_then(serde_json::Value::as_i64)
                .ok_or_else(|| {
                    Error::data(
                        path,
                        None,
                        Some("frame"),
                        "a report entry without a frame number",
                    )
                })?;
            if frames.last().is_some_and(|&k| frame <= k) {
                return Err(Error::data(
                    path,
                    None,
                    Some("frame"),
                    "the entries are not in frame order",
                ));
            }
            frames.push(frame);
        }
        let body: Vec<&str> = entries.iter().map(|e| e.get()).collect();
        blocks.push(Block {
            path: path.clone(),
            frames: frames.first().zip(frames.last()).map(|(&a, &b)| (a, b)),
            body: body.join(",\n  ").into_bytes(),
        });
    }
    let blocks = in_frame_order(blocks)?;
    if blocks.is_empty() {
        return Err(Error::Invalid("no report entries to merge".into()));
    }
    // serde_json's pretty layout, as `infer` writes a sequence's report.
    let mut out = b"[\n  ".to_vec();
    for (k, block) in blocks.iter().enumerate() {
        if k > 0 {
            out.extend_from_slice(b",\n  ");
        }
        out.extend_from_slice(&block.body);
    }
    out.extend_from_slice(b"\n]");
    Ok(out)
}

/// Merges shards into `out`: reports when `out` ends in `.json`, frame
/// tables otherwise. Written atomically.
pub fn merge(out: &Path, shards: &[PathBuf]) -> Result<()> {
    let bytes = if out
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"))
    {
        merge_reports(shards)?
    } else {
        merge_frame_tables(shards)?
    };
    crate::scene::write_file_atomically(out, &bytes)
}
