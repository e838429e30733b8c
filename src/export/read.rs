//! Readers for the files [`super::encode`] writes: binary little-endian PLY and PCD v0.7
//! binary. The header's property/field list is parsed in any order, unknown fields are skipped by
//! their size, and every count is checked against the bytes present before anything is
//! allocated; bad input is an [`ExportError`] naming the field or header line, never a panic.

use std::path::Path;

use super::{ExportError, ExportedCloud, Format, XI_FIELDS};
use crate::io::IoError;

/// Reads an export back, PLY or PCD by its first bytes.
pub fn read(bytes: &[u8]) -> Result<ExportedCloud, ExportError> {
    if bytes.starts_with(b"ply\n") || bytes.starts_with(b"ply\r\n") {
        read_ply(bytes)
    } else {
        read_pcd(bytes)
    }
}

/// Reads an export file back (PLY or PCD by its first bytes).
pub fn read_file(path: &Path) -> Result<ExportedCloud, ExportError> {
    let bytes = std::fs::read(path).map_err(|e| IoError::new("cannot read", path, e))?;
    read(&bytes)
}

/// What a field holds, as far as the readers care.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Kind {
    F32,
    U8,
    /// Anything else: skipped by its size.
    Other,
}

#[derive(Debug, Clone)]
struct Field {
    name: String,
    kind: Kind,
    /// Type as written in the header, for error messages.
    type_name: String,
    size: usize,
}

/// Header lines with their 1-based numbers.
type Lines<'a> = Vec<(usize, &'a str)>;

/// Splits the header into numbered text lines up to and including the one `is_end` accepts;
/// returns them and the offset of the first data byte.
fn header_lines<'a>(
    bytes: &'a [u8],
    format: Format,
    end: &'static str,
    is_end: impl Fn(&str) -> bool,
) -> Result<(Lines<'a>, usize), ExportError> {
    let mut lines = Vec::new();
    let mut pos = 0;
    loop {
        let line = lines.len() + 1;
        let rest = bytes.get(pos..).unwrap_or_default();
        let Some(nl) = rest.iter().position(|&b| b == b'\n') else {
            return Err(ExportError::NoEndOfHeader { format, end });
        };
        let raw = rest.get(..nl).unwrap_or_default();
        let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
        let text = std::str::from_utf8(raw).map_err(|_| ExportError::NotUtf8 { format, line })?;
        lines.push((line, text));
        pos += nl + 1;
        if is_end(text) {
            return Ok((lines, pos));
        }
    }
}

fn parse_count(format: Format, line: usize, what: &str, s: Option<&str>) -> Result<usize, ExportError> {
    let s = s.ok_or_else(|| ExportError::Header {
        format,
        line,
        what: format!("{what} is missing"),
    })?;
    s.parse().map_err(|_| ExportError::Header {
        format,
        line,
        what: format!("{what} '{s}' is not a count"),
    })
}

/// PLY scalar types: (size in bytes, kind).
fn ply_type(name: &str) -> Option<(usize, Kind)> {
    Some(match name {
        "char" | "int8" => (1, Kind::Other),
        "uchar" | "uint8" => (1, Kind::U8),
        "short" | "int16" | "ushort" | "uint16" => (2, Kind::Other),
        "int" | "int32" | "uint" | "uint32" => (4, Kind::Other),
        "float" | "float32" => (4, Kind::F32),
        "double" | "float64" => (8, Kind::Other),
        _ => return None,
    })
}

struct PlyElement {
    name: String,
    count: usize,
    fields: Vec<Field>,
    /// The header line of the first list property, if any (its records have no fixed size).
    list_line: Option<usize>,
}

