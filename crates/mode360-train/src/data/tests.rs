//! The data stream's tests that need the rig pool.

use super::super::rig_layouts::RigLayouts;
use super::super::rig_pool::RENEW_SAMPLES_PER_RIG;
use super::{training_spec, DataConfig, RigChoice, SceneMix, StreamOptions};

#[test]
fn a_pooled_stream_reuses_its_rigs_and_keeps_its_scenes() {
    let rigs = 4;
    let free = DataConfig {
        stream: StreamOptions {
            seed: 5,
            soiled_fraction: 0.3,
            deep360_fraction: 0.25,
            camera_effects: false,
            mix: SceneMix {
                objects_fraction: 0.25,
                street: mode360_synth::StreetStyle::Varied,
                fisheye_fraction: 0.25,
                rig_layouts: RigLayouts::Any,
                blocked_fraction: 0.2,
                rig_pool: 0,
                camera_pairs: false,
            },
        },
        width: 64,
        max_depth_m: 100.0,
        deep360_disk: None,
    };
    let mut pooled = free.clone();
    pooled.stream.mix.rig_pool = rigs;
    let renew = RENEW_SAMPLES_PER_RIG * rigs as u64;
    let mut seen = Vec::new();
    for k in 0..renew {
        let (a, b) = (training_spec(&free, k), training_spec(&pooled, k));
        assert_eq!(
            (a.world_seed, a.frame_index, a.soiled, a.scene, a.blocker),
            (b.world_seed, b.frame_index, b.soiled, b.scene, b.blocker),
            "sample {k}"
        );
        if b.rig != RigChoice::Deep360 && !seen.contains(&b.rig) {
            seen.push(b.rig);
        }
    }
    // One generation: at most `rigs` random rigs (a slot whose rig is Deep360-drawn
    // samples can leave fewer), against a new one nearly every sample without the pool.
    assert!((2..=rigs).contains(&seen.len()), "{seen:?}");
    let next: Vec<_> = (renew..2 * renew)
        .map(|k| training_spec(&pooled, k).rig)
        .filter(|r| *r != RigChoice::Deep360)
        .collect();
    assert!(
        next.iter().all(|r| !seen.contains(r)),
        "generation 1 reuses generation 0"
    );
}
