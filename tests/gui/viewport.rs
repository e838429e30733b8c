//! The 3D viewport rendered headlessly (lavapipe under `WGPU_BACKEND=vulkan` in CI): depth,
//! empty scenes, bird's-eye orientation, and the same renderer inside an eframe app driven by
//! egui_kittest.
#![cfg(feature = "gui")]

use egui_kittest::Harness;
use image::RgbaImage;
use mlod::render::{
    grid_lines, render_offscreen, Camera, HeadlessGpu, OffscreenRenderer, SceneHandle, View, ViewSettings,
    Viewport,
};

const RED: [u8; 4] = [230, 30, 30, 255];
const GREEN: [u8; 4] = [30, 220, 40, 255];

fn gpu() -> HeadlessGpu {
    match HeadlessGpu::new() {
        Ok(gpu) => gpu,
        Err(e) => panic!("{e}"),
    }
}

fn view(camera: Camera) -> Viewport {
    Viewport {
        camera,
        settings: ViewSettings {
            point_size: 12.0,
            ..ViewSettings::default()
        },
    }
}

fn pixel(img: &RgbaImage, x: u32, y: u32) -> [u8; 4] {
    img.get_pixel(x, y).0
}

fn is_close(a: [u8; 4], b: [u8; 4]) -> bool {
    a.iter().zip(b).take(3).all(|(x, y)| x.abs_diff(y) <= 8)
}

fn background() -> [u8; 4] {
    let [r, g, b] = ViewSettings::default().background;
    [r, g, b, 255]
}

#[test]
fn nearer_point_hides_the_farther_one_whatever_the_draw_order() {
    let gpu = gpu();
    let camera = Camera::preset(View::Chase, 50.0);
    let eye = camera.eye();
    let dir = camera.forward();
    let near = (eye + dir * 8.0).to_array();
    let far = (eye + dir * 16.0).to_array();
    for msaa in [1, 4] {
        let mut renderer = OffscreenRenderer::with_msaa(&gpu.device, &gpu.queue, msaa);
        // Far point drawn last, then first: the near one wins both times.
        for (points, colors) in [
            (vec![near, far], vec![RED, GREEN]),
            (vec![far, near], vec![GREEN, RED]),
        ] {
            let mut scene = SceneHandle::new();
            scene.set_points(points, colors).unwrap();
            let img = renderer.render(&scene, &view(camera.clone()), (64, 48)).unwrap();
            let centre = pixel(&img, 32, 24);
            assert!(is_close(centre, RED), "msaa {msaa}: centre pixel {centre:?}");
            // The far point is bigger than nothing but hidden; no green anywhere near the centre.
            assert!(
                !img.pixels().any(|p| is_close(p.0, GREEN)),
                "msaa {msaa}: far point visible"
            );
        }
    }
}

#[test]
fn empty_scene_renders_the_background() {
    let gpu = gpu();
    let scene = SceneHandle::new();
    let img = render_offscreen(&gpu.device, &gpu.queue, &scene, &Viewport::default(), (40, 30)).unwrap();
    assert_eq!((img.width(), img.height()), (40, 30));
    assert!(img.pixels().all(|p| is_close(p.0, background())));
    // Lines but no points, and points that all lie behind the camera, are fine too.
    let mut scene = SceneHandle::new();
    scene.set_lines(grid_lines(30.0, 5.0, -1.8));
    let camera = Camera::preset(View::Overview, 30.0);
    let behind = (camera.eye() - camera.forward() * 5.0).to_array();
    scene.set_points(vec![behind], vec![RED]).unwrap();
    let img = render_offscreen(&gpu.device, &gpu.queue, &scene, &view(camera), (40, 30)).unwrap();
    assert!(img.pixels().any(|p| !is_close(p.0, background())), "grid missing");
    assert!(!img.pixels().any(|p| is_close(p.0, RED)));
    // Zero sizes are an error, not a panic.
    assert!(render_offscreen(&gpu.device, &gpu.queue, &scene, &Viewport::default(), (0, 10)).is_err());
}

#[test]
fn birds_eye_puts_plus_x_above_the_centre() {
    let gpu = gpu();
    let mut scene = SceneHandle::new();
    scene
        .set_points(vec![[10.0, 0.0, 0.0], [0.0, 10.0, 0.0]], vec![RED, GREEN])
        .unwrap();
    let camera = Camera::preset(View::Bev, 20.0);
    let img = render_offscreen(&gpu.device, &gpu.queue, &scene, &view(camera), (101, 101)).unwrap();
    let find = |color| {
        let hits: Vec<(u32, u32)> = img
            .enumerate_pixels()
            .filter(|(_, _, p)| is_close(p.0, color))
            .map(|(x, y, _)| (x, y))
            .collect();
        assert!(!hits.is_empty(), "colour {color:?} not drawn");
        let n = hits.len() as f32;
        let cx = hits.iter().map(|h| h.0 as f32).sum::<f32>() / n;
        let cy = hits.iter().map(|h| h.1 as f32).sum::<f32>() / n;
        (cx, cy)
    };
    let (rx, ry) = find(RED);
    assert!((rx - 50.0).abs() < 2.0 && ry < 40.0, "+x at ({rx}, {ry})");
    let (gx, gy) = find(GREEN);
    assert!(gx < 40.0 && (gy - 50.0).abs() < 2.0, "+y at ({gx}, {gy})");
}

