//! SSMODE weight files: safetensors with the [`SsmodeConfig`] as JSON in the header metadata
//! under [`CONFIG_METADATA_KEY`]. Tensor names are the `VarBuilder` paths of the network
//! (`feature.layer1.0.conv1.weight`, `aggregation.hourglass0.conv1.weight`, ...).

use std::collections::HashMap;
use std::path::Path;

use candle_core::{DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};

use super::fine_head::FINE_HEAD_KEY;
use super::readout::{Readout, RECORDED_KEYS};
use super::{FusionConfig, ModelError, SsmodeConfig};

/// Header metadata key holding the config JSON.
pub const CONFIG_METADATA_KEY: &str = "mode360.config";
/// Header metadata key holding a PSMODE fusion network's config JSON ([`FusionConfig`]).
pub const FUSION_CONFIG_METADATA_KEY: &str = "mode360.fusion_config";

/// Writes every variable of `varmap` and `cfg` (as JSON metadata) to `path`.
pub fn save_weights(
    varmap: &VarMap,
    cfg: &SsmodeConfig,
    path: impl AsRef<Path>,
) -> Result<(), ModelError> {
    save_with_config(varmap, cfg, CONFIG_METADATA_KEY, path.as_ref())
}

/// Writes a PSMODE fusion network's variables and `cfg` to `path`.
pub fn save_fusion_weights(
    varmap: &VarMap,
    cfg: &FusionConfig,
    path: impl AsRef<Path>,
) -> Result<(), ModelError> {
    save_with_config(varmap, cfg, FUSION_CONFIG_METADATA_KEY, path.as_ref())
}

fn save_with_config(
    varmap: &VarMap,
    cfg: &impl serde::Serialize,
    key: &str,
    path: &Path,
) -> Result<(), ModelError> {
    let weights_err = |problem: String| ModelError::Weights {
        path: path.display().to_string(),
        problem,
    };
    let tensors: Vec<(String, Tensor)> = {
        let data = varmap
            .data()
            .lock()
            .map_err(|_| weights_err("variable map lock poisoned".to_string()))?;
        data.iter()
            .map(|(name, var)| (name.clone(), var.as_tensor().clone()))
            .collect()
    };
    let config_json =
        serde_json::to_string(cfg).map_err(|e| weights_err(format!("config to JSON: {e}")))?;
    let metadata = HashMap::from([(key.to_string(), config_json)]);
    safetensors::serialize_to_file(tensors, Some(metadata), path)
        .map_err(|e| weights_err(format!("writing safetensors: {e}")))
}

/// One kind of weights file: the metadata key of its config, what it holds, and the other
/// kind's key (a file of the other kind is refused by name).
struct FileKind {
    key: &'static str,
    holds: &'static str,
    other_key: &'static str,
}

const SSMODE_FILE: FileKind = FileKind {
    key: CONFIG_METADATA_KEY,
    holds: "an SSMODE (PSMODE stage-1) network",
    other_key: FUSION_CONFIG_METADATA_KEY,
};

const FUSION_FILE: FileKind = FileKind {
    key: FUSION_CONFIG_METADATA_KEY,
    holds: "PSMODE's fusion network (stage 2)",
    other_key: CONFIG_METADATA_KEY,
};

/// The config of `kind` stored in a safetensors buffer's metadata, parsed and validated.
fn config_from_bytes<T: serde::de::DeserializeOwned>(
    bytes: &[u8],
    path: &Path,
    kind: &FileKind,
    validate: impl FnOnce(&T) -> Result<(), String>,
) -> Result<T, ModelError> {
    let json = metadata_json(bytes, path, kind)?;
    let cfg: T = serde_json::from_str(&json).map_err(|e| {
        weights_err(
            path,
            format!(
                "metadata '{}': {e} (a configuration this mode360 does not know)",
                kind.key
            ),
        )
    })?;
    validate(&cfg).map_err(|e| weights_err(path, format!("metadata '{}': {e}", kind.key)))?;
    Ok(cfg)
}

fn weights_err(path: &Path, problem: String) -> ModelError {
    ModelError::Weights {
        path: path.display().to_string(),
        problem,
    }
}

