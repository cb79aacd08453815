//! The receive loop on the DDS thread. [`dds_setup`] creates the node, its publishers and
//! subscriptions and sends `/tf_static`; [`dds_main`] then runs a current-thread tokio runtime
//! whose loop (`tokio::select!`) receives every camera topic (sensor-data QoS: best effort,
//! keep last), validates and decodes each image ([`decode_camera`]) and feeds
//! [`ApproxTimeSync`]; with `use_sim_time` it also follows `/clock` ([`NodeClock`]); a
//! `tokio::time` ticker ([`TICK`]) times cameras out and publishes `/diagnostics` once a
//! second; a watch channel stops it. Complete groups go to the inference worker's mailbox
//! ([`super::worker`]), which this loop starts and, at shutdown, stops and waits for.

use super::clock::{seconds_between, NodeClock};
use super::dds::{
    clock_qos, create_publisher, create_subscription, dds_context, latched_qos, output_qos,
    runtime, sensor_qos, DdsOptions, SpunNode,
};
use super::diagnostics::{diagnostic_array, BadImageReason};
use super::error::dds_err;
use super::live_view::LiveViewTopics;
use super::params::{ImageTransport, NodeParams};
use super::pipeline::Pipeline;
use super::qos_overrides::QosEntity;
use super::ros_params::{node_options, RuntimeParams};
use super::worker::{lock, post_groups, worker_main, OutputPublishers, Shared};
use super::{
    resolve_topic, NodeError, CLOCK_TOPIC, COMPRESSED_DEPTH_TOPIC, CONFIDENCE_TOPIC, DEPTH_TOPIC,
    DIAGNOSTICS_TOPIC, POINTS_TOPIC, TF_STATIC_TOPIC,
};
use futures::StreamExt;
use mode360_core::frame::RgbImage;
use mode360_core::geometry::{Rig, RigCamera};
use mode360_core::sync::{ApproxTimeSync, SyncConfig};
use mode360_io::bag::rig_tf_static;
use mode360_io::msgs::image::{rgb_from_compressed, rgb_from_image_msg, ImageMsgError};
use mode360_io::msgs::{Clock, CompressedImage, DiagnosticArray, Image, TFMessage};
use ros2_client::{Context, Publisher};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::watch;

/// Housekeeping period of the DDS thread (timeouts, shutdown, diagnostics schedule).
pub const TICK: Duration = Duration::from_millis(50);
/// Period of `/diagnostics`.
pub const DIAGNOSTICS_PERIOD: Duration = Duration::from_secs(1);
/// Fewest cameras the node keeps running with.
pub const MIN_ACTIVE_CAMERAS: usize = 2;
/// Suffix of image_transport's compressed topic.
pub const COMPRESSED_SUFFIX: &str = "compressed";

/// The topic camera `name` is received on (after remapping and transport suffix).
pub(super) fn camera_topic(params: &NodeParams, name: &str, topic: &str) -> String {
    let base = params.remap(topic);
    match params.image_transport(name) {
        ImageTransport::Raw => base,
        ImageTransport::Compressed => format!("{base}/{COMPRESSED_SUFFIX}"),
    }
}

/// The topic output `name` (relative or absolute) is published on, after namespace and
/// remapping.
pub(super) fn output_topic(params: &NodeParams, name: &str) -> String {
    match params.remaps.get(name) {
        // `-r depth:=range` remaps the relative name; the result resolves in the namespace.
        Some(to) => resolve_topic(&params.namespace, to),
        None => params.remap(&resolve_topic(&params.namespace, name)),
    }
}

