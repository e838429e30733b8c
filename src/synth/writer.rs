//! The dataset writer: runs the simulator over every key frame of every scene and writes a
//! complete Lyft-format dataset that the official devkit opens like a real one.
//!
//! ```text
//! out/v1.01-train/{scene,sample,sample_data,calibrated_sensor,sensor,ego_pose,
//!                  sample_annotation,instance,category,attribute,visibility,log,map}.json
//! out/lidar/host-a101_lidar{1,0,2}_<GPS ns>.bin     LIDAR_TOP, FRONT_LEFT, FRONT_RIGHT
//! out/maps/map_raster_palo_alto.png
//! ```
//!
//! Tokens are 64 hex digits like the real ones (32 for the map row, as in the real map table):
//! SHA-256 of the seed, the table and the row's indices, so every link is reproducible. Rows
//! follow the real files: one log per scene with the scene's token, the real sensor, category,
//! attribute and visibility rows verbatim, one calibrated_sensor row per LiDAR per log with the
//! real mount, one ego_pose row per key frame shared by the three synchronised LiDARs (as in the
//! real sample), LiDAR sample_data rows without width/height, `prev`/`next` chains per sample,
//! per channel and per instance, timestamps as float microseconds (Unix) and file names in GPS
//! nanoseconds. Annotations carry `num_lidar_pts` (points on the object, all LiDARs), one
//! attribute and an empty `visibility_token` (as the real rows). JSON is written as Python's
//! `json.dump` writes it ([`crate::dataset::tables::to_devkit_json`]); every file is written
//! atomically (temp file + rename). Stale files from an earlier run in `out/` are left alone.

use std::path::Path;

use sha2::{Digest, Sha256};

use super::map;
use super::raycast::scan_sample;
use super::rig::LYFT_MOUNTS;
use super::scene::{Town, GPS_EPOCH_UNIX_S};
use super::{Category, SynthConfig, SynthError, SynthSummary};
use crate::dataset::tables::{
    to_devkit_json, Attribute, CalibratedSensor, Category as CategoryRow, EgoPose, Instance, Log, Map,
    Record, Sample, SampleAnnotation, SampleData, Scene, Sensor, Visibility,
};
use crate::geometry::quat_to_wxyz;
use crate::io::write_atomic;

/// The vehicle whose real calibration the simulated car uses.
pub const HOST: &str = "a101";
/// The version folder written.
pub const VERSION_DIR: &str = "v1.01-train";
/// The map raster, relative to the dataset root.
pub const MAP_FILENAME: &str = "maps/map_raster_palo_alto.png";

/// The real `attribute.json` rows (token, name), in file order.
const ATTRIBUTES: [(&str, &str); 18] = [
    (
        "f5081f1e5aa941f9d9f727ad186c8db67b916336f975a2f5d65d14ea01ed098f",
        "object_action_lane_change_right",
    ),
    (
        "1b388c1f5e5149ae173ad3d674e7ad7f1847e213173d14ce5ecf431ad697ca17",
        "object_action_running",
    ),
    (
        "17d61007ee69782e0ad8ffa5f8cd4c075f18b4b09e11f0e966bc27026c7929ea",
        "object_action_lane_change_left",
    ),
    (
        "5466ded30df08d7d825412ac907017d6ae00ff19051c63666de3dcc4a535c8cc",
        "object_action_parked",
    ),
    (
        "8b08df37edc70b7327d54b3fbf9e7e5894e1a31a93fe772102ff7598e35d0f91",
        "object_action_standing",
    ),
    (
        "0989569fa372d3192628f37ed14a9eb242089187ee53e890c9094cbe13a6a703",
        "object_action_right_turn",
    ),
    (
        "fb20c010bc51767ac99f7cecf51e16bff8e14533259b2337c6c7f8a36e621994",
        "object_action_gliding_on_wheels",
    ),
    (
        "9f0c089e1d2ee9ba32d38e15e3ba271fb4b905f7fc8bee09488250782356af9e",
        "object_action_loss_of_control",
    ),
    (
        "fe119c23bb398acdc112c5d3a6ff4bdedc2f6f52d1253fcc2ee049300ed8a774",
        "object_action_u_turn",
    ),
    (
        "9f853fbe56e7d974482d50000ebd07d29ea4ecdc344efdcdf9812de40e41eaf7",
        "object_action_sitting",
    ),
    (
        "29177d5bec11b5063bd3066d583a9391891546e8d54655e804f7366e5fc6254d",
        "object_action_walking",
    ),
    (
        "1ba8c9a8bda54423fa710b0af1441d849ecca8ed7b7f9393ba1794afe4aa6aa2",
        "object_action_stopped",
    ),
    (
        "d049e95939be40194b077bb970b0fbeeb732308978c5455e3a8a1095efddd03b",
        "object_action_left_turn",
    ),
    (
        "b2395906b761701dfca268fa8a9aa2b44f13ff02e19ada1f66d9fabe99e57cd1",
        "object_action_reversing",
    ),
    (
        "daf16a3f6499553cc5e1df4a456de5ee46e2e6b06544686d918dfb1ddb088f6f",
        "is_stationary",
    ),
    (
        "7fc1ca3d36808cd1858e9c01ad4e7630ff3ca9e720065034abd244122646acc8",
        "object_action_driving_straight_forward",
    ),
    (
        "8888fd4a06ef74a907cdae0da9d370ad3bf26f96f05f03d8da5d9dbd1e2ab84e",
        "object_action_abnormal_or_traffic_violation",
    ),
    (
        "ad3510a8b66087839b8deb7610e90972f36a5b79d09b117ace5c211e3dbdbbd5",
        "object_action_other_motion",
    ),
];

