//! Ground-truth sampling, the "dataset sampling" of SECOND that the paper trains its stage-1
//! networks with (§V-A-5).
//!
//! - A database is cut once from the training split: every box of the learned category with at
//!   least `min_points` points (on the LiDARs the case sees, nominal extrinsics) keeps its points,
//!   per LiDAR, in the base frame.
//! - Each training step tops a frame up to `max_per_frame` boxes of the category: candidates are
//!   drawn from the database and kept if their BEV footprint overlaps no box of the frame (of any
//!   category) nor one kept before. A kept object is pasted where it was recorded (the same place
//!   relative to the car, so its point pattern is the one these sensors would see there): the
//!   frame's points inside its box are removed and the object's points are added to the LiDAR that
//!   measured them.
//! - Occlusion is not re-simulated (SECOND does not either).
//!
//! The draws come from the caller's RNG, so a run stays deterministic given its seed.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::dataset::{Dataset, Frame, LidarChannel};
use crate::detect::anchors::{box3d_of, raw_box, RawBox};
use crate::detect::{Case, DetectError};
use crate::geometry::iou::Footprint;
use crate::pipeline::{fuse, FuseParams, FusedCloud};

/// One object of the database: its box and its points per LiDAR (in [`LidarChannel::ALL`] order),
/// each point `[x, y, z, intensity]` in the base frame.
#[derive(Debug, Clone, PartialEq)]
pub struct GtObject {
    pub raw: RawBox,
    pub points: [Vec<[f32; 4]>; 3],
}

impl GtObject {
    pub fn num_points(&self) -> usize {
        self.points.iter().map(Vec::len).sum()
    }
}

/// The sampling database of one case and category.
#[derive(Debug, Clone, Default)]
pub struct GtDatabase {
    pub objects: Vec<GtObject>,
}

/// Whether a point lies in an upright box (box frame: l along the heading).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Inside {
    b: RawBox,
    s: f32,
    c: f32,
    r: f32,
}

impl Inside {
    pub(crate) fn new(b: &RawBox) -> Self {
        let (s, c) = b[6].sin_cos();
        Self {
            b: *b,
            s,
            c,
            r: 0.5 * (b[3] * b[3] + b[4] * b[4]).sqrt(),
        }
    }

    pub(crate) fn contains(&self, x: f32, y: f32, z: f32) -> bool {
        let b = &self.b;
        let dx = x - b[0];
        let dy = y - b[1];
        if dx.abs() > self.r || dy.abs() > self.r {
            return false;
        }
        let lx = self.c * dx + self.s * dy;
        let ly = -self.s * dx + self.c * dy;
        lx.abs() <= 0.5 * b[3] && ly.abs() <= 0.5 * b[4] && (z - b[2]).abs() <= 0.5 * b[5]
    }
}

fn channel_index(ch: LidarChannel) -> usize {
    LidarChannel::ALL.iter().position(|c| *c == ch).unwrap_or(0)
}

/// The LiDARs a case's network sees.
fn seen_by(case: Case) -> [bool; 3] {
    match case.channel() {
        Some(ch) => {
            let mut s = [false; 3];
            s[channel_index(ch)] = true;
            s
        }
        None => [true; 3],
    }
}

fn footprint(b: &RawBox) -> Footprint {
    Footprint::of_box(&box3d_of(b))
}

/// The objects of one fused frame: boxes of `category` with ≥ `min_points` points on the LiDARs
/// `case` sees.
pub fn objects_of(
    cloud: &FusedCloud,
    frame: &Frame,
    case: Case,
    category: &str,
    min_points: usize,
) -> Vec<GtObject> {
    let seen = seen_by(case);
    let mut out = Vec::new();
    for b in frame
        .boxes
        .iter()
        .filter(|b| b.category == category && b.box3d.is_valid())
    {
        let raw = raw_box(&b.box3d);
        let inside = Inside::new(&raw);
        let mut points: [Vec<[f32; 4]>; 3] = Default::default();
        for l in &cloud.lidars {
            let k = channel_index(l.channel);
            let end = l.range.end.min(cloud.len()).min(cloud.intensity.len());
            for i in l.range.start.min(end)..end {
                if inside.contains(cloud.x[i], cloud.y[i], cloud.z[i]) {
                    points[k].push([cloud.x[i], cloud.y[i], cloud.z[i], cloud.intensity[i]]);
                }
            }
        }
        let seen_points: usize = (0..3).filter(|&k| seen[k]).map(|k| points[k].len()).sum();
        if seen_points >= min_points {
            out.push(GtObject { raw, points });
        }
    }
    out
}

