//! The node's parameters over ROS 2's parameter services (loopback, own domain), called by a
//! separate ros2-client node as `ros2 param` does: `get_parameters` reads the declared values,
//! `set_parameters` changes run-time parameters at once (the next depth image follows the new
//! maximum range, and `publish_points: false` stops the clouds of a subscribed `points`) and
//! refuses, with a reason, a parameter that cannot change while running and an invalid value,
//! while the node keeps running.

use super::harness::{loopback, render, Cameras};
use crate::common::{reliable_qos, TestResult, RIG_PATH};
use mode360::geometry::Rig;
use mode360::msgs::image::float_from_image_msg;
use mode360::msgs::{Image, PointCloud2};
use mode360::node::{create_subscription, dds_context, runtime, spawn_node, NodeParams, SpunNode};
use ros2_client::rcl_interfaces::{
    GetParametersRequest, GetParametersResponse, SetParametersRequest, SetParametersResponse,
};
use ros2_client::service::Client;
use ros2_client::{Name, Parameter, ParameterValue, ServiceMapping, ServiceTypeName};
use std::time::{Duration, Instant};

/// Unique domain of this test file.
const DOMAIN_ID: u16 = 49;
const WIDTH: usize = 64;
const SERVICE_TIMEOUT: Duration = Duration::from_secs(15);
const PHASE_TIMEOUT: Duration = Duration::from_secs(20);
const SEND_PERIOD: Duration = Duration::from_millis(200);
const STAMP_STEP_NS: u64 = 100_000_000;
/// A maximum range below every range in the scene: all of depth becomes +Inf.
const TINY_MAX_DEPTH_M: f64 = 0.01;

/// Calls `client` with `request`, waiting for the service first.
fn call<Req, Resp>(
    node: &ros2_client::Node,
    client: &Client<Req, Resp>,
    request: Req,
) -> Result<Resp, Box<dyn std::error::Error>>
where
    Req: ros2_client::Message + Clone + 'static,
    Resp: ros2_client::Message + 'static,
{
    let rt = runtime()?;
    rt.block_on(async {
        tokio::time::timeout(SERVICE_TIMEOUT, async {
            client.wait_for_service(node).await;
            client.async_call_service(request).await
        })
        .await
    })
    .map_err(|_| "parameter service timed out")?
    .map_err(|e| format!("{e:?}").into())
}

#[test]
fn parameters_are_served_changed_at_run_time_and_refused_with_a_reason() -> TestResult {
    let _one_node_at_a_time = crate::common::live_node_lock();
    let rig = Rig::from_file(RIG_PATH)?;
    let frame = render(&rig, 6, WIDTH)?;
    let dds = loopback(DOMAIN_ID);
    let node = spawn_node(
        NodeParams {
            rig_file: RIG_PATH.into(),
            output_width: WIDTH,
            min_confidence: 0.0,
            ..Default::default()
        },
        dds.clone(),
    )?;
    let context = dds_context(&dds)?;
    let mut client = SpunNode::new(&context, "/", "mode360_param_client")?;
    let qos = reliable_qos();
    let get = client
        .node
        .create_client::<GetParametersRequest, GetParametersResponse>(
            ServiceMapping::Enhanced,
            &Name::new("/mode360", "get_parameters")?,
            &ServiceTypeName::new("rcl_interfaces", "GetParameters"),
            qos.clone(),
            qos.clone(),
        )?;
    let set = client
        .node
        .create_client::<SetParametersRequest, SetParametersResponse>(
            ServiceMapping::Enhanced,
            &Name::new("/mode360", "set_parameters")?,
            &ServiceTypeName::new("rcl_interfaces", "SetParameters"),
            qos.clone(),
            qos,
        )?;

    // A points subscriber from the start: only the toggle below keeps clouds away.
    let points_sub =
        create_subscription::<PointCloud2>(&mut client.node, "/points", reliable_qos())?;

    // get: the declared values.
    let got = call(
        &client.node,
        &get,
        GetParametersRequest {
            names: vec![
                "output_width".into(),
                "max_depth_m".into(),
                "estimator".into(),
            ],
        },
    )?;
    let values: Vec<ParameterValue> = got.values.into_iter().map(ParameterValue::from).collect();
    assert_eq!(
        values,
        vec![
            ParameterValue::Integer(WIDTH as i64),
            ParameterValue::Double(1000.0),
            ParameterValue::String("ssmode".into()),
        ]
    );

    // set: one run-time change accepted, a start-up-only one and an invalid one refused.
    let set_one =
        |name: &str, value: ParameterValue| -> Result<(bool, String), Box<dyn std::error::Error>> {
            let r = call(
                &client.node,
                &set,
                SetParametersRequest {
                    parameter: vec![Parameter {
                        name: name.into(),
                        value,
                    }
                    .into()],
                },
            )?;
            let first = r.results.into_iter().next().ok_or("no result")?;
            Ok((first.successful, first.reason))
        };
    let (ok, reason) = set_one("output_width", ParameterValue::Integer(128))?;
    assert!(
        !ok && reason.contains("cannot change while the node runs"),
        "{reason}"
    );
    let (ok, reason) = set_one("min_confidence", ParameterValue::Double(1.5))?;
    assert!(!ok && reason.contains("0 to 1"), "{reason}");
    let (ok, reason) = set_one("max_depth_m", ParameterValue::Double(TINY_MAX_DEPTH_M))?;
    assert!(ok, "max_depth_m refused: {reason}");
    // An output toggle: no point cloud even with a subscriber.
    let (ok, reason) = set_one("publish_points", ParameterValue::Boolean(false))?;
    assert!(ok, "publish_points refused: {reason}");
    let got = call(
        &client.node,
        &get,
        GetParametersRequest {
            names: vec!["max_depth_m".into(), "output_width".into()],
        },
    )?;
    let values: Vec<ParameterValue> = got.values.into_iter().map(ParameterValue::from).collect();
    assert_eq!(
        values,
        vec![
            ParameterValue::Double(TINY_MAX_DEPTH_M),
            ParameterValue::Integer(WIDTH as i64)
        ]
    );

    // The next depth image follows the new maximum range: nothing is within 1 cm.
    let depth_sub = create_subscription::<Image>(&mut client.node, "/depth", reliable_qos())?;
    let mut cameras = Cameras::new(&mut client, &rig, frame, STAMP_STEP_NS)?;
    let t0 = Instant::now();
    let mut depth = None;
    while depth.is_none() && t0.elapsed() < PHASE_TIMEOUT {
        cameras.send_all()?;
        std::thread::sleep(SEND_PERIOD);
        while let Some((m, _)) = depth_sub.take()? {
            depth = Some(m);
        }
    }
    let range = float_from_image_msg(&depth.ok_or("no depth after the parameter change")?)?;
    let measured = range.data.iter().filter(|r| r.is_finite()).count();
    let beyond = range.data.iter().filter(|r| **r == f32::INFINITY).count();
    assert_eq!(measured, 0, "ranges within {TINY_MAX_DEPTH_M} m");
    assert!(
        beyond > range.data.len() / 2,
        "{beyond} of {} +Inf",
        range.data.len()
    );
    assert!(!node.is_finished(), "the node stopped");
    assert!(
        points_sub.take()?.is_none(),
        "a cloud with publish_points false"
    );
    let h = node.health();
    assert!(
        h.groups_processed >= 1 && h.clouds_skipped == h.groups_processed,
        "{h:?}"
    );
    drop(points_sub);
    drop(cameras);
    drop(depth_sub);
    drop(get);
    drop(set);
    client.stop()?;
    node.shutdown()?;
    Ok(())
}
