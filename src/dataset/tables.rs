//! The 13 Lyft Level 5 / nuScenes tables as serde structs, read and written in the exact on-disk
//! form of `v1.01-train/*.json`, so that files we write are read by the official devkit
//! (`lyft_dataset_sdk.LyftDataset`) exactly like real ones.
//!
//! Conventions of the on-disk format (checked against the real excerpt in
//! `tests/fixtures/lyft-real/`):
//! - every row has a `token`; links are tokens, `""` meaning "none" (`prev`/`next`, `visibility_token`);
//! - `timestamp` is a float in microseconds;
//! - `translation` is [x, y, z] in metres, `rotation` a quaternion [w, x, y, z];
//! - annotation `size` is [w, l, h] and its `translation` the box centre in the global frame;
//! - `camera_intrinsic` is a 3×3 matrix for cameras and `[]` for LiDARs;
//! - LiDAR `sample_data` rows have no `width`/`height`, camera rows do.
//!
//! Reading tolerates unknown fields. Struct fields are declared in the order the real files use,
//! and [`write_table`] writes what Python's `json.dump` writes (`", "` and `": "` separators,
//! Python float repr, ASCII only, one line, trailing newline), so written files look like real ones.

#![deny(clippy::indexing_slicing)]

use std::collections::HashMap;
use std::io::Write;
use std::path::Path;

use serde::de::DeserializeOwned;
use serde::ser::SerializeStruct;
use serde::{Deserialize, Serialize, Serializer};

use super::error::DatasetError;

/// A row of one of the 13 tables.
pub trait Record: Serialize + DeserializeOwned + Send + Sync {
    /// The table name; the file is `<TABLE>.json`.
    const TABLE: &'static str;
    /// The row's primary key.
    fn token(&self) -> &str;
}

macro_rules! record {
    ($ty:ty, $name:literal) => {
        impl Record for $ty {
            const TABLE: &'static str = $name;
            fn token(&self) -> &str {
                &self.token
            }
        }
    };
}

/// `scene.json`: one driving sequence.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Scene {
    #[serde(default)]
    pub description: String,
    pub log_token: String,
    pub name: String,
    pub first_sample_token: String,
    pub last_sample_token: String,
    pub nbr_samples: u32,
    pub token: String,
}
record!(Scene, "scene");

/// `sample.json`: one annotated key frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Sample {
    pub next: String,
    pub prev: String,
    pub token: String,
    pub scene_token: String,
    /// Microseconds.
    pub timestamp: f64,
}
record!(Sample, "sample");

/// `sample_data.json`: one sensor recording (a LiDAR sweep or a camera image).
///
/// Serialized in the field order of real rows: camera rows (with `width`/`height`) and LiDAR rows
/// (without) use two different orders in the real files, and both are reproduced.
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct SampleData {
    pub is_key_frame: bool,
    pub prev: String,
    /// `"bin"` for LiDAR sweeps, `"jpeg"` for images.
    pub fileformat: String,
    pub ego_pose_token: String,
    /// Microseconds.
    pub timestamp: f64,
    pub next: String,
    pub token: String,
    pub sample_token: String,
    /// Relative to the dataset root, e.g. `lidar/host-a101_lidar1_1240710385903083166.bin`.
    pub filename: String,
    pub calibrated_sensor_token: String,
    /// Image width in pixels; absent for LiDAR rows.
    #[serde(default)]
    pub width: Option<u32>,
    /// Image height in pixels; absent for LiDAR rows.
    #[serde(default)]
    pub height: Option<u32>,
}
record!(SampleData, "sample_data");

