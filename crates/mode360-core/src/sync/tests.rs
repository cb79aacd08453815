//! Tests of the parent module.

use super::*;

const MS: u64 = 1_000_000;

fn sync(n: usize) -> ApproxTimeSync<&'static str> {
    ApproxTimeSync::new(
        n,
        SyncConfig {
            tolerance_ns: 5 * MS,
            queue_size: 3,
            ..SyncConfig::default()
        },
    )
}

#[test]
fn groups_messages_within_tolerance() {
    let mut s = sync(3);
    assert!(s.push(0, 100 * MS, "a0").unwrap().is_empty());
    assert!(s.push(1, 102 * MS, "b0").unwrap().is_empty());
    let g = s.push(2, 104 * MS, "c0").unwrap();
    assert_eq!(g.len(), 1);
    assert_eq!(g[0].stamp_ns, 100 * MS);
    let names: Vec<_> = g[0].messages.iter().map(|m| m.unwrap().1).collect();
    assert_eq!(names, ["a0", "b0", "c0"]);
    assert_eq!(s.stats().groups, 1);
}

#[test]
fn drops_messages_that_can_never_match() {
    let mut s = sync(2);
    s.push(0, 0, "a0").unwrap();
    s.push(0, 100 * MS, "a1").unwrap();
    let g = s.push(1, 98 * MS, "b0").unwrap();
    assert_eq!(g.len(), 1);
    assert_eq!(g[0].messages[0].unwrap().1, "a1");
    assert_eq!(s.stats().unmatched, 1);
}

#[test]
fn out_of_order_is_rejected_and_queue_is_bounded() {
    let mut s = sync(2);
    s.push(0, 50 * MS, "a").unwrap();
    assert_eq!(
        s.push(0, 40 * MS, "late"),
        Err(SyncError::OutOfOrder {
            stream: 0,
            stamp_ns: 40 * MS,
            last_ns: 50 * MS
        })
    );
    for k in 0..10 {
        s.push(0, (60 + k) * MS, "x").unwrap();
    }
    assert_eq!(s.stats().overflow, 8);
    assert!(matches!(
        s.push(5, 0, "?"),
        Err(SyncError::NoSuchStream { .. })
    ));
}

#[test]
fn inactive_stream_is_not_waited_for_and_returns() {
    let mut s = sync(3);
    s.set_active(2, false);
    s.push(0, 10 * MS, "a").unwrap();
    let g = s.push(1, 11 * MS, "b").unwrap();
    assert_eq!(g.len(), 1);
    assert!(g[0].messages[2].is_none());
    // Back again: it joins when it matches.
    s.set_active(2, true);
    s.push(0, 20 * MS, "a").unwrap();
    s.push(1, 21 * MS, "b").unwrap();
    let g = s.push(2, 22 * MS, "c").unwrap();
    assert_eq!(g[0].messages.iter().filter(|m| m.is_some()).count(), 3);
}

const S: u64 = 1_000_000_000;
/// A camera period of 30 Hz.
const PERIOD: u64 = 33 * MS;
/// Where the synthetic streams' clocks start (an ordinary epoch time).
const T0: u64 = 1_700_000_000 * S;
/// Delivery latency of the synthetic receive times.
const LATENCY: u64 = 2 * MS;
/// The receive time of a bag recorded at `T0` and played a year later on the system clock.
const WALL: u64 = T0 + 365 * 86_400 * S;

/// Pushes one frame: every stream stamped `stamp_ns` (stream `k` jittered by `k` ms,
/// inside the 5 ms tolerance), received `LATENCY` later when `with_receipt`. Returns the
/// stamps of the groups completed and the resets reported.
fn frame(
    s: &mut ApproxTimeSync<&'static str>,
    streams: usize,
    stamp_ns: u64,
    with_receipt: bool,
) -> (Vec<u64>, Vec<ClockReset>) {
    let (mut groups, mut resets) = (Vec::new(), Vec::new());
    for k in 0..streams {
        let t = stamp_ns + k as u64 * MS;
        let receipt = with_receipt.then_some(t + LATENCY);
        let pushed = s.push_at(k, t, receipt, "img").expect("a good message");
        groups.extend(pushed.groups.iter().map(|g| g.stamp_ns));
        resets.extend(pushed.reset);
    }
    (groups, resets)
}

