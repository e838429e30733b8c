//! Lyft `.bin` point clouds: little-endian float32, five per point — x, y, z (m, in the LiDAR's own
//! sensor frame), intensity, ring index — with no header.
//!
//! How it works: the file is read with one `read` call into a byte buffer, its size checked against
//! the 20-byte record, then converted in one pass over `chunks_exact(20)` into a structure of
//! arrays (five `Vec<f32>`), skipping and counting points with any non-finite value. No per-point
//! allocation. All five columns are kept as `f32`, exactly as stored (the ring index is a small
//! integer stored as a float), so a file without non-finite points is written back byte-identically
//! by [`encode_bin`].

#![deny(clippy::indexing_slicing)]

use std::path::Path;

use super::error::DatasetError;

/// Bytes per point: five float32.
pub const POINT_BYTES: usize = 20;

/// How strictly point clouds are read.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LoadOptions {
    /// Accept a file whose size is not a multiple of 20 bytes: the incomplete last point is
    /// dropped and [`PointCloud::trimmed_bytes`] says how many bytes were ignored. Off by default:
    /// such a file is [`DatasetError::TruncatedPointCloud`].
    pub lenient: bool,
}

/// One LiDAR sweep as a structure of arrays, in the LiDAR's own sensor frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointCloud {
    pub x: Vec<f32>,
    pub y: Vec<f32>,
    pub z: Vec<f32>,
    pub intensity: Vec<f32>,
    /// Laser ring (beam) index, stored by Lyft as a float.
    pub ring: Vec<f32>,
    /// Points dropped because one of their five values was NaN or infinite.
    pub dropped: usize,
    /// Bytes ignored at the end of a truncated file (only with [`LoadOptions::lenient`]).
    pub trimmed_bytes: usize,
}

impl PointCloud {
    /// An empty cloud with room for `n` points.
    pub fn with_capacity(n: usize) -> Self {
        Self {
            x: Vec::with_capacity(n),
            y: Vec::with_capacity(n),
            z: Vec::with_capacity(n),
            intensity: Vec::with_capacity(n),
            ring: Vec::with_capacity(n),
            dropped: 0,
            trimmed_bytes: 0,
        }
    }

    /// Number of (finite) points kept.
    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Appends one point.
    pub fn push(&mut self, x: f32, y: f32, z: f32, intensity: f32, ring: f32) {
        self.x.push(x);
        self.y.push(y);
        self.z.push(z);
        self.intensity.push(intensity);
        self.ring.push(ring);
    }

    /// The five columns have equal lengths.
    pub fn is_consistent(&self) -> bool {
        let n = self.x.len();
        self.y.len() == n && self.z.len() == n && self.intensity.len() == n && self.ring.len() == n
    }
}

/// How a format lays out its point files. Every format we read stores little-endian float32
/// records with no header; they differ in the record's width and the intensity's scale.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PointLayout {
    /// Lyft `.bin` and nuScenes `.pcd.bin`: x, y, z, intensity (0–255), ring.
    #[default]
    XyzIntensityRing,
    /// KITTI `.bin`: x, y, z, reflectance (0–1, read as 0–255). The ring is recovered from the
    /// scan order where possible, else −1.
    XyzReflectance,
    /// An Argoverse 2 sweep (feather): both roof LiDARs in one file, in the ego frame; read by
    /// [`super::av2::sweep`], never by [`parse_points`].
    Av2Sweep,
}

impl PointLayout {
    /// Bytes per point.
    pub fn point_bytes(self) -> usize {
        match self {
            Self::XyzIntensityRing => POINT_BYTES,
            Self::XyzReflectance => 16,
            // Not a record format; `parse_points` refuses it before dividing by this.
            Self::Av2Sweep => 1,
        }
    }

    /// What one record holds, for error messages.
    pub fn describe(self) -> &'static str {
        match self {
            Self::XyzIntensityRing => "5 float32 per point: x, y, z, intensity, ring",
            Self::XyzReflectance => "4 float32 per point: x, y, z, reflectance (KITTI)",
            Self::Av2Sweep => "an Argoverse 2 sweep (feather: x, y, z, intensity, laser_number)",
        }
    }
}

/// Decodes the bytes of a `.bin` file. `path` only names the file in errors.
pub fn parse_bin(bytes: &[u8], path: &Path, opts: LoadOptions) -> Result<PointCloud, DatasetError> {
    parse_points(bytes, path, opts, PointLayout::XyzIntensityRing)
}

/// Decodes the bytes of a point file of any [`PointLayout`].
pub fn parse_points(
    bytes: &[u8],
    path: &Path,
    opts: LoadOptions,
    layout: PointLayout,
) -> Result<PointCloud, DatasetError> {
    if layout == PointLayout::Av2Sweep {
        return Err(DatasetError::BadColumn {
            path: path.to_path_buf(),
            column: None,
            message: "an Argoverse 2 sweep is a feather file, not a record file; open its dataset".to_owned(),
        });
    }
    let width = layout.point_bytes();
    let tail = bytes.len() % width;
    if tail != 0 && !opts.lenient {
        return Err(DatasetError::TruncatedPointCloud {
            path: path.to_path_buf(),
            size: bytes.len() as u64,
            record: width,
            layout: layout.describe(),
        });
    }
    let chunks = bytes.chunks_exact(width);
    let mut cloud = PointCloud::with_capacity(chunks.len());
    cloud.trimmed_bytes = tail;
    for p in chunks {
        let mut v = [0f32; 5];
        for (d, w) in v.iter_mut().zip(p.chunks_exact(4)) {
            if let [a, b, c, e] = *w {
                *d = f32::from_le_bytes([a, b, c, e]);
            }
        }
        let [x, y, z, i, r] = v;
        let (i, r) = match layout {
            PointLayout::XyzIntensityRing => (i, r),
            PointLayout::XyzReflectance => (i * 255.0, -1.0),
            PointLayout::Av2Sweep => (i, r),
        };
        if x.is_finite() && y.is_finite() && z.is_finite() && i.is_finite() && r.is_finite() {
            cloud.push(x, y, z, i, r);
        } else {
            cloud.dropped += 1;
        }
    }
    if layout == PointLayout::XyzReflectance {
        if let Some(rings) = super::kitti::rings_from_scan_order(&cloud.x, &cloud.y) {
            cloud.ring = rings;
        }
    }
    Ok(cloud)
}

