//! Which camera pairs stage 1 matches ([`PairChoice`]): every pair, or pairs named by their
//! cameras, and the names the estimator reports them by.

use crate::EstimatorError;
use mode360_core::geometry::{CameraPair, Rig};

/// Separator of the two camera names of a pair in [`PairChoice::parse`].
pub const PAIR_SEPARATOR: char = '-';

/// Which camera pairs stage 1 matches.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum PairChoice {
    /// Every pair of cameras whose views overlap.
    #[default]
    All,
    /// These pairs, by camera name, the left camera first.
    Named(Vec<(String, String)>),
}

impl PairChoice {
    /// `all`, or comma-separated pairs of camera names, `left-right` (`front-back,left-right`).
    pub fn parse(text: &str) -> Result<Self, EstimatorError> {
        let text = text.trim();
        if text.is_empty() || text == "all" {
            return Ok(Self::All);
        }
        let bad = |problem: String| EstimatorError::BadConfig {
            field: "pairs".to_string(),
            problem,
        };
        let pairs = text
            .split(',')
            .map(|item| {
                let item = item.trim();
                let (l, r) = item.split_once(PAIR_SEPARATOR).ok_or_else(|| {
                    bad(format!(
                        "'{item}' is not a pair: write two camera names as left{PAIR_SEPARATOR}right"
                    ))
                })?;
                if l.is_empty() || r.is_empty() || l == r {
                    return Err(bad(format!("'{item}' does not name two different cameras")));
                }
                Ok((l.to_string(), r.to_string()))
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self::Named(pairs))
    }

    /// The pairs of `rig` by index; an error naming an unknown camera.
    pub(super) fn resolve(&self, rig: &Rig) -> Result<Vec<CameraPair>, EstimatorError> {
        match self {
            Self::All => Ok(CameraPair::all(rig.cameras.len())),
            Self::Named(names) => names
                .iter()
                .map(|(l, r)| {
                    let index = |name: &str| {
                        rig.cameras
                            .iter()
                            .position(|c| c.name == name)
                            .ok_or_else(|| EstimatorError::BadConfig {
                                field: "pairs".to_string(),
                                problem: format!(
                                    "no camera '{name}' in the rig (cameras: {})",
                                    camera_names(rig)
                                ),
                            })
                    };
                    Ok(CameraPair {
                        left: index(l)?,
                        right: index(r)?,
                    })
                })
                .collect(),
        }
    }
}

impl std::fmt::Display for PairChoice {
    /// The text [`PairChoice::parse`] reads back: `all`, or `left-right` pairs joined by commas.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::All => f.write_str("all"),
            Self::Named(pairs) => {
                let text: Vec<String> = pairs
                    .iter()
                    .map(|(l, r)| format!("{l}{PAIR_SEPARATOR}{r}"))
                    .collect();
                f.write_str(&text.join(","))
            }
        }
    }
}

/// The rig's camera names, comma-separated (for errors).
pub(super) fn camera_names(rig: &Rig) -> String {
    rig.cameras
        .iter()
        .map(|c| c.name.as_str())
        .collect::<Vec<_>>()
        .join(", ")
}

/// A pair's name, `left-right` by camera name.
pub(super) fn pair_name(rig: &Rig, pair: CameraPair) -> String {
    format!(
        "{}{PAIR_SEPARATOR}{}",
        rig.cameras[pair.left].name, rig.cameras[pair.right].name
    )
}
