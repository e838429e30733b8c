//! Export of a fused cloud to the files other point-cloud tools open: binary little-endian PLY
//! (CloudCompare, Open3D, MeshLab read the extra properties as scalar fields) and PCD v0.7 binary
//! (PCL, Autoware tools, Open3D) — and readers for exactly those files, so an export can be
//! loaded back and checked.
//!
//! Per-point fields, in file order (all little-endian, packed without padding):
//!
//! | field | type | meaning |
//! |---|---|---|
//! | `x`, `y`, `z` | float32 | position in the base frame (LIDAR_TOP's), m |
//! | `intensity` | float32 | the LiDAR's intensity, as in the `.bin` |
//! | `lidar` | uint8 | source LiDAR: 0 LIDAR_TOP, 1 LIDAR_FRONT_LEFT, 2 LIDAR_FRONT_RIGHT ([`lidar_id`]) |
//! | `trace` | float32 | tr(Ξ), m² (paper eq. 8) |
//! | `xi_xx`, `xi_xy`, `xi_xz`, `xi_yy`, `xi_yz`, `xi_zz` | float32 | Ξ itself (m², base frame), only with a covariance |
//!
//! The `lidar` id is the channel, not the position in the frame: [`FusedCloud::source`] indexes
//! [`FusedCloud::lidars`], which skips LiDARs a sample lacks, so a sample without
//! LIDAR_FRONT_LEFT still writes LIDAR_FRONT_RIGHT as 2.
//!
//! In memory a covariance is `[f32; 6]` in the order of
//! [`TraceKernel::covariance6`](crate::uncertainty::TraceKernel::covariance6) (xx, yy, zz, xy, xz,
//! yz); the files store the upper triangle row by row ([`XI_FIELDS`] maps one to the other).
//!
//! How it works: the whole file is built in one `Vec<u8>` (header, then one packed record per
//! point; 150k points are a few MB) and written with [`write_atomic`]. Both headers carry the
//! caller's comment (dataset, sample, α, seed: [`source_comment`]) and a line naming the fields.
//! The readers parse the header's property/field list in any order, skip fields they do not know by
//! their size, and check every count against the bytes present before allocating; bad input is an
//! [`ExportError`] naming the field or header line, never a panic. They read what this module
//! writes (binary little-endian, the fields above as float32/uint8), not every PLY or PCD.

use std::fmt;
use std::path::Path;
use std::str::FromStr;

use crate::dataset::LidarChannel;
use crate::io::{write_atomic, IoError};
use crate::pipeline::{FuseParams, FusedCloud};

mod read;
pub use read::{read, read_file, read_pcd, read_ply};

/// The two file formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Format {
    /// Binary little-endian PLY 1.0.
    Ply,
    /// PCD v0.7, `DATA binary`.
    Pcd,
}

impl Format {
    pub const ALL: [Format; 2] = [Format::Ply, Format::Pcd];

    /// The file extension (and the `--format` value): `ply` or `pcd`.
    pub fn extension(self) -> &'static str {
        match self {
            Format::Ply => "ply",
            Format::Pcd => "pcd",
        }
    }

    /// The format a file name's extension names (case-insensitive), if any.
    pub fn from_path(path: &Path) -> Option<Self> {
        let ext = path.extension()?.to_str()?;
        Self::ALL
            .into_iter()
            .find(|f| f.extension().eq_ignore_ascii_case(ext))
    }
}

impl fmt::Display for Format {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Format::Ply => "PLY",
            Format::Pcd => "PCD",
        })
    }
}

impl FromStr for Format {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|f| f.extension().eq_ignore_ascii_case(s.trim()))
            .ok_or_else(|| format!("unknown format '{s}' (expected ply or pcd)"))
    }
}

/// The `lidar` field of a channel: 0 LIDAR_TOP, 1 LIDAR_FRONT_LEFT, 2 LIDAR_FRONT_RIGHT.
pub fn lidar_id(channel: LidarChannel) -> u8 {
    match channel {
        LidarChannel::Top => 0,
        LidarChannel::FrontLeft => 1,
        LidarChannel::FrontRight => 2,
    }
}

/// The channel of a `lidar` field value, if it names one.
pub fn lidar_channel(id: u8) -> Option<LidarChannel> {
    LidarChannel::ALL.into_iter().find(|c| lidar_id(*c) == id)
}

