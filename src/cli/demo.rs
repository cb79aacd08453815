//! `mode360 demo`: the node, fed by the bundled bag over loopback DDS, end to end.
//!
//! Starts the node in-process, plays the bag into it, receives `depth`, `points` and
//! `confidence`, writes them with the inputs to an output bag, writes PNG previews
//! (colour-mapped depth under the panorama; a top-down view of the point cloud) and scores the
//! received depth against the bag's ground truth.

use super::bundled_bag::{locate_bag, BUNDLED_BAG};
use super::estimator_args::EstimatorArgs;
use crate::viz::{colorize_range, depth_legend, stack_vertical};
use anyhow::{anyhow, Context, Result};
use clap::Args;
use image::Rgb;
use mode360_core::frame::{FloatImage, RgbImage, RigFrame};
use mode360_core::geometry::Rig;
use mode360_core::metrics::{depth_metrics, DepthMetrics, FrameAverage};
use mode360_estimator::EstimatorSpec;
use mode360_io::bag::{BagWriter, RigBagReader};
use mode360_io::msgs::image::{float_from_image_msg, image_msg_from_rgb};
use mode360_io::msgs::{Header, Image, PointCloud2};
use mode360_node::live_view::{DEFAULT_FOXGLOVE_PORT, FOXGLOVE_OFF};
use mode360_node::pipeline::decode_points;
use mode360_node::player::{play_bag, play_bag_until, PlayOptions};
use mode360_node::{
    create_subscription, dds_context, runtime, spawn_node, stop_flag_on_signals, DdsOptions,
    NodeHandle, NodeParams, SpunNode,
};
use ros2_client::qos::History;
use ros2_client::QosProfile;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// How long to wait for DDS discovery.
const DISCOVERY_TIMEOUT: Duration = Duration::from_secs(15);
/// How long to wait for outputs after the last frame was played.
const RECEIVE_TIMEOUT: Duration = Duration::from_secs(60);
const POLL: Duration = Duration::from_millis(20);
/// Top-down preview: image side in pixels and metres per pixel.
const TOP_VIEW_PX: u32 = 512;
const TOP_VIEW_M_PER_PX: f32 = 0.1;
/// Nearest range of the preview colour map, metres.
const PREVIEW_MIN_DEPTH_M: f32 = 1.0;

/// What to run.
#[derive(Clone, Debug)]
pub struct DemoOptions {
    pub bag: PathBuf,
    pub rig_file: PathBuf,
    /// The estimator and its weights.
    pub estimator: EstimatorSpec,
    pub out_bag: PathBuf,
    pub png_dir: PathBuf,
    /// Playback speed factor; slow enough that inference keeps up.
    pub rate: f64,
    pub dds: DdsOptions,
    /// Serve the Foxglove live view on this port and keep playing the bag, in a loop, after
    /// the demo until SIGINT or SIGTERM.
    pub foxglove_port: Option<u16>,
}

/// What came back.
#[derive(Clone, Debug)]
pub struct DemoSummary {
    pub frames_played: usize,
    pub depth_received: usize,
    pub points_received: usize,
    pub mean_points: f64,
    pub metrics: Option<DepthMetrics>,
}

/// A DDS read error of the listener, as an error of the demo.
fn dds_read(e: impl std::fmt::Display) -> anyhow::Error {
    anyhow!("reading the node's outputs from DDS: {e}")
}

/// Runs the demo (see the module docs).
pub fn run_demo(opts: &DemoOptions) -> Result<DemoSummary> {
    let (summary, node) = demo_with_node(opts)?;
    node.shutdown()?;
    Ok(summary)
}

