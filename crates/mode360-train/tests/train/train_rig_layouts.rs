//! Rig layout families and blocked lenses in the training stream (issue 19): every family
//! gives valid rigs that differ from the others as documented, `--rig-layouts roof` is the
//! roof stream of older runs bit for bit, and the layout and blocker draws come from streams
//! of their own.

use mode360_core::geometry::Rig;
use mode360_synth::noise::Rng;
use mode360_synth::BlockerKind;
use mode360_train::data::{
    render_sample, training_spec, DataConfig, RigChoice, SampleSpec, SceneMix, StreamOptions,
    MAX_TRAIN_BLOCKED_FRACTION, MIN_TRAIN_BLOCKED_FRACTION,
};
use mode360_train::rack::random_rig;
use mode360_train::rig_layouts::{
    layout_rig, LayoutFamily, RigLayouts, BUMPER_MIN_HEIGHT_M, MAST_MAX_CAMERAS, MAST_MIN_GAP_M,
    MIRROR_MAX_HEIGHT_M, TURNED_MAX_ROLL_PITCH_RAD,
};
use nalgebra::Vector3;

const SEEDS: u64 = 120;

fn cfg(seed: u64, rig_layouts: RigLayouts, blocked_fraction: f64) -> DataConfig {
    DataConfig {
        stream: StreamOptions {
            seed,
            soiled_fraction: 0.3,
            deep360_fraction: 0.25,
            camera_effects: false,
            mix: SceneMix {
                objects_fraction: 0.2,
                street: mode360_synth::StreetStyle::Regular,
                fisheye_fraction: 0.1,
                rig_layouts,
                blocked_fraction,
                rig_pool: 0,
                camera_pairs: false,
            },
        },
        width: 64,
        max_depth_m: 100.0,
        deep360_disk: None,
    }
}

// ---- the roof stream as it was before layout families (reference copy) -------------------

const REF_RACK_HALF_SIZE_M: f64 = 0.75;
const REF_MIN_SEPARATION_M: f64 = 0.3;
const REF_MIN_HEIGHT_M: f64 = 1.5;
const REF_MAX_HEIGHT_M: f64 = 2.2;
const REF_MAX_TILT_RAD: f64 = 0.087;

fn reference_rack_positions(rng: &mut Rng, n: usize) -> Vec<[f64; 2]> {
    let mut xy: Vec<[f64; 2]> = Vec::with_capacity(n);
    for _ in 0..n {
        let mut best = [0.0, 0.0];
        let mut best_sep = f64::NEG_INFINITY;
        for _ in 0..64 {
            let p = [
                rng.range(-REF_RACK_HALF_SIZE_M, REF_RACK_HALF_SIZE_M),
                rng.range(-REF_RACK_HALF_SIZE_M, REF_RACK_HALF_SIZE_M),
            ];
            let sep = xy
                .iter()
                .map(|q| (p[0] - q[0]).hypot(p[1] - q[1]))
                .fold(f64::INFINITY, f64::min);
            if sep > best_sep {
                best = p;
                best_sep = sep;
            }
            if sep >= REF_MIN_SEPARATION_M {
                break;
            }
        }
        xy.push(best);
    }
    xy
}

