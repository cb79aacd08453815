//! Whether a rig calibration fits recorded data: the same cameras, in the same order, with the
//! same topics and projections (a replacement calibration may change poses only).

use super::rig::Rig;

/// How a replacement rig does not fit the cameras of the data it is meant for.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum RigMismatch {
    #[error("has {given} cameras, the data has {expected}")]
    CameraCount { expected: usize, given: usize },
    #[error("camera {index} is '{given}', the data's camera {index} is '{expected}'")]
    Name {
        index: usize,
        expected: String,
        given: String,
    },
    #[error("camera '{camera}': field '{field}' is '{given}', the data's is '{expected}'")]
    Field {
        camera: String,
        field: &'static str,
        expected: String,
        given: String,
    },
}

/// `Ok` when `given` has `expected`'s cameras in the same order with the same names, topics and
/// projections (model and image size); poses, frames and the output may differ.
pub fn check_same_cameras(expected: &Rig, given: &Rig) -> Result<(), RigMismatch> {
    if expected.cameras.len() != given.cameras.len() {
        return Err(RigMismatch::CameraCount {
            expected: expected.cameras.len(),
            given: given.cameras.len(),
        });
    }
    for (i, (e, g)) in expected.cameras.iter().zip(&given.cameras).enumerate() {
        if e.name != g.name {
            return Err(RigMismatch::Name {
                index: i + 1,
                expected: e.name.clone(),
                given: g.name.clone(),
            });
        }
        let field = |field: &'static str, expected: String, given: String| RigMismatch::Field {
            camera: e.name.clone(),
            field,
            expected,
            given,
        };
        if e.topic != g.topic {
            return Err(field("topic", e.topic.clone(), g.topic.clone()));
        }
        if e.projection.name() != g.projection.name()
            || e.projection.image_size() != g.projection.image_size()
        {
            let describe = |r: &super::rig::RigCamera| match r.projection.image_size() {
                Some(s) => format!("{} {}x{}", r.projection.name(), s.width, s.height),
                None => r.projection.name().to_string(),
            };
            return Err(field("projection", describe(e), describe(g)));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const RIG: &str = "cameras:\n  - {name: a, topic: /a, frame_id: a, rig_from_cam: {translation: [0, 0, 1], rotation_xyzw: [0, 0, 0, 1]}}\n  - {name: b, topic: /b, frame_id: b, rig_from_cam: {translation: [0, 1, 1], rotation_xyzw: [0, 0, 0, 1]}}\n";

    #[test]
    fn poses_may_differ_cameras_may_not() {
        let bag = Rig::from_yaml_str(RIG, "bag").unwrap();
        let moved = Rig::from_yaml_str(&RIG.replace("[0, 1, 1]", "[0, 1.1, 1]"), "f").unwrap();
        assert_eq!(check_same_cameras(&bag, &moved), Ok(()));
        let renamed = Rig::from_yaml_str(&RIG.replace("name: b", "name: c"), "f").unwrap();
        let e = check_same_cameras(&bag, &renamed).unwrap_err().to_string();
        assert!(e.contains("'c'") && e.contains("'b'"), "{e}");
        let retopic = Rig::from_yaml_str(&RIG.replace("topic: /b", "topic: /x"), "f").unwrap();
        let e = check_same_cameras(&bag, &retopic).unwrap_err().to_string();
        assert!(e.contains("camera 'b'") && e.contains("topic"), "{e}");
        let fewer = bag.subset(&[0, 1]).unwrap();
        assert_eq!(check_same_cameras(&bag, &fewer), Ok(()));
    }
}