/// The config text of `kind` in a safetensors buffer's metadata; an error naming the other
/// kind where the file holds that one.
fn metadata_json(bytes: &[u8], path: &Path, kind: &FileKind) -> Result<String, ModelError> {
    let weights_err = |problem: String| weights_err(path, problem);
    let (_, metadata) = safetensors::SafeTensors::read_metadata(bytes)
        .map_err(|e| weights_err(format!("not a safetensors file: {e}")))?;
    let header = metadata.metadata().as_ref();
    let key = kind.key;
    let Some(json) = header.and_then(|m| m.get(key)) else {
        let other = [&SSMODE_FILE, &FUSION_FILE]
            .into_iter()
            .find(|k| k.key == kind.other_key);
        let what = match other {
            Some(o) if header.is_some_and(|m| m.contains_key(o.key)) => {
                format!("holds {}, not {}", o.holds, kind.holds)
            }
            _ => format!("no '{key}' header metadata"),
        };
        return Err(weights_err(what));
    };
    Ok(json.clone())
}

/// An SSMODE file's network config and the readout it records (files written before the
/// readout was a setting; else the default), parsed and validated; a field this build does
/// not know is refused by name.
fn ssmode_config(bytes: &[u8], path: &Path) -> Result<(SsmodeConfig, Readout), ModelError> {
    let key = CONFIG_METADATA_KEY;
    let json = metadata_json(bytes, path, &SSMODE_FILE)?;
    let err = |problem: String| weights_err(path, format!("metadata '{key}': {problem}"));
    let mut value: serde_json::Value =
        serde_json::from_str(&json).map_err(|e| err(e.to_string()))?;
    let Some(fields) = value.as_object_mut() else {
        return Err(err("not a JSON object".to_string()));
    };
    let known = known_config_fields();
    if let Some(unknown) = fields.keys().find(|k| !known.contains(*k)) {
        return Err(err(format!(
            "unknown field `{unknown}` (a configuration this mode360 does not know)"
        )));
    }
    let readout = Readout::recorded(fields).map_err(|e| err(e.to_string()))?;
    for recorded in RECORDED_KEYS {
        fields.remove(recorded);
    }
    let cfg: SsmodeConfig = serde_json::from_value(value)
        .map_err(|e| err(format!("{e} (a configuration this mode360 does not know)")))?;
    cfg.validate().map_err(|e| err(e.to_string()))?;
    Ok((cfg, readout))
}

/// The fields an SSMODE config may have: the network's, the removed ablations' (refused by
/// name in [`SsmodeConfig::validate`]) and the readout recorded by older files.
fn known_config_fields() -> Vec<String> {
    let network = serde_json::to_value(SsmodeConfig::parallax_zncc_log())
        .ok()
        .and_then(|v| v.as_object().map(|m| m.keys().cloned().collect::<Vec<_>>()))
        .unwrap_or_default();
    network
        .into_iter()
        .chain(REMOVED_FIELDS.iter().map(|k| k.to_string()))
        .chain(RECORDED_KEYS.iter().map(|k| k.to_string()))
        .collect()
}

/// Config fields of ablations that lost and were removed (written only when set).
const REMOVED_FIELDS: [&str; 2] = ["position_channels", "logit_prior"];

fn read_bytes(path: &Path) -> Result<Vec<u8>, ModelError> {
    std::fs::read(path).map_err(|source| ModelError::Io {
        path: path.display().to_string(),
        source,
    })
}

/// A `VarBuilder` over a weights file's tensors (f32 on `device`).
fn tensors_of(
    bytes: &[u8],
    path: &Path,
    device: &Device,
) -> Result<VarBuilder<'static>, ModelError> {
    let tensors =
        candle_core::safetensors::load_buffer(bytes, device).map_err(|e| ModelError::Weights {
            path: path.display().to_string(),
            problem: format!("reading tensors: {e}"),
        })?;
    Ok(VarBuilder::from_tensors(tensors, DType::F32, device))
}

/// The fusion config and a `VarBuilder` over the tensors of a PSMODE fusion weights file.
pub fn load_fusion_weights(
    path: impl AsRef<Path>,
    device: &Device,
) -> Result<(FusionConfig, VarBuilder<'static>), ModelError> {
    let path = path.as_ref();
    let bytes = read_bytes(path)?;
    let cfg = config_from_bytes(&bytes, path, &FUSION_FILE, |c: &FusionConfig| {
        c.validate().map_err(|e| e.to_string())
    })?;
    Ok((cfg, tensors_of(&bytes, path, device)?))
}