/// `random_rig` as the roof-only code wrote it, YAML text and all.
fn reference_random_rig(seed: u64) -> Rig {
    let mut rng = Rng::new(&[seed, 0x416]);
    let n = 2 + rng.index(4);
    let xy = reference_rack_positions(&mut rng, n);
    let mut yaml = String::from("rig_frame: base_link\nreference_camera: cam1\ncameras:\n");
    for (k, p) in xy.iter().enumerate() {
        let z = rng.range(REF_MIN_HEIGHT_M, REF_MAX_HEIGHT_M);
        let rpy = [
            rng.range(-REF_MAX_TILT_RAD, REF_MAX_TILT_RAD),
            rng.range(-REF_MAX_TILT_RAD, REF_MAX_TILT_RAD),
            rng.range(-REF_MAX_TILT_RAD, REF_MAX_TILT_RAD),
        ];
        let c = k + 1;
        yaml.push_str(&format!(
            "  - name: cam{c}\n    topic: /cam{c}/image_raw\n    frame_id: cam{c}_link\n    \
             projection: equirectangular\n    rig_from_cam: {{translation: [{:.17e}, {:.17e}, {:.17e}], \
             rotation_rpy: [{:.17e}, {:.17e}, {:.17e}]}}\n",
            p[0], p[1], z, rpy[0], rpy[1], rpy[2]
        ));
    }
    Rig::from_yaml_str(&yaml, &format!("<random rig {seed}>")).unwrap()
}

/// What the roof-only `training_spec` drew for sample `index` (no Deep360 disk mix):
/// world seed, frame, soiled, rig choice, objects scene.
fn reference_spec_fields(c: &DataConfig, index: u64) -> (u64, usize, bool, RigChoice, bool) {
    let c = &c.stream;
    let mut rng = Rng::new(&[c.seed, index, 0x7A41_0001]);
    let world_seed = rng.next_u64() & !(1 << 63);
    let frame_index = rng.index(400);
    let soiled = rng.chance(c.soiled_fraction);
    let rig = if rng.chance(c.deep360_fraction) {
        RigChoice::Deep360
    } else {
        RigChoice::Random(rng.next_u64())
    };
    let mut fisheye = Rng::new(&[c.seed, index, 0x7A41_0005]);
    let rig = if c.mix.fisheye_fraction > 0.0 && fisheye.chance(c.mix.fisheye_fraction) {
        RigChoice::Fisheye(fisheye.next_u64())
    } else {
        rig
    };
    let objects = Rng::new(&[c.seed, index, 0x7A41_0004]).chance(c.mix.objects_fraction);
    (world_seed, frame_index, soiled, rig, objects)
}

fn fields(s: &SampleSpec) -> (u64, usize, bool, RigChoice, bool) {
    (
        s.world_seed,
        s.frame_index,
        s.soiled,
        s.rig.clone(),
        s.scene == mode360_synth::SceneKind::Objects,
    )
}

#[test]
fn roof_layouts_reproduce_the_roof_stream_bit_for_bit() {
    for seed in 0..300 {
        assert_eq!(
            random_rig(seed).unwrap(),
            reference_random_rig(seed),
            "rig seed {seed}"
        );
    }
    for stream in [1, 7] {
        let roof = cfg(stream, RigLayouts::Roof, 0.0);
        for index in 0..600 {
            let spec = training_spec(&roof, index);
            assert_eq!(
                fields(&spec),
                reference_spec_fields(&roof, index),
                "{index}"
            );
            assert_eq!(spec.blocker, None);
            assert!(!matches!(spec.rig, RigChoice::Layout(..)));
        }
    }
}

/// Per rig: the largest vertical and horizontal distance between two cameras, the largest
/// rotation angle of a camera, and the largest tilt of a camera's z axis from vertical.
struct RigStats {
    max_dz_m: f64,
    min_dz_m: f64,
    max_dxy_m: f64,
    max_baseline_m: f64,
    max_rotation_rad: f64,
    max_up_tilt_rad: f64,
    heights_m: Vec<f64>,
}

