//! The CPU cost of an α change in the debugger: re-fuse a 150 000-point three-LiDAR frame and
//! recompute every tr(Ξ) (`pipeline::fuse`). Target (GUI issue): ≤ 16 ms. And online calibration
//! of one auxiliary LiDAR of a sample_data frame at α = 0.1, the target's downsampling, kd-tree
//! and normals included (`calib`). Target (OC issue): ≤ 50 ms on 2 cores. And (feature `gui`)
//! the offscreen render of 150 000 points at 1280×800 with read-back, without and with 4× MSAA,
//! with and without a colour upload (an α-slider drag), on whatever adapter wgpu finds (lavapipe
//! without a GPU).
use criterion::{criterion_group, criterion_main, Criterion};
use mlod::color::{colorize, histogram, ColorParams};
use mlod::dataset::{Frame, LidarChannel, LidarScan, PointCloud};
use mlod::geometry::{pose_from_rt, rpy_to_matrix, Pose};
use mlod::pipeline::{fuse, FuseParams};
use mlod::uncertainty::Perturbation;
use nalgebra::Vector3;
use std::hint::black_box;

fn cloud(n: usize) -> PointCloud {
    let mut c = PointCloud::with_capacity(n);
    for i in 0..n {
        let a = i as f32 * 0.0035;
        let r = 3.0 + (i % 700) as f32 * 0.08;
        c.push(
            a.cos() * r,
            a.sin() * r,
            (i % 40) as f32 * 0.1 - 2.0,
            10.0,
            (i % 40) as f32,
        );
    }
    c
}

fn bench(c: &mut Criterion) {
    let aux = |ch, rpy: [f64; 3], t: [f64; 3], n| {
        LidarScan::in_memory(
            ch,
            pose_from_rt(&rpy_to_matrix(rpy[0], rpy[1], rpy[2]), &Vector3::from(t)),
            cloud(n),
        )
    };
    let frame = Frame::in_memory(
        "bench",
        LidarScan::in_memory(LidarChannel::Top, Pose::identity(), cloud(70_000)),
        vec![
            aux(
                LidarChannel::FrontLeft,
                [3.1, -0.03, -1.5],
                [-2.23, -0.97, -1.34],
                40_000,
            ),
            aux(
                LidarChannel::FrontRight,
                [3.13, 0.005, 1.6],
                [-2.28, 0.92, -1.33],
                40_000,
            ),
        ],
        Vec::new(),
    );
    let mut alpha = 0.0;
    c.bench_function("fuse_150k_alpha_change", |b| {
        b.iter(|| {
            alpha = if alpha >= 0.1 { 0.0 } else { alpha + 0.01 };
            let params = FuseParams {
                perturbation: Perturbation::new(alpha, 7).unwrap(),
                ..Default::default()
            };
            black_box(fuse(black_box(&frame), &params).unwrap())
        })
    });
    // What the GUI does per α tick: fuse, recolour by tr(Ξ), histogram and |P_u|/|P|.
    let color = ColorParams::default();
    c.bench_function("alpha_change_fuse_color_histogram_150k", |b| {
        b.iter(|| {
            alpha = if alpha >= 0.1 { 0.0 } else { alpha + 0.01 };
            let params = FuseParams {
                perturbation: Perturbation::new(alpha, 7).unwrap(),
                ..Default::default()
            };
            let cloud = fuse(black_box(&frame), &params).unwrap();
            let colors = colorize(&cloud, &color);
            let hist = histogram(&cloud.trace, color.range, color.scale, 64);
            black_box((colors, hist, cloud.uncertain_fraction(0.05)))
        })
    });
}

/// What the Python package's `Dataset.fuse` does per call on the largest sample of sample_data/:
/// load the frame from disk, fuse it with tr(Ξ) (python/bench/fuse_bench.py times the same from
/// Python).
fn bench_sample_fuse(c: &mut Criterion) {
    let dataset =
        mlod::dataset::Dataset::open(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("sample_data"))
            .unwrap();
    let size = |t: &str| {
        let f = dataset.frame(t).unwrap();
        f.lidars().map(|l| l.points.x.len()).sum::<usize>()
    };
    let token = mlod::dataset::list(&dataset)
        .into_iter()
        .map(|s| s.sample_token)
        .max_by_key(|t| size(t))
        .unwrap();
    let params = FuseParams {
        perturbation: Perturbation::new(0.1, 7).unwrap(),
        ..Default::default()
    };
    c.bench_function("sample_data_frame_and_fuse", |b| {
        b.iter(|| {
            let frame = dataset.frame(black_box(&token)).unwrap();
            black_box(fuse(&frame, &params).unwrap())
        })
    });
}

