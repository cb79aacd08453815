//! The multi-stage inverse-depth SmoothL1 loss, checked by hand.

use candle_core::{Device, Tensor};
use mode360_core::frame::{FloatImage, SceneLabels, SurfaceClass};
use mode360_train::loss::{smooth_l1, LossConfig, LossWeighting};

/// One stage over `min_depth_m`..100 m, D = 11 hypotheses uniform in inverse depth.
fn one_stage(min_depth_m: f64, weighting: LossWeighting) -> LossConfig {
    LossConfig {
        min_depth_m,
        max_depth_m: 100.0,
        hypotheses: 11,
        spacing: mode360_core::geometry::HypothesisSpacing::InverseDepth,
        stage_weights: vec![1.0],
        weighting,
    }
}

/// A tensor's values, flattened.
fn values(t: &Tensor) -> Vec<f32> {
    t.flatten_all().unwrap().to_vec1().unwrap()
}

/// A one-row range image.
fn row_image(data: Vec<f32>) -> FloatImage {
    FloatImage {
        width: data.len(),
        height: 1,
        data,
    }
}

#[test]
fn smooth_l1_by_hand() {
    let x = Tensor::new(&[-3.0f32, -0.5, 0.0, 0.4, 2.0], &Device::Cpu).unwrap();
    let y: Vec<f32> = smooth_l1(&x, 1.0).unwrap().to_vec1().unwrap();
    let expected = [2.5f32, 0.125, 0.0, 0.08, 1.5];
    for (a, b) in y.iter().zip(expected) {
        assert!((a - b).abs() < 1e-6, "{y:?}");
    }
}

#[test]
fn multi_stage_loss_by_hand() {
    // Depth range 1..100 m, D = 11 hypotheses: one hypothesis step is 0.1 in normalized units.
    let cfg = LossConfig {
        min_depth_m: 1.0,
        max_depth_m: 100.0,
        hypotheses: 11,
        spacing: mode360_core::geometry::HypothesisSpacing::InverseDepth,
        stage_weights: vec![0.5, 0.7, 1.0],
        weighting: Default::default(),
    };
    // Ground truth (1 x 2 x 2): 1 m (n = 1), 100 m (n = 0), NaN (invalid), 200 m (invalid).
    let gt = FloatImage {
        width: 2,
        height: 1,
        data: vec![1.0, 100.0],
    };
    let gt2 = FloatImage {
        width: 2,
        height: 1,
        data: vec![f32::NAN, 200.0],
    };
    let target = cfg.target(&[&gt, &gt2], &Device::Cpu).unwrap();
    let mask: Vec<f32> = values(&target.mask);
    assert_eq!(mask, vec![1.0, 1.0, 0.0, 0.0]);
    let n: Vec<f32> = values(&target.normalized_inverse_depth);
    assert!((n[0] - 1.0).abs() < 1e-6 && n[1].abs() < 1e-6);

    // Two stages (weights 0.7 and 1.0). Predictions in normalized inverse depth; errors in
    // hypothesis units are 10 * (pred - target).
    // stage 1: pred (0.95, 0.3) -> errors (-0.5, 3.0) -> SmoothL1 (0.125, 2.5), mean 1.3125
    // stage 2: pred (1.0, 0.02) -> errors (0, 0.2) -> (0, 0.02), mean 0.01
    // invalid pixels get wild predictions that must not count.
    let s1 = Tensor::new(&[[[0.95f32, 0.3]], [[9.0, -9.0]]], &Device::Cpu).unwrap();
    let s2 = Tensor::new(&[[[1.0f32, 0.02]], [[5.0, 5.0]]], &Device::Cpu).unwrap();
    let loss: f32 = cfg.loss(&[s1, s2], &target).unwrap().to_scalar().unwrap();
    let expected = 0.7 * 1.3125 + 1.0 * 0.01;
    assert!(
        (f64::from(loss) - expected).abs() < 1e-5,
        "{loss} vs {expected}"
    );

    // Too many stages for the weights is an error.
    let z = Tensor::zeros((2, 1, 2), candle_core::DType::F32, &Device::Cpu).unwrap();
    assert!(cfg
        .loss(&[z.clone(), z.clone(), z.clone(), z], &target)
        .is_err());
}

