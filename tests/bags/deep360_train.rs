//! Deep360 in training: samples drawn from a fixture's training split equal what the reader
//! gives (and the background stream yields the same), the share of dataset frames follows the
//! configured fraction, and fine-tuning runs on the fixture with resume checking the dataset.

use crate::deep360_writer::write_training_split;
use mode360::deep360::{
    deep360_rig, Deep360Dataset, Deep360FrameId, Deep360FrameVariant, Deep360Split,
    DEEP360_MAX_DEPTH_M,
};
use mode360::train::data::{
    image_tensor, sample_fingerprint, training_sample, training_spec, DataConfig, Deep360Mix,
    RigChoice, SampleStream, StreamOptions,
};

fn data_cfg(mix: Option<Deep360Mix>) -> DataConfig {
    DataConfig {
        stream: StreamOptions {
            seed: 3,
            soiled_fraction: 0.5,
            deep360_fraction: 0.25,
            ..Default::default()
        },
        width: 64,
        max_depth_m: DEEP360_MAX_DEPTH_M,
        deep360_disk: mix,
    }
}

#[test]
fn deep360_training_samples_come_from_the_fixture() {
    let dir = tempfile::tempdir().unwrap();
    write_training_split(dir.path());
    let mix = Deep360Mix::open(dir.path(), 1.0).unwrap();
    let variant = |episode, frame, soiled| Deep360FrameVariant {
        id: Deep360FrameId { episode, frame },
        soiled,
    };
    assert_eq!(
        mix.frames,
        vec![
            variant(1, 0, false),
            variant(1, 0, true),
            variant(1, 1, false),
            variant(1, 1, true),
            variant(2, 5, false),
        ]
    );
    let cfg = data_cfg(Some(mix.clone()));

    // Fraction 1: every sample is a fixture frame, all five get picked.
    let specs: Vec<_> = (0..60).map(|k| training_spec(&cfg, k)).collect();
    let mut picked = std::collections::BTreeSet::new();
    for s in &specs {
        let id = s.deep360_frame.expect("a Deep360 frame");
        assert_eq!(s.rig, RigChoice::Deep360);
        assert!(mix.frames.contains(&Deep360FrameVariant {
            id,
            soiled: s.soiled
        }));
        picked.insert((id, s.soiled));
    }
    assert_eq!(picked.len(), 5);

    // A sample holds the frame as the reader gives it at the training width.
    let ds = Deep360Dataset::open(dir.path()).unwrap();
    for k in [0, 1] {
        let sample = training_sample(&cfg, k).unwrap();
        let id = sample.spec.deep360_frame.unwrap();
        let direct = ds
            .load_frame(id, Deep360Split::Training, sample.spec.soiled, 64)
            .unwrap();
        assert_eq!(sample.rig, deep360_rig().unwrap());
        assert_eq!(sample.images.len(), 4);
        for (t, img) in sample.images.iter().zip(&direct.images) {
            assert_eq!(t.dims(), &[1, 32, 64, 3]);
            let a: Vec<f32> = t.flatten_all().unwrap().to_vec1().unwrap();
            let b: Vec<f32> = image_tensor(img)
                .unwrap()
                .flatten_all()
                .unwrap()
                .to_vec1()
                .unwrap();
            assert_eq!(a, b);
        }
        assert_eq!((sample.range_m.width, sample.range_m.height), (64, 32));
        assert_eq!(sample.range_m, direct.ground_truth.unwrap());
    }
    // The background stream yields the same samples (resume reads the same frames).
    let mut stream = SampleStream::start(cfg.clone(), 1, 1).unwrap();
    let s = stream.next_sample().unwrap();
    assert_eq!(s.index, 1);
    assert_eq!(
        sample_fingerprint(&s.sample.unwrap()).unwrap(),
        sample_fingerprint(&training_sample(&cfg, 1).unwrap()).unwrap()
    );

    // Fraction 0.5: about half; the rendered ones are exactly the stream without a dataset.
    let half_cfg = data_cfg(Some(Deep360Mix {
        fraction: 0.5,
        ..mix.clone()
    }));
    let plain = data_cfg(None);
    let mut from_disk = 0;
    for k in 0..400 {
        let s = training_spec(&half_cfg, k);
        match s.deep360_frame {
            Some(_) => from_disk += 1,
            None => assert_eq!(s, training_spec(&plain, k)),
        }
    }
    assert!(
        (150..=250).contains(&from_disk),
        "{from_disk}/400 from disk"
    );
    // Fraction 0: none.
    let none_cfg = data_cfg(Some(Deep360Mix {
        fraction: 0.0,
        ..mix
    }));
    assert!((0..100).all(|k| training_spec(&none_cfg, k).deep360_frame.is_none()));

    // A root without training frames is an error naming it.
    let empty = tempfile::tempdir().unwrap();
    let e = Deep360Mix::open(empty.path(), 1.0).unwrap_err().to_string();
    assert!(e.contains("no Deep360 training frames"), "{e}");
    assert!(Deep360Mix::open(dir.path(), 1.5).is_err());
}

#[test]
fn fine_tune_runs_on_the_fixture_and_resume_checks_the_dataset() {
    use mode360::train::{run_training, CheckpointState, TrainOptions, CHECKPOINT_DIR, STATE_FILE};
    let dir = tempfile::tempdir().unwrap();
    write_training_split(dir.path());
    let out = tempfile::tempdir().unwrap();
    let opts = TrainOptions {
        preset: mode360::model::Preset::Tiny,
        steps: 2,
        out_dir: out.path().to_path_buf(),
        warmup_steps: 1,
        val_every: 0,
        checkpoint_every_steps: 1,
        stream: StreamOptions {
            seed: 3,
            ..Default::default()
        },
        deep360_disk: Some(dir.path().to_path_buf()),
        deep360_disk_fraction: 1.0,
        show_progress: false,
        ..TrainOptions::default()
    };
    let s = run_training(&opts).unwrap();
    assert_eq!(s.final_step, 2);
    assert!(s.last_loss.is_finite() && s.last_loss > 0.0);
    let state: CheckpointState = serde_json::from_str(
        &std::fs::read_to_string(out.path().join(CHECKPOINT_DIR).join(STATE_FILE)).unwrap(),
    )
    .unwrap();
    let disk = state.deep360_disk.unwrap();
    assert_eq!((disk.frames, disk.fraction), (5, 1.0));
    assert_eq!(state.next_sample_index, 2);
    // The two samples trained on were fixture frames.
    let cfg = data_cfg(Some(Deep360Mix::open(dir.path(), 1.0).unwrap()));
    for k in 0..2 {
        assert!(training_spec(&cfg, k).deep360_frame.is_some());
    }
    // Resuming without the dataset would change the stream: refused, naming the option.
    let e = run_training(&TrainOptions {
        steps: 3,
        resume: true,
        deep360_disk: None,
        ..opts
    })
    .unwrap_err()
    .to_string();
    assert!(e.contains("deep360_disk"), "{e}");
}