#[test]
fn an_hour_ahead_stamp_on_every_camera_costs_those_images_only() {
    for with_receipt in [false, true] {
        let mut s = sync(3);
        let mut groups = 0;
        for f in 0..10 {
            groups += frame(&mut s, 3, T0 + f * PERIOD, with_receipt).0.len();
        }
        // Each camera in turn sends one image stamped an hour ahead.
        let hour_ahead = T0 + 10 * PERIOD + 3600 * S;
        for k in 0..3 {
            let receipt = with_receipt.then_some(T0 + 10 * PERIOD);
            let err = s.push_at(k, hour_ahead, receipt, "bad").unwrap_err();
            assert!(matches!(err, SyncError::Ahead { stream, .. } if stream == k));
        }
        for f in 10..20 {
            groups += frame(&mut s, 3, T0 + f * PERIOD, with_receipt).0.len();
        }
        assert_eq!(
            groups, 20,
            "with_receipt {with_receipt}: every normal frame grouped"
        );
        let st = s.stats();
        assert_eq!(
            (st.groups, st.ahead),
            (20, 3),
            "with_receipt {with_receipt}"
        );
        assert_eq!((st.resets, st.out_of_order, st.unmatched), (0, 0, 0));
    }
    // A bag from the past played on the system clock: the receive time cannot tell, the
    // stray stamps form one group, the next normal stamp resets and groups go on.
    let mut s = sync(3);
    let mut groups = Vec::new();
    for f in 0..20 {
        if f == 10 {
            for k in 0..3 {
                let hour_ahead = T0 + 10 * PERIOD + 3600 * S + k as u64 * MS;
                let pushed = s.push_at(k, hour_ahead, Some(WALL), "bad").unwrap();
                groups.extend(pushed.groups.iter().map(|g| g.stamp_ns));
            }
        }
        for k in 0..3 {
            let pushed = s.push_at(k, T0 + f * PERIOD + k as u64 * MS, Some(WALL), "img");
            groups.extend(pushed.unwrap().groups.iter().map(|g| g.stamp_ns));
        }
    }
    assert_eq!(
        groups.len(),
        21,
        "20 normal groups and the stray one: {groups:?}"
    );
    assert_eq!((s.stats().resets, s.stats().ahead), (1, 0));
}

#[test]
fn a_20_s_clock_reset_resumes_groups_within_one_group_period() {
    let mut s = sync(4);
    let mut before = 0;
    for f in 0..30 {
        before += frame(&mut s, 4, T0 + f * PERIOD, true).0.len();
    }
    assert_eq!(before, 30);
    // Simulated time starts over 20 s earlier, on every camera.
    let back = T0 + 30 * PERIOD - 20 * S;
    let (groups, resets) = frame(&mut s, 4, back, true);
    assert_eq!(groups, [back], "the first frame after the reset is a group");
    assert_eq!(resets.len(), 1, "reported once: {resets:?}");
    assert_eq!(resets[0].stream, 0);
    assert_eq!(resets[0].jump_ns(), 20 * S - PERIOD);
    // A straggler from before the reset (camera 1, delivered late) is far ahead now: it
    // is dropped and does not reset again.
    let straggler = T0 + 29 * PERIOD + MS;
    assert!(matches!(
        s.push_at(1, straggler, None, "late"),
        Err(SyncError::Ahead {
            reference: TimeReference::OtherStreams,
            ..
        })
    ));
    let mut after = 0;
    for f in 1..10 {
        after += frame(&mut s, 4, back + f * PERIOD, true).0.len();
    }
    assert_eq!(after, 9);
    let st = s.stats();
    assert_eq!((st.resets, st.ahead, st.groups), (1, 1, 40));
}