#[test]
fn obstacle_weighting_by_hand() {
    // Depth range 1..100 m, D = 11: errors in hypothesis units are 10 * (pred - target).
    let cfg = one_stage(
        1.0,
        LossWeighting {
            near_range_m: 5.0,
            near_weight: 3.0,
            too_far_weight: 2.0,
            too_far_range_m: f64::INFINITY,
            ..Default::default()
        },
    );
    // 1 m (n = 1, near) and 100 m (n = 0, far).
    let gt = FloatImage {
        width: 2,
        height: 1,
        data: vec![1.0, 100.0],
    };
    let target = cfg.target(&[&gt], &Device::Cpu).unwrap();
    let w: Vec<f32> = values(&target.weight);
    assert_eq!(w, vec![3.0, 1.0]);
    // Near pixel read too far: pred 0.8 -> error -2 -> SmoothL1 1.5, times 3 x 2 = 9.
    // Far pixel read too near: pred 0.1 -> error +1 -> 0.5, times 1. Mean over 2: 4.75.
    let pred = Tensor::new(&[[[0.8f32, 0.1]]], &Device::Cpu).unwrap();
    let loss: f32 = cfg.loss(&[pred], &target).unwrap().to_scalar().unwrap();
    assert!((loss - 4.75).abs() < 1e-5, "{loss}");
    // The same errors the other way round: near too near (x3), far too far (x2).
    let pred = Tensor::new(&[[[1.0f32, 0.0]]], &Device::Cpu).unwrap();
    let exact: f32 = cfg.loss(&[pred], &target).unwrap().to_scalar().unwrap();
    assert!(exact.abs() < 1e-6, "{exact}");
    let plain = LossConfig {
        weighting: Default::default(),
        ..cfg.clone()
    };
    let pred = Tensor::new(&[[[0.8f32, 0.1]]], &Device::Cpu).unwrap();
    let loss: f32 = plain.loss(&[pred], &target).unwrap().to_scalar().unwrap();
    assert!((loss - 1.0).abs() < 1e-5, "{loss}");
    // Too-far weight only within 10 m: a 50 m pixel read too far keeps weight 1.
    let near_only = LossConfig {
        weighting: mode360_train::loss::LossWeighting {
            too_far_range_m: 10.0,
            ..cfg.weighting
        },
        ..cfg.clone()
    };
    let gt50 = FloatImage {
        width: 2,
        height: 1,
        data: vec![1.0, 50.0],
    };
    let target = near_only.target(&[&gt50], &Device::Cpu).unwrap();
    let zone: Vec<f32> = values(&target.too_far_zone);
    assert_eq!(zone, vec![1.0, 0.0]);
    // n(50 m) = (1/50 - 1/100) / (1 - 1/100); pred 0 is 10 n hypothesis steps too far:
    // SmoothL1 0.5 (10 n)^2. The near pixel read 2 steps too far weighs 3 x 2: 6 x 1.5 = 9.
    let n50 = (1.0f64 / 50.0 - 1.0 / 100.0) / (1.0 - 1.0 / 100.0);
    let far_term = 0.5 * (10.0 * n50).powi(2);
    let pred = Tensor::new(&[[[0.8f32, 0.0]]], &Device::Cpu).unwrap();
    let loss: f32 = near_only
        .loss(std::slice::from_ref(&pred), &target)
        .unwrap()
        .to_scalar()
        .unwrap();
    assert!(
        (f64::from(loss) - (9.0 + far_term) / 2.0).abs() < 1e-5,
        "{loss}"
    );
    let everywhere = cfg.target(&[&gt50], &Device::Cpu).unwrap();
    let loss: f32 = cfg.loss(&[pred], &everywhere).unwrap().to_scalar().unwrap();
    assert!(
        (f64::from(loss) - (9.0 + 2.0 * far_term) / 2.0).abs() < 1e-5,
        "{loss}"
    );
}

