//! The node's DDS endpoints, created once on the DDS thread: the node itself (with its
//! parameter services), the output publishers, `/tf_static` (sent at once) and
//! `/diagnostics`, the camera subscriptions (raw or compressed per camera) and `/clock`. The
//! QoS of each is the node's default for its kind, then the parameters' overrides.

use super::dds::{
    clock_qos, create_publisher, create_subscription, dds_context, latched_qos, output_qos,
    sensor_qos, DdsOptions, SpunNode,
};
use super::error::dds_err;
use super::outputs::{Output, OutputType, PerOutput};
use super::params::{ImageTransport, NodeParams};
use super::qos_overrides::QosEntity;
use super::ros_params::{node_options, RuntimeParams};
use super::rosout::{attach, logger_name, RosoutGuard};
use super::topics::{camera_topic, output_topic, CLOCK_TOPIC, DIAGNOSTICS_TOPIC, TF_STATIC_TOPIC};
use super::worker::{OutputPublisher, OutputPublishers};
use super::NodeError;
use mode360_core::geometry::Rig;
use mode360_io::bag::rig_tf_static_at;
use mode360_io::msgs::{Clock, CompressedImage, DiagnosticArray, Image, PointCloud2, TFMessage};
use ros2_client::{Context, Publisher};
use std::sync::Arc;

/// Everything the DDS thread sets up before it reports ready.
pub(super) struct DdsSetup {
    pub(super) context: Context,
    pub(super) spun: SpunNode,
    pub(super) publishers: OutputPublishers,
    /// The publishers built only while subscribed, whose subscribers the DDS thread counts
    /// (shared with `publishers`).
    pub(super) points_pub: Arc<Publisher<PointCloud2>>,
    pub(super) compressed_pub: Arc<Publisher<CompressedImage>>,
    /// `None` with `publish_tf: false`.
    pub(super) tf_static: Option<Publisher<TFMessage>>,
    pub(super) diagnostics: Publisher<DiagnosticArray>,
    pub(super) raw_subs: Vec<(usize, ros2_client::Subscription<Image>)>,
    pub(super) compressed_subs: Vec<(usize, ros2_client::Subscription<CompressedImage>)>,
    pub(super) clock_sub: Option<ros2_client::Subscription<Clock>>,
    /// The node's log records on `/rosout` while this lives.
    pub(super) rosout: RosoutGuard,
}

pub(super) fn dds_setup(
    params: &NodeParams,
    dds: &DdsOptions,
    rig: &Rig,
    runtime: RuntimeParams,
) -> Result<DdsSetup, NodeError> {
    let context = dds_context(dds)?;
    let options = node_options(params, runtime);
    let mut spun = SpunNode::with_options(&context, &params.namespace, &params.node_name, options)?;
    // QoS of each endpoint: the node's default for its kind, then the parameters' overrides.
    let pub_qos = |t: &str, base| params.qos_overrides.qos(t, QosEntity::Publisher, base);
    let sub_qos = |t: &str, base| params.qos_overrides.qos(t, QosEntity::Subscription, base);
    let node = &mut spun.node;
    let (publishers, points_pub, compressed_pub) = output_publishers(node, params)?;
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
            .publish(rig_tf_static_at(
                rig,
                tf_static_stamp_ns(params.use_sim_time),
            ))
            .map_err(|e| format!("{e:?}"))
            .map_err(dds_err("publishing /tf_static"))?;
    }
    let rosout = attach(
        spun.node.logging_handle(),
        logger_name(&params.namespace, &params.node_name),
    );
    Ok(DdsSetup {
        context,
        spun,
        publishers,
        points_pub,
        compressed_pub,
        tf_static,
        diagnostics,
        raw_subs,
        compressed_subs,
        clock_sub,
        rosout,
    })
}

/// The publishers of the output table (topic after namespace and remapping, QoS of outputs
/// with the parameters' overrides), and the two that the DDS thread watches for subscribers.
#[allow(clippy::type_complexity)]
fn output_publishers(
    node: &mut ros2_client::Node,
    params: &NodeParams,
) -> Result<
    (
        OutputPublishers,
        Arc<Publisher<PointCloud2>>,
        Arc<Publisher<CompressedImage>>,
    ),
    NodeError,
> {
    let publishers = PerOutput::try_new(|o: Output| {
        let t = output_topic(params, o.topic());
        let q = params
            .qos_overrides
            .qos(&t, QosEntity::Publisher, output_qos());
        Ok::<_, NodeError>(match o.message_type() {
            OutputType::Image => OutputPublisher::Image(Arc::new(create_publisher(node, &t, q)?)),
            OutputType::CompressedImage => {
                OutputPublisher::CompressedImage(Arc::new(create_publisher(node, &t, q)?))
            }
            OutputType::PointCloud => {
                OutputPublisher::PointCloud(Arc::new(create_publisher(node, &t, q)?))
            }
        })
    })?;
    let (OutputPublisher::PointCloud(points), OutputPublisher::CompressedImage(compressed)) = (
        &publishers[Output::Points],
        &publishers[Output::CompressedDepth],
    ) else {
        return Err(NodeError::Dds {
            what: "the output table".into(),
            problem: "points and compressed depth are not PointCloud2 and CompressedImage".into(),
        });
    };
    let (points, compressed) = (points.clone(), compressed.clone());
    Ok((publishers, points, compressed))
}

/// The stamp of the node's `/tf_static`: the wall clock at start, or 0 with simulated time
/// (no `/clock` has arrived when it is sent; tf2 uses static transforms at any time).
fn tf_static_stamp_ns(use_sim_time: bool) -> u64 {
    if use_sim_time {
        0
    } else {
        super::clock::system_now_ns()
    }
}
