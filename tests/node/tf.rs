//! `extrinsics_source: tf` over DDS (loopback, own domain): a robot's `/tf_static` (a chain
//! base_link -> roof_rack -> camN_link, placed differently from the rig YAML) gives the rig the
//! node runs with; without a transform for one camera the node refuses to start and names the
//! frames.

use super::harness::loopback;
use crate::common::{TestResult, RIG_PATH};
use mode360::geometry::Rig;
use mode360::msgs::{Header, TFMessage, Transform, TransformStamped};
use mode360::node::params::ExtrinsicsSource;
use mode360::node::{create_publisher, dds_context, latched_qos, spawn_node, NodeParams, SpunNode};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// Unique domain of this test file.
const DOMAIN_ID: u16 = 50;

fn stamped(parent: &str, child: &str, t: &Isometry3<f64>) -> TransformStamped {
    TransformStamped {
        header: Header::new(0, parent),
        child_frame_id: child.into(),
        transform: Transform::from_isometry(t),
    }
}

fn params(tf_timeout_s: f64) -> NodeParams {
    NodeParams {
        rig_file: RIG_PATH.into(),
        output_width: 64,
        extrinsics_source: ExtrinsicsSource::Tf,
        tf_timeout_s,
        ..Default::default()
    }
}

#[test]
fn extrinsics_come_from_tf_and_a_missing_camera_is_named() -> TestResult {
    let _one_node_at_a_time = crate::common::live_node_lock();
    let yaml = Rig::from_file(RIG_PATH)?;
    let dds = loopback(DOMAIN_ID);
    // The robot's tree: a roof rack 0.3 m higher and turned 5° about z, cameras on it.
    let base_from_rack = Isometry3::from_parts(
        Translation3::new(0.1, 0.0, 0.3),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 5f64.to_radians()),
    );
    let rack_from_cam: Vec<Isometry3<f64>> = yaml.cameras.iter().map(|c| c.rig_from_cam).collect();
    let mut transforms = vec![stamped(&yaml.rig_frame, "roof_rack", &base_from_rack)];
    for (c, t) in yaml.cameras.iter().zip(&rack_from_cam) {
        transforms.push(stamped("roof_rack", &c.frame_id, t));
    }
    let context = dds_context(&dds)?;
    let mut robot = SpunNode::new(&context, "/", "robot_state_publisher")?;
    let tf_pub = create_publisher::<TFMessage>(&mut robot.node, "/tf_static", latched_qos())?;
    tf_pub
        .publish(TFMessage {
            transforms: transforms.clone(),
        })
        .map_err(|e| format!("{e:?}"))?;

    let node = spawn_node(params(10.0), dds.clone())?;
    for (i, c) in node.rig().cameras.iter().enumerate() {
        let want = base_from_rack * rack_from_cam[i];
        let err = (c.rig_from_cam.to_homogeneous() - want.to_homogeneous())
            .abs()
            .max();
        assert!(err < 1e-9, "camera {}: {err}", c.name);
        let moved = (c.rig_from_cam.translation.vector
            - yaml.cameras[i].rig_from_cam.translation.vector)
            .norm();
        assert!(moved > 0.25, "camera {} was not moved by TF", c.name);
    }
    node.shutdown()?;

    // A tree without camera 3: the node does not start, and says which frames.
    drop(tf_pub);
    robot.stop()?;
    let mut robot = SpunNode::new(&context, "/", "robot_state_publisher_2")?;
    let tf_pub = create_publisher::<TFMessage>(&mut robot.node, "/tf_static", latched_qos())?;
    let missing = yaml.cameras[2].frame_id.clone();
    tf_pub
        .publish(TFMessage {
            transforms: transforms
                .into_iter()
                .filter(|t| t.child_frame_id != missing)
                .collect(),
        })
        .map_err(|e| format!("{e:?}"))?;
    let err = match spawn_node(params(2.0), dds) {
        Ok(node) => {
            node.shutdown()?;
            return Err("the node started without camera 3's transform".into());
        }
        Err(e) => e.to_string(),
    };
    assert!(
        err.contains(&missing) && err.contains(&yaml.rig_frame) && err.contains("/tf_static"),
        "{err}"
    );
    drop(tf_pub);
    robot.stop()?;
    Ok(())
}