/// The demo, leaving the node running.
fn demo_with_node(opts: &DemoOptions) -> Result<(DemoSummary, NodeHandle)> {
    let reader = RigBagReader::open(&opts.bag)?;
    let rig = reader.rig().clone();
    let max_depth_m = reader.max_depth_m()?;
    let frames: Vec<_> = reader.frames().collect::<Result<_, _>>()?;
    let width = frames
        .first()
        .map(|f| f.images[0].width() as usize)
        .unwrap_or(0);
    let params = NodeParams {
        rig_file: opts.rig_file.clone(),
        estimator: opts.estimator.clone(),
        output_width: width,
        max_depth_m,
        camera_timeout_s: 60.0,
        foxglove_port: opts.foxglove_port.unwrap_or(FOXGLOVE_OFF),
        ..Default::default()
    };
    let node = spawn_node(params, opts.dds.clone())?;
    let context = dds_context(&opts.dds)?;
    let mut listener = SpunNode::new(&context, "/", "mode360_demo_listener")?;
    let qos = QosProfile::publisher_default().history(History::KeepLast { depth: 10 });
    let depth_sub = create_subscription::<Image>(&mut listener.node, "/depth", qos.clone())?;
    let points_sub =
        create_subscription::<PointCloud2>(&mut listener.node, "/points", qos.clone())?;
    let conf_sub = create_subscription::<Image>(&mut listener.node, "/confidence", qos)?;
    // Wait for the node's publishers (ros2-client's match futures; a timeout here is not an
    // error: play_bag waits for the node's subscriptions below and reports what is missing).
    runtime()?.block_on(async {
        let _ = tokio::time::timeout(DISCOVERY_TIMEOUT, async {
            depth_sub.wait_for_publisher(&listener.node).await;
            points_sub.wait_for_publisher(&listener.node).await;
        })
        .await;
    });
    tracing::info!(
        "node up; playing {} frames of {}",
        frames.len(),
        opts.bag.display()
    );
    play_bag(&PlayOptions {
        input: opts.bag.clone(),
        rate: opts.rate,
        loops: 1,
        publish_clock: true,
        dds: opts.dds.clone(),
        wait_for_subscribers: Some(DISCOVERY_TIMEOUT),
        wait_topics: rig.cameras.iter().map(|c| c.topic.clone()).collect(),
    })?;
    let mut received = Received::default();
    let t0 = Instant::now();
    loop {
        while let Some((m, _)) = depth_sub.take().map_err(dds_read)? {
            received.depths.insert(m.header.stamp.to_nanos(), m);
        }
        while let Some((m, _)) = points_sub.take().map_err(dds_read)? {
            received.clouds.insert(m.header.stamp.to_nanos(), m);
        }
        while let Some((m, _)) = conf_sub.take().map_err(dds_read)? {
            received.confs.insert(m.header.stamp.to_nanos(), m);
        }
        let h = node.health();
        let settled = (h.groups_processed + h.groups_dropped) as usize >= frames.len()
            && received.depths.len() as u64 >= h.groups_processed
            && received.clouds.len() as u64 >= h.groups_processed;
        if settled || t0.elapsed() > RECEIVE_TIMEOUT {
            break;
        }
        std::thread::sleep(POLL);
    }
    listener.stop()?;

    write_output_bag(&opts.out_bag, &rig, &frames, &received)?;

    let (average, total_points) =
        score_and_preview(&opts.png_dir, &rig, &frames, &received, max_depth_m)?;
    let summary = DemoSummary {
        frames_played: frames.len(),
        depth_received: received.depths.len(),
        points_received: received.clouds.len(),
        mean_points: total_points as f64 / received.clouds.len().max(1) as f64,
        metrics: (average.frames() > 0).then(|| average.depth()),
    };
    Ok((summary, node))
}

/// What the demo's listener received from the node, by stamp.
#[derive(Default)]
struct Received {
    depths: BTreeMap<u64, Image>,
    clouds: BTreeMap<u64, PointCloud2>,
    confs: BTreeMap<u64, Image>,
}