/// Reads a `.bin` file with one read call. A missing file is [`DatasetError::Io`] naming the path.
pub fn read_bin(path: &Path, opts: LoadOptions) -> Result<PointCloud, DatasetError> {
    let bytes = std::fs::read(path).map_err(|source| DatasetError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_bin(&bytes, path, opts)
}

/// Encodes a cloud in the `.bin` layout (the inverse of [`parse_bin`]). Columns shorter than `x`
/// are padded with zeros rather than panicking.
pub fn encode_bin(cloud: &PointCloud) -> Vec<u8> {
    let n = cloud.len();
    let mut out = Vec::with_capacity(n * POINT_BYTES);
    let col = |v: &[f32], k: usize| v.get(k).copied().unwrap_or(0.0);
    for k in 0..n {
        for v in [
            col(&cloud.x, k),
            col(&cloud.y, k),
            col(&cloud.z, k),
            col(&cloud.intensity, k),
            col(&cloud.ring, k),
        ] {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

/// Writes a cloud as a `.bin` file, creating its folder.
pub fn write_bin(path: &Path, cloud: &PointCloud) -> Result<(), DatasetError> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|source| DatasetError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
    }
    std::fs::write(path, encode_bin(cloud)).map_err(|source| DatasetError::Io {
        path: path.to_path_buf(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bytes_of(points: &[[f32; 5]]) -> Vec<u8> {
        points.iter().flatten().flat_map(|v| v.to_le_bytes()).collect()
    }

    #[test]
    fn parses_columns_in_order() {
        let b = bytes_of(&[[1.0, 2.0, 3.0, 4.0, 5.0], [-1.0, -2.0, -3.0, 0.5, 31.0]]);
        let c = parse_bin(&b, Path::new("a.bin"), LoadOptions::default()).unwrap();
        assert_eq!(c.x, [1.0, -1.0]);
        assert_eq!(c.y, [2.0, -2.0]);
        assert_eq!(c.z, [3.0, -3.0]);
        assert_eq!(c.intensity, [4.0, 0.5]);
        assert_eq!(c.ring, [5.0, 31.0]);
        assert_eq!((c.dropped, c.trimmed_bytes), (0, 0));
        assert_eq!(encode_bin(&c), b);
    }

    #[test]
    fn non_finite_points_are_dropped_and_counted() {
        let b = bytes_of(&[
            [1.0, 2.0, 3.0, 4.0, 5.0],
            [f32::NAN, 0.0, 0.0, 0.0, 0.0],
            [0.0, 0.0, f32::INFINITY, 0.0, 0.0],
            [0.0, 0.0, 0.0, f32::NEG_INFINITY, 0.0],
            [0.0, 0.0, 0.0, 0.0, f32::NAN],
            [6.0, 7.0, 8.0, 9.0, 10.0],
        ]);
        let c = parse_bin(&b, Path::new("a.bin"), LoadOptions::default()).unwrap();
        assert_eq!(c.len(), 2);
        assert_eq!(c.dropped, 4);
        assert_eq!(c.x, [1.0, 6.0]);
        assert!(c.is_consistent());
    }

    #[test]
    fn truncated_is_an_error_unless_lenient() {
        let mut b = bytes_of(&[[1.0; 5], [2.0; 5]]);
        b.extend_from_slice(&[0u8; 7]);
        let err = parse_bin(&b, Path::new("x/t.bin"), LoadOptions::default()).unwrap_err();
        let msg = err.to_string();
        assert!(msg.contains("x/t.bin") && msg.contains("47"), "{msg}");
        // The same bytes as KITTI records (16 bytes): 47 is not a multiple of 16 either.
        let msg = parse_points(
            &b,
            Path::new("k.bin"),
            LoadOptions::default(),
            PointLayout::XyzReflectance,
        )
        .unwrap_err()
        .to_string();
        assert!(msg.contains("16") && msg.contains("KITTI"), "{msg}");
        let c = parse_bin(&b, Path::new("x/t.bin"), LoadOptions { lenient: true }).unwrap();
        assert_eq!((c.len(), c.trimmed_bytes), (2, 7));
    }

    #[test]
    fn kitti_records_scale_reflectance_to_0_255() {
        let b: Vec<u8> = [
            [1.0f32, 2.0, 3.0, 0.5],
            [4.0, 5.0, 6.0, 1.0],
            [f32::NAN, 0.0, 0.0, 0.2],
        ]
        .iter()
        .flatten()
        .flat_map(|v| v.to_le_bytes())
        .collect();
        let c = parse_points(
            &b,
            Path::new("k.bin"),
            LoadOptions::default(),
            PointLayout::XyzReflectance,
        )
        .unwrap();
        assert_eq!(c.x, [1.0, 4.0]);
        assert_eq!(c.intensity, [127.5, 255.0]);
        assert_eq!(c.ring, [-1.0, -1.0]);
        assert_eq!(c.dropped, 1);
    }

    #[test]
    fn empty_file_is_an_empty_cloud() {
        let c = parse_bin(&[], Path::new("e.bin"), LoadOptions::default()).unwrap();
        assert!(c.is_empty());
    }
}