impl Serialize for SampleData {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match (self.width, self.height) {
            (Some(width), Some(height)) => {
                // Camera rows: width, height, calibrated_sensor_token, token, sample_token, ...
                let mut st = s.serialize_struct("SampleData", 12)?;
                st.serialize_field("width", &width)?;
                st.serialize_field("height", &height)?;
                st.serialize_field("calibrated_sensor_token", &self.calibrated_sensor_token)?;
                st.serialize_field("token", &self.token)?;
                st.serialize_field("sample_token", &self.sample_token)?;
                st.serialize_field("is_key_frame", &self.is_key_frame)?;
                st.serialize_field("prev", &self.prev)?;
                st.serialize_field("fileformat", &self.fileformat)?;
                st.serialize_field("ego_pose_token", &self.ego_pose_token)?;
                st.serialize_field("timestamp", &self.timestamp)?;
                st.serialize_field("next", &self.next)?;
                st.serialize_field("filename", &self.filename)?;
                st.end()
            }
            _ => {
                // LiDAR rows: is_key_frame, prev, fileformat, ..., calibrated_sensor_token.
                let n = 10 + usize::from(self.width.is_some()) + usize::from(self.height.is_some());
                let mut st = s.serialize_struct("SampleData", n)?;
                st.serialize_field("is_key_frame", &self.is_key_frame)?;
                st.serialize_field("prev", &self.prev)?;
                st.serialize_field("fileformat", &self.fileformat)?;
                st.serialize_field("ego_pose_token", &self.ego_pose_token)?;
                st.serialize_field("timestamp", &self.timestamp)?;
                st.serialize_field("next", &self.next)?;
                st.serialize_field("token", &self.token)?;
                st.serialize_field("sample_token", &self.sample_token)?;
                st.serialize_field("filename", &self.filename)?;
                st.serialize_field("calibrated_sensor_token", &self.calibrated_sensor_token)?;
                if let Some(w) = self.width {
                    st.serialize_field("width", &w)?;
                }
                if let Some(h) = self.height {
                    st.serialize_field("height", &h)?;
                }
                st.end()
            }
        }
    }
}

/// `calibrated_sensor.json`: a sensor's mounting on the ego car, T_ego←sensor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibratedSensor {
    pub sensor_token: String,
    /// [w, x, y, z], sensor frame → ego frame.
    pub rotation: [f64; 4],
    /// 3×3 for cameras, `[]` for LiDARs.
    #[serde(default)]
    pub camera_intrinsic: Vec<Vec<f64>>,
    /// Sensor origin in the ego frame (m).
    pub translation: [f64; 3],
    pub token: String,
}
record!(CalibratedSensor, "calibrated_sensor");

/// `sensor.json`: a physical sensor; `channel` is e.g. `LIDAR_TOP`, `modality` `lidar` or `camera`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Sensor {
    pub modality: String,
    pub channel: String,
    pub token: String,
}
record!(Sensor, "sensor");

/// `ego_pose.json`: the car's pose T_global←ego at a timestamp.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EgoPose {
    /// [w, x, y, z], ego frame → global frame.
    pub rotation: [f64; 4],
    /// Ego origin in the global frame (m).
    pub translation: [f64; 3],
    pub token: String,
    /// Microseconds.
    pub timestamp: f64,
}
record!(EgoPose, "ego_pose");

/// `sample_annotation.json`: one object box at one sample, in the global frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SampleAnnotation {
    pub token: String,
    /// LiDAR points inside the box (`-1` in the real Lyft data: not computed).
    pub num_lidar_pts: i64,
    /// [w, l, h] (m).
    pub size: [f64; 3],
    pub sample_token: String,
    /// [w, x, y, z], box frame → global frame.
    pub rotation: [f64; 4],
    pub prev: String,
    /// Box centre in the global frame (m).
    pub translation: [f64; 3],
    #[serde(default)]
    pub num_radar_pts: i64,
    #[serde(default)]
    pub attribute_tokens: Vec<String>,
    pub next: String,
    pub instance_token: String,
    #[serde(default)]
    pub visibility_token: String,
}
record!(SampleAnnotation, "sample_annotation");

/// `instance.json`: one tracked object across samples.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Instance {
    pub last_annotation_token: String,
    pub category_token: String,
    pub token: String,
    pub first_annotation_token: String,
    pub nbr_annotations: u32,
}
record!(Instance, "instance");