#[test]
fn obstacle_and_thin_weights_follow_the_counted_instances() {
    // 256 x 2 at 1.40625 degrees a pixel: thin is under 3 degrees (2 pixels), a counted
    // instance has at least 20 (256 / 512)^2 = 5 pixels and a median range within 10 m.
    let (w, h) = (256, 2);
    let mut range = vec![50.0f32; w * h];
    let mut labels = SceneLabels::sky(w, h);
    labels.class.fill(SurfaceClass::Structure);
    let mut put = |cols: std::ops::Range<usize>, id: u16, class: SurfaceClass, r: f32| {
        for row in 0..h {
            for c in cols.clone() {
                range[row * w + c] = r;
                labels.class[row * w + c] = class;
                labels.instance[row * w + c] = id;
            }
        }
    };
    put(0..3, 1, SurfaceClass::Object, 3.0); // 6 px, 4.2 degrees at 3 m: counted, not thin
    put(10..12, 2, SurfaceClass::Object, 8.0); // 4 px: too few, not counted
    put(20..23, 3, SurfaceClass::Object, 20.0); // beyond 10 m: not counted
    put(30..32, 4, SurfaceClass::Object, 4.0); // 4 px at 2.8 degrees: too few
    put(40..42, 5, SurfaceClass::Object, 6.0); // with the rows below: 2 wide, 6 px, thin
    put(50..51, 0, SurfaceClass::Structure, 2.0); // near wall, not an object
    let gt = FloatImage {
        width: w,
        height: h,
        data: range,
    };
    let mut tall_labels = labels.clone();
    let mut tall = gt.clone();
    // Instance 5 gets a third row so that it has 6 pixels.
    tall.height = 3;
    tall.data.extend(std::iter::repeat_n(50.0f32, w));
    tall_labels.height = 3;
    tall_labels
        .class
        .extend(std::iter::repeat_n(SurfaceClass::Structure, w));
    tall_labels.instance.extend(std::iter::repeat_n(0u16, w));
    for c in 40..42 {
        tall.data[2 * w + c] = 6.0;
        tall_labels.class[2 * w + c] = SurfaceClass::Object;
        tall_labels.instance[2 * w + c] = 5;
    }
    let cfg = one_stage(
        0.5,
        LossWeighting {
            near_weight: 3.0,
            obstacle_weight: 4.0,
            thin_weight: 2.0,
            ..Default::default()
        },
    );
    let target = cfg
        .target_labelled(&[(&tall, Some(&tall_labels))], &Device::Cpu)
        .unwrap();
    let weight: Vec<f32> = values(&target.weight);
    let at = |row: usize, col: usize| weight[row * w + col];
    assert_eq!(at(0, 1), 3.0 * 4.0, "near, counted, wide");
    assert_eq!(at(1, 11), 1.0, "too few pixels");
    assert_eq!(at(0, 21), 1.0, "beyond 10 m");
    assert_eq!(
        at(1, 30),
        3.0,
        "near but too few pixels: the near weight alone"
    );
    assert_eq!(at(2, 41), 4.0 * 2.0, "counted and thin, beyond 5 m");
    assert_eq!(at(0, 50), 3.0, "a near wall is not an obstacle");
    assert_eq!(at(0, 100), 1.0);
    // The too-near zone: beyond the near range and not on a weighted obstacle.
    let zone: Vec<f32> = values(&target.too_near_zone);
    let zone_at = |row: usize, col: usize| zone[row * w + col];
    assert_eq!(zone_at(2, 41), 0.0, "a counted obstacle at 6 m");
    assert_eq!(zone_at(1, 11), 1.0, "8 m, too few pixels to count");
    assert_eq!(zone_at(0, 21), 1.0, "an object beyond 10 m");
    assert_eq!(zone_at(0, 1), 0.0, "near");
    assert_eq!(zone_at(0, 100), 1.0, "the 50 m background");
    // Without labels only the near weight applies.
    let unlabelled = cfg.target(&[&tall], &Device::Cpu).unwrap();
    let weight: Vec<f32> = values(&unlabelled.weight);
    assert_eq!((weight[1], weight[2 * w + 41]), (3.0, 1.0));
    // The two-row frame alone: instance 5 has 4 pixels and is not counted.
    let target = cfg
        .target_labelled(&[(&gt, Some(&labels))], &Device::Cpu)
        .unwrap();
    let weight: Vec<f32> = values(&target.weight);
    assert_eq!((weight[1], weight[41]), (12.0, 1.0));
}

#[test]
fn sky_weight_applies_at_the_maximum_depth_only() {
    let cfg = one_stage(
        0.5,
        LossWeighting {
            near_weight: 3.0,
            sky_weight: 2.5,
            ..Default::default()
        },
    );
    // near, middle, just short of the sky, the sky, beyond it (invalid)
    let gt = row_image(vec![2.0, 50.0, 99.9, 100.0, 150.0]);
    let target = cfg.target(&[&gt], &Device::Cpu).unwrap();
    let weight: Vec<f32> = values(&target.weight);
    assert_eq!(weight, vec![3.0, 1.0, 1.0, 2.5, 0.0]);
    // The truth everywhere but the sky, which reads one hypothesis step (0.1) too near:
    // 10 * 0.1 = 1 hypothesis unit -> SmoothL1 0.5, times 2.5, over the 4 valid pixels.
    let mut pred: Vec<f32> = values(&target.normalized_inverse_depth);
    assert_eq!(pred[3], 0.0, "the sky is the farthest hypothesis");
    pred[3] = 0.1;
    let pred = Tensor::from_vec(pred, (1, 1, 5), &Device::Cpu).unwrap();
    let loss: f32 = cfg.loss(&[pred], &target).unwrap().to_scalar().unwrap();
    assert!((loss - 2.5 * 0.5 / 4.0).abs() < 1e-5, "{loss}");
}