/// Only the config of a weights file.
pub fn read_config(path: impl AsRef<Path>) -> Result<SsmodeConfig, ModelError> {
    let path = path.as_ref();
    Ok(ssmode_config(&read_bytes(path)?, path)?.0)
}

/// The config and a `VarBuilder` over the tensors of a weights file (f32 on `device`).
/// To resume training into an existing `VarMap`, use `VarMap::load(path)` instead.
pub fn load_weights(
    path: impl AsRef<Path>,
    device: &Device,
) -> Result<(SsmodeConfig, VarBuilder<'static>), ModelError> {
    let (cfg, _, vb) = load_weights_and_readout(path, device)?;
    Ok((cfg, vb))
}

/// [`load_weights`] with the readout the file records ([`Readout::recorded`]: the values it
/// was tuned with, in files written before the readout was a setting; else the default).
pub fn load_weights_and_readout(
    path: impl AsRef<Path>,
    device: &Device,
) -> Result<(SsmodeConfig, Readout, VarBuilder<'static>), ModelError> {
    let path = path.as_ref();
    let bytes = read_bytes(path)?;
    let (cfg, readout) = ssmode_config(&bytes, path)?;
    let vb = tensors_of(&bytes, path, device)?;
    if cfg.fine_head_channels > 0 && !vb.contains_tensor(FINE_HEAD_KEY) {
        return Err(weights_err(
            path,
            format!(
                "its config has a fine head (fine_head_channels {}) but the file holds none of \
                 its weights (no tensor '{FINE_HEAD_KEY}'): a file of a network without the \
                 head with a changed config, or a truncated one",
                cfg.fine_head_channels
            ),
        ));
    }
    Ok((cfg, readout, vb))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A weights file whose config metadata is `config_json` (one dummy tensor).
    fn file_with_config(dir: &Path, config_json: &str) -> std::path::PathBuf {
        let path = dir.join("weights.safetensors");
        let data = [0u8; 4];
        let view = safetensors::tensor::TensorView::new(safetensors::Dtype::F32, vec![1], &data)
            .expect("tensor view");
        let metadata = HashMap::from([(CONFIG_METADATA_KEY.to_string(), config_json.to_string())]);
        safetensors::serialize_to_file([("x", view)], Some(metadata), &path).expect("write");
        path
    }

    #[test]
    fn sizes_a_build_cannot_run_are_refused_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let base = SsmodeConfig::parallax_zncc();
        let cases = [
            (
                "spheres",
                SsmodeConfig {
                    spheres: 1_000_000_000,
                    ..base.clone()
                },
            ),
            (
                "hypotheses",
                SsmodeConfig {
                    hypotheses: 1_000_000_000,
                    ..base.clone()
                },
            ),
            (
                "width",
                SsmodeConfig {
                    width: 4_000_000_000,
                    ..base.clone()
                },
            ),
            (
                "hourglass_channels",
                SsmodeConfig {
                    hourglass_channels: 1 << 20,
                    ..base.clone()
                },
            ),
            // Each within its own limit, together too large: 1024 spheres at 8192 wide.
            (
                "cost-volume cells",
                SsmodeConfig {
                    spheres: 1024,
                    width: 8192,
                    ..base.clone()
                },
            ),
        ];
        for (what, cfg) in cases {
            let path = file_with_config(dir.path(), &serde_json::to_string(&cfg).unwrap());
            let err = read_config(&path).unwrap_err().to_string();
            assert!(
                err.contains("weights.safetensors") && err.contains(what),
                "{what}: {err}"
            );
        }
        assert!(base.validate().is_ok());
        assert!(SsmodeConfig::paper().validate().is_ok());
    }

    #[test]
    fn a_fine_head_config_without_its_weights_is_refused_naming_the_file_and_the_part() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = SsmodeConfig::parallax_zncc_log_fine();
        let path = file_with_config(dir.path(), &serde_json::to_string(&cfg).unwrap());
        let err = match load_weights(&path, &Device::Cpu) {
            Ok(_) => panic!("a fine head without its weights loaded"),
            Err(e) => e.to_string(),
        };
        assert!(
            err.contains("weights.safetensors")
                && err.contains("fine head")
                && err.contains(FINE_HEAD_KEY),
            "{err}"
        );
        // the same file without the head in its config loads (its tensors are checked when
        // the network is built)
        let plain = SsmodeConfig::parallax_zncc_log();
        let path = file_with_config(dir.path(), &serde_json::to_string(&plain).unwrap());
        assert!(load_weights(&path, &Device::Cpu).is_ok());
    }

    #[test]
    fn unknown_or_invalid_configurations_name_the_file_and_the_field() {
        let dir = tempfile::tempdir().unwrap();
        let mut json: serde_json::Value =
            serde_json::to_value(SsmodeConfig::parallax_zncc()).unwrap();
        json["depth_refiner"] = serde_json::json!(true);
        let path = file_with_config(dir.path(), &json.to_string());
        let err = read_config(&path).unwrap_err().to_string();
        assert!(
            err.contains("weights.safetensors") && err.contains("depth_refiner"),
            "{err}"
        );
        let bad = SsmodeConfig {
            cost_downsample: 4,
            ..SsmodeConfig::parallax_zncc()
        };
        let path = file_with_config(dir.path(), &serde_json::to_string(&bad).unwrap());
        let err = read_config(&path).unwrap_err().to_string();
        assert!(
            err.contains("weights.safetensors") && err.contains("photometric_cost"),
            "{err}"
        );
        // a readout recorded by an older file is checked too
        let mut json: serde_json::Value =
            serde_json::to_value(SsmodeConfig::parallax_zncc()).unwrap();
        json["far_parallax_cells"] = serde_json::json!(-1.0);
        let path = file_with_config(dir.path(), &json.to_string());
        let err = read_config(&path).unwrap_err().to_string();
        assert!(
            err.contains("weights.safetensors") && err.contains("far_parallax_cells"),
            "{err}"
        );
        json["far_parallax_cells"] = serde_json::json!(0.25);
        json["refine_radius_cells"] =
            serde_json::json!(super::super::readout::MAX_REFINE_RADIUS_CELLS + 1);
        let path = file_with_config(dir.path(), &json.to_string());
        let err = read_config(&path).unwrap_err().to_string();
        assert!(
            err.contains("weights.safetensors") && err.contains("refine_radius_cells"),
            "{err}"
        );
        // 2 x 3 is not a multiple of the aggregation's divisor 8
        for (seam_pad_cells, problem) in [(3, "multiple"), (1024, "wider")] {
            let bad = SsmodeConfig {
                seam_pad_cells,
                ..SsmodeConfig::parallax_zncc()
            };
            let path = file_with_config(dir.path(), &serde_json::to_string(&bad).unwrap());
            let err = read_config(&path).unwrap_err().to_string();
            assert!(
                err.contains("weights.safetensors")
                    && err.contains("seam_pad_cells")
                    && err.contains(problem),
                "{err}"
            );
        }
    }

    /// A file written before the far field, the edge refinement and the seam wrap (no
    /// `far_parallax_cells`, `refine_radius_cells` or `seam_pad_cells`) reads the default
    /// readout but its own far-plane probability, and no seam wrap; a file written now
    /// records no readout at all.
    #[test]
    fn files_without_the_far_field_get_the_default() {
        use super::super::readout::{DEFAULT_FAR_PARALLAX_CELLS, DEFAULT_REFINE_RADIUS_CELLS};
        let dir = tempfile::tempdir().unwrap();
        let mut json: serde_json::Value =
            serde_json::to_value(SsmodeConfig::parallax_zncc()).unwrap();
        for recorded in RECORDED_KEYS {
            assert!(json.get(recorded).is_none(), "{recorded} written");
        }
        json.as_object_mut().unwrap().remove("seam_pad_cells");
        json["far_plane_probability"] = serde_json::json!(0.8);
        let path = file_with_config(dir.path(), &json.to_string());
        let (cfg, readout, _) = load_weights_and_readout(&path, &Device::Cpu).unwrap();
        assert_eq!(readout.far_parallax_cells, DEFAULT_FAR_PARALLAX_CELLS);
        assert_eq!(readout.far_plane_probability, 0.8);
        assert_eq!(readout.refine_radius_cells, DEFAULT_REFINE_RADIUS_CELLS);
        // trained with the 3-D convolutions' zero padding at the seam: kept so
        assert_eq!(cfg.seam_pad_cells, 0);
    }
}