fn stats(rig: &Rig) -> RigStats {
    let t: Vec<Vector3<f64>> = rig
        .cameras
        .iter()
        .map(|c| c.rig_from_cam.translation.vector)
        .collect();
    let (mut max_dz_m, mut min_dz_m, mut max_dxy_m, mut max_baseline_m) =
        (0.0f64, f64::INFINITY, 0.0f64, 0.0f64);
    for i in 0..t.len() {
        for j in i + 1..t.len() {
            let d = t[j] - t[i];
            max_dz_m = max_dz_m.max(d.z.abs());
            min_dz_m = min_dz_m.min(d.z.abs());
            max_dxy_m = max_dxy_m.max(d.xy().norm());
            max_baseline_m = max_baseline_m.max(d.norm());
        }
    }
    let rot = |f: fn(&nalgebra::UnitQuaternion<f64>) -> f64| {
        rig.cameras
            .iter()
            .map(|c| f(&c.rig_from_cam.rotation))
            .fold(0.0, f64::max)
    };
    RigStats {
        max_dz_m,
        min_dz_m,
        max_dxy_m,
        max_baseline_m,
        max_rotation_rad: rot(|q| q.angle()),
        max_up_tilt_rad: rot(|q| (q * Vector3::z()).z.clamp(-1.0, 1.0).acos()),
        heights_m: t.iter().map(|v| v.z).collect(),
    }
}

#[test]
fn every_layout_family_yields_valid_distinct_rigs() {
    let mut counts = [0usize; 6];
    for family in LayoutFamily::ALL {
        let (mut turned, mut reference_not_lowest, mut wide) = (0, 0, 0);
        for seed in 0..SEEDS {
            let rig = layout_rig(family, seed).unwrap();
            let n = rig.cameras.len();
            assert!((2..=5).contains(&n), "{family:?} {seed}: {n} cameras");
            counts[n] += 1;
            assert_eq!(rig.reference, 0);
            assert_eq!(rig.rig_from_output, rig.cameras[0].rig_from_cam);
            assert!(rig
                .cameras
                .iter()
                .all(|c| c.projection.is_equirectangular()));
            let again = Rig::from_yaml_str(&rig.to_yaml(), "roundtrip").unwrap();
            assert_eq!(again.cameras.len(), n);
            let s = stats(&rig);
            assert!(
                s.max_baseline_m > 0.15,
                "{family:?} {seed}: cameras on top of each other"
            );
            turned += usize::from(s.max_rotation_rad > 45f64.to_radians());
            // Wider than the roof rack's diagonal (2.12 m).
            wide += usize::from(s.max_dxy_m > 2.2);
            let lowest = s.heights_m.iter().cloned().fold(f64::INFINITY, f64::min);
            reference_not_lowest += usize::from(s.heights_m[0] > lowest);
            match family {
                LayoutFamily::RoofRack => {
                    assert_eq!(rig, random_rig(seed).unwrap());
                    assert!(s.max_dz_m <= 0.7 + 1e-9 && s.max_up_tilt_rad < 0.13);
                    assert!(s.max_rotation_rad < 0.16, "{}", s.max_rotation_rad);
                }
                LayoutFamily::VerticalMast => {
                    assert!(n <= MAST_MAX_CAMERAS);
                    // Every pair is stacked: a vertical baseline of at least 0.2 m, and
                    // horizontally within the mast's jitter.
                    assert!(
                        s.min_dz_m >= MAST_MIN_GAP_M - 1e-9,
                        "{seed}: {}",
                        s.min_dz_m
                    );
                    assert!(s.max_dxy_m <= 0.15, "{seed}: {}", s.max_dxy_m);
                    assert!(s.max_up_tilt_rad < 0.13);
                }
                LayoutFamily::TurnedMixedHeights => {
                    // Roll and pitch up to 30° each tilt the z axis by at most 41.4°.
                    let bound = (TURNED_MAX_ROLL_PITCH_RAD.cos().powi(2)).acos();
                    assert!(s.max_up_tilt_rad <= bound + 1e-9);
                }
                LayoutFamily::BodyCorners => {
                    for h in &s.heights_m {
                        assert!(
                            (BUMPER_MIN_HEIGHT_M..=MIRROR_MAX_HEIGHT_M).contains(h),
                            "{h}"
                        );
                    }
                    assert!(s.max_baseline_m >= 0.9, "{seed}: {}", s.max_baseline_m);
                    assert!(s.max_up_tilt_rad < 0.13);
                }
            }
        }
        let share = |k: usize| k as f64 / SEEDS as f64;
        match family {
            LayoutFamily::RoofRack => {
                assert_eq!((turned, wide), (0, 0), "{family:?}");
            }
            LayoutFamily::VerticalMast => {
                // Yaw is free; the reference is not always the lowest camera.
                assert!(share(turned) > 0.5, "{turned}");
                assert!(share(reference_not_lowest) > 0.3, "{reference_not_lowest}");
                assert_eq!(wide, 0);
            }
            LayoutFamily::TurnedMixedHeights => {
                assert!(share(turned) > 0.85, "{turned}");
                assert_eq!(wide, 0);
            }
            LayoutFamily::BodyCorners => {
                assert!(share(wide) > 0.5, "{wide}");
                assert!(share(turned) > 0.8, "{turned}");
            }
        }
    }
    // All camera counts occur.
    for (n, c) in counts.iter().enumerate().skip(2) {
        assert!(*c >= 30, "{n} cameras drawn {c} times: {counts:?}");
    }
}