/// Reads a binary little-endian PLY with a `vertex` element holding at least `x y z intensity
/// lidar trace` (float, uchar for `lidar`) and optionally the six `xi_*` floats.
pub fn read_ply(bytes: &[u8]) -> Result<ExportedCloud, ExportError> {
    let f = Format::Ply;
    let (lines, data_start) = header_lines(bytes, f, "end_header", |l| l.trim() == "end_header")?;
    let mut lines = lines.into_iter();
    match lines.next() {
        Some((_, "ply")) => {}
        _ => {
            return Err(ExportError::Header {
                format: f,
                line: 1,
                what: "not a PLY file (the first line must be 'ply')".into(),
            })
        }
    }
    let mut format_seen = false;
    let mut comments = Vec::new();
    let mut elements: Vec<PlyElement> = Vec::new();
    let err = |line: usize, what: String| ExportError::Header {
        format: f,
        line,
        what,
    };
    for (line, text) in lines {
        let mut words = text.split_whitespace();
        match words.next() {
            None | Some("end_header") | Some("obj_info") => {}
            Some("comment") => {
                let rest = text.trim_start().strip_prefix("comment").unwrap_or_default();
                comments.push(rest.strip_prefix(' ').unwrap_or(rest).to_string());
            }
            Some("format") => {
                match (words.next(), words.next()) {
                    (Some("binary_little_endian"), Some("1.0")) => {}
                    (Some(kind @ ("ascii" | "binary_big_endian")), _) => {
                        return Err(ExportError::Unsupported {
                            format: f,
                            what: format!("format {kind}"),
                        })
                    }
                    _ => return Err(err(line, format!("bad format line '{text}'"))),
                }
                format_seen = true;
            }
            Some("element") => {
                let name = words
                    .next()
                    .ok_or_else(|| err(line, "element without a name".into()))?;
                let count = parse_count(f, line, "element count", words.next())?;
                elements.push(PlyElement {
                    name: name.to_string(),
                    count,
                    fields: Vec::new(),
                    list_line: None,
                });
            }
            Some("property") => {
                let Some(el) = elements.last_mut() else {
                    return Err(err(line, "property before any element".into()));
                };
                let ty = words
                    .next()
                    .ok_or_else(|| err(line, "property without a type".into()))?;
                if ty == "list" {
                    el.list_line.get_or_insert(line);
                    continue;
                }
                let (size, kind) =
                    ply_type(ty).ok_or_else(|| err(line, format!("unknown property type '{ty}'")))?;
                let name = words
                    .next()
                    .ok_or_else(|| err(line, "property without a name".into()))?;
                el.fields.push(Field {
                    name: name.to_string(),
                    kind,
                    type_name: ty.to_string(),
                    size,
                });
            }
            Some(other) => return Err(err(line, format!("unknown keyword '{other}'"))),
        }
    }
    if !format_seen {
        return Err(ExportError::Missing {
            format: f,
            what: "the format line".into(),
        });
    }
    let mut data = bytes.get(data_start..).unwrap_or_default();
    let last = elements.len().saturating_sub(1);
    for (i, el) in elements.into_iter().enumerate() {
        if let Some(line) = el.list_line {
            return Err(ExportError::Unsupported {
                format: f,
                what: format!("list property of element '{}' (header line {line})", el.name),
            });
        }
        let stride = record_stride(f, &el.fields)?;
        if el.name == "vertex" {
            let cloud = decode(f, &el.fields, el.count, data, comments)?;
            // Anything after the vertices belongs to later elements, which are not read.
            let used = el.count.saturating_mul(stride);
            if i == last && data.len() > used {
                return Err(ExportError::TrailingBytes {
                    format: f,
                    extra: data.len() - used,
                });
            }
            return Ok(cloud);
        }
        let needed = checked_size(f, &format!("element '{}'", el.name), el.count, stride, data.len())?;
        data = data.get(needed..).unwrap_or_default();
    }
    Err(ExportError::Missing {
        format: f,
        what: "element vertex".into(),
    })
}

