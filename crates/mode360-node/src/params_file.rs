//! ROS 2 params files: `node_name: {ros__parameters: {...}}`, where the key may be the node
//! name, `/node_name`, `/ns/node_name`, `/ns/**` or the wildcard `/**`; nested maps become
//! dotted names (`sync: {tolerance_s: 0.01}` is `sync.tolerance_s`).

use super::params::{NodeParams, ParamsError, ROS_PARAMETERS_KEY, WILDCARD_NODE_KEY};

/// The parameters in `text` (a params file) that apply to this node, as dotted names
/// and YAML scalar text, wildcard entries first so that named entries override them.
pub(super) fn file_parameters(
    node: &NodeParams,
    text: &str,
    file: &str,
) -> Result<Vec<(String, String)>, ParamsError> {
    let err = |problem: String| ParamsError::File {
        file: file.to_string(),
        problem,
    };
    let doc: serde_yaml::Value =
        serde_yaml::from_str(text).map_err(|e| err(format!("not YAML: {e}")))?;
    let map = doc
        .as_mapping()
        .ok_or_else(|| err("top level must map node names to ros__parameters".into()))?;
    let fq = node.fully_qualified_name();
    let matches = |key: &str| -> Option<u8> {
        if key == WILDCARD_NODE_KEY {
            Some(0)
        } else if key == node.node_name
            || key.trim_start_matches('/') == node.node_name
            || key == fq
            || key == format!("{}/**", node.namespace.trim_end_matches('/'))
        {
            Some(1)
        } else {
            None
        }
    };
    let mut entries: Vec<(u8, &serde_yaml::Value)> = Vec::new();
    for (key, value) in map {
        let key = key
            .as_str()
            .ok_or_else(|| err("node keys must be strings".into()))?;
        if let Some(rank) = matches(key) {
            entries.push((rank, value));
        }
    }
    entries.sort_by_key(|(rank, _)| *rank);
    let mut out = Vec::new();
    for (_, node_value) in entries {
        let params = node_value
            .get(ROS_PARAMETERS_KEY)
            .ok_or_else(|| err(format!("node entry has no '{ROS_PARAMETERS_KEY}' key")))?;
        flatten("", params, &mut out).map_err(err)?;
    }
    Ok(out)
}

/// Dotted names and scalar text of a nested YAML map.
fn flatten(
    prefix: &str,
    value: &serde_yaml::Value,
    out: &mut Vec<(String, String)>,
) -> Result<(), String> {
    use serde_yaml::Value;
    let scalar = match value {
        Value::Mapping(map) => {
            for (k, v) in map {
                let key = k
                    .as_str()
                    .ok_or_else(|| format!("parameter names must be strings (under '{prefix}')"))?;
                let name = if prefix.is_empty() {
                    key.to_string()
                } else {
                    format!("{prefix}.{key}")
                };
                flatten(&name, v, out)?;
            }
            return Ok(());
        }
        Value::Bool(b) => b.to_string(),
        Value::Number(n) => n.to_string(),
        Value::String(s) => s.clone(),
        Value::Null => return Err(format!("parameter '{prefix}' has no value")),
        Value::Sequence(_) | Value::Tagged(_) => {
            return Err(format!("parameter '{prefix}': lists are not supported"))
        }
    };
    out.push((prefix.to_string(), scalar));
    Ok(())
}