#[test]
fn any_layouts_and_blockers_come_from_their_own_streams() {
    let roof = cfg(5, RigLayouts::Roof, 0.0);
    let any = cfg(5, RigLayouts::Any, 0.0);
    let blocked = cfg(5, RigLayouts::Any, 0.5);
    let mut families = std::collections::HashMap::new();
    let (mut random, mut n_blocked) = (0usize, 0usize);
    let mut kinds = std::collections::HashSet::new();
    for index in 0..800 {
        let (r, a, b) = (
            training_spec(&roof, index),
            training_spec(&any, index),
            training_spec(&blocked, index),
        );
        // Everything but the rig layout is the roof stream's; the blocker changes nothing else.
        assert_eq!(
            (r.world_seed, r.frame_index, r.soiled, r.scene),
            (a.world_seed, a.frame_index, a.soiled, a.scene)
        );
        assert_eq!(
            SampleSpec {
                blocker: None,
                ..b.clone()
            },
            a
        );
        match (&r.rig, &a.rig) {
            (RigChoice::Random(s), RigChoice::Random(t)) => {
                assert_eq!(s, t);
                random += 1;
                *families.entry(LayoutFamily::RoofRack).or_insert(0usize) += 1;
            }
            (RigChoice::Random(s), RigChoice::Layout(f, t)) => {
                assert_eq!(s, t);
                assert_ne!(*f, LayoutFamily::RoofRack);
                random += 1;
                *families.entry(*f).or_insert(0usize) += 1;
            }
            (x, y) => assert_eq!(x, y),
        }
        if let Some(bl) = b.blocker {
            n_blocked += 1;
            assert!(
                (MIN_TRAIN_BLOCKED_FRACTION..=MAX_TRAIN_BLOCKED_FRACTION).contains(&bl.fraction)
            );
            kinds.insert(bl.kind);
        }
    }
    for f in LayoutFamily::ALL {
        let share = families.get(&f).copied().unwrap_or(0) as f64 / random as f64;
        assert!((0.18..=0.32).contains(&share), "{f:?}: {share}");
    }
    assert!((340..=460).contains(&n_blocked), "{n_blocked}");
    assert_eq!(kinds.len(), BlockerKind::ALL.len());

    // A blocked sample renders like the clean one except for the blocked camera's image.
    let index = (0..800)
        .find(|&k| {
            let s = training_spec(&blocked, k);
            s.blocker.is_some() && matches!(s.rig, RigChoice::Layout(LayoutFamily::VerticalMast, _))
        })
        .expect("a blocked mast sample");
    let spec = training_spec(&blocked, index);
    let clean = render_sample(
        &blocked,
        &SampleSpec {
            blocker: None,
            ..spec.clone()
        },
    )
    .unwrap();
    let dirty = render_sample(&blocked, &spec).unwrap();
    let camera = spec.blocker.unwrap().on_rig(dirty.rig.cameras.len()).camera;
    assert_eq!(clean.range_m.data, dirty.range_m.data);
    for (k, (a, b)) in clean.images.iter().zip(&dirty.images).enumerate() {
        let (a, b): (Vec<f32>, Vec<f32>) = (
            a.flatten_all().unwrap().to_vec1().unwrap(),
            b.flatten_all().unwrap().to_vec1().unwrap(),
        );
        let changed = a.chunks(3).zip(b.chunks(3)).filter(|(p, q)| p != q).count();
        if k == camera {
            // At least 5 % of the view; near the horizon that is 2/pi of it in ERP pixels.
            assert!(
                changed as f64 > 0.025 * (a.len() / 3) as f64,
                "camera {k}: {changed}"
            );
        } else {
            assert_eq!(changed, 0, "camera {k}");
        }
    }
}

