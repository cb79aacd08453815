//! A slowly renewed pool of random rigs, so that training reuses sweep tables.
//!
//! Building a rig's sweep tables (and their transposes for the backward pass) costs about as
//! much as a training step at width 128, and a stream that draws a new random rig for every
//! sample pays it every step (measured: 2.1 s per step with a new rig each step, 0.7 s on one
//! cached rig). With a pool of `K` rigs, sample `k`'s random rig is one of the `K` rigs of
//! generation `g = floor(k / renew)`, `renew = RENEW_SAMPLES_PER_RIG * K`:
//!
//! ```text
//! rig seed = hash(stream seed, g, slot, POOL_TAG),   slot = uniform in 0..K (the sample's own draw)
//! ```
//!
//! so the trainer's cache of `K` rigs misses about `K` times per `renew` samples (once per
//! `RENEW_SAMPLES_PER_RIG` samples), and over a run every generation brings `K` new rigs: the
//! rig diversity grows with the run's length instead of being fixed. Every rig draw of a
//! sample (its random rig's seed, layout family, fisheye or not) is taken at the pooled rig's
//! index [`pooled_rig_index`] instead of the sample's own index, so a pooled rig is the same
//! rig every time; the scene, world, frame and soiling stay the sample's own.

use mode360_synth::noise::{hash_words, Rng};

/// Samples per pooled rig before its generation is renewed.
pub const RENEW_SAMPLES_PER_RIG: u64 = 25;
/// Domain separation of the pooled rig seeds.
const POOL_TAG: u64 = 0x7A41_0B00;

/// Domain separation of the slot draw.
const SLOT_TAG: u64 = 0x7A41_0B01;

/// The index at which sample `index` of stream `seed` draws its rig, with a pool of `rigs`
/// rigs: the index of pooled rig `slot` of the sample's generation, the slot drawn from the
/// sample's own stream `Rng::new(&[seed, index, SLOT_TAG])`.
pub fn pooled_rig_index(seed: u64, index: u64, rigs: usize) -> u64 {
    let slot = Rng::new(&[seed, index, SLOT_TAG]).index(rigs.max(1));
    pool_member(seed, index, rigs, slot)
}

/// The rig index of pooled rig `slot` (in `0..rigs`) of sample `index`'s generation.
fn pool_member(seed: u64, index: u64, rigs: usize, slot: usize) -> u64 {
    let renew = RENEW_SAMPLES_PER_RIG * rigs.max(1) as u64;
    hash_words(&[seed, index / renew, slot as u64, POOL_TAG])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_generation_holds_exactly_its_rigs_and_the_next_one_renews_them() {
        let rigs = 4;
        let renew = RENEW_SAMPLES_PER_RIG * rigs as u64;
        let generation = |g: u64| -> std::collections::BTreeSet<u64> {
            (g * renew..(g + 1) * renew)
                .map(|k| pooled_rig_index(1, k, rigs))
                .collect()
        };
        let (g0, g1) = (generation(0), generation(1));
        assert_eq!(g0.len(), rigs);
        assert_eq!(g1.len(), rigs);
        assert!(g0.is_disjoint(&g1));
        assert_ne!(pool_member(1, 0, rigs, 0), pool_member(2, 0, rigs, 0));
    }
}