/// The real `visibility.json` rows (level, description, token), in file order.
const VISIBILITIES: [(&str, &str, &str); 4] = [
    ("v60-80", "visibility of whole object is between 60 and 80%", "3"),
    ("v0-40", "visibility of whole object is between 0 and 40%", "1"),
    ("v40-60", "visibility of whole object is between 40 and 60%", "2"),
    (
        "v80-100",
        "visibility of whole object is between 80 and 100%",
        "4",
    ),
];

/// Deterministic tokens: SHA-256 of (seed, table, indices) in hex.
struct Tokens {
    seed: u64,
}

impl Tokens {
    fn make(&self, table: &str, ids: &[usize]) -> String {
        let mut h = Sha256::new();
        h.update(b"mlod-synth\0");
        h.update(self.seed.to_le_bytes());
        h.update(table.as_bytes());
        for &i in ids {
            h.update((i as u64).to_le_bytes());
        }
        h.finalize().iter().map(|b| format!("{b:02x}")).collect()
    }
}

/// Unix microseconds as Lyft's float timestamps, from GPS nanoseconds.
fn unix_micros(gps_ns: u64) -> f64 {
    let unix_ns = gps_ns + GPS_EPOCH_UNIX_S * 1_000_000_000;
    (unix_ns / 1000) as f64 + (unix_ns % 1000) as f64 / 1000.0
}

/// The proleptic Gregorian date (YYYY-MM-DD) of a Unix time in seconds.
fn civil_date(unix_s: u64) -> String {
    // Howard Hinnant's days-to-civil algorithm.
    let z = (unix_s / 86_400) as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!("{year:04}-{month:02}-{day:02}")
}

/// Links rows of a chain in order: prev/next tokens.
fn link(tokens: &[String]) -> Vec<(String, String)> {
    (0..tokens.len())
        .map(|i| {
            let prev = if i > 0 {
                tokens[i - 1].clone()
            } else {
                String::new()
            };
            let next = tokens.get(i + 1).cloned().unwrap_or_default();
            (prev, next)
        })
        .collect()
}

fn write_table<T: Record>(version_dir: &Path, rows: &[T], bytes: &mut u64) -> Result<(), SynthError> {
    let path = version_dir.join(format!("{}.json", T::TABLE));
    let json = to_devkit_json(rows).map_err(|source| SynthError::Json {
        path: path.clone(),
        source,
    })?;
    write_atomic(&path, &json)?;
    *bytes += json.len() as u64;
    Ok(())
}