/// `category.json`: an object class (`car`, `pedestrian`, ...).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Category {
    #[serde(default)]
    pub description: String,
    pub token: String,
    pub name: String,
}
record!(Category, "category");

/// `attribute.json`: an object state (`object_action_parked`, ...).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Attribute {
    #[serde(default)]
    pub description: String,
    pub token: String,
    pub name: String,
}
record!(Attribute, "attribute");

/// `visibility.json`: a visibility bin (`v0-40`, ...); tokens are `"1"`–`"4"`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Visibility {
    pub level: String,
    #[serde(default)]
    pub description: String,
    pub token: String,
}
record!(Visibility, "visibility");

/// `log.json`: one recording drive.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Log {
    pub date_captured: String,
    pub location: String,
    pub token: String,
    pub vehicle: String,
    #[serde(default)]
    pub logfile: String,
}
record!(Log, "log");

/// `map.json`: a semantic map raster, `filename` relative to the dataset root (`maps/...png`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Map {
    pub log_tokens: Vec<String>,
    pub token: String,
    pub filename: String,
    pub category: String,
}
record!(Map, "map");

/// The names of the 13 tables, in the order they are loaded.
pub const TABLE_NAMES: [&str; 13] = [
    "scene",
    "sample",
    "sample_data",
    "calibrated_sensor",
    "sensor",
    "ego_pose",
    "sample_annotation",
    "instance",
    "category",
    "attribute",
    "visibility",
    "log",
    "map",
];

/// The rows of one table in file order, indexed by token.
#[derive(Debug, Clone)]
pub struct Table<T> {
    rows: Vec<T>,
    index: HashMap<String, usize>,
}

impl<T: Record> Table<T> {
    /// Indexes rows by token; two rows with one token are an error.
    pub fn new(rows: Vec<T>) -> Result<Self, DatasetError> {
        let mut index = HashMap::with_capacity(rows.len());
        for (i, row) in rows.iter().enumerate() {
            if index.insert(row.token().to_owned(), i).is_some() {
                return Err(DatasetError::DuplicateToken {
                    table: T::TABLE,
                    token: row.token().to_owned(),
                });
            }
        }
        Ok(Self { rows, index })
    }

    /// The row with this token.
    pub fn get(&self, token: &str) -> Option<&T> {
        self.index.get(token).and_then(|&i| self.rows.get(i))
    }

    /// The position of the row with this token in file order.
    pub fn position(&self, token: &str) -> Option<usize> {
        self.index.get(token).copied()
    }

    /// All rows, in file order.
    pub fn rows(&self) -> &[T] {
        &self.rows
    }

    pub fn len(&self) -> usize {
        self.rows.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// The rows, giving up the index.
    pub fn into_rows(self) -> Vec<T> {
        self.rows
    }
}

/// All 13 tables of a version folder.
#[derive(Debug, Clone)]
pub struct Tables {
    pub scene: Table<Scene>,
    pub sample: Table<Sample>,
    pub sample_data: Table<SampleData>,
    pub calibrated_sensor: Table<CalibratedSensor>,
    pub sensor: Table<Sensor>,
    pub ego_pose: Table<EgoPose>,
    pub sample_annotation: Table<SampleAnnotation>,
    pub instance: Table<Instance>,
    pub category: Table<Category>,
    pub attribute: Table<Attribute>,
    pub visibility: Table<Visibility>,
    pub log: Table<Log>,
    pub map: Table<Map>,
}

/// Reads one table file: a missing file is [`DatasetError::MissingTable`], bad JSON is
/// [`DatasetError::Json`] with serde_json's line and column.
pub fn read_table<T: Record>(version_dir: &Path) -> Result<Vec<T>, DatasetError> {
    let path = version_dir.join(format!("{}.json", T::TABLE));
    let bytes = match std::fs::read(&path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(DatasetError::MissingTable {
                table: T::TABLE,
                path,
            })
        }
        Err(source) => return Err(DatasetError::Io { path, source }),
    };
    serde_json::from_slice::<Vec<T>>(&bytes).map_err(|source| DatasetError::Json {
        table: T::TABLE,
        line: source.line(),
        column: source.column(),
        path,
        source,
    })
}