/// Reads a PCD v0.7 `DATA binary` file with at least the fields `x y z intensity lidar trace`
/// (F 4, U 1 for `lidar`, COUNT 1) and optionally the six `xi_*` (F 4).
pub fn read_pcd(bytes: &[u8]) -> Result<ExportedCloud, ExportError> {
    let f = Format::Pcd;
    let (lines, data_start) =
        header_lines(bytes, f, "DATA", |l| l.split_whitespace().next() == Some("DATA"))?;
    let err = |line: usize, what: String| ExportError::Header {
        format: f,
        line,
        what,
    };
    let mut comments = Vec::new();
    let mut names: Option<(usize, Vec<&str>)> = None;
    let mut sizes: Option<(usize, Vec<&str>)> = None;
    let mut types: Option<(usize, Vec<&str>)> = None;
    let mut counts: Option<(usize, Vec<&str>)> = None;
    let (mut width, mut height, mut points) = (None, None, None);
    let mut version_seen = false;
    for (line, text) in lines {
        let t = text.trim_start();
        if let Some(c) = t.strip_prefix('#') {
            comments.push(c.strip_prefix(' ').unwrap_or(c).to_string());
            continue;
        }
        let mut words = t.split_whitespace();
        let Some(key) = words.next() else { continue };
        let values: Vec<&str> = words.collect();
        match key {
            "VERSION" => {
                if !matches!(values.first(), Some(&("0.7" | ".7"))) {
                    return Err(ExportError::Unsupported {
                        format: f,
                        what: format!("VERSION {} (line {line})", values.join(" ")),
                    });
                }
                version_seen = true;
            }
            "FIELDS" => names = Some((line, values)),
            "SIZE" => sizes = Some((line, values)),
            "TYPE" => types = Some((line, values)),
            "COUNT" => counts = Some((line, values)),
            "WIDTH" => width = Some(parse_count(f, line, "WIDTH", values.first().copied())?),
            "HEIGHT" => height = Some(parse_count(f, line, "HEIGHT", values.first().copied())?),
            "POINTS" => points = Some((line, parse_count(f, line, "POINTS", values.first().copied())?)),
            "VIEWPOINT" => {}
            "DATA" => match values.first() {
                Some(&"binary") => {}
                Some(other @ (&"ascii" | &"binary_compressed")) => {
                    return Err(ExportError::Unsupported {
                        format: f,
                        what: format!("DATA {other}"),
                    })
                }
                _ => return Err(err(line, format!("bad DATA line '{text}'"))),
            },
            other => return Err(err(line, format!("unknown key '{other}'"))),
        }
    }
    let missing = |what: &str| ExportError::Missing {
        format: f,
        what: format!("the {what} line"),
    };
    if !version_seen {
        return Err(missing("VERSION"));
    }
    let (_, names) = names.ok_or_else(|| missing("FIELDS"))?;
    let (size_line, sizes) = sizes.ok_or_else(|| missing("SIZE"))?;
    let (type_line, types) = types.ok_or_else(|| missing("TYPE"))?;
    let (count_line, counts) = counts.unwrap_or((0, vec!["1"; names.len()]));
    for (key, line, len) in [
        ("SIZE", size_line, sizes.len()),
        ("TYPE", type_line, types.len()),
        ("COUNT", count_line, counts.len()),
    ] {
        if len != names.len() {
            return Err(err(
                line,
                format!("{len} {key} values for {} fields", names.len()),
            ));
        }
    }
    let mut fields = Vec::with_capacity(names.len());
    for (((name, size), ty), count) in names.iter().zip(&sizes).zip(&types).zip(&counts) {
        let size_n = parse_count(f, size_line, &format!("SIZE of '{name}'"), Some(*size))?;
        let count_n = parse_count(f, count_line, &format!("COUNT of '{name}'"), Some(*count))?;
        if !matches!(*ty, "F" | "U" | "I") {
            return Err(err(
                type_line,
                format!("TYPE of '{name}' is '{ty}', not F, U or I"),
            ));
        }
        let kind = match (*ty, size_n, count_n) {
            ("F", 4, 1) => Kind::F32,
            ("U", 1, 1) => Kind::U8,
            _ => Kind::Other,
        };
        let bytes = size_n
            .checked_mul(count_n)
            .ok_or_else(|| err(count_line, format!("'{name}' is absurdly large")))?;
        fields.push(Field {
            name: name.to_string(),
            kind,
            type_name: format!("{ty} {size_n} × {count_n}"),
            size: bytes,
        });
    }
    let (points_line, n) = points.ok_or_else(|| missing("POINTS"))?;
    if let (Some(w), Some(h)) = (width, height) {
        if w.checked_mul(h) != Some(n) {
            return Err(err(
                points_line,
                format!("POINTS {n} is not WIDTH {w} × HEIGHT {h}"),
            ));
        }
    }
    let data = bytes.get(data_start..).unwrap_or_default();
    let stride = record_stride(f, &fields)?;
    let cloud = decode(f, &fields, n, data, comments)?;
    let used = n.saturating_mul(stride);
    if data.len() > used {
        return Err(ExportError::TrailingBytes {
            format: f,
            extra: data.len() - used,
        });
    }
    Ok(cloud)
}

/// The bytes of one record: the sum of the field sizes, checked for overflow.
fn record_stride(format: Format, fields: &[Field]) -> Result<usize, ExportError> {
    fields
        .iter()
        .try_fold(0usize, |acc, p| acc.checked_add(p.size))
        .ok_or_else(|| ExportError::Unsupported {
            format,
            what: "a record larger than usize::MAX bytes".into(),
        })
}

