//! The messages of `mlod-detector/1` (docs/external.md): the request line, the points file and
//! the answer line.
//!
//! How it works: the fused cloud ([`FusedCloud`], structure-of-arrays) is written row by row as
//! little-endian float32 `x, y, z, intensity, lidar, trace` (24 bytes a point, base frame; `lidar`
//! 0 top, 1 front-left, 2 front-right), converted in parallel above 64k points into one buffer
//! and written with one call. The answer's boxes are checked (finite, positive sizes) before they
//! become [`Detection`]s.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::dataset::LidarChannel;
use crate::geometry::{Box3d, Detection};
use crate::pipeline::FusedCloud;

/// The protocol's name and version, sent in every request.
pub const PROTOCOL: &str = "mlod-detector/1";
/// The fields of a point, in file order.
pub const FIELDS: [&str; 6] = ["x", "y", "z", "intensity", "lidar", "trace"];
/// Bytes of one point in the points file.
pub const POINT_BYTES: usize = 4 * FIELDS.len();

/// One frame's request (one JSON line on the detector's stdin).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Request {
    pub protocol: String,
    pub sample_token: String,
    /// Absolute path of the points file, complete before the line is sent.
    pub points_file: String,
    pub num_points: usize,
    pub fields: Vec<String>,
    /// Always `base`: the base frame (LIDAR_TOP's sensor frame).
    pub frame: String,
}

impl Request {
    pub fn new(sample_token: &str, points_file: &std::path::Path, num_points: usize) -> Self {
        Self {
            protocol: PROTOCOL.into(),
            sample_token: sample_token.into(),
            points_file: points_file.display().to_string(),
            num_points,
            fields: FIELDS.iter().map(|f| f.to_string()).collect(),
            frame: "base".into(),
        }
    }
}

/// One box of an answer (the convention of `mlod detect --json`: geometric centre, l along the
/// heading, yaw about +z, base frame).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AnswerBox {
    pub category: String,
    pub score: f32,
    pub center: [f64; 3],
    pub size_lwh: [f64; 3],
    pub yaw: f64,
}

/// One frame's answer (one JSON line on the detector's stdout): boxes, or an error.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Answer {
    pub sample_token: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub boxes: Option<Vec<AnswerBox>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

/// The value of the `lidar` field of a channel (as `mlod export` writes it).
pub fn lidar_id(channel: LidarChannel) -> f32 {
    f32::from(crate::export::lidar_id(channel))
}

/// The points file's bytes for `cloud`; `Err` names an inconsistent cloud.
pub fn points_bytes(cloud: &FusedCloud) -> Result<Vec<u8>, String> {
    let n = cloud.len();
    let lens = [
        cloud.y.len(),
        cloud.z.len(),
        cloud.intensity.len(),
        cloud.source.len(),
        cloud.trace.len(),
    ];
    if lens.iter().any(|l| *l != n) {
        return Err(format!(
            "the fused cloud's arrays differ in length ({n} vs {lens:?})"
        ));
    }
    let ids: Vec<f32> = cloud.lidars.iter().map(|l| lidar_id(l.channel)).collect();
    if let Some(s) = cloud.source.iter().find(|s| usize::from(**s) >= ids.len()) {
        return Err(format!("a point's source LiDAR {s} is not in the cloud"));
    }
    let mut out = vec![0u8; n * POINT_BYTES];
    let row = |(i, chunk): (usize, &mut [u8])| {
        let id = ids.get(usize::from(cloud.source[i])).copied().unwrap_or(f32::NAN);
        let v = [
            cloud.x[i],
            cloud.y[i],
            cloud.z[i],
            cloud.intensity[i],
            id,
            cloud.trace[i],
        ];
        for (dst, x) in chunk.chunks_exact_mut(4).zip(v) {
            dst.copy_from_slice(&x.to_le_bytes());
        }
    };
    if n > 65_536 {
        out.par_chunks_exact_mut(POINT_BYTES).enumerate().for_each(row);
    } else {
        out.chunks_exact_mut(POINT_BYTES).enumerate().for_each(row);
    }
    Ok(out)
}

impl AnswerBox {
    /// The box as a detection, if its numbers make sense.
    pub fn to_detection(&self) -> Result<Detection, String> {
        let finite = self.center.iter().chain(&self.size_lwh).all(|v| v.is_finite())
            && self.yaw.is_finite()
            && self.score.is_finite();
        if !finite {
            return Err("a number is not finite".into());
        }
        if self.size_lwh.iter().any(|s| *s <= 0.0) {
            return Err(format!("size_lwh {:?} is not positive", self.size_lwh));
        }
        if self.category.is_empty() {
            return Err("the category is empty".into());
        }
        Ok(Detection {
            box3d: Box3d::new(self.center, self.size_lwh, self.yaw),
            score: self.score,
            category: self.category.clone(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::FusedLidar;

    #[test]
    fn points_are_rows_of_little_endian_floats() {
        let cloud = FusedCloud {
            x: vec![1.0, 2.0],
            y: vec![3.0, 4.0],
            z: vec![5.0, 6.0],
            intensity: vec![0.5, 0.25],
            source: vec![0, 1],
            trace: vec![0.001, 0.2],
            lidars: vec![
                FusedLidar::identity(LidarChannel::Top, 0..1),
                FusedLidar::identity(LidarChannel::FrontRight, 1..2),
            ],
        };
        let b = points_bytes(&cloud).unwrap();
        let f: Vec<f32> = b
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        assert_eq!(f, [1.0, 3.0, 5.0, 0.5, 0.0, 0.001, 2.0, 4.0, 6.0, 0.25, 2.0, 0.2]);
        let mut bad = cloud.clone();
        bad.source[1] = 7;
        assert!(points_bytes(&bad).is_err());
    }

    #[test]
    fn the_issue_s_answer_reads() {
        let a: Answer = serde_json::from_str(
            r#"{"sample_token": "t", "boxes": [{"category": "car", "score": 0.9, "center": [1,2,3], "size_lwh": [4,2,1.5], "yaw": 0.1}]}"#,
        )
        .unwrap();
        let d = a.boxes.unwrap()[0].to_detection().unwrap();
        assert_eq!(d.box3d.size_lwh, [4.0, 2.0, 1.5]);
        let e: Answer = serde_json::from_str(r#"{"sample_token": "t", "error": "out of memory"}"#).unwrap();
        assert_eq!(e.error.as_deref(), Some("out of memory"));
        let r = serde_json::to_value(Request::new("t", std::path::Path::new("/p"), 3)).unwrap();
        assert_eq!(r["fields"][5], "trace");
        assert_eq!(r["protocol"], PROTOCOL);
    }
}