fn load<T: Record>(version_dir: &Path) -> Result<Table<T>, DatasetError> {
    Table::new(read_table::<T>(version_dir)?)
}

impl Tables {
    /// Reads and indexes all 13 tables of a version folder (the folder holding `sample.json`).
    /// The three large tables are parsed in parallel with the rest; when several tables are bad,
    /// the first in [`TABLE_NAMES`] order is reported, independently of thread timing.
    pub fn load(version_dir: &Path) -> Result<Self, DatasetError> {
        let d = version_dir;
        let ((sample_data, sample_annotation), (ego_pose, small)) = rayon::join(
            || rayon::join(|| load::<SampleData>(d), || load::<SampleAnnotation>(d)),
            || {
                rayon::join(
                    || load::<EgoPose>(d),
                    || {
                        (
                            load::<Scene>(d),
                            load::<Sample>(d),
                            load::<CalibratedSensor>(d),
                            load::<Sensor>(d),
                            load::<Instance>(d),
                            load::<Category>(d),
                            load::<Attribute>(d),
                            load::<Visibility>(d),
                            load::<Log>(d),
                            load::<Map>(d),
                        )
                    },
                )
            },
        );
        let (scene, sample, calibrated_sensor, sensor, instance, category, attribute, visibility, log, map) =
            small;
        Ok(Self {
            scene: scene?,
            sample: sample?,
            sample_data: sample_data?,
            calibrated_sensor: calibrated_sensor?,
            sensor: sensor?,
            ego_pose: ego_pose?,
            sample_annotation: sample_annotation?,
            instance: instance?,
            category: category?,
            attribute: attribute?,
            visibility: visibility?,
            log: log?,
            map: map?,
        })
    }

    /// Writes all 13 tables into `version_dir` (created if needed) with [`write_table`].
    pub fn write(&self, version_dir: &Path) -> Result<(), DatasetError> {
        std::fs::create_dir_all(version_dir).map_err(|source| DatasetError::Io {
            path: version_dir.to_path_buf(),
            source,
        })?;
        write_table(version_dir, self.scene.rows())?;
        write_table(version_dir, self.sample.rows())?;
        write_table(version_dir, self.sample_data.rows())?;
        write_table(version_dir, self.calibrated_sensor.rows())?;
        write_table(version_dir, self.sensor.rows())?;
        write_table(version_dir, self.ego_pose.rows())?;
        write_table(version_dir, self.sample_annotation.rows())?;
        write_table(version_dir, self.instance.rows())?;
        write_table(version_dir, self.category.rows())?;
        write_table(version_dir, self.attribute.rows())?;
        write_table(version_dir, self.visibility.rows())?;
        write_table(version_dir, self.log.rows())?;
        write_table(version_dir, self.map.rows())?;
        Ok(())
    }
}

/// Writes `<version_dir>/<TABLE>.json` as Python's `json.dump` would (see [`to_devkit_json`]).
pub fn write_table<T: Record>(version_dir: &Path, rows: &[T]) -> Result<(), DatasetError> {
    let path = version_dir.join(format!("{}.json", T::TABLE));
    let bytes = to_devkit_json(rows).map_err(|source| DatasetError::Json {
        table: T::TABLE,
        path: path.clone(),
        line: 0,
        column: 0,
        source,
    })?;
    std::fs::write(&path, bytes).map_err(|source| DatasetError::Io { path, source })
}

/// Serializes a value as Python's `json.dump(obj, f)` followed by a newline: one line,
/// `", "` and `": "` separators, floats in Python's `repr` (`1e-05`, `1556675185903083.2`),
/// non-ASCII escaped as `\uXXXX`. This is the form of the real Lyft table files.
pub fn to_devkit_json<T: Serialize + ?Sized>(value: &T) -> Result<Vec<u8>, serde_json::Error> {
    let mut out = Vec::new();
    let mut ser = serde_json::Serializer::with_formatter(&mut out, PythonFormatter);
    value.serialize(&mut ser)?;
    out.push(b'\n');
    Ok(out)
}