/// The file names of Ξ's six entries, in file order, each with its index in the in-memory
/// `[f32; 6]` (xx, yy, zz, xy, xz, yz, as `TraceKernel::covariance6` returns them).
pub const XI_FIELDS: [(&str, usize); 6] = [
    ("xi_xx", 0),
    ("xi_xy", 3),
    ("xi_xz", 4),
    ("xi_yy", 1),
    ("xi_yz", 5),
    ("xi_zz", 2),
];

/// How to write a cloud.
#[derive(Debug, Clone, Copy)]
pub struct ExportOptions<'a> {
    pub format: Format,
    /// Ξ of every point (xx, yy, zz, xy, xz, yz; e.g. from
    /// [`fused_covariance`](crate::pipeline::fused_covariance)); `None`: only tr(Ξ) is written.
    pub covariance: Option<&'a [[f32; 6]]>,
    /// Where the cloud came from, written as a header comment (line breaks become spaces).
    pub comment: &'a str,
}

/// A cloud read back from an export.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ExportedCloud {
    pub x: Vec<f32>,
    pub y: Vec<f32>,
    pub z: Vec<f32>,
    pub intensity: Vec<f32>,
    /// The `lidar` field ([`lidar_channel`] turns it back into a channel).
    pub lidar: Vec<u8>,
    /// tr(Ξ), m².
    pub trace: Vec<f32>,
    /// Ξ (xx, yy, zz, xy, xz, yz) when the file has the six `xi_*` fields.
    pub covariance: Option<Vec<[f32; 6]>>,
    /// The header's comment lines, without the `comment ` / `# ` prefix.
    pub comments: Vec<String>,
}

impl ExportedCloud {
    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }
}

