//! Argoverse 2's feather files (Apache Arrow IPC, LZ4-compressed) as typed columns.
//!
//! How it works: the file is read into memory and decoded by the `arrow-ipc` crate's file reader
//! (which decompresses the LZ4 frames and validates every buffer); each record batch's column is
//! then checked for its name and type and copied into one `Vec` over all batches. Every failure —
//! a file that is not Arrow IPC, a missing column, a column of another type, a null in a column
//! that must be filled — is [`DatasetError::BadColumn`] naming the file and the column, so a user
//! can fix their data without reading our code.

#![deny(clippy::indexing_slicing)]

use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow_array::cast::AsArray;
use arrow_array::types::{Float16Type, Float32Type, Float64Type, Int32Type, Int64Type, UInt8Type};
use arrow_array::{Array, RecordBatch};
use arrow_ipc::reader::FileReader;
use arrow_schema::DataType;

use crate::dataset::error::DatasetError;

/// An IEEE half-precision value (its bits) as f32, exactly: a few integer operations for normal
/// numbers (AV2's coordinates), where the `half` crate's portable path costs several times more.
#[inline]
pub fn f16_bits_to_f32(h: u16) -> f32 {
    let sign = u32::from(h & 0x8000) << 16;
    let exp = u32::from((h >> 10) & 0x1f);
    let mant = u32::from(h & 0x03ff);
    match exp {
        0 => {
            // Zero or subnormal: mant · 2⁻²⁴.
            let v = mant as f32 * (1.0 / 16_777_216.0);
            if sign != 0 {
                -v
            } else {
                v
            }
        }
        31 => f32::from_bits(sign | 0x7f80_0000 | (mant << 13)),
        _ => f32::from_bits(sign | ((exp + 112) << 23) | (mant << 13)),
    }
}

/// A feather file in memory: its record batches and the path errors name.
#[derive(Debug, Clone)]
pub struct Feather {
    path: PathBuf,
    batches: Vec<RecordBatch>,
}

fn bad(path: &Path, column: Option<&str>, message: impl Into<String>) -> DatasetError {
    DatasetError::BadColumn {
        path: path.to_path_buf(),
        column: column.map(str::to_owned),
        message: message.into(),
    }
}