/// A serde_json formatter that writes what Python's `json` module writes by default.
struct PythonFormatter;

impl serde_json::ser::Formatter for PythonFormatter {
    fn begin_array_value<W: ?Sized + Write>(&mut self, w: &mut W, first: bool) -> std::io::Result<()> {
        if first {
            Ok(())
        } else {
            w.write_all(b", ")
        }
    }

    fn begin_object_key<W: ?Sized + Write>(&mut self, w: &mut W, first: bool) -> std::io::Result<()> {
        if first {
            Ok(())
        } else {
            w.write_all(b", ")
        }
    }

    fn begin_object_value<W: ?Sized + Write>(&mut self, w: &mut W) -> std::io::Result<()> {
        w.write_all(b": ")
    }

    fn write_f64<W: ?Sized + Write>(&mut self, w: &mut W, value: f64) -> std::io::Result<()> {
        w.write_all(python_float_repr(value).as_bytes())
    }

    fn write_f32<W: ?Sized + Write>(&mut self, w: &mut W, value: f32) -> std::io::Result<()> {
        w.write_all(python_float_repr(f64::from(value)).as_bytes())
    }

    fn write_string_fragment<W: ?Sized + Write>(&mut self, w: &mut W, fragment: &str) -> std::io::Result<()> {
        if fragment.is_ascii() {
            return w.write_all(fragment.as_bytes());
        }
        let mut units = [0u16; 2];
        for c in fragment.chars() {
            if c.is_ascii() {
                w.write_all(&[c as u8])?;
            } else {
                for u in c.encode_utf16(&mut units).iter() {
                    write!(w, "\\u{u:04x}")?;
                }
            }
        }
        Ok(())
    }
}