/// Errors of export and of reading an export back.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error(transparent)]
    Io(#[from] IoError),
    #[error("cannot export: {0}")]
    Inconsistent(String),
    #[error("cannot export: {got} covariances for {points} points")]
    CovarianceLength { points: usize, got: usize },
    #[error("{format} header line {line}: {what}")]
    Header {
        format: Format,
        line: usize,
        what: String,
    },
    #[error("{format} header line {line} is not UTF-8 text")]
    NotUtf8 { format: Format, line: usize },
    #[error("{format} header has no {end} line")]
    NoEndOfHeader { format: Format, end: &'static str },
    #[error("{format}: {what}")]
    Missing { format: Format, what: String },
    #[error("{format}: field '{field}' is {found}, expected {expected}")]
    FieldType {
        format: Format,
        field: String,
        found: String,
        expected: &'static str,
    },
    #[error("{format}: {what} ({count} × {stride} bytes) needs {needed} bytes, {available} remain")]
    Truncated {
        format: Format,
        what: String,
        count: usize,
        stride: usize,
        needed: String,
        available: usize,
    },
    #[error("{format}: {extra} bytes after the last point (wrong point count?)")]
    TrailingBytes { format: Format, extra: usize },
    #[error("{format}: {what} is not supported (only what `mlod export` writes is read)")]
    Unsupported { format: Format, what: String },
}

/// The comment `mlod export` and the window write: tool version, dataset, sample and the fuse
/// parameters, enough to reproduce the cloud.
pub fn source_comment(dataset: &Path, sample: &str, params: &FuseParams) -> String {
    format!(
        "mlod {} export: dataset {} sample {} alpha {} seed {} prior_alpha {} linearization {}",
        env!("CARGO_PKG_VERSION"),
        dataset.display(),
        sample,
        params.perturbation.alpha,
        params.perturbation.seed,
        params.effective_prior_alpha(),
        params.linearization.name(),
    )
}

/// Bytes per point: five float32 and a uint8, plus six float32 with a covariance.
fn record_size(covariance: bool) -> usize {
    5 * 4 + 1 + if covariance { 6 * 4 } else { 0 }
}

const FIELDS_COMMENT: &str = "fields: x y z (m, base frame = LIDAR_TOP), intensity, \
lidar (0 LIDAR_TOP, 1 LIDAR_FRONT_LEFT, 2 LIDAR_FRONT_RIGHT), trace = tr(Xi) (m^2)";
const XI_COMMENT: &str = ", xi_* = entries of Xi (m^2, base frame)";

fn clean_comment(s: &str) -> String {
    s.chars().map(|c| if c.is_control() { ' ' } else { c }).collect()
}

fn ply_header(n: usize, covariance: bool, comment: &str) -> String {
    let mut h = String::from("ply\nformat binary_little_endian 1.0\n");
    if !comment.is_empty() {
        h += &format!("comment {}\n", clean_comment(comment));
    }
    h += &format!(
        "comment {FIELDS_COMMENT}{}\n",
        if covariance { XI_COMMENT } else { "" }
    );
    h += &format!("element vertex {n}\n");
    for name in ["x", "y", "z", "intensity"] {
        h += &format!("property float {name}\n");
    }
    h += "property uchar lidar\nproperty float trace\n";
    if covariance {
        for (name, _) in XI_FIELDS {
            h += &format!("property float {name}\n");
        }
    }
    h + "end_header\n"
}

fn pcd_header(n: usize, covariance: bool, comment: &str) -> String {
    let mut h = String::from("# .PCD v0.7 - Point Cloud Data file format\n");
    if !comment.is_empty() {
        h += &format!("# {}\n", clean_comment(comment));
    }
    h += &format!("# {FIELDS_COMMENT}{}\n", if covariance { XI_COMMENT } else { "" });
    let xi = if covariance { 6 } else { 0 };
    let mut fields = String::from("x y z intensity lidar trace");
    for (name, _) in XI_FIELDS.iter().take(xi) {
        fields += " ";
        fields += name;
    }
    h += &format!("VERSION 0.7\nFIELDS {fields}\n");
    h += &format!("SIZE 4 4 4 4 1 4{}\n", " 4".repeat(xi));
    h += &format!("TYPE F F F F U F{}\n", " F".repeat(xi));
    h += &format!("COUNT 1 1 1 1 1 1{}\n", " 1".repeat(xi));
    h += &format!("WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n");
    h
}

/// The file's bytes: header, then one packed little-endian record per point.
pub fn encode(cloud: &FusedCloud, opts: &ExportOptions<'_>) -> Result<Vec<u8>, ExportError> {
    let n = cloud.len();
    for (name, len) in [
        ("y", cloud.y.len()),
        ("z", cloud.z.len()),
        ("intensity", cloud.intensity.len()),
        ("source", cloud.source.len()),
        ("trace", cloud.trace.len()),
    ] {
        if len != n {
            return Err(ExportError::Inconsistent(format!(
                "{name} has {len} values for {n} points"
            )));
        }
    }
    if let Some(cov) = opts.covariance {
        if cov.len() != n {
            return Err(ExportError::CovarianceLength {
                points: n,
                got: cov.len(),
            });
        }
    }
    // source (an index into `lidars`) → the channel's id; 255 marks an index with no LiDAR.
    let mut ids = [u8::MAX; 256];
    for (slot, l) in ids.iter_mut().zip(&cloud.lidars) {
        *slot = lidar_id(l.channel);
    }
    if let Some(i) = cloud.source.iter().position(|&s| ids[s as usize] == u8::MAX) {
        return Err(ExportError::Inconsistent(format!(
            "point {i} names LiDAR {} of {}",
            cloud.source[i],
            cloud.lidars.len()
        )));
    }
    let header = match opts.format {
        Format::Ply => ply_header(n, opts.covariance.is_some(), opts.comment),
        Format::Pcd => pcd_header(n, opts.covariance.is_some(), opts.comment),
    };
    let mut out = Vec::with_capacity(header.len() + n * record_size(opts.covariance.is_some()));
    out.extend_from_slice(header.as_bytes());
    let (x, y, z) = (&cloud.x[..n], &cloud.y[..n], &cloud.z[..n]);
    let (inten, src, tr) = (&cloud.intensity[..n], &cloud.source[..n], &cloud.trace[..n]);
    for i in 0..n {
        for v in [x[i], y[i], z[i], inten[i]] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.push(ids[src[i] as usize]);
        out.extend_from_slice(&tr[i].to_le_bytes());
        if let Some(cov) = opts.covariance {
            let c = &cov[i];
            for (_, k) in XI_FIELDS {
                out.extend_from_slice(&c[k].to_le_bytes());
            }
        }
    }
    Ok(out)
}

/// Writes `cloud` to `path` atomically (temp file + rename).
pub fn write(path: &Path, cloud: &FusedCloud, opts: &ExportOptions<'_>) -> Result<(), ExportError> {
    let bytes = encode(cloud, opts)?;
    write_atomic(path, &bytes)?;
    Ok(())
}

#[cfg(test)]
mod tests;