/// The live view's topics: the node's, as on DDS.
pub(super) fn live_view_topics(params: &NodeParams, rig: &Rig) -> LiveViewTopics {
    LiveViewTopics {
        cameras: rig
            .cameras
            .iter()
            .map(|c| {
                let compressed = params.image_transport(&c.name) == ImageTransport::Compressed;
                (camera_topic(params, &c.name, &c.topic), compressed)
            })
            .collect(),
        depth: output_topic(params, DEPTH_TOPIC),
        compressed_depth: output_topic(params, COMPRESSED_DEPTH_TOPIC),
        points: output_topic(params, POINTS_TOPIC),
        confidence: output_topic(params, CONFIDENCE_TOPIC),
        tf_static: TF_STATIC_TOPIC.to_string(),
        diagnostics: DIAGNOSTICS_TOPIC.to_string(),
    }
}

/// A received camera message.
enum CameraMsg {
    Raw(Image),
    Compressed(CompressedImage),
}

/// Per-camera receive bookkeeping on the DDS thread.
struct CameraState {
    /// Node-clock time of the newest good message.
    last_receipt_ns: Option<u64>,
    received_in_period: u64,
}

/// A dropped camera message: why (the diagnostics counter) and what exactly.
type Bad = (BadImageReason, String);

fn bad_image(e: ImageMsgError) -> Bad {
    (BadImageReason::from(&e), e.to_string())
}

/// Validates and decodes one camera message of `camera`: encoding, step and data length, and
/// the size its model takes (an ERP panorama 2:1 at any width, a fisheye or dual-fisheye
/// image exactly its `image_size`). A wrong size is [`BadImageReason::WrongSize`], with a
/// detail naming the camera, the size expected and the size received.
fn decode_camera(camera: &RigCamera, msg: &CameraMsg) -> Result<(u64, RgbImage), Bad> {
    let (stamp_ns, image) = match msg {
        CameraMsg::Raw(m) => (
            m.header.stamp.to_nanos(),
            rgb_from_image_msg(m).map_err(bad_image)?,
        ),
        CameraMsg::Compressed(m) => (
            m.header.stamp.to_nanos(),
            rgb_from_compressed(m).map_err(bad_image)?,
        ),
    };
    camera
        .projection
        .check_image_size(image.width(), image.height())
        .map_err(|e| {
            (
                BadImageReason::WrongSize,
                format!("camera '{}': {e}", camera.name),
            )
        })?;
    Ok((stamp_ns, image))
}

/// Everything the DDS thread sets up before it reports ready.
struct DdsSetup {
    context: Context,
    spun: SpunNode,
    publishers: OutputPublishers,
    /// `None` with `publish_tf: false`.
    tf_static: Option<Publisher<TFMessage>>,
    diagnostics: Publisher<DiagnosticArray>,
    raw_subs: Vec<(usize, ros2_client::Subscription<Image>)>,
    compressed_subs: Vec<(usize, ros2_client::Subscription<CompressedImage>)>,
    clock_sub: Option<ros2_client::Subscription<Clock>>,
}