/// The demo's output bag: the rig, the input images, then what the node published.
fn write_output_bag(
    path: &Path,
    rig: &Rig,
    frames: &[RigFrame],
    received: &Received,
) -> Result<()> {
    let mut out = BagWriter::create(path)?;
    out.write_metadata(
        mode360_io::bag::RIG_METADATA,
        BTreeMap::from([(mode360_io::bag::RIG_YAML_KEY.to_string(), rig.to_yaml())]),
    )?;
    for f in frames {
        for (cam, img) in rig.cameras.iter().zip(&f.images) {
            out.write(
                &cam.topic,
                f.stamp_ns,
                &image_msg_from_rgb(Header::new(f.stamp_ns, cam.frame_id.clone()), img),
            )?;
        }
    }
    for (stamp, m) in &received.depths {
        out.write("/mode360/depth", *stamp, m)?;
    }
    for (stamp, m) in &received.clouds {
        out.write("/mode360/points", *stamp, m)?;
    }
    for (stamp, m) in &received.confs {
        out.write("/mode360/confidence", *stamp, m)?;
    }
    out.finish()?;

    Ok(())
}

/// Scores the received depth against the frames' ground truth and writes the previews (depth
/// with its legend, the cloud from above) to `png_dir`; returns the metrics and the points
/// received in all.
fn score_and_preview(
    png_dir: &Path,
    rig: &Rig,
    frames: &[RigFrame],
    received: &Received,
    max_depth_m: f64,
) -> Result<(FrameAverage, usize)> {
    std::fs::create_dir_all(png_dir).with_context(|| format!("creating {}", png_dir.display()))?;
    let mut average = FrameAverage::default();
    let mut total_points = 0usize;
    for (n, f) in frames.iter().enumerate() {
        let Some(depth) = received.depths.get(&f.stamp_ns) else {
            continue;
        };
        let pred = float_from_image_msg(depth)
            .with_context(|| format!("the depth image at {} ns", f.stamp_ns))?;
        if let Some(gt) = &f.ground_truth {
            average.push(
                depth_metrics(&pred.data, &gt.data, max_depth_m)
                    .with_context(|| format!("metrics of the frame at {} ns", f.stamp_ns))?,
                None,
            );
        }
        let mut rows = vec![
            f.images[rig.reference].clone(),
            colorize_range(&pred, PREVIEW_MIN_DEPTH_M, max_depth_m as f32),
        ];
        if let Some(gt) = &f.ground_truth {
            rows.push(colorize_range(gt, PREVIEW_MIN_DEPTH_M, max_depth_m as f32));
        }
        rows.push(depth_legend(
            pred.width as u32,
            PREVIEW_MIN_DEPTH_M,
            max_depth_m as f32,
        ));
        let png = png_dir.join(format!("demo_depth_{n:03}.png"));
        stack_vertical(&rows)
            .save(&png)
            .with_context(|| format!("writing {}", png.display()))?;
        if let Some(points) = received.clouds.get(&f.stamp_ns).and_then(decode_points) {
            total_points += points.len();
            let png = png_dir.join(format!("demo_points_top_{n:03}.png"));
            top_view(&points)
                .save(&png)
                .with_context(|| format!("writing {}", png.display()))?;
        }
    }
    Ok((average, total_points))
}

/// Keeps the node's live view fed: plays the bag in a loop until SIGINT or SIGTERM.
fn serve_live_view(opts: &DemoOptions, port: u16) -> Result<()> {
    let rig = RigBagReader::open(&opts.bag)?.rig().clone();
    let stop = stop_flag_on_signals()?;
    println!(
        "Foxglove live view on ws://127.0.0.1:{port}: in Foxglove, Open connection > Foxglove \
         WebSocket, then import the layout launch_configs/foxglove_layout.json; replaying {} \
         in a loop, Ctrl-C to stop",
        opts.bag.display()
    );
    let summary = play_bag_until(
        &PlayOptions {
            input: opts.bag.clone(),
            rate: opts.rate,
            loops: usize::MAX,
            publish_clock: true,
            dds: opts.dds.clone(),
            wait_for_subscribers: Some(DISCOVERY_TIMEOUT),
            wait_topics: rig.cameras.iter().map(|c| c.topic.clone()).collect(),
        },
        &stop,
        |_| {},
    )?;
    tracing::info!(
        "live view stopped after {} loops of the bag",
        summary.loops_played
    );
    Ok(())
}