#[test]
fn too_near_weight_applies_beyond_the_near_range_only() {
    // 1..100 m, D = 11: errors in hypothesis units are 10 * (pred - target).
    let cfg = one_stage(
        1.0,
        LossWeighting {
            near_range_m: 5.0,
            too_near_weight: 3.0,
            ..Default::default()
        },
    );
    // near (2 m), mid-range (20 m), the sky (100 m)
    let gt = row_image(vec![2.0, 20.0, 100.0]);
    let target = cfg.target(&[&gt], &Device::Cpu).unwrap();
    let zone: Vec<f32> = values(&target.too_near_zone);
    assert_eq!(zone, vec![0.0, 1.0, 0.0]);
    let truth: Vec<f32> = values(&target.normalized_inverse_depth);
    let loss_of = |offsets: [f32; 3]| -> f32 {
        let pred: Vec<f32> = truth.iter().zip(offsets).map(|(t, o)| t + o).collect();
        let pred = Tensor::from_vec(pred, (1, 1, 3), &Device::Cpu).unwrap();
        cfg.loss(&[pred], &target).unwrap().to_scalar().unwrap()
    };
    // Every pixel one hypothesis step (0.1) too near: SmoothL1 0.5 each, the mid-range one
    // times 3, over 3 valid pixels: (0.5 + 1.5 + 0.5) / 3.
    let near = loss_of([0.1, 0.1, 0.1]);
    assert!((near - 2.5 / 3.0).abs() < 1e-5, "{near}");
    // One step too far (the near pixel and the sky cannot go farther than 0: keep them
    // exact): the mid-range pixel alone, weight 1.
    let far = loss_of([0.0, -0.1, 0.0]);
    assert!((far - 0.5 / 3.0).abs() < 1e-5, "{far}");
}

#[test]
fn too_near_edge_px_leaves_out_the_far_side_of_a_depth_edge() {
    // Two rows: a 2 m post at column 3 of the first, 20 m behind it, a 17 m patch (not an
    // edge: under 1.25 times nearer than 20 m) at column 6; the second row all 20 m.
    let mut data = vec![20.0f32, 20.0, 20.0, 2.0, 20.0, 20.0, 17.0, 20.0];
    data.extend([20.0f32; 8]);
    let gt = FloatImage {
        width: 8,
        height: 2,
        data,
    };
    let zone_with = |edge_px: usize| {
        let cfg = one_stage(
            1.0,
            LossWeighting {
                too_near_weight: 4.0,
                too_near_edge_px: edge_px,
                ..Default::default()
            },
        );
        values(&cfg.target(&[&gt], &Device::Cpu).unwrap().too_near_zone)
    };
    let off = zone_with(0);
    assert_eq!(&off[..8], &[1.0, 1.0, 1.0, 0.0, 1.0, 1.0, 1.0, 1.0]);
    assert!(off[8..].iter().all(|&z| z == 1.0));
    // Within 2 pixels of the post (the second row too): left out.
    let edge = zone_with(2);
    assert_eq!(&edge[..8], &[1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0]);
    assert_eq!(&edge[8..], &[1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0]);
}

#[test]
fn too_near_min_range_m_moves_the_start_of_the_zone_out() {
    // near (2 m), mid-range (7 m, 10 m, 12 m), far (50 m), the sky (100 m)
    let gt = row_image(vec![2.0, 7.0, 10.0, 12.0, 50.0, 100.0]);
    let zone_from = |min_range_m: f64| {
        let cfg = one_stage(
            1.0,
            LossWeighting {
                near_range_m: 5.0,
                too_near_weight: 4.0,
                too_near_min_range_m: min_range_m,
                ..Default::default()
            },
        );
        values(&cfg.target(&[&gt], &Device::Cpu).unwrap().too_near_zone)
    };
    // 0 (the default) and anything inside the near range: from the near range out.
    assert_eq!(zone_from(0.0), vec![0.0, 1.0, 1.0, 1.0, 1.0, 0.0]);
    assert_eq!(zone_from(3.0), vec![0.0, 1.0, 1.0, 1.0, 1.0, 0.0]);
    // From 10 m: strictly beyond it.
    assert_eq!(zone_from(10.0), vec![0.0, 0.0, 0.0, 1.0, 1.0, 0.0]);
}