#[test]
fn checkpoints_record_layouts_and_blockers_and_old_ones_resume_as_roof() {
    use mode360_train::{run_training, CheckpointState, TrainOptions, CHECKPOINT_DIR, STATE_FILE};
    // A state written before these options existed reads as roof racks without blockers.
    let old = r#"{"version": 1, "step": 3, "next_sample_index": 3, "preset": "tiny",
        "width": 64, "seed": 1, "batch_size": 1, "train_s": 1.0}"#;
    let state: CheckpointState = serde_json::from_str(old).unwrap();
    assert_eq!(
        (state.mix.rig_layouts, state.mix.blocked_fraction),
        (RigLayouts::Roof, 0.0)
    );
    assert_eq!(state.loss_weighting, None);

    let out = tempfile::tempdir().unwrap();
    let loss_weighting = mode360_train::loss::LossWeighting {
        near_weight: 8.0,
        obstacle_weight: 2.0,
        ..Default::default()
    };
    let opts = TrainOptions {
        preset: mode360_model::model::Preset::Tiny,
        steps: 1,
        out_dir: out.path().to_path_buf(),
        warmup_steps: 1,
        val_every: 0,
        checkpoint_every_steps: 1,
        stream: StreamOptions {
            seed: 9,
            mix: SceneMix {
                rig_layouts: RigLayouts::Any,
                blocked_fraction: 0.5,
                ..Default::default()
            },
            ..Default::default()
        },
        loss_weighting,
        show_progress: false,
        ..TrainOptions::default()
    };
    run_training(&opts).unwrap();
    let text = std::fs::read_to_string(out.path().join(CHECKPOINT_DIR).join(STATE_FILE)).unwrap();
    let state: CheckpointState = serde_json::from_str(&text).unwrap();
    assert_eq!(
        (state.mix.rig_layouts, state.mix.blocked_fraction),
        (RigLayouts::Any, 0.5)
    );
    assert!(text.contains("\"rig_layouts\": \"any\""), "{text}");
    // The loss the run trains with is on record.
    assert_eq!(state.loss_weighting, Some(loss_weighting));
    // Resuming with another layout or blocker share would change the stream: refused.
    for (other, field) in [
        (
            TrainOptions {
                steps: 2,
                resume: true,
                stream: StreamOptions {
                    mix: SceneMix {
                        rig_layouts: RigLayouts::Roof,
                        ..opts.stream.mix
                    },
                    ..opts.stream
                },
                ..opts.clone()
            },
            "rig_layouts",
        ),
        (
            TrainOptions {
                steps: 2,
                resume: true,
                stream: StreamOptions {
                    mix: SceneMix {
                        blocked_fraction: 0.1,
                        ..opts.stream.mix
                    },
                    ..opts.stream
                },
                ..opts.clone()
            },
            "blocked_fraction",
        ),
    ] {
        let e = run_training(&other).unwrap_err().to_string();
        assert!(e.contains(field), "{e}");
    }
}
