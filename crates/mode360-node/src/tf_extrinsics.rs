//! `extrinsics_source: tf`: the rig's extrinsics read from `/tf_static` and `/tf` instead of
//! the rig YAML, for robots whose URDF (robot_state_publisher) already publishes the cameras.
//!
//! [`TfTree`] keeps the newest transform per child frame (`parent_from_child`, as
//! `TransformStamped` states it) and composes chains: `a_from_b = (root_from_a)^-1 root_from_b`
//! when `a` and `b` hang below the same root. [`wait_for_extrinsics`] listens on DDS until every
//! camera (and the output frame) can be placed in the rig frame, or names what is missing.

use super::dds::{create_subscription, dds_context, latched_qos, DdsOptions, SpunNode};
use super::error::NodeError;
use super::TF_STATIC_TOPIC;
use mode360_core::geometry::Rig;
use mode360_io::msgs::TFMessage;
use nalgebra::Isometry3;
use ros2_client::QosProfile;
use std::collections::HashMap;
use std::time::{Duration, Instant};

/// Topic of the dynamic transforms.
pub const TF_TOPIC: &str = "/tf";
/// Longest chain followed (guards against cycles in a broken tree).
const MAX_CHAIN: usize = 64;
/// Poll period while waiting for transforms.
const POLL: Duration = Duration::from_millis(20);

/// Transforms by child frame.
#[derive(Clone, Debug, Default)]
pub struct TfTree {
    parent_of: HashMap<String, (String, Isometry3<f64>)>,
}

impl TfTree {
    /// Adds (or replaces) every transform of `msg`.
    pub fn insert(&mut self, msg: &TFMessage) {
        for t in &msg.transforms {
            self.parent_of.insert(
                t.child_frame_id.clone(),
                (t.header.frame_id.clone(), t.transform.to_isometry()),
            );
        }
    }

    /// `(root, root_from_frame)`: the top of `frame`'s chain.
    fn root_from(&self, frame: &str) -> (String, Isometry3<f64>) {
        let mut current = frame.to_string();
        let mut root_from = Isometry3::identity();
        for _ in 0..MAX_CHAIN {
            match self.parent_of.get(&current) {
                Some((parent, parent_from_current)) => {
                    root_from = parent_from_current * root_from;
                    current = parent.clone();
                }
                None => break,
            }
        }
        (current, root_from)
    }

    /// `a_from_b`, or why not (the frames and the roots their chains reach).
    pub fn a_from_b(&self, a: &str, b: &str) -> Result<Isometry3<f64>, String> {
        if a == b {
            return Ok(Isometry3::identity());
        }
        let (root_a, root_from_a) = self.root_from(a);
        let (root_b, root_from_b) = self.root_from(b);
        if root_a != root_b {
            return Err(format!(
                "no transform from '{a}' to '{b}' ('{a}' reaches '{root_a}', '{b}' reaches '{root_b}')"
            ));
        }
        Ok(root_from_a.inverse() * root_from_b)
    }

    /// `rig` with every `rig_from_cam` (and `rig_from_output`) from this tree.
    pub fn apply_to(&self, rig: &Rig) -> Result<Rig, String> {
        let mut out = rig.clone();
        let mut missing = Vec::new();
        for cam in &mut out.cameras {
            match self.a_from_b(&rig.rig_frame, &cam.frame_id) {
                Ok(t) => cam.rig_from_cam = t,
                Err(e) => missing.push(e),
            }
        }
        match self.a_from_b(&rig.rig_frame, &rig.output_frame_id) {
            Ok(t) => out.rig_from_output = t,
            Err(e) => missing.push(e),
        }
        missing.dedup();
        if missing.is_empty() {
            Ok(out)
        } else {
            Err(missing.join("; "))
        }
    }
}

/// Listens on `/tf_static` and `/tf` until every camera of `rig` can be placed in the rig
/// frame, then returns the rig with those extrinsics; after `timeout`, an error naming the
/// frames without a transform.
pub fn wait_for_extrinsics(
    rig: &Rig,
    dds: &DdsOptions,
    timeout: Duration,
) -> Result<Rig, NodeError> {
    let context = dds_context(dds)?;
    let mut spun = SpunNode::new(&context, "/", "mode360_tf_listener")?;
    let tf_static =
        create_subscription::<TFMessage>(&mut spun.node, TF_STATIC_TOPIC, latched_qos())?;
    // best effort matches reliable and best-effort /tf publishers
    let tf = create_subscription::<TFMessage>(
        &mut spun.node,
        TF_TOPIC,
        QosProfile::subscription_default(),
    )?;
    let mut tree = TfTree::default();
    let t0 = Instant::now();
    let result = loop {
        for sub in [&tf_static, &tf] {
            while let Ok(Some((msg, _))) = sub.take() {
                tree.insert(&msg);
            }
        }
        match tree.apply_to(rig) {
            Ok(placed) => break Ok(placed),
            Err(problem) if t0.elapsed() >= timeout => {
                break Err(NodeError::Extrinsics {
                    problem: format!(
                        "extrinsics_source is tf, but within {:.1} s: {problem} (listening on {TF_STATIC_TOPIC} and {TF_TOPIC})",
                        timeout.as_secs_f64()
                    ),
                })
            }
            Err(_) => std::thread::sleep(POLL),
        }
    };
    drop(tf_static);
    drop(tf);
    spun.stop()?;
    drop(context);
    result
}

#[cfg(test)]
mod tests {
    use super::*;
    use mode360_io::msgs::{Header, Transform, TransformStamped};
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    fn stamped(parent: &str, child: &str, t: Isometry3<f64>) -> TransformStamped {
        TransformStamped {
            header: Header::new(0, parent),
            child_frame_id: child.into(),
            transform: Transform::from_isometry(&t),
        }
    }

    #[test]
    fn chains_compose_and_missing_frames_are_named() {
        let rack = Isometry3::from_parts(
            Translation3::new(0.2, 0.0, 1.5),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.3),
        );
        let cam = Isometry3::from_parts(
            Translation3::new(0.5, -0.5, 0.3),
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 0.1),
        );
        let mut tree = TfTree::default();
        tree.insert(&TFMessage {
            transforms: vec![
                stamped("base_link", "rack", rack),
                stamped("rack", "cam2_link", cam),
            ],
        });
        let got = tree.a_from_b("base_link", "cam2_link").unwrap();
        let want = rack * cam;
        assert!((got.to_homogeneous() - want.to_homogeneous()).abs().max() < 1e-12);
        let back = tree.a_from_b("cam2_link", "base_link").unwrap();
        assert!(
            (back.to_homogeneous() - want.inverse().to_homogeneous())
                .abs()
                .max()
                < 1e-12
        );
        let e = tree.a_from_b("base_link", "cam3_link").unwrap_err();
        assert!(
            e.contains("'base_link'") && e.contains("'cam3_link'"),
            "{e}"
        );
    }
}
