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

/// The config stored in a safetensors buffer's metadata.
fn config_from_bytes(bytes: &[u8], path: &Path) -> Result<SsmodeConfig, ModelError> {
    let weights_err = |problem: String| ModelError::Weights {
        path: path.display().to_string(),
        problem,
    };
    let (_, metadata) = safetensors::SafeTensors::read_metadata(bytes)
        .map_err(|e| weights_err(format!("not a safetensors file: {e}")))?;
    let header = metadata.metadata().as_ref();
    if header.is_some_and(|m| m.contains_key(FUSION_CONFIG_METADATA_KEY)) {
        return Err(weights_err(
            "holds PSMODE's fusion network (stage 2), not an SSMODE or PSMODE stage-1 network"
                .to_string(),
        ));
    }
    let json = header
        .and_then(|m| m.get(CONFIG_METADATA_KEY))
        .ok_or_else(|| weights_err(format!("no '{CONFIG_METADATA_KEY}' header metadata")))?;
    let cfg: SsmodeConfig = serde_json::from_str(json).map_err(|e| {
        weights_err(format!(
            "metadata '{CONFIG_METADATA_KEY}': {e} (a network configuration this mode360 \
                 does not know)"
        ))
    })?;
    cfg.validate()
        .map_err(|e| weights_err(format!("metadata '{CONFIG_METADATA_KEY}': {e}")))?;
    Ok(cfg)
}

fn read_bytes(path: &Path) -> Result<Vec<u8>, ModelError> {
    std::fs::read(path).map_err(|source| ModelError::Io {
        path: path.display().to_string(),
        source,
    })
}

/// The fusion config stored in a safetensors buffer's metadata.
fn fusion_config_from_bytes(bytes: &[u8], path: &Path) -> Result<FusionConfig, ModelError> {
    let weights_err = |problem: String| ModelError::Weights {
        path: path.display().to_string(),
        problem,
    };
    let (_, metadata) = safetensors::SafeTensors::read_metadata(bytes)
        .map_err(|e| weights_err(format!("not a safetensors file: {e}")))?;
    let header = metadata.metadata().as_ref();
    let Some(json) = header.and_then(|m| m.get(FUSION_CONFIG_METADATA_KEY)) else {
        let what = if header.is_some_and(|m| m.contains_key(CONFIG_METADATA_KEY)) {
            "holds an SSMODE (PSMODE stage-1) network, not PSMODE's fusion network (stage 2)"
                .to_string()
        } else {
            format!("no '{FUSION_CONFIG_METADATA_KEY}' header metadata")
        };
        return Err(weights_err(what));
    };
    let cfg: FusionConfig = serde_json::from_str(json).map_err(|e| {
        weights_err(format!(
            "metadata '{FUSION_CONFIG_METADATA_KEY}': {e} (a fusion configuration this mode360 \
                 does not know)"
        ))
    })?;
    cfg.validate()
        .map_err(|e| weights_err(format!("metadata '{FUSION_CONFIG_METADATA_KEY}': {e}")))?;
    Ok(cfg)
}

/// The fusion config and a `VarBuilder` over the tensors of a PSMODE fusion weights file.
pub fn load_fusion_weights(
    path: impl AsRef<Path>,
    device: &Device,
) -> Result<(FusionConfig, VarBuilder<'static>), ModelError> {
    let path = path.as_ref();
    let bytes = read_bytes(path)?;
    let cfg = fusion_config_from_bytes(&bytes, path)?;
    let tensors =
        candle_core::safetensors::load_buffer(&bytes, device).map_err(|e| ModelError::Weights {
            path: path.display().to_string(),
            problem: format!("reading tensors: {e}"),
        })?;
    Ok((cfg, VarBuilder::from_tensors(tensors, DType::F32, device)))
}

/// Only the config of a weights file.
pub fn read_config(path: impl AsRef<Path>) -> Result<SsmodeConfig, ModelError> {
    let path = path.as_ref();
    config_from_bytes(&read_bytes(path)?, path)
}

/// The config and a `VarBuilder` over the tensors of a weights file (f32 on `device`).
/// To resume training into an existing `VarMap`, use `VarMap::load(path)` instead.
pub fn load_weights(
    path: impl AsRef<Path>,
    device: &Device,
) -> Result<(SsmodeConfig, VarBuilder<'static>), ModelError> {
    let path = path.as_ref();
    let bytes = read_bytes(path)?;
    let cfg = config_from_bytes(&bytes, path)?;
    let tensors =
        candle_core::safetensors::load_buffer(&bytes, device).map_err(|e| ModelError::Weights {
            path: path.display().to_string(),
            problem: format!("reading tensors: {e}"),
        })?;
    Ok((cfg, VarBuilder::from_tensors(tensors, DType::F32, device)))
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