/// `count × stride`, checked against the `available` bytes.
fn checked_size(
    format: Format,
    what: &str,
    count: usize,
    stride: usize,
    available: usize,
) -> Result<usize, ExportError> {
    match count.checked_mul(stride) {
        Some(needed) if needed <= available => Ok(needed),
        needed => Err(ExportError::Truncated {
            format,
            what: what.to_string(),
            count,
            stride,
            needed: needed.map_or_else(|| "more than usize::MAX".into(), |v| v.to_string()),
            available,
        }),
    }
}

/// Decodes `n` packed records of `fields` from the start of `data`.
fn decode(
    format: Format,
    fields: &[Field],
    n: usize,
    data: &[u8],
    comments: Vec<String>,
) -> Result<ExportedCloud, ExportError> {
    let stride = record_stride(format, fields)?;
    // The byte offset of a field within a record, checked for its kind.
    let offset_of = |name: &str, kind: Kind| -> Result<Option<usize>, ExportError> {
        let mut off = 0;
        for p in fields {
            if p.name == name {
                if p.kind != kind {
                    return Err(ExportError::FieldType {
                        format,
                        field: name.to_string(),
                        found: p.type_name.clone(),
                        expected: match kind {
                            Kind::U8 => "uint8",
                            _ => "float32",
                        },
                    });
                }
                return Ok(Some(off));
            }
            off += p.size;
        }
        Ok(None)
    };
    let required = |name: &'static str, kind: Kind| -> Result<usize, ExportError> {
        offset_of(name, kind)?.ok_or_else(|| ExportError::Missing {
            format,
            what: format!("field '{name}'"),
        })
    };
    let floats = [
        required("x", Kind::F32)?,
        required("y", Kind::F32)?,
        required("z", Kind::F32)?,
        required("intensity", Kind::F32)?,
        required("trace", Kind::F32)?,
    ];
    let lidar_off = required("lidar", Kind::U8)?;
    let mut xi = [None; 6];
    for (slot, (name, _)) in xi.iter_mut().zip(XI_FIELDS) {
        *slot = offset_of(name, Kind::F32)?;
    }
    let xi_offsets: Option<[usize; 6]> = match xi.iter().filter(|o| o.is_some()).count() {
        0 => None,
        6 => Some(xi.map(|o| o.unwrap_or_default())),
        _ => {
            let absent = XI_FIELDS
                .iter()
                .zip(&xi)
                .filter(|(_, o)| o.is_none())
                .map(|((name, _), _)| *name)
                .collect::<Vec<_>>()
                .join(", ");
            return Err(ExportError::Missing {
                format,
                what: format!("covariance field(s) {absent} (the six xi_* come together)"),
            });
        }
    };
    let needed = checked_size(format, "the points", n, stride, data.len())?;
    let data = data.get(..needed).unwrap_or_default();
    let f32_at = |rec: &[u8], o: usize| -> f32 {
        rec.get(o..o + 4)
            .and_then(|b| <[u8; 4]>::try_from(b).ok())
            .map_or(f32::NAN, f32::from_le_bytes)
    };
    let mut cols: [Vec<f32>; 5] = std::array::from_fn(|_| Vec::with_capacity(n));
    let mut lidar = Vec::with_capacity(n);
    let mut cov = xi_offsets.map(|_| Vec::with_capacity(n));
    // Every offset + size lies within `stride` (offsets are sums of the sizes before them), so
    // the `get`s below always succeed on a full record.
    for rec in data.chunks_exact(stride.max(1)) {
        for (col, &o) in cols.iter_mut().zip(&floats) {
            col.push(f32_at(rec, o));
        }
        lidar.push(rec.get(lidar_off).copied().unwrap_or(u8::MAX));
        if let (Some(cov), Some(offs)) = (cov.as_mut(), xi_offsets.as_ref()) {
            let mut c = [0.0f32; 6];
            for ((_, k), &o) in XI_FIELDS.iter().zip(offs) {
                c[*k] = f32_at(rec, o);
            }
            cov.push(c);
        }
    }
    let [x, y, z, intensity, trace] = cols;
    Ok(ExportedCloud {
        x,
        y,
        z,
        intensity,
        lidar,
        trace,
        covariance: cov,
        comments,
    })
}