/// Python's `repr(float)` for a finite value: the shortest round-trip digits, in fixed notation
/// when the decimal exponent is in [-4, 16) and in scientific notation (`1e-05`, `1.5e+16`) otherwise.
pub fn python_float_repr(v: f64) -> String {
    if !v.is_finite() {
        // Python writes NaN/Infinity; serde_json never calls us for those (it writes null).
        return if v.is_nan() {
            "NaN".into()
        } else if v > 0.0 {
            "Infinity".into()
        } else {
            "-Infinity".into()
        };
    }
    if v == 0.0 {
        return if v.is_sign_negative() {
            "-0.0".into()
        } else {
            "0.0".into()
        };
    }
    // Rust's `{:e}` gives the shortest round-trip digits ("-3.680498291456359e-5", "1e16"). When
    // two digit strings of that length round-trip equally well (an exact tie, e.g.
    // 1556675185903083.25 → ".2" or ".3"), Python takes the correctly rounded one (ties to even),
    // which is what Rust's fixed-precision formatting gives.
    let shortest = format!("{v:e}");
    let n_digits = shortest
        .split('e')
        .next()
        .map_or(0, |m| m.chars().filter(char::is_ascii_digit).count());
    let rounded = format!("{:.*e}", n_digits.saturating_sub(1), v);
    let sci = if rounded.parse::<f64>().is_ok_and(|r| r.to_bits() == v.to_bits()) {
        rounded
    } else {
        shortest
    };
    let (mantissa, exp) = match sci.split_once('e') {
        Some((m, e)) => (m, e.parse::<i32>().unwrap_or(0)),
        None => (sci.as_str(), 0),
    };
    let negative = mantissa.starts_with('-');
    let digits: String = mantissa.chars().filter(char::is_ascii_digit).collect();
    if digits.is_empty() {
        return format!("{v:?}");
    }
    let n = digits.len() as i32;
    let mut out = String::with_capacity(digits.len() + 8);
    if negative {
        out.push('-');
    }
    if (-4..16).contains(&exp) {
        if exp >= 0 {
            let int_len = (exp + 1) as usize;
            if n <= exp + 1 {
                out.push_str(&digits);
                out.extend(std::iter::repeat_n('0', int_len - digits.len()));
                out.push_str(".0");
            } else {
                out.push_str(&digits[..int_len]);
                out.push('.');
                out.push_str(&digits[int_len..]);
            }
        } else {
            out.push_str("0.");
            out.extend(std::iter::repeat_n('0', (-exp - 1) as usize));
            out.push_str(&digits);
        }
    } else {
        out.push_str(&digits[..1]);
        if n > 1 {
            out.push('.');
            out.push_str(&digits[1..]);
        }
        out.push('e');
        out.push(if exp < 0 { '-' } else { '+' });
        out.push_str(&format!("{:02}", exp.abs()));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn python_float_repr_matches_python() {
        let cases = [
            (1.0, "1.0"),
            (0.5, "0.5"),
            (-2.25, "-2.25"),
            (1556675185903083.2, "1556675185903083.2"),
            (1556675185850000.0, "1556675185850000.0"),
            (3.680498291456359e-05, "3.680498291456359e-05"),
            (1e-05, "1e-05"),
            (0.0001, "0.0001"),
            (1e16, "1e+16"),
            (1.5e16, "1.5e+16"),
            (123456789012345.0, "123456789012345.0"),
            (0.1, "0.1"),
            (-0.0, "-0.0"),
            (1e300, "1e+300"),
            (2.5e-300, "2.5e-300"),
            (457.3505853301973, "457.3505853301973"),
        ];
        for (v, want) in cases {
            assert_eq!(python_float_repr(v), want, "{v:e}");
            assert_eq!(
                python_float_repr(v).parse::<f64>().unwrap().to_bits(),
                v.to_bits()
            );
        }
    }

    #[test]
    fn devkit_json_separators_and_ascii() {
        let v = serde_json::json!([{"a": [1.0, 2], "b": "é\n"}]);
        let s = String::from_utf8(to_devkit_json(&v).unwrap()).unwrap();
        assert_eq!(s, "[{\"a\": [1.0, 2], \"b\": \"\\u00e9\\n\"}]\n");
    }

    #[test]
    fn sample_data_rows_keep_their_real_field_order() {
        let lidar = r#"{"is_key_frame": true, "prev": "", "fileformat": "bin", "ego_pose_token": "e", "timestamp": 1.5, "next": "", "token": "t", "sample_token": "s", "filename": "lidar/a.bin", "calibrated_sensor_token": "c"}"#;
        let cam = r#"{"width": 1920, "height": 1080, "calibrated_sensor_token": "c", "token": "t", "sample_token": "s", "is_key_frame": false, "prev": "p", "fileformat": "jpeg", "ego_pose_token": "e", "timestamp": 2.0, "next": "n", "filename": "images/a.jpeg"}"#;
        for text in [lidar, cam] {
            let row: SampleData = serde_json::from_str(text).unwrap();
            let back = to_devkit_json(&row).unwrap();
            assert_eq!(std::str::from_utf8(&back).unwrap().trim_end(), text);
        }
    }

    #[test]
    fn unknown_fields_are_tolerated_and_lidar_intrinsic_is_empty() {
        let text = r#"[{"sensor_token": "s", "rotation": [1, 0, 0, 0], "camera_intrinsic": [], "translation": [1.0, 2.0, 3.0], "token": "c", "extra": {"x": 1}}]"#;
        let rows: Vec<CalibratedSensor> = serde_json::from_str(text).unwrap();
        assert!(rows[0].camera_intrinsic.is_empty());
        assert_eq!(rows[0].rotation, [1.0, 0.0, 0.0, 0.0]);
    }

    #[test]
    fn duplicate_tokens_are_an_error() {
        let row = Sensor {
            modality: "lidar".into(),
            channel: "LIDAR_TOP".into(),
            token: "x".into(),
        };
        let err = Table::new(vec![row.clone(), row]).unwrap_err();
        assert!(err.to_string().contains("sensor.json") && err.to_string().contains('x'));
    }
}