/// Generates a dataset into `out_dir` (created if needed): see the module documentation.
/// `progress(done, total)` is called with the number of key frames simulated so far.
pub fn generate(
    cfg: &SynthConfig,
    out_dir: &Path,
    mut progress: impl FnMut(usize, usize),
) -> Result<SynthSummary, SynthError> {
    cfg.validate()?;
    let town = Town::generate(cfg);
    let tok = Tokens { seed: cfg.seed };
    let total = cfg.scenes * cfg.samples_per_scene;
    progress(0, total);
    let mut done = 0;
    let mut bytes = 0u64;
    let mut points = 0u64;

    let mut scenes = Vec::new();
    let mut samples = Vec::new();
    let mut sample_data = Vec::new();
    let mut calibrated = Vec::new();
    let mut ego_poses = Vec::new();
    let mut annotations: Vec<SampleAnnotation> = Vec::new();
    let mut instances = Vec::new();
    let mut logs = Vec::new();

    for scene in &town.scenes {
        let si = scene.index;
        let scene_token = tok.make("scene", &[si]);
        let first_ns = scene.timestamps_ns.first().copied().unwrap_or(0);
        let last_ns = scene.timestamps_ns.last().copied().unwrap_or(0);
        logs.push(Log {
            date_captured: civil_date(first_ns / 1_000_000_000 + GPS_EPOCH_UNIX_S),
            location: "Palo Alto".into(),
            token: scene_token.clone(),
            vehicle: HOST.into(),
            logfile: String::new(),
        });
        let cs_tokens: Vec<String> = (0..LYFT_MOUNTS.len())
            .map(|l| tok.make("calibrated_sensor", &[si, l]))
            .collect();
        for (l, token) in cs_tokens.iter().enumerate() {
            let m = town.mount_of(scene, l);
            calibrated.push(CalibratedSensor {
                sensor_token: m.sensor_token.into(),
                rotation: m.rotation_wxyz,
                camera_intrinsic: Vec::new(),
                translation: m.translation,
                token: token.clone(),
            });
        }
        let sample_tokens: Vec<String> = (0..scene.len()).map(|k| tok.make("sample", &[si, k])).collect();
        let sd_tokens: Vec<Vec<String>> = (0..LYFT_MOUNTS.len())
            .map(|l| {
                (0..scene.len())
                    .map(|k| tok.make("sample_data", &[si, k, l]))
                    .collect()
            })
            .collect();
        let sd_links: Vec<Vec<(String, String)>> = sd_tokens.iter().map(|t| link(t)).collect();
        // Per actor, the rows of its annotations in order.
        let mut per_actor: Vec<Vec<usize>> = vec![Vec::new(); scene.actors.len()];

        for (k, ((sample_token, (prev, next)), &ts)) in sample_tokens
            .iter()
            .zip(link(&sample_tokens))
            .zip(&scene.timestamps_ns)
            .enumerate()
        {
            let micros = unix_micros(ts);
            samples.push(Sample {
                next,
                prev,
                token: sample_token.clone(),
                scene_token: scene_token.clone(),
                timestamp: micros,
            });
            let ego = town.ego_pose_global(scene, k);
            let ego_token = tok.make("ego_pose", &[si, k]);
            ego_poses.push(EgoPose {
                rotation: quat_to_wxyz(&ego.rotation),
                translation: [ego.translation.x, ego.translation.y, ego.translation.z],
                token: ego_token.clone(),
                timestamp: micros,
            });
            let scan = scan_sample(&town, scene, k, &cfg.lidar, cfg.seed);
            for (l, (m, lidar)) in LYFT_MOUNTS.iter().zip(&scan.lidars).enumerate() {
                let filename = format!("lidar/host-{HOST}_lidar{}_{ts}.bin", m.file_index);
                let bin = lidar.to_bin_bytes();
                write_atomic(&out_dir.join(&filename), &bin)?;
                bytes += bin.len() as u64;
                points += lidar.points.len() as u64;
                let (prev, next) = sd_links[l][k].clone();
                sample_data.push(SampleData {
                    is_key_frame: true,
                    prev,
                    fileformat: "bin".into(),
                    ego_pose_token: ego_token.clone(),
                    timestamp: micros,
                    next,
                    token: sd_tokens[l][k].clone(),
                    sample_token: sample_token.clone(),
                    filename,
                    calibrated_sensor_token: cs_tokens[l].clone(),
                    width: None,
                    height: None,
                });
            }
            let counts = scan.actor_point_counts(scene.actors.len());
            let (ex, ey) = (ego.translation.x, ego.translation.y);
            for (a, actor) in scene.actors.iter().enumerate() {
                let Some(b) = town.actor_box_global(scene, a, k) else {
                    continue;
                };
                let n = counts.get(a).copied().unwrap_or(0);
                let far = (b.center[0] - ex).hypot(b.center[1] - ey) > cfg.annotation_range_m;
                if far || n < cfg.min_points_per_box.max(1) {
                    continue;
                }
                per_actor[a].push(annotations.len());
                annotations.push(SampleAnnotation {
                    token: tok.make("sample_annotation", &[si, k, a]),
                    num_lidar_pts: i64::from(n),
                    size: b.size_wlh(),
                    sample_token: sample_token.clone(),
                    rotation: quat_to_wxyz(&b.rotation()),
                    prev: String::new(),
                    translation: b.center,
                    num_radar_pts: 0,
                    attribute_tokens: vec![actor.attribute.token().into()],
                    next: String::new(),
                    instance_token: tok.make("instance", &[si, a]),
                    visibility_token: String::new(),
                });
            }
            done += 1;
            progress(done, total);
        }

        for (a, rows) in per_actor.iter().enumerate() {
            let (Some(&first), Some(&last)) = (rows.first(), rows.last()) else {
                continue;
            };
            let tokens: Vec<String> = rows.iter().map(|&r| annotations[r].token.clone()).collect();
            for (&r, (prev, next)) in rows.iter().zip(link(&tokens)) {
                annotations[r].prev = prev;
                annotations[r].next = next;
            }
            instances.push(Instance {
                last_annotation_token: annotations[last].token.clone(),
                category_token: scene.actors[a].category.token().into(),
                token: tok.make("instance", &[si, a]),
                first_annotation_token: annotations[first].token.clone(),
                nbr_annotations: rows.len() as u32,
            });
        }
        scenes.push(Scene {
            description: String::new(),
            log_token: scene_token.clone(),
            name: format!("host-{HOST}-lidar0-{first_ns}-{last_ns}"),
            first_sample_token: sample_tokens.first().cloned().unwrap_or_default(),
            last_sample_token: sample_tokens.last().cloned().unwrap_or_default(),
            nbr_samples: scene.len() as u32,
            token: scene_token,
        });
    }

    let sensors: Vec<Sensor> = LYFT_MOUNTS
        .iter()
        .map(|m| Sensor {
            modality: "lidar".into(),
            channel: m.channel.into(),
            token: m.sensor_token.into(),
        })
        .collect();
    let categories: Vec<CategoryRow> = Category::ALL
        .iter()
        .map(|c| CategoryRow {
            description: String::new(),
            token: c.token().into(),
            name: c.name().into(),
        })
        .collect();
    let attributes: Vec<Attribute> = ATTRIBUTES
        .iter()
        .map(|(token, name)| Attribute {
            description: String::new(),
            token: (*token).into(),
            name: (*name).into(),
        })
        .collect();
    let visibilities: Vec<Visibility> = VISIBILITIES
        .iter()
        .map(|(level, description, token)| Visibility {
            level: (*level).into(),
            description: (*description).into(),
            token: (*token).into(),
        })
        .collect();
    let maps = vec![Map {
        log_tokens: logs.iter().map(|l| l.token.clone()).collect(),
        token: tok.make("map", &[])[..32].to_string(),
        filename: MAP_FILENAME.into(),
        category: "semantic_prior".into(),
    }];

    let version_dir = out_dir.join(VERSION_DIR);
    write_table(&version_dir, &scenes, &mut bytes)?;
    write_table(&version_dir, &samples, &mut bytes)?;
    write_table(&version_dir, &sample_data, &mut bytes)?;
    write_table(&version_dir, &calibrated, &mut bytes)?;
    write_table(&version_dir, &sensors, &mut bytes)?;
    write_table(&version_dir, &ego_poses, &mut bytes)?;
    write_table(&version_dir, &annotations, &mut bytes)?;
    write_table(&version_dir, &instances, &mut bytes)?;
    write_table(&version_dir, &categories, &mut bytes)?;
    write_table(&version_dir, &attributes, &mut bytes)?;
    write_table(&version_dir, &visibilities, &mut bytes)?;
    write_table(&version_dir, &logs, &mut bytes)?;
    write_table(&version_dir, &maps, &mut bytes)?;

    let map_file = out_dir.join(MAP_FILENAME);
    let (w, h, gray) = map::render(&town);
    let png = map::encode_png(w, h, &gray).map_err(|source| SynthError::Png {
        path: map_file.clone(),
        source,
    })?;
    write_atomic(&map_file, &png)?;
    bytes += png.len() as u64;

    Ok(SynthSummary {
        version_dir,
        map_file,
        scenes: scenes.len(),
        samples: samples.len(),
        sample_data: sample_data.len(),
        annotations: annotations.len(),
        instances: instances.len(),
        points,
        bytes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timestamps_match_the_real_file_name_convention() {
        // The real host-a101 sweep: file name 1240710385903083166, table 1556675185903083.2.
        assert_eq!(unix_micros(1_240_710_385_903_083_166), 1556675185903083.2);
        assert_eq!(civil_date(1_556_675_185), "2019-05-01");
        assert_eq!(civil_date(0), "1970-01-01");
    }

    #[test]
    fn tokens_are_64_hex_and_depend_on_everything() {
        let t = Tokens { seed: 1 };
        let a = t.make("sample", &[0, 1]);
        assert_eq!(a.len(), 64);
        assert!(a.chars().all(|c| c.is_ascii_hexdigit()));
        assert_ne!(a, t.make("sample", &[1, 0]));
        assert_ne!(a, Tokens { seed: 2 }.make("sample", &[0, 1]));
        assert_ne!(a, t.make("sample_data", &[0, 1]));
    }

    #[test]
    fn chains_link_neighbours() {
        let l = link(&["a".into(), "b".into(), "c".into()]);
        assert_eq!(l[0], (String::new(), "b".into()));
        assert_eq!(l[1], ("a".into(), "c".into()));
        assert_eq!(l[2], ("b".into(), String::new()));
    }
}