#[test]
fn recolouring_reuses_the_buffers_and_shows_the_new_colour() {
    let gpu = gpu();
    let camera = Camera::preset(View::Chase, 50.0);
    let p = (camera.eye() + camera.forward() * 10.0).to_array();
    let mut scene = SceneHandle::new();
    scene.set_points(vec![p], vec![RED]).unwrap();
    let mut renderer = OffscreenRenderer::new(&gpu.device, &gpu.queue);
    let v = view(camera);
    let img = renderer.render(&scene, &v, (32, 32)).unwrap();
    assert!(is_close(pixel(&img, 16, 16), RED));
    scene.set_colors(vec![GREEN]).unwrap();
    let img = renderer.render(&scene, &v, (32, 32)).unwrap();
    assert!(is_close(pixel(&img, 16, 16), GREEN));
}

/// A ring of points around the origin, plus the grid, as the app would hand them over.
fn ring_scene(n: usize) -> SceneHandle {
    let points: Vec<[f32; 3]> = (0..n)
        .map(|i| {
            let a = i as f32 * 0.01;
            let r = 5.0 + (i % 50) as f32 * 0.5;
            [r * a.cos(), r * a.sin(), -1.5 + (i % 7) as f32 * 0.3]
        })
        .collect();
    let mut scene = SceneHandle::new();
    scene.set_points(points, vec![RED; n]).unwrap();
    scene.set_lines(grid_lines(40.0, 10.0, -1.8));
    scene
}

struct ViewportApp {
    view: Viewport,
    scene: SceneHandle,
}

impl eframe::App for ViewportApp {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        egui::CentralPanel::default().show(ui, |ui| {
            mlod::render::show(ui, &mut self.view, &self.scene);
        });
    }
}

#[test]
fn kittest_eframe_app_draws_the_points() {
    let mut harness = Harness::builder()
        .with_size(egui::vec2(320.0, 240.0))
        .wgpu()
        .build_eframe(|cc| {
            if let Some(rs) = cc.wgpu_render_state.as_ref() {
                mlod::render::install(rs);
            }
            ViewportApp {
                view: Viewport::default(),
                scene: ring_scene(3000),
            }
        });
    harness.run_steps(2);
    let img = harness.render().unwrap();
    let red = img.pixels().filter(|p| is_close(p.0, RED)).count();
    let bg = img.pixels().filter(|p| is_close(p.0, background())).count();
    assert!(red > 500, "only {red} point pixels");
    assert!(bg > 5000, "only {bg} background pixels");

    // Scrolling over the viewport zooms in (within bounds) and the frame changes.
    let before = harness.state().view.camera.distance;
    harness.hover_at(egui::pos2(160.0, 120.0));
    harness.event(egui::Event::MouseWheel {
        unit: egui::MouseWheelUnit::Point,
        delta: egui::vec2(0.0, 200.0),
        modifiers: egui::Modifiers::NONE,
        phase: egui::TouchPhase::Move,
        source: egui::MouseWheelSource::Wheel,
    });
    harness.run_steps(4);
    let after = harness.state().view.camera.distance;
    assert!(after < before, "scroll did not zoom: {before} -> {after}");
    let zoomed = harness.render().unwrap();
    assert_ne!(img.as_raw(), zoomed.as_raw());
}

/// Writes a few views of a street-like scene to the temp dir, to look at:
/// `cargo test --test gui -- --ignored dump --nocapture`.
#[test]
#[ignore]
fn dump_views_for_inspection() {
    let gpu = gpu();
    let mut points = Vec::new();
    let mut colors = Vec::new();
    // Ground returns on rings, coloured by range; a car-sized block of points ahead-left.
    for ring in 0..40 {
        let r = 3.0 + ring as f32 * 1.2;
        for k in 0..1500 {
            let a = k as f32 / 1500.0 * std::f32::consts::TAU;
            points.push([r * a.cos(), r * a.sin(), -1.8]);
            let t = ring as f32 / 40.0;
            colors.push([
                (40.0 + 200.0 * t) as u8,
                (120.0 + 60.0 * (1.0 - t)) as u8,
                (230.0 * (1.0 - t)) as u8,
                255,
            ]);
        }
    }
    for i in 0..4000 {
        let u = (i % 40) as f32 / 40.0;
        let v = (i / 40 % 10) as f32 / 10.0;
        let w = (i / 400) as f32 / 10.0;
        points.push([12.0 + 4.4 * u - 2.2, 4.0 + 1.8 * v - 0.9, -1.8 + 1.5 * w]);
        colors.push([240, 90, 200, 255]);
    }
    let mut lines = grid_lines(50.0, 10.0, -1.8);
    let (c, l, w, h) = ([12.0f64, 4.0, -1.05], 4.6f64, 1.9f64, 1.6f64);
    let corners: [[f64; 3]; 8] = std::array::from_fn(|k| {
        let xs = [0.5 * l, -0.5 * l, -0.5 * l, 0.5 * l];
        let ys = [0.5 * w, 0.5 * w, -0.5 * w, -0.5 * w];
        let z = if k < 4 { -0.5 * h } else { 0.5 * h };
        [c[0] + xs[k % 4], c[1] + ys[k % 4], c[2] + z]
    });
    lines.extend(mlod::render::box_lines(corners, [60, 230, 90, 255], true));
    let mut scene = SceneHandle::new();
    scene.set_points(points, colors).unwrap();
    scene.set_lines(lines);
    let mut renderer = OffscreenRenderer::new(&gpu.device, &gpu.queue);
    for v in View::ALL {
        let view = Viewport {
            camera: Camera::preset(v, scene.radius()),
            settings: ViewSettings::default(),
        };
        let img = renderer.render(&scene, &view, (1280, 800)).unwrap();
        let path = std::env::temp_dir().join(format!("mlod_viewport_{v:?}.png"));
        img.save(&path).unwrap();
        eprintln!("wrote {}", path.display());
    }
}
