//! The node's parameters as ROS 2 parameters: declared with ros2-client, so that
//! `ros2 param list/get/set/dump` work on the node.
//!
//! Every parameter of [`PARAMETERS`] is declared with its current value. The ones marked
//! `runtime` there take effect at once when set ([`RuntimeParams`], read by the
//! inference worker before each group); setting any other one is refused with the reason
//! (restart the node with the new value). A value the node would refuse at start is refused
//! at run time with the same reason, and the node keeps running. `describe_parameters`
//! answers with [`param_docs`]' descriptors (the README's description, range, read-only).

use super::param_docs;
use super::param_table::{parameter, runtime_parameter_names, ParamValue, PARAMETERS};
use super::params::NodeParams;
use super::pipeline::PipelineParams;
use ros2_client::{NodeOptions, ParameterValue};
use std::sync::{Arc, Mutex};

/// Which optional outputs are switched on (each is also built only while subscribed).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OutputToggles {
    pub points: bool,
    pub confidence: bool,
    pub compressed_depth: bool,
}

impl OutputToggles {
    /// The toggles of `p`.
    pub fn of(p: &NodeParams) -> Self {
        Self {
            points: p.publish_points,
            confidence: p.publish_confidence,
            compressed_depth: p.publish_compressed_depth,
        }
    }
}

/// What may change while the node runs: the pipeline's settings and the output toggles.
#[derive(Clone, Debug, PartialEq)]
pub struct RuntimeSettings {
    pub pipeline: PipelineParams,
    pub outputs: OutputToggles,
}

/// The run-time settings, shared between the parameter services and the worker.
pub type RuntimeParams = Arc<Mutex<RuntimeSettings>>;

/// Every parameter of [`PARAMETERS`] with its ROS 2 value in `p`.
pub fn declared_parameters(p: &NodeParams) -> Vec<(&'static str, ParameterValue)> {
    PARAMETERS
        .iter()
        .map(|spec| {
            let value = match (spec.get)(p) {
                ParamValue::String(s) => ParameterValue::String(s),
                ParamValue::Double(d) => ParameterValue::Double(d),
                ParamValue::Integer(i) => ParameterValue::Integer(i),
                ParamValue::Bool(b) => ParameterValue::Boolean(b),
            };
            (spec.name, value)
        })
        .collect()
}

/// A ROS 2 value as the text [`NodeParams::set`] parses (`None` for arrays and unset).
fn as_text(value: &ParameterValue) -> Option<String> {
    match value {
        ParameterValue::Boolean(b) => Some(b.to_string()),
        ParameterValue::Integer(i) => Some(i.to_string()),
        ParameterValue::Double(d) => Some(d.to_string()),
        ParameterValue::String(s) => Some(s.clone()),
        _ => None,
    }
}

/// Checks that `name = value` may be set now: a run-time parameter with a valid value.
fn validate(base: &NodeParams, name: &str, value: &ParameterValue) -> Result<NodeParams, String> {
    if !parameter(name).is_some_and(|spec| spec.runtime) {
        // Declaring sets each parameter to its value once; only a change is refused.
        let unchanged = declared_parameters(base)
            .into_iter()
            .any(|(n, v)| n == name && &v == value);
        if unchanged {
            return Ok(base.clone());
        }
        return Err(format!(
            "'{name}' cannot change while the node runs (restart it with the new value); \
             these can: {}",
            runtime_parameter_names().collect::<Vec<_>>().join(", ")
        ));
    }
    let text = as_text(value).ok_or_else(|| format!("'{name}': expected a single value"))?;
    let mut next = base.clone();
    next.set(name, &text).map_err(|e| e.to_string())?;
    Ok(next)
}

/// Node options declaring every parameter of `params`, with the validator and the action
/// that updates `runtime`.
pub fn node_options(params: &NodeParams, runtime: RuntimeParams) -> NodeOptions {
    let mut options = NodeOptions::new()
        .enable_rosout(true)
        .start_parameter_services(true);
    for (name, value) in declared_parameters(params) {
        options = options.declare_parameter(name, value);
    }
    for descriptor in param_docs::descriptors() {
        options = options.describe_parameter(descriptor);
    }
    let current = Arc::new(Mutex::new(params.clone()));
    let for_validator = current.clone();
    options
        .parameter_validator(Box::new(move |name, value| {
            let base = for_validator
                .lock()
                .map_err(|_| "parameters lock poisoned")?;
            validate(&base, name, value).map(|_| ())
        }))
        .parameter_set_action(Box::new(move |name, value| {
            let mut base = current.lock().map_err(|_| "parameters lock poisoned")?;
            let next = validate(&base, name, value)?;
            let mut settings = runtime.lock().map_err(|_| "settings lock poisoned")?;
            // Only run-time parameters pass `validate`, so the rest stays as it was.
            settings.pipeline = next.pipeline_params();
            settings.outputs = OutputToggles::of(&next);
            tracing::info!("parameter {name} = {value:?}");
            *base = next;
            Ok(())
        }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::FarValue;

    #[test]
    fn runtime_parameters_validate_like_the_params_file() {
        let p = NodeParams::default();
        let names: Vec<&str> = declared_parameters(&p).iter().map(|(n, _)| *n).collect();
        for r in runtime_parameter_names() {
            assert!(names.contains(&r), "{r} is not declared");
        }
        let next = validate(&p, "min_confidence", &ParameterValue::Double(0.4)).unwrap();
        assert_eq!(next.min_confidence, 0.4);
        let e = validate(&p, "min_confidence", &ParameterValue::Double(1.4)).unwrap_err();
        assert!(e.contains("0 to 1"), "{e}");
        let e = validate(&p, "output_width", &ParameterValue::Integer(128)).unwrap_err();
        // Declaring (setting the current value) is not a change.
        assert!(validate(&p, "output_width", &ParameterValue::Integer(512)).is_ok());
        assert!(e.contains("cannot change while the node runs"), "{e}");
        let e = validate(
            &p,
            "depth_far_value",
            &ParameterValue::String("zero".into()),
        )
        .unwrap_err();
        assert!(e.contains("inf, max_depth"), "{e}");
        let next = validate(
            &p,
            "depth_far_value",
            &ParameterValue::String("max_depth".into()),
        )
        .unwrap();
        assert_eq!(next.far_value, FarValue::MaxDepth);
    }
}
