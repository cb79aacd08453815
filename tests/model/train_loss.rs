//! The multi-stage inverse-depth SmoothL1 loss, checked by hand.

use candle_core::{Device, Tensor};
use mode360::frame::FloatImage;
use mode360::train::loss::{smooth_l1, LossConfig};

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
        spacing: mode360::geometry::HypothesisSpacing::InverseDepth,
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
    let mask: Vec<f32> = target.mask.flatten_all().unwrap().to_vec1().unwrap();
    assert_eq!(mask, vec![1.0, 1.0, 0.0, 0.0]);
    let n: Vec<f32> = target
        .normalized_inverse_depth
        .flatten_all()
        .unwrap()
        .to_vec1()
        .unwrap();
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
    let cfg = LossConfig {
        min_depth_m: 1.0,
        max_depth_m: 100.0,
        hypotheses: 11,
        spacing: mode360::geometry::HypothesisSpacing::InverseDepth,
        stage_weights: vec![1.0],
        weighting: mode360::train::loss::LossWeighting {
            near_range_m: 5.0,
            near_weight: 3.0,
            too_far_weight: 2.0,
            too_far_range_m: f64::INFINITY,
        },
    };
    // 1 m (n = 1, near) and 100 m (n = 0, far).
    let gt = FloatImage {
        width: 2,
        height: 1,
        data: vec![1.0, 100.0],
    };
    let target = cfg.target(&[&gt], &Device::Cpu).unwrap();
    let w: Vec<f32> = target.weight.flatten_all().unwrap().to_vec1().unwrap();
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
        weighting: mode360::train::loss::LossWeighting {
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
    let zone: Vec<f32> = target
        .too_far_zone
        .flatten_all()
        .unwrap()
        .to_vec1()
        .unwrap();
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