fn bench_icp(c: &mut Criterion) {
    use mlod::calib::{align, voxel_downsample, IcpConfig, Target};
    let ds = mlod::dataset::Dataset::open(concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data")).unwrap();
    let frame = ds.frame(ds.first_sample_token().unwrap()).unwrap();
    let params = FuseParams {
        perturbation: Perturbation::new(0.1, 0).unwrap(),
        ..Default::default()
    };
    let cfg = IcpConfig::default();
    let theta = params.prior.scaled(0.1).unwrap();
    let mut prior = nalgebra::Matrix6::zeros();
    prior.fixed_view_mut::<3, 3>(0, 0).copy_from(&theta.p);
    prior.fixed_view_mut::<3, 3>(3, 3).copy_from(&theta.phi);
    let aux = &frame.auxiliaries[0];
    let start = params
        .noise_for(aux.info.channel)
        .unwrap()
        .apply(&aux.info.extrinsic);
    let top = &frame.primary.points;
    let p = &aux.points;
    c.bench_function("icp_one_lidar_sample_data_alpha_0.1", |b| {
        b.iter(|| {
            let target = Target::new(
                voxel_downsample(&top.x, &top.y, &top.z, cfg.target_voxel, cfg.max_range),
                &cfg,
            )
            .unwrap();
            let source = voxel_downsample(&p.x, &p.y, &p.z, cfg.source_voxel, cfg.max_range);
            black_box(align(&source, &start, &target, &prior, &cfg).unwrap())
        })
    });
    // The part of it built once per frame: the target's downsampling, kd-tree and normals.
    c.bench_function("icp_target_build_sample_data", |b| {
        b.iter(|| {
            black_box(
                Target::new(
                    voxel_downsample(&top.x, &top.y, &top.z, cfg.target_voxel, cfg.max_range),
                    &cfg,
                )
                .unwrap(),
            )
        })
    });
}

#[cfg(feature = "gui")]
fn bench_render(c: &mut Criterion) {
    use mlod::render::{grid_lines, HeadlessGpu, OffscreenRenderer, SceneHandle, Viewport};
    let gpu = HeadlessGpu::new().expect("a wgpu adapter (lavapipe without a GPU)");
    eprintln!(
        "adapter: {} ({:?})",
        gpu.adapter_info.name, gpu.adapter_info.backend
    );
    let n = 150_000;
    let points: Vec<[f32; 3]> = (0..n)
        .map(|i| {
            let a = i as f32 * 0.01;
            let r = 5.0 + (i % 50) as f32 * 0.5;
            [r * a.cos(), r * a.sin(), -1.5 + (i % 7) as f32 * 0.3]
        })
        .collect();
    let mut scene = SceneHandle::new();
    scene
        .set_points(points, vec![[230, 30, 30, 255]; n])
        .expect("points");
    scene.set_lines(grid_lines(40.0, 10.0, -1.8));
    let v = Viewport::default();
    let mut g = c.benchmark_group("render_150k_1280x800");
    g.sample_size(10);
    for msaa in [1, 4] {
        let mut r = OffscreenRenderer::with_msaa(&gpu.device, &gpu.queue, msaa);
        g.bench_function(format!("msaa{msaa}"), |b| {
            b.iter(|| r.render(&scene, &v, (1280, 800)).expect("render"))
        });
        let mut recoloured = scene.clone();
        let mut k = 0u8;
        g.bench_function(format!("msaa{msaa}_colour_upload"), |b| {
            b.iter(|| {
                k = k.wrapping_add(10);
                recoloured
                    .set_colors(vec![[k, 100, 200, 255]; n])
                    .expect("colours");
                r.render(&recoloured, &v, (1280, 800)).expect("render")
            })
        });
    }
    g.finish();
}

#[cfg(not(feature = "gui"))]
fn bench_render(_: &mut Criterion) {}

criterion_group!(benches, bench, bench_sample_fuse, bench_icp, bench_render);
criterion_main!(benches);