impl GtDatabase {
    /// Cuts the database from `tokens` of `dataset` (fused with the nominal extrinsics), in token
    /// order whatever the thread count.
    pub fn build(
        dataset: &Dataset,
        tokens: &[String],
        case: Case,
        category: &str,
        min_points: usize,
    ) -> Result<Self, DetectError> {
        let per_frame: Vec<Result<Vec<GtObject>, DetectError>> = tokens
            .par_iter()
            .map(|t| {
                let frame = dataset.frame(t)?;
                let cloud = fuse(&frame, &FuseParams::default())?;
                Ok(objects_of(&cloud, &frame, case, category, min_points))
            })
            .collect();
        let mut objects = Vec::new();
        for r in per_frame {
            objects.extend(r?);
        }
        Ok(Self { objects })
    }

    pub fn len(&self) -> usize {
        self.objects.len()
    }

    pub fn is_empty(&self) -> bool {
        self.objects.is_empty()
    }

    /// Draws objects to top a frame with `existing` boxes of the category up to `max_per_frame`;
    /// `occupied` are the footprints of every box of the frame (all categories). At most
    /// `2 × wanted` candidates are tried; the kept ones overlap nothing in BEV.
    pub fn sample(
        &self,
        rng: &mut ChaCha8Rng,
        existing: usize,
        occupied: &[RawBox],
        max_per_frame: usize,
    ) -> Vec<usize> {
        let wanted = max_per_frame.saturating_sub(existing);
        if wanted == 0 || self.objects.is_empty() {
            return Vec::new();
        }
        let mut taken: Vec<Footprint> = occupied.iter().map(footprint).collect();
        let mut kept = Vec::new();
        for _ in 0..2 * wanted {
            if kept.len() == wanted {
                break;
            }
            let i = rng.random_range(0..self.objects.len());
            if kept.contains(&i) {
                continue;
            }
            let f = footprint(&self.objects[i].raw);
            if taken.iter().any(|t| t.intersection_area(&f) > 0.0) {
                continue;
            }
            taken.push(f);
            kept.push(i);
        }
        kept
    }
}