#[test]
fn an_old_epoch_image_delivered_after_a_reset_is_dropped_not_a_second_reset() {
    // A bag from the past looped on the system clock; camera 1's last image of the first
    // pass is delivered after camera 0's first image of the second pass.
    let mut s = sync(3);
    let push =
        |s: &mut ApproxTimeSync<&'static str>, k: usize, t: u64| s.push_at(k, t, Some(WALL), "img");
    for f in 0..40 {
        frame_at(&mut s, 3, T0 + f * PERIOD, WALL);
    }
    let last = T0 + 40 * PERIOD;
    push(&mut s, 0, last).unwrap();
    push(&mut s, 2, last + 2 * MS).unwrap();
    let reset = push(&mut s, 0, T0).unwrap().reset.expect("a reset");
    assert_eq!((reset.stream, reset.discarded), (0, 2));
    assert!(matches!(
        push(&mut s, 1, last + MS),
        Err(SyncError::Ahead {
            stream: 1,
            reference: TimeReference::OtherStreams,
            ..
        })
    ));
    let mut groups = Vec::new();
    groups.extend(push(&mut s, 1, T0 + MS).unwrap().groups);
    groups.extend(push(&mut s, 2, T0 + 2 * MS).unwrap().groups);
    assert_eq!(groups.len(), 1, "the second pass's first frame is a group");
    for f in 1..10 {
        frame_at(&mut s, 3, T0 + f * PERIOD, WALL);
    }
    let st = s.stats();
    assert_eq!((st.groups, st.resets, st.ahead), (50, 1, 1));
}

/// [`frame`] with every message received at `receipt_ns`.
fn frame_at(s: &mut ApproxTimeSync<&'static str>, streams: usize, stamp_ns: u64, receipt_ns: u64) {
    for k in 0..streams {
        s.push_at(k, stamp_ns + k as u64 * MS, Some(receipt_ns), "img")
            .expect("a good message");
    }
}

#[test]
fn a_looped_sequence_played_twice_yields_every_group_of_both_passes() {
    // Two seconds: longer than reset_jump_ns, as a loop must be to be told from a reorder.
    const FRAMES: u64 = 60;
    let mut s = sync(4);
    let mut stamps = Vec::new();
    let mut resets = Vec::new();
    for _pass in 0..2 {
        for f in 0..FRAMES {
            // Cameras arrive in a different order each frame.
            for j in 0..4 {
                let k = ((f as usize) + j) % 4;
                let t = T0 + f * PERIOD + k as u64 * MS;
                let pushed = s.push_at(k, t, None, "img").expect("a good message");
                stamps.extend(pushed.groups.iter().map(|g| g.stamp_ns));
                resets.extend(pushed.reset);
            }
        }
    }
    assert_eq!(stamps.len() as u64, 2 * FRAMES);
    assert_eq!(stamps[..FRAMES as usize], stamps[FRAMES as usize..]);
    assert_eq!(resets.len(), 1, "one reset per loop: {resets:?}");
    let st = s.stats();
    assert_eq!((st.resets, st.ahead, st.out_of_order), (1, 0, 0));
}

#[test]
fn a_stamp_in_2038_is_dropped_and_counted_and_the_stream_goes_on() {
    let year_2038 = ((1u64 << 31) - 1) * S;
    let mut s = sync(2);
    let mut groups = 0;
    for f in 0..5 {
        groups += frame(&mut s, 2, T0 + f * PERIOD, false).0.len();
    }
    assert_eq!(
        s.push(0, year_2038, "bad"),
        Err(SyncError::Ahead {
            stream: 0,
            stamp_ns: year_2038,
            reference: TimeReference::OtherStreams,
            reference_ns: T0 + 4 * PERIOD + MS,
        })
    );
    for f in 5..10 {
        groups += frame(&mut s, 2, T0 + f * PERIOD, false).0.len();
    }
    assert_eq!(groups, 10);
    assert_eq!((s.stats().ahead, s.stats().resets), (1, 0));
    // As the very first message, only the receive time can tell.
    let mut fresh = sync(2);
    let receipt = Some(T0);
    let err = fresh.push_at(1, year_2038, receipt, "bad").unwrap_err();
    assert!(matches!(
        err,
        SyncError::Ahead {
            reference: TimeReference::Receipt,
            ..
        }
    ));
    assert!(
        err.to_string().contains("s ahead of the receive time"),
        "{err}"
    );
    let mut groups = 0;
    for f in 0..5 {
        groups += frame(&mut fresh, 2, T0 + f * PERIOD, true).0.len();
    }
    assert_eq!(groups, 5);
}

