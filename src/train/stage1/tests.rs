//! Tests of the stage-1 trainer ([`super`]).

mod augmentation {
    use crate::geometry::Box3d;
    use crate::train::stage1::*;

    #[test]
    fn augmentation_moves_points_and_boxes_together() {
        let a = Augmentation {
            flip_y: true,
            yaw: 0.05,
            translation: [0.3, -0.2, 0.1],
        };
        let b = Box3d::new([10.0, 4.0, -1.0], [4.5, 1.9, 1.6], 0.7);
        let p_local = [1.5f64, 0.5, 0.3];
        let (s, c) = b.yaw.sin_cos();
        let p = [
            b.center[0] + c * p_local[0] - s * p_local[1],
            b.center[1] + s * p_local[0] + c * p_local[1],
            b.center[2] + p_local[2],
        ];
        let mut cloud = FusedCloud {
            x: vec![p[0] as f32],
            y: vec![p[1] as f32],
            z: vec![p[2] as f32],
            intensity: vec![0.0],
            ..Default::default()
        };
        let mut boxes = [raw_box(&b)];
        a.apply(&mut cloud, &mut boxes);
        let nb = Box3d::new(
            [boxes[0][0] as f64, boxes[0][1] as f64, boxes[0][2] as f64],
            [4.5, 1.9, 1.6],
            boxes[0][6] as f64,
        );
        let q = nb.to_local([cloud.x[0] as f64, cloud.y[0] as f64, cloud.z[0] as f64]);
        // Mirrored: the local y flips sign, x and z are kept.
        assert!(
            (q[0] - 1.5).abs() < 1e-4 && (q[1] + 0.5).abs() < 1e-4 && (q[2] - 0.3).abs() < 1e-4,
            "{q:?}"
        );
    }
}

mod training {
    use crate::train::stage1::*;