/// Pastes objects into a cloud: removes the cloud's points inside their boxes and appends their
/// points to the LiDAR that measured them (an object's points of a LiDAR the frame lacks are
/// dropped). Pasted points get tr(Ξ) = 0.
pub fn paste(cloud: &FusedCloud, objects: &[&GtObject]) -> FusedCloud {
    if objects.is_empty() {
        return cloud.clone();
    }
    let insides: Vec<Inside> = objects.iter().map(|o| Inside::new(&o.raw)).collect();
    let mut out = FusedCloud {
        x: Vec::with_capacity(cloud.len()),
        y: Vec::with_capacity(cloud.len()),
        z: Vec::with_capacity(cloud.len()),
        intensity: Vec::with_capacity(cloud.len()),
        source: Vec::with_capacity(cloud.len()),
        trace: Vec::with_capacity(cloud.len()),
        lidars: Vec::with_capacity(cloud.lidars.len()),
    };
    let n = cloud
        .len()
        .min(cloud.intensity.len())
        .min(cloud.source.len())
        .min(cloud.trace.len());
    for (li, l) in cloud.lidars.iter().enumerate() {
        let start = out.x.len();
        let end = l.range.end.min(n);
        for i in l.range.start.min(end)..end {
            let (x, y, z) = (cloud.x[i], cloud.y[i], cloud.z[i]);
            if insides.iter().any(|b| b.contains(x, y, z)) {
                continue;
            }
            out.x.push(x);
            out.y.push(y);
            out.z.push(z);
            out.intensity.push(cloud.intensity[i]);
            out.source.push(cloud.source[i]);
            out.trace.push(cloud.trace[i]);
        }
        let k = channel_index(l.channel);
        for o in objects {
            for p in &o.points[k] {
                out.x.push(p[0]);
                out.y.push(p[1]);
                out.z.push(p[2]);
                out.intensity.push(p[3]);
                out.source.push(li as u8);
                out.trace.push(0.0);
            }
        }
        let mut lidar = l.clone();
        lidar.range = start..out.x.len();
        out.lidars.push(lidar);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn sample_data() -> Dataset {
        Dataset::open(concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data")).unwrap()
    }

    fn first_frame(ds: &Dataset) -> (Frame, FusedCloud) {
        let token = ds.first_sample_token().unwrap().to_string();
        let frame = ds.frame(&token).unwrap();
        let cloud = fuse(&frame, &FuseParams::default()).unwrap();
        (frame, cloud)
    }

    #[test]
    fn objects_keep_their_points_per_lidar_and_count_only_what_the_case_sees() {
        let ds = sample_data();
        let (frame, cloud) = first_frame(&ds);
        let input = objects_of(&cloud, &frame, Case::Input, "car", 5);
        assert!(!input.is_empty());
        for o in &input {
            assert!(o.num_points() >= 5);
            let inside = Inside::new(&o.raw);
            assert!(o
                .points
                .iter()
                .flatten()
                .all(|p| inside.contains(p[0], p[1], p[2])));
        }
        // Some car is measured by a bumper LiDAR as well as the top one.
        assert!(input
            .iter()
            .any(|o| !o.points[0].is_empty() && !o.points[1].is_empty()));
        // LiDAR-Left keeps exactly the cars with ≥ 5 left points, whatever the others saw.
        let left = objects_of(&cloud, &frame, Case::Left, "car", 5);
        let expected: Vec<RawBox> = input
            .iter()
            .filter(|o| o.points[1].len() >= 5)
            .map(|o| o.raw)
            .collect();
        assert_eq!(left.iter().map(|o| o.raw).collect::<Vec<_>>(), expected);
        assert!(left.len() < input.len());
    }

    #[test]
    fn paste_replaces_the_points_inside_and_keeps_each_lidar_contiguous() {
        let ds = sample_data();
        let (_, cloud) = first_frame(&ds);
        // A made-up object in free space, 3 top points and 2 left ones.
        let raw: RawBox = [0.0, 30.0, -1.0, 4.0, 2.0, 1.6, 0.3];
        let obj = GtObject {
            raw,
            points: [
                vec![
                    [0.0, 30.0, -1.0, 10.0],
                    [0.5, 30.2, -0.8, 11.0],
                    [-0.5, 29.8, -1.2, 12.0],
                ],
                vec![[0.1, 30.1, -1.1, 20.0], [0.2, 29.9, -0.9, 21.0]],
                Vec::new(),
            ],
        };
        let inside = Inside::new(&raw);
        let before_inside = (0..cloud.len())
            .filter(|&i| inside.contains(cloud.x[i], cloud.y[i], cloud.z[i]))
            .count();
        let out = paste(&cloud, &[&obj]);
        assert_eq!(out.len(), cloud.len() - before_inside + 5);
        for v in [
            out.y.len(),
            out.z.len(),
            out.intensity.len(),
            out.source.len(),
            out.trace.len(),
        ] {
            assert_eq!(v, out.len());
        }
        let mut next = 0;
        for (li, l) in out.lidars.iter().enumerate() {
            assert_eq!(l.range.start, next);
            next = l.range.end;
            assert!(out.source[l.range.clone()].iter().all(|&s| s as usize == li));
            let inside_here: Vec<f32> = l
                .range
                .clone()
                .filter(|&i| inside.contains(out.x[i], out.y[i], out.z[i]))
                .map(|i| out.intensity[i])
                .collect();
            let want: Vec<f32> = obj.points[channel_index(l.channel)]
                .iter()
                .map(|p| p[3])
                .collect();
            assert_eq!(inside_here, want, "{:?}", l.channel);
        }
        assert_eq!(next, out.len());
        // Nothing pasted: the cloud is unchanged.
        assert_eq!(paste(&cloud, &[]), cloud);
    }

    #[test]
    fn sampled_objects_overlap_nothing_and_repeat_with_the_seed() {
        let ds = sample_data();
        let tokens: Vec<String> = ds.samples().into_iter().map(|s| s.sample_token).collect();
        let db = GtDatabase::build(&ds, &tokens, Case::Input, "car", 5).unwrap();
        assert!(db.len() > 10);
        // An empty street: every draw that does not overlap an earlier one is kept.
        let draw = |seed: u64, occupied: &[RawBox], existing: usize| {
            db.sample(&mut ChaCha8Rng::seed_from_u64(seed), existing, occupied, 8)
        };
        let picked = draw(1, &[], 0);
        assert!(!picked.is_empty() && picked.len() <= 8);
        assert_eq!(picked, draw(1, &[], 0));
        // Topping up: a frame that already has 8 cars gets none.
        assert!(draw(1, &[], 8).is_empty());
        // Against a real frame's boxes: no kept box overlaps them or another kept one.
        let (frame, _) = first_frame(&ds);
        let occupied: Vec<RawBox> = frame.boxes.iter().map(|b| raw_box(&b.box3d)).collect();
        for seed in 0..20 {
            let picked = draw(seed, &occupied, 0);
            let mut all: Vec<Footprint> = occupied.iter().map(footprint).collect();
            for &i in &picked {
                let f = footprint(&db.objects[i].raw);
                assert!(all.iter().all(|t| t.intersection_area(&f) <= 0.0));
                all.push(f);
            }
        }
    }
}