/// Top-down view of a cloud (x forward = up in the image, y left = left), coloured by the
/// points' own colours, the highest point winning each pixel.
fn top_view(points: &[mode360_node::pipeline::DecodedPoint]) -> RgbImage {
    let mut img = RgbImage::from_pixel(TOP_VIEW_PX, TOP_VIEW_PX, Rgb([20, 20, 20]));
    let mut height = FloatImage::filled(
        TOP_VIEW_PX as usize,
        TOP_VIEW_PX as usize,
        f32::NEG_INFINITY,
    );
    let c = TOP_VIEW_PX as f32 / 2.0;
    for p in points {
        let col = c - p.y_m / TOP_VIEW_M_PER_PX;
        let row = c - p.x_m / TOP_VIEW_M_PER_PX;
        if col < 0.0 || row < 0.0 || col >= TOP_VIEW_PX as f32 || row >= TOP_VIEW_PX as f32 {
            continue;
        }
        let (u, v) = (col as usize, row as usize);
        let k = v * TOP_VIEW_PX as usize + u;
        if p.z_m > height.data[k] {
            height.data[k] = p.z_m;
            img.put_pixel(u as u32, v as u32, Rgb(p.rgb));
        }
    }
    img
}

#[derive(Args)]
pub struct DemoArgs {
    /// Bag to play into the node (the bundled one is rendered into the data directory where
    /// neither the working directory nor an install has it).
    #[arg(long, default_value = BUNDLED_BAG)]
    pub bag: PathBuf,
    /// Rig calibration YAML.
    #[arg(long, default_value = "launch_configs/rig_deep360.yaml")]
    pub rig: PathBuf,
    #[command(flatten)]
    pub estimator: EstimatorArgs,
    /// Output bag: inputs plus what the node published.
    #[arg(long, default_value = "demo_out.mcap")]
    pub out: PathBuf,
    /// Folder for the preview PNGs.
    #[arg(long, default_value = "demo_out")]
    pub png_dir: PathBuf,
    /// Playback speed factor: slow enough that every frame is processed.
    #[arg(long, default_value_t = 0.03)]
    pub rate: f64,
    /// After the demo, serve the Foxglove live view and replay the bag in a loop until Ctrl-C.
    #[arg(long)]
    pub foxglove: bool,
    /// Port of the live view (with --foxglove).
    #[arg(long, default_value_t = DEFAULT_FOXGLOVE_PORT)]
    pub foxglove_port: u16,
}

/// `mode360 demo`: runs the demo and prints what came back and how good it was.
pub fn run(a: DemoArgs) -> Result<()> {
    let mut dds = DdsOptions::from_env()?;
    dds.loopback_only = true;
    let opts = DemoOptions {
        bag: locate_bag(&a.bag)?,
        rig_file: a.rig,
        estimator: a.estimator.spec(),
        out_bag: a.out.clone(),
        png_dir: a.png_dir.clone(),
        rate: a.rate,
        dds,
        foxglove_port: a.foxglove.then_some(a.foxglove_port),
    };
    let (s, node) = demo_with_node(&opts)?;
    println!(
        "played {} frames; received {} depth images and {} point clouds ({:.0} points each)",
        s.frames_played, s.depth_received, s.points_received, s.mean_points
    );
    println!("node: {}", node.health().summary());
    if let Some(m) = s.metrics {
        println!(
            "depth vs ground truth: MAE {:.3} m, RMSE {:.3} m, AbsRel {:.4}, SqRel {:.3}, SILog {:.3}, delta1 {:.2} %, delta2 {:.2} %, delta3 {:.2} %",
            m.mae_m, m.rmse_m, m.abs_rel, m.sq_rel_m, m.silog, m.delta1_pct, m.delta2_pct, m.delta3_pct
        );
    }
    println!(
        "wrote {} and previews in {}",
        a.out.display(),
        a.png_dir.display()
    );
    if let Some(port) = node.foxglove_port() {
        serve_live_view(&opts, port)?;
    }
    node.shutdown()?;
    Ok(())
}