    #[test]
    fn pasted_objects_become_training_targets() {
        use crate::train::gt_sampling::GtDatabase;
        let ds = Dataset::open(concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data")).unwrap();
        let tokens: Vec<String> = ds.samples().into_iter().map(|s| s.sample_token).collect();
        let frame = ds.frame(&tokens[0]).unwrap();
        let model = Stage1Model::new_trainable(ModelConfig::new(Case::Top), 1).unwrap();
        let db = GtDatabase::build(&ds, &tokens[1..], Case::Top, "car", 5).unwrap();
        let occupied: Vec<RawBox> = frame.boxes.iter().map(|b| raw_box(&b.box3d)).collect();
        let picked = db.sample(&mut stream_rng(5, 0), 0, &occupied, 6);
        assert!(!picked.is_empty());
        let objects: Vec<&GtObject> = picked.iter().map(|&i| &db.objects[i]).collect();
        let plain = prepare_sample(&model, &frame, None, &[]).unwrap();
        let pasted = prepare_sample(&model, &frame, None, &objects).unwrap();
        assert_eq!(pasted.num_gt, plain.num_gt + objects.len());
        assert!(pasted.targets.positives.len() > plain.targets.positives.len());
    }

    #[test]
    fn a_few_training_steps_lower_the_loss_on_a_sample_frame() {
        let ds = Dataset::open(concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data")).unwrap();
        let token = ds.first_sample_token().unwrap().to_string();
        let frame = ds.frame(&token).unwrap();
        let model = Stage1Model::new_trainable(ModelConfig::new(Case::Input), 11).unwrap();
        let sample = prepare_sample(&model, &frame, None, &[]).unwrap();
        assert!(sample.num_gt > 0 && !sample.targets.positives.is_empty());
        let mut opt = AdamW::new(&model, 0.01).unwrap();
        let mut losses = Vec::new();
        for _ in 0..6 {
            let l = compute_loss(&model, &sample).unwrap();
            losses.push(l.cls + l.reg + l.dir);
            let g = l.total.backward().unwrap();
            opt.update(&g, 2e-3, 10.0).unwrap();
        }
        let after = compute_loss(&model, &sample).unwrap();
        let last = after.cls + after.reg + after.dir;
        assert!(losses.iter().all(|l| l.is_finite()));
        assert!(last < 0.8 * losses[0], "loss {losses:?} -> {last}");
    }

    #[test]
    fn size_weight_scales_only_the_size_terms() {
        let ds = Dataset::open(concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data")).unwrap();
        let token = ds.first_sample_token().unwrap().to_string();
        let frame = ds.frame(&token).unwrap();
        let model = Stage1Model::new_trainable(ModelConfig::new(Case::Top), 3).unwrap();
        let sample = prepare_sample(&model, &frame, None, &[]).unwrap();
        let plain = compute_loss(&model, &sample).unwrap();
        let one = compute_loss_with(&model, &sample, 1.0).unwrap();
        assert_eq!(plain.reg.to_bits(), one.reg.to_bits());
        let heavy = compute_loss_with(&model, &sample, 5.0).unwrap();
        let light = compute_loss_with(&model, &sample, 0.0).unwrap();
        // Classification and direction do not see the weight; the size terms weigh 0, 1 and 5.
        assert_eq!(plain.cls.to_bits(), heavy.cls.to_bits());
        assert_eq!(plain.dir.to_bits(), heavy.dir.to_bits());
        let size_part = plain.reg - light.reg;
        assert!(
            size_part > 1e-6,
            "an untrained net has size residuals: {size_part}"
        );
        let expect = light.reg + 5.0 * size_part;
        assert!(
            (heavy.reg - expect).abs() <= 1e-4 * expect.abs(),
            "{} vs {expect}",
            heavy.reg
        );
    }
}

mod labelled_region {
    use nalgebra::Matrix3x4;

    use crate::dataset::region::EvalRegion;
    use crate::detect::anchors::{Anchors, Targets};
    use crate::detect::model::ModelConfig;
    use crate::detect::Case;
    use crate::train::stage1::*;

    /// A camera at the sensor looking along +x (1200 × 360 pixels, focal 500).
    fn camera() -> EvalRegion {
        // Camera axes: right = −y, down = −z, forward = x.
        let projection = Matrix3x4::new(
            600.0, -500.0, 0.0, 0.0, //
            180.0, 0.0, -500.0, 0.0, //
            1.0, 0.0, 0.0, 0.0,
        );
        EvalRegion {
            projection,
            width: 1200.0,
            height: 360.0,
            dont_care: vec![[0.0, 0.0, 300.0, 360.0]],
        }
    }

    fn weights_at(aug: Option<&Augmentation>, points: &[[f32; 2]]) -> Vec<f32> {
        let cfg = ModelConfig::new(Case::Top);
        let anchors = Anchors::new(&cfg.grid, &cfg.anchor);
        let n = anchors.len();
        let mut t = Targets {
            labels: vec![0.0; n],
            cls_weights: vec![1.0; n],
            positives: Vec::new(),
            reg: Vec::new(),
            dir: Vec::new(),
        };
        // One positive behind the camera: it keeps its weight.
        let behind = nearest(&anchors, [-20.0, 0.0]);
        t.labels[behind] = 1.0;
        ignore_unlabelled(&mut t, &anchors, &camera(), aug, None);
        assert_eq!(t.cls_weights[behind], 1.0, "a positive is never ignored");
        points
            .iter()
            .map(|&p| t.cls_weights[nearest(&anchors, p)])
            .collect()
    }

    fn nearest(anchors: &Anchors, p: [f32; 2]) -> usize {
        let d = |i: usize| (anchors.boxes[i][0] - p[0]).hypot(anchors.boxes[i][1] - p[1]);
        (0..anchors.len())
            .min_by(|&a, &b| d(a).total_cmp(&d(b)))
            .unwrap_or(0)
    }

    #[test]
    fn only_the_labelled_view_teaches_background() {
        // Ahead: taught. Behind, far to the side, or in the DontCare columns (u ≤ 300, to the
        // camera's left, i.e. +y): ignored.
        let w = weights_at(None, &[[20.0, 0.0], [-20.0, 1.0], [5.0, -30.0], [20.0, 15.0]]);
        assert_eq!(w, vec![1.0, 0.0, 0.0, 0.0]);
        // Rotated by 180° in augmentation: what lies behind now was ahead, and is taught.
        let turned = Augmentation {
            flip_y: false,
            yaw: std::f32::consts::PI,
            translation: [0.0; 3],
        };
        let w = weights_at(Some(&turned), &[[-20.0, 1.0], [20.0, 0.0]]);
        assert_eq!(w, vec![1.0, 0.0]);
        // Mirrored: the DontCare side swaps.
        let flipped = Augmentation {
            flip_y: true,
            yaw: 0.0,
            translation: [0.0; 3],
        };
        let w = weights_at(Some(&flipped), &[[20.0, -15.0], [20.0, 15.0]]);
        assert_eq!(w, vec![0.0, 1.0]);
    }
}