#[test]
fn a_small_reorder_is_out_of_order_not_a_reset() {
    let mut s = sync(2);
    let mut groups = 0;
    for f in 0..5 {
        groups += frame(&mut s, 2, T0 + f * PERIOD, true).0.len();
    }
    // 40 ms back: well inside reset_jump_ns.
    let late = T0 + 4 * PERIOD - 40 * MS;
    assert!(matches!(
        s.push_at(0, late, Some(T0 + 5 * PERIOD), "late"),
        Err(SyncError::OutOfOrder { stream: 0, .. })
    ));
    for f in 5..10 {
        groups += frame(&mut s, 2, T0 + f * PERIOD, true).0.len();
    }
    assert_eq!(groups, 10);
    let st = s.stats();
    assert_eq!((st.out_of_order, st.resets, st.ahead), (1, 0, 0));
}

#[test]
fn a_forward_step_of_every_clock_is_followed() {
    // A gap of 10 s in a bag played faster than real time: no receive time to vouch for
    // the new stamps, each camera's first ones look far ahead of the others'.
    let mut s = sync(3);
    for f in 0..5 {
        frame(&mut s, 3, T0 + f * PERIOD, false);
    }
    let gap = 10 * S;
    let mut stamps = Vec::new();
    for f in 5..10 {
        for k in 0..3 {
            let t = T0 + gap + f * PERIOD + k as u64 * MS;
            if let Ok(g) = s.push(k, t, "img") {
                stamps.extend(g.iter().map(|g| g.stamp_ns));
            }
        }
    }
    // Camera 0 needs AHEAD_STAMPS_TO_FOLLOW frames; cameras 1 and 2 then follow it.
    let lost = AHEAD_STAMPS_TO_FOLLOW as usize - 1;
    assert_eq!(stamps.len(), 5 - lost, "{stamps:?}");
    assert_eq!(s.stats().ahead, (3 * lost) as u64);
    assert_eq!(s.stats().resets, 0);
    // The same bag on the system clock: the receive time vouches, nothing is lost.
    let mut s = sync(3);
    for f in 0..5 {
        frame_at(&mut s, 3, T0 + f * PERIOD, WALL);
    }
    for f in 5..10 {
        frame_at(&mut s, 3, T0 + gap + f * PERIOD, WALL);
    }
    assert_eq!((s.stats().groups, s.stats().ahead), (10, 0));
}

#[test]
fn settings_without_the_time_limits_still_load() {
    let c: SyncConfig =
        serde_yaml::from_str("tolerance_ns: 20000000\nqueue_size: 4\n").expect("old settings load");
    assert_eq!(c.max_ahead_ns, DEFAULT_MAX_AHEAD_NS);
    assert_eq!(c.reset_jump_ns, DEFAULT_RESET_JUMP_NS);
    assert_eq!((c.tolerance_ns, c.queue_size), (20_000_000, 4));
}

#[test]
fn queues_are_bounded_in_bytes_too() {
    // Messages weigh their length; a queue may hold 10 bytes (and always its newest message).
    let mut s = ApproxTimeSync::<Vec<u8>>::new(2, SyncConfig::default())
        .with_bytes_cap(|m: &Vec<u8>| m.len(), 10);
    // Stream 1 never sends: stream 0's messages wait, and only what fits 10 bytes stays.
    for k in 0..4 {
        s.push(0, (10 + k) * MS, vec![0; 4]).unwrap();
    }
    // 4 + 4 fit, a third would make 12: two of the four were dropped.
    assert_eq!(s.stats().overflow, 2);
    // A single message larger than the cap is kept alone (the newest is never dropped).
    s.push(0, 20 * MS, vec![0; 50]).unwrap();
    assert_eq!(s.stats().overflow, 4);
    // Its partner arrives: one group, carrying the large message.
    let groups = s.push(1, 20 * MS, vec![1]).unwrap();
    assert_eq!(groups.len(), 1);
    assert_eq!(
        groups[0].messages[0].as_ref().map(|(_, m)| m.len()),
        Some(50)
    );
}
