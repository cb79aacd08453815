//! SSMODE weight files: safetensors with the [`SsmodeConfig`] as JSON in the header metadata
//! under [`CONFIG_METADATA_KEY`]. Tensor names are the `VarBuilder` paths of the network
//! (`feature.layer1.0.conv1.weight`, `aggregation.hourglass0.conv1.weight`, ...).

use std::collections::HashMap;
use std::path::Path;

use candle_core::{DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};

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
    let weights_err = |problem: String| ModelError::Weights {
        path: path.display().to_string(),
        problem,
    };
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
    let cfg: T = serde_json::from_str(json).map_err(|e| {
        weights_err(format!(
            "metadata '{key}': {e} (a configuration this mode360 does not know)"
        ))
    })?;
    validate(&cfg).map_err(|e| weights_err(format!("metadata '{key}': {e}")))?;
    Ok(cfg)
}

fn ssmode_config(bytes: &[u8], path: &Path) -> Result<SsmodeConfig, ModelError> {
    config_from_bytes(bytes, path, &SSMODE_FILE, |c: &SsmodeConfig| {
        c.validate().map_err(|e| e.to_string())
    })
}

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
    ssmode_config(&read_bytes(path)?, path)
}

/// The config and a `VarBuilder` over the tensors of a weights file (f32 on `device`).
/// To resume training into an existing `VarMap`, use `VarMap::load(path)` instead.
pub fn load_weights(
    path: impl AsRef<Path>,
    device: &Device,
) -> Result<(SsmodeConfig, VarBuilder<'static>), ModelError> {
    let path = path.as_ref();
    let bytes = read_bytes(path)?;
    let cfg = ssmode_config(&bytes, path)?;
    Ok((cfg, tensors_of(&bytes, path, device)?))
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
        let bad = SsmodeConfig {
            far_parallax_cells: -1.0,
            ..SsmodeConfig::parallax_zncc()
        };
        let path = file_with_config(dir.path(), &serde_json::to_string(&bad).unwrap());
        let err = read_config(&path).unwrap_err().to_string();
        assert!(err.contains("far_parallax_cells"), "{err}");
        let bad = SsmodeConfig {
            refine_radius_cells: super::super::config::MAX_REFINE_RADIUS_CELLS + 1,
            ..SsmodeConfig::parallax_zncc()
        };
        let path = file_with_config(dir.path(), &serde_json::to_string(&bad).unwrap());
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
    /// `far_parallax_cells`, `refine_radius_cells` or `seam_pad_cells`) reads the default ones
    /// (no seam wrap), and keeps its own far-plane probability.
    #[test]
    fn files_without_the_far_field_get_the_default() {
        let dir = tempfile::tempdir().unwrap();
        let mut json: serde_json::Value =
            serde_json::to_value(SsmodeConfig::parallax_zncc()).unwrap();
        json.as_object_mut().unwrap().remove("far_parallax_cells");
        json.as_object_mut().unwrap().remove("refine_radius_cells");
        json.as_object_mut().unwrap().remove("seam_pad_cells");
        json["far_plane_probability"] = serde_json::json!(0.8);
        let cfg = read_config(file_with_config(dir.path(), &json.to_string())).unwrap();
        assert_eq!(
            cfg.far_parallax_cells,
            super::super::config::DEFAULT_FAR_PARALLAX_CELLS
        );
        assert_eq!(cfg.far_plane_probability, 0.8);
        assert_eq!(
            cfg.refine_radius_cells,
            super::super::config::DEFAULT_REFINE_RADIUS_CELLS
        );
        // trained with the 3-D convolutions' zero padding at the seam: kept so
        assert_eq!(cfg.seam_pad_cells, 0);
    }
}