impl Feather {
    /// Reads and decodes a feather file. A missing file is [`DatasetError::Io`] with
    /// `NotFound`, so callers can tell it from a bad one.
    pub fn read(path: &Path) -> Result<Self, DatasetError> {
        let bytes = std::fs::read(path).map_err(|source| DatasetError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(bytes, path)
    }

    /// Decodes the bytes of a feather file; `path` only names the file in errors.
    pub fn parse(bytes: Vec<u8>, path: &Path) -> Result<Self, DatasetError> {
        let not_arrow = |e: arrow_schema::ArrowError| {
            bad(
                path,
                None,
                format!("not a readable feather (Arrow IPC) file: {e}"),
            )
        };
        let reader = FileReader::try_new(std::io::Cursor::new(bytes), None).map_err(not_arrow)?;
        let batches = reader.collect::<Result<Vec<_>, _>>().map_err(not_arrow)?;
        Ok(Self {
            path: path.to_path_buf(),
            batches,
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Rows over all batches.
    pub fn num_rows(&self) -> usize {
        self.batches.iter().map(RecordBatch::num_rows).sum()
    }

    /// The column's array in each batch, checked to have no nulls. A file with no batch has no
    /// rows: any column is then empty (its schema is not checked).
    fn arrays(&self, name: &str) -> Result<Vec<Arc<dyn Array>>, DatasetError> {
        let mut out = Vec::with_capacity(self.batches.len());
        for batch in &self.batches {
            let Some(col) = batch.column_by_name(name) else {
                let have: Vec<String> = batch.schema().fields().iter().map(|f| f.name().clone()).collect();
                return Err(bad(
                    &self.path,
                    Some(name),
                    format!("the column is missing (the file has: {})", have.join(", ")),
                ));
            };
            if col.null_count() > 0 {
                let row = (0..col.len()).find(|&i| col.is_null(i)).unwrap_or(0);
                return Err(bad(
                    &self.path,
                    Some(name),
                    format!("{} null value(s), the first at row {row}", col.null_count()),
                ));
            }
            out.push(Arc::clone(col));
        }
        Ok(out)
    }

    fn wrong_type(&self, name: &str, want: &str, got: &DataType) -> DatasetError {
        bad(&self.path, Some(name), format!("expected {want}, found {got}"))
    }

    /// A column over all batches: `take` appends a batch's array to the output and says whether
    /// its type was one it reads; otherwise the column is of the wrong type (`want` names the
    /// types read).
    fn collect<T>(
        &self,
        name: &str,
        want: &str,
        take: impl Fn(&dyn Array, &mut Vec<T>) -> bool,
    ) -> Result<Vec<T>, DatasetError> {
        let mut out = Vec::with_capacity(self.num_rows());
        for a in self.arrays(name)? {
            if !take(a.as_ref(), &mut out) {
                return Err(self.wrong_type(name, want, a.data_type()));
            }
        }
        Ok(out)
    }

    /// A float64 column.
    pub fn f64s(&self, name: &str) -> Result<Vec<f64>, DatasetError> {
        self.collect(name, "float64", |a, out| {
            a.as_primitive_opt::<Float64Type>()
                .map(|v| out.extend_from_slice(v.values()))
                .is_some()
        })
    }

    /// A float16 or float32 column as f32 (AV2 stores point coordinates as float16).
    pub fn f32s(&self, name: &str) -> Result<Vec<f32>, DatasetError> {
        self.collect(name, "float16 or float32", |a, out| {
            if let Some(v) = a.as_primitive_opt::<Float16Type>() {
                out.extend(v.values().iter().map(|h| f16_bits_to_f32(h.to_bits())));
            } else if let Some(v) = a.as_primitive_opt::<Float32Type>() {
                out.extend_from_slice(v.values());
            } else {
                return false;
            }
            true
        })
    }

    /// A uint8 column.
    pub fn u8s(&self, name: &str) -> Result<Vec<u8>, DatasetError> {
        self.collect(name, "uint8", |a, out| {
            a.as_primitive_opt::<UInt8Type>()
                .map(|v| out.extend_from_slice(v.values()))
                .is_some()
        })
    }

    /// An int64 (or int32) column as i64.
    pub fn i64s(&self, name: &str) -> Result<Vec<i64>, DatasetError> {
        self.collect(name, "int64", |a, out| {
            if let Some(v) = a.as_primitive_opt::<Int64Type>() {
                out.extend_from_slice(v.values());
            } else if let Some(v) = a.as_primitive_opt::<Int32Type>() {
                out.extend(v.values().iter().map(|&x| i64::from(x)));
            } else {
                return false;
            }
            true
        })
    }

    /// A string column.
    pub fn strings(&self, name: &str) -> Result<Vec<String>, DatasetError> {
        self.collect(name, "string", |a, out| {
            if let Some(v) = a.as_string_opt::<i32>() {
                out.extend(v.iter().map(|s| s.unwrap_or_default().to_owned()));
            } else if let Some(v) = a.as_string_opt::<i64>() {
                out.extend(v.iter().map(|s| s.unwrap_or_default().to_owned()));
            } else {
                return false;
            }
            true
        })
    }

    /// Several float64 columns of equal length, row by row; a non-finite value is an error
    /// naming its column and row.
    pub fn finite_rows<const N: usize>(&self, names: [&str; N]) -> Result<Vec<[f64; N]>, DatasetError> {
        let cols = names
            .iter()
            .map(|n| self.f64s(n))
            .collect::<Result<Vec<_>, _>>()?;
        let rows = self.num_rows();
        let mut out = vec![[0.0; N]; rows];
        for (col, name) in cols.iter().zip(names) {
            if let Some(i) = col.iter().position(|v| !v.is_finite()) {
                return Err(bad(
                    &self.path,
                    Some(name),
                    format!("row {i} holds {}", col.get(i).copied().unwrap_or(f64::NAN)),
                ));
            }
        }
        for (r, row) in out.iter_mut().enumerate() {
            for (v, col) in row.iter_mut().zip(&cols) {
                *v = col.get(r).copied().unwrap_or(f64::NAN);
            }
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::f16_bits_to_f32;

    #[test]
    fn every_half_converts_as_the_half_crate_does() {
        for bits in 0..=u16::MAX {
            let ours = f16_bits_to_f32(bits);
            type F16 = <arrow_array::types::Float16Type as arrow_array::ArrowPrimitiveType>::Native;
            let theirs = F16::from_bits(bits).to_f32();
            if theirs.is_nan() {
                assert!(ours.is_nan(), "{bits:#06x}");
            } else {
                assert_eq!(
                    ours.to_bits(),
                    theirs.to_bits(),
                    "{bits:#06x}: {ours} vs {theirs}"
                );
            }
        }
    }
}
