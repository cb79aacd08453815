//! What `ros2 param describe` shows for each parameter: the description is the meaning
//! column of the README's parameter table (one text for the reader of the README and the user
//! of the running node; the README is embedded at compile time), the constraints and range
//! come from [`Constraint`], and a parameter that only takes effect at start is read-only.

use super::param_table::{Constraint, ParamSpec, PARAMETERS};
use ros2_client::{NumericRange, ParameterDescriptor};

/// The README, whose `### Parameters` table documents every parameter.
const README: &str = include_str!("../../../README.md");
/// The heading above the parameter table.
const PARAMETERS_HEADING: &str = "### Parameters";
/// Table lines before the first row: the header and the separator.
const TABLE_HEADER_LINES: usize = 2;
/// Largest TCP port.
const MAX_PORT: i64 = 65_535;

/// One row of the README's parameter table: the names it documents (`a`, or `a`, `b`, `c`
/// for parameters that share a row), and its type, default and meaning cells as written.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ParamRow {
    pub names: Vec<String>,
    pub type_cell: String,
    pub default_cell: String,
    pub meaning: String,
}

/// The rows of the parameter table in the README text `readme`.
pub fn parameter_rows(readme: &str) -> Vec<ParamRow> {
    readme
        .lines()
        .skip_while(|l| !l.starts_with(PARAMETERS_HEADING))
        .skip_while(|l| !l.starts_with('|'))
        .take_while(|l| l.starts_with('|'))
        .skip(TABLE_HEADER_LINES)
        .filter_map(|line| {
            let cells: Vec<&str> = line.trim_matches('|').split(" | ").map(str::trim).collect();
            let [names, type_cell, default_cell, meaning @ ..] = cells.as_slice() else {
                return None;
            };
            Some(ParamRow {
                names: names
                    .split(", ")
                    .map(|n| n.trim_matches('`').to_string())
                    .collect(),
                type_cell: type_cell.to_string(),
                default_cell: default_cell.to_string(),
                meaning: meaning.join(" | "),
            })
        })
        .collect()
}

/// The README's description of parameter `name`, without Markdown's backticks and links.
pub fn description(name: &str) -> Option<String> {
    let row = parameter_rows(README)
        .into_iter()
        .find(|row| row.names.iter().any(|n| n == name))?;
    Some(plain_text(&row.meaning))
}

/// `text` without backticks, and `[label](target)` links as their label.
fn plain_text(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(open) = rest.find('[') {
        let (before, after) = rest.split_at(open);
        out.push_str(before);
        match after.find("](").and_then(|mid| {
            after[mid..]
                .find(')')
                .map(|close| (&after[1..mid], mid + close + 1))
        }) {
            Some((label, end)) => {
                out.push_str(label);
                rest = &after[end..];
            }
            None => {
                out.push('[');
                rest = &after[1..];
            }
        }
    }
    out.push_str(rest);
    out.replace('`', "")
}

/// The descriptor of `spec` (its type is filled in from the value by ros2-client).
pub fn descriptor(spec: &ParamSpec) -> ParameterDescriptor {
    let (range, constraint) = match spec.constraint {
        Constraint::None => (NumericRange::NotSpecified, ""),
        Constraint::Positive => (NumericRange::NotSpecified, "greater than 0"),
        Constraint::UnitInterval => (
            NumericRange::FloatingPointRange {
                from_value: 0.0,
                to_value: 1.0,
                step: 0.0,
            },
            "from 0 to 1",
        ),
        Constraint::Port => (
            NumericRange::IntegerRange {
                from_value: 0,
                to_value: MAX_PORT,
                step: 1,
            },
            "a TCP port; 0: off",
        ),
    };
    let when = if spec.runtime {
        "changes at run time"
    } else {
        "read at start: restart the node to change it"
    };
    let additional_constraints = if constraint.is_empty() {
        when.to_string()
    } else {
        format!("{constraint}; {when}")
    };
    ParameterDescriptor {
        name: spec.name.to_string(),
        param_type: ros2_client::parameters::ParameterType::NotSet,
        description: description(spec.name).unwrap_or_default(),
        additional_constraints,
        read_only: !spec.runtime,
        dynamic_typing: false,
        range,
    }
}

/// The descriptors of every parameter of [`PARAMETERS`].
pub fn descriptors() -> Vec<ParameterDescriptor> {
    PARAMETERS.iter().map(descriptor).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::param_table::parameter;
    use crate::params::NodeParams;
    use crate::qos_overrides::QOS_OVERRIDES_PREFIX;
    use std::collections::BTreeSet;

    #[test]
    fn every_parameter_has_the_readme_meaning_as_its_description() {
        for spec in PARAMETERS {
            let d = descriptor(spec);
            assert!(
                d.description.len() > 10,
                "{}: '{}'",
                spec.name,
                d.description
            );
            assert!(!d.description.contains('`'), "{}", d.description);
            assert_eq!(d.read_only, !spec.runtime, "{}", spec.name);
        }
        let rig = description("rig_file").unwrap_or_default();
        assert_eq!(rig, "rig calibration YAML");
        // A shared row describes each of its parameters; links keep their label.
        assert!(description("publish_confidence")
            .is_some_and(|d| d.starts_with("output toggles (run time)")));
        let device = description("device").unwrap_or_default();
        assert!(
            device.contains("see GPU builds)") && !device.contains("]("),
            "{device}"
        );
    }

    #[test]
    fn ranges_follow_the_constraints() {
        let min_confidence = parameter("min_confidence").map(descriptor);
        assert!(matches!(
            min_confidence.map(|d| d.range),
            Some(NumericRange::FloatingPointRange { from_value, to_value, .. })
                if from_value == 0.0 && to_value == 1.0
        ));
        let port = parameter("foxglove_port").map(descriptor);
        assert!(matches!(
            port.map(|d| d.range),
            Some(NumericRange::IntegerRange {
                from_value: 0,
                to_value: MAX_PORT,
                ..
            })
        ));
        let width = parameter("output_width").map(descriptor);
        assert!(width.is_some_and(|d| d.read_only
            && d.additional_constraints
                .starts_with("greater than 0; read at start")));
    }

    #[test]
    fn links_become_their_labels() {
        assert_eq!(plain_text("a [b](#c) d [e"), "a b d [e");
        assert_eq!(plain_text("`x` [y](z)"), "x y");
    }

    /// The README's parameter table lists exactly the table's parameters (plus the families),
    /// each with its type and default.
    #[test]
    fn readme_parameter_table_matches_the_table() {
        let (path, text) = ("README.md", README);
        let rows = parameter_rows(text);
        assert!(!rows.is_empty(), "{path}: no parameter table");
        let defaults = NodeParams::default();
        let mut documented = BTreeSet::new();
        for row in &rows {
            for name in &row.names {
                if name.starts_with(QOS_OVERRIDES_PREFIX) {
                    continue;
                }
                let spec = parameter(name)
                    .unwrap_or_else(|| panic!("{path}: '{name}' is not a node parameter"));
                documented.insert(spec.name);
                assert!(
                    row.type_cell.starts_with(spec.param_type().as_str()),
                    "{path}: {name} has type '{}', the node's is {}",
                    row.type_cell,
                    spec.param_type().as_str()
                );
                let default = (spec.get)(&defaults).to_text();
                let cell = row.default_cell.trim_matches('`');
                let cell = if cell == "\"\"" { "" } else { cell };
                assert_eq!(cell, default, "{path}: default of {name}");
            }
        }
        let all: BTreeSet<&str> = PARAMETERS.iter().map(|s| s.name).collect();
        assert_eq!(documented, all, "{path}: parameters documented");
    }
}