fn dds_setup(
    params: &NodeParams,
    dds: &DdsOptions,
    rig: &Rig,
    runtime: RuntimeParams,
) -> Result<DdsSetup, NodeError> {
    let context = dds_context(dds)?;
    let options = node_options(params, runtime);
    let mut spun = SpunNode::with_options(&context, &params.namespace, &params.node_name, options)?;
    let topic = |name: &str| output_topic(params, name);
    // QoS of each endpoint: the node's default for its kind, then the parameters' overrides.
    let pub_qos = |t: &str, base| params.qos_overrides.qos(t, QosEntity::Publisher, base);
    let sub_qos = |t: &str, base| params.qos_overrides.qos(t, QosEntity::Subscription, base);
    let output = |name: &str| {
        let t = topic(name);
        let q = pub_qos(&t, output_qos());
        (t, q)
    };
    let node = &mut spun.node;
    let (t, q) = output(DEPTH_TOPIC);
    let depth = create_publisher(node, &t, q)?;
    let (t, q) = output(POINTS_TOPIC);
    let points = Arc::new(create_publisher(node, &t, q)?);
    let (t, q) = output(COMPRESSED_DEPTH_TOPIC);
    let compressed_depth = Arc::new(create_publisher(node, &t, q)?);
    let (t, q) = output(CONFIDENCE_TOPIC);
    let confidence = create_publisher(node, &t, q)?;
    let publishers = OutputPublishers {
        depth,
        points,
        compressed_depth,
        confidence,
    };
    let tf_static: Option<Publisher<TFMessage>> = if params.publish_tf {
        Some(create_publisher(
            node,
            TF_STATIC_TOPIC,
            pub_qos(TF_STATIC_TOPIC, latched_qos()),
        )?)
    } else {
        None
    };
    let diagnostics: Publisher<DiagnosticArray> = create_publisher(
        node,
        DIAGNOSTICS_TOPIC,
        pub_qos(DIAGNOSTICS_TOPIC, output_qos()),
    )?;
    let mut raw_subs = Vec::new();
    let mut compressed_subs = Vec::new();
    for (i, cam) in rig.cameras.iter().enumerate() {
        let t = camera_topic(params, &cam.name, &cam.topic);
        match params.image_transport(&cam.name) {
            ImageTransport::Raw => raw_subs.push((
                i,
                create_subscription::<Image>(node, &t, sub_qos(&t, sensor_qos()))?,
            )),
            ImageTransport::Compressed => compressed_subs.push((
                i,
                create_subscription::<CompressedImage>(node, &t, sub_qos(&t, sensor_qos()))?,
            )),
        }
    }
    let clock_sub = if params.use_sim_time {
        Some(create_subscription::<Clock>(
            node,
            CLOCK_TOPIC,
            sub_qos(CLOCK_TOPIC, clock_qos()),
        )?)
    } else {
        None
    };
    if let Some(tf_static) = &tf_static {
        tf_static
            .publish(rig_tf_static(rig))
            .map_err(|e| format!("{e:?}"))
            .map_err(dds_err("publishing /tf_static"))?;
    }
    Ok(DdsSetup {
        context,
        spun,
        publishers,
        tf_static,
        diagnostics,
        raw_subs,
        compressed_subs,
        clock_sub,
    })
}

/// Matched subscribers of the outputs built only on demand.
#[derive(Clone, Copy, Debug)]
struct Subscribers {
    points: usize,
    compressed_depth: usize,
}

/// Receive-side state of the DDS loop: synchronizer, clock, per-camera bookkeeping.
struct Receiver {
    sync: ApproxTimeSync<RgbImage>,
    clock: NodeClock,
    cams: Vec<CameraState>,
    /// Node-clock time of the first tick or image (the baseline of cameras never heard).
    started_ns: Option<u64>,
    timeout_ns: u64,
    shared: Arc<Shared>,
    hardware_id: String,
    last_diag: Instant,
    /// The rig's transforms, for the live view.
    tf_static: TFMessage,
    /// The rig's cameras (rig order), whose models say which image sizes are accepted.
    cameras: Vec<RigCamera>,
}

impl Receiver {
    fn on_camera(&mut self, i: usize, result: Result<CameraMsg, Bad>) {
        let now_ns = self.clock.now_ns();
        if let Some(now) = now_ns {
            self.started_ns.get_or_insert(now);
        }
        if let (Some(live), Ok(msg)) = (&self.shared.live, &result) {
            match msg {
                CameraMsg::Raw(m) => live.log_camera_raw(i, m),
                CameraMsg::Compressed(m) => live.log_camera_compressed(i, m),
            }
        }
        let sync = &mut self.sync;
        let camera = &self.cameras[i];
        let outcome =
            result
                .and_then(|msg| decode_camera(camera, &msg))
                .and_then(|(stamp_ns, img)| {
                    sync.push(i, stamp_ns, img)
                        .map_err(|e| (BadImageReason::from(&e), e.to_string()))
                });
        let mut groups = Vec::new();
        {
            let mut h = lock(&self.shared.health);
            match outcome {
                Ok(g) => {
                    groups = g;
                    if now_ns.is_some() {
                        self.cams[i].last_receipt_ns = now_ns;
                    }
                    self.cams[i].received_in_period += 1;
                    h.cameras[i].record_good();
                    if !self.sync.is_active(i) {
                        h.cameras[i].active = true;
                        groups.extend(self.sync.set_active(i, true));
                    }
                }
                Err((reason, detail)) => h.cameras[i].record_bad(reason, detail),
            }
            h.sync = self.sync.stats();
        }
        post_groups(&self.shared, groups);
    }

    fn on_tick(&mut self, diagnostics: &Publisher<DiagnosticArray>, subscribers: Subscribers) {
        self.shared
            .points_wanted
            .store(subscribers.points > 0, Ordering::Relaxed);
        self.shared
            .compressed_depth_wanted
            .store(subscribers.compressed_depth > 0, Ordering::Relaxed);
        let now_ns = self.clock.now_ns();
        if let Some(now) = now_ns {
            let started = *self.started_ns.get_or_insert(now);
            // Cameras silent for longer than the timeout are no longer waited for, as long
            // as at least MIN_ACTIVE_CAMERAS stay active.
            let mut groups = Vec::new();
            for i in 0..self.cams.len() {
                let silent_since = self.cams[i].last_receipt_ns.unwrap_or(started);
                let active_count = (0..self.cams.len())
                    .filter(|&k| self.sync.is_active(k))
                    .count();
                if self.sync.is_active(i)
                    && now.saturating_sub(silent_since) > self.timeout_ns
                    && active_count > MIN_ACTIVE_CAMERAS
                {
                    groups.extend(self.sync.set_active(i, false));
                    lock(&self.shared.health).cameras[i].active = false;
                }
            }
            post_groups(&self.shared, groups);
        }
        let period = self.last_diag.elapsed();
        if period >= DIAGNOSTICS_PERIOD {
            let report = {
                let mut h = lock(&self.shared.health);
                for (i, c) in self.cams.iter_mut().enumerate() {
                    h.cameras[i].rate_hz = c.received_in_period as f64 / period.as_secs_f64();
                    h.cameras[i].age_s = match (c.last_receipt_ns, now_ns) {
                        (Some(t), Some(now)) => Some(seconds_between(t, now)),
                        _ => None,
                    };
                    c.received_in_period = 0;
                }
                h.sync = self.sync.stats();
                // Stamp 0 with simulated time before the first /clock, as in ROS 2.
                diagnostic_array(now_ns.unwrap_or(0), &self.hardware_id, &h)
            };
            if let Some(live) = &self.shared.live {
                live.diagnostics.log(&report);
                // No latching on the WebSocket: the rig's transforms again for late viewers.
                if live.tf_static.wanted() {
                    live.tf_static.log(&self.tf_static);
                }
            }
            if let Err(e) = diagnostics.publish(report) {
                tracing::warn!("publishing /diagnostics: {e:?}");
            }
            self.last_diag = Instant::now();
        }
    }
}

pub(super) fn dds_main(
    params: NodeParams,
    dds: DdsOptions,
    rig: Rig,
    pipeline: Pipeline,
    shared: Arc<Shared>,
    mut stop: watch::Receiver<bool>,
    ready: std::sync::mpsc::Sender<Result<(), NodeError>>,
) -> Result<(), NodeError> {
    let setup =
        runtime().and_then(|rt| Ok((rt, dds_setup(&params, &dds, &rig, shared.runtime.clone())?)));
    let (rt, setup) = match setup {
        Ok(s) => s,
        Err(e) => {
            let text = e.to_string();
            let _ = ready.send(Err(e));
            return Err(NodeError::Dds {
                what: "setup".into(),
                problem: text,
            });
        }
    };
    let DdsSetup {
        context,
        spun,
        publishers,
        tf_static,
        diagnostics,
        raw_subs,
        compressed_subs,
        clock_sub,
    } = setup;
    let points_pub = publishers.points.clone();
    let compressed_pub = publishers.compressed_depth.clone();
    let worker = {
        let shared = shared.clone();
        std::thread::Builder::new()
            .name("mode360-inference".into())
            .spawn(move || worker_main(pipeline, publishers, shared))
            .map_err(|e| e.to_string())
            .map_err(dds_err("starting the inference thread"))?
    };
    let _ = ready.send(Ok(()));

    let n = rig.cameras.len();
    let mut rx = Receiver {
        sync: ApproxTimeSync::new(
            n,
            SyncConfig {
                tolerance_ns: (params.sync_tolerance_s * 1e9).round() as u64,
                queue_size: params.sync_queue_size,
            },
        ),
        clock: NodeClock::new(params.use_sim_time),
        cams: (0..n)
            .map(|_| CameraState {
                last_receipt_ns: None,
                received_in_period: 0,
            })
            .collect(),
        started_ns: None,
        timeout_ns: (params.camera_timeout_s * 1e9).round() as u64,
        shared: shared.clone(),
        hardware_id: params.fully_qualified_name(),
        last_diag: Instant::now(),
        tf_static: rig_tf_static(&rig),
        cameras: rig.cameras.clone(),
    };

    rt.block_on(async {
        let raw = futures::stream::select_all(raw_subs.iter().map(|(i, s)| {
            let i = *i;
            s.async_stream()
                .map(move |r| (i, r.map(|(m, _)| CameraMsg::Raw(m))))
                .boxed()
        }));
        let compressed = futures::stream::select_all(compressed_subs.iter().map(|(i, s)| {
            let i = *i;
            s.async_stream()
                .map(move |r| (i, r.map(|(m, _)| CameraMsg::Compressed(m))))
                .boxed()
        }));
        let mut incoming = futures::stream::select(raw, compressed);
        let mut clock_msgs = match &clock_sub {
            Some(s) => s.async_stream().boxed(),
            None => futures::stream::pending().boxed(),
        };
        let mut ticker = tokio::time::interval(TICK);
        ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        // ros2-client logs an ERROR for every match count of a publisher that never had a
        // subscriber (it keeps no entry for it), 20 times a second here: count only after
        // the first match.
        let mut first_points_subscriber = Box::pin(points_pub.wait_for_subscription(&spun.node));
        let mut first_compressed_subscriber =
            Box::pin(compressed_pub.wait_for_subscription(&spun.node));
        let (mut points_matched, mut compressed_matched) = (false, false);
        loop {
            tokio::select! {
                _ = &mut first_points_subscriber, if !points_matched => points_matched = true,
                _ = &mut first_compressed_subscriber, if !compressed_matched => {
                    compressed_matched = true
                }
                // A stop request, or the handle dropped.
                _ = stop.changed() => break,
                Some((i, result)) = incoming.next() => {
                    rx.on_camera(
                        i,
                        result.map_err(|e| {
                            (BadImageReason::Transport, format!("cannot deserialize: {e:?}"))
                        }),
                    );
                }
                Some(result) = clock_msgs.next() => match result {
                    Ok((clock, _)) => rx.clock.on_clock(clock.clock.to_nanos()),
                    Err(e) => tracing::warn!("/clock: cannot deserialize: {e:?}"),
                },
                _ = ticker.tick() => {
                    let subscribers = Subscribers {
                        points: if points_matched {
                            points_pub.get_subscription_count(&spun.node)
                        } else {
                            0
                        },
                        compressed_depth: if compressed_matched {
                            compressed_pub.get_subscription_count(&spun.node)
                        } else {
                            0
                        },
                    };
                    rx.on_tick(&diagnostics, subscribers)
                }
            }
        }
    });

    {
        let mut mb = lock(&shared.mailbox);
        mb.shutdown = true;
        // A group still waiting for inference is not processed any more: dropped.
        if mb.slot.take().is_some() {
            lock(&shared.health).groups_dropped += 1;
        }
    }
    shared.wake.notify_all();
    let worker_result = worker.join();
    drop(clock_sub);
    drop(raw_subs);
    drop(compressed_subs);
    drop(tf_static);
    drop(diagnostics);
    spun.stop()?;
    drop(context);
    drop(rt);
    worker_result.map_err(|_| NodeError::ThreadPanic {
        thread: "inference".into(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use mode360_io::msgs::image::image_msg_from_rgb;
    use mode360_io::msgs::Header;

    const OMNIMVS_RIG: &str = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../launch_configs/rig_omnimvs.yaml"
    );
    const DUAL_RIG: &str = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../launch_configs/rig_dual_fisheye.yaml"
    );
    const DEEP360_RIG: &str = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../launch_configs/rig_deep360.yaml"
    );
    const STAMP_NS: u64 = 1_700_000_000_000_000_000;

    fn raw(width: u32, height: u32) -> CameraMsg {
        let img = RgbImage::from_pixel(width, height, image::Rgb([10, 20, 30]));
        CameraMsg::Raw(image_msg_from_rgb(Header::new(STAMP_NS, "cam"), &img))
    }

    fn png(width: u32, height: u32) -> CameraMsg {
        let img = RgbImage::from_pixel(width, height, image::Rgb([10, 20, 30]));
        let mut data = Vec::new();
        img.write_to(
            &mut std::io::Cursor::new(&mut data),
            image::ImageFormat::Png,
        )
        .expect("png");
        CameraMsg::Compressed(CompressedImage {
            header: Header::new(STAMP_NS, "cam"),
            format: "rgb8; png compressed bgr8".into(),
            data,
        })
    }

    #[test]
    fn fisheye_images_are_accepted_at_their_image_size_only() {
        let rig = Rig::from_file(OMNIMVS_RIG).expect("omnimvs rig");
        let cam = &rig.cameras[1];
        for msg in [raw(384, 384), png(384, 384)] {
            let (stamp_ns, img) = decode_camera(cam, &msg).expect("good fisheye image");
            assert_eq!((stamp_ns, img.dimensions()), (STAMP_NS, (384, 384)));
        }
        // A panorama, a half-size image and a transposed one are all dropped.
        for (w, h) in [(768, 384), (192, 192), (384, 383)] {
            for msg in [raw(w, h), png(w, h)] {
                let (reason, detail) = decode_camera(cam, &msg).expect_err("wrong size");
                assert_eq!(reason, BadImageReason::WrongSize);
                assert_eq!(reason.key(), "wrong_size");
                assert_eq!(
                    detail,
                    format!(
                        "camera 'front_right': expected 384x384 (its double_sphere image_size), got {w}x{h}"
                    )
                );
            }
        }
    }

    #[test]
    fn dual_fisheye_and_panorama_sizes() {
        let dual = Rig::from_file(DUAL_RIG).expect("dual rig");
        let cam = &dual.cameras[0];
        assert!(decode_camera(cam, &raw(512, 256)).is_ok());
        let (reason, detail) = decode_camera(cam, &raw(256, 256)).expect_err("one lens only");
        assert_eq!(reason, BadImageReason::WrongSize);
        assert_eq!(
            detail,
            "camera 'cam1': expected 512x256 (its dual_fisheye image_size), got 256x256"
        );
        // ERP cameras: any 2:1 size.
        let erp = Rig::from_file(DEEP360_RIG).expect("deep360 rig");
        let cam = &erp.cameras[2];
        for w in [64, 512, 1024] {
            assert!(decode_camera(cam, &raw(w, w / 2)).is_ok(), "{w}");
        }
        let (reason, detail) = decode_camera(cam, &png(384, 384)).expect_err("square");
        assert_eq!(reason, BadImageReason::WrongSize);
        assert_eq!(
            detail,
            "camera 'cam3': expected a 2:1 equirectangular panorama (width = 2 x height), got 384x384"
        );
    }
}
