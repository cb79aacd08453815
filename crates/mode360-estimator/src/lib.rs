//! mode360's depth estimators: the learning-free photometric sweep ([`photometric`]), SSMODE
//! ([`ssmode`], whose network is `mode360_model::model`) and PSMODE ([`psmode`]); they build on
//! the windowed ZNCC matching of `mode360_model::matching`. The lens masks the rig's health
//! checks (`mode360-health`) hand them are [`lens_mask`].
//!
//! Depth estimators: N synchronized panoramas in, one ERP range image of the rig's output
//! frame out.

use std::path::PathBuf;

use mode360_core::frame::{FloatImage, RgbImage};
use mode360_core::geometry::{ErpGrid, Rig};
use mode360_model::model::{ComputeDevice, ReadoutOverrides};

pub mod edge_refine;
pub mod guided_upsample;
pub mod lens_mask;
pub mod near_pass;
pub mod photometric;
pub mod psmode;
pub mod ssmode;

/// What an estimator returns for one frame.
#[derive(Clone, Debug)]
pub struct DepthEstimate {
    /// Range in metres along each output pixel's ray (NaN where invalid).
    pub range_m: FloatImage,
    /// Per-pixel confidence in [0, 1].
    pub confidence: FloatImage,
}

impl DepthEstimate {
    /// An estimate on `output` from row-major range and confidence values.
    pub fn on_grid(output: ErpGrid, range_m: Vec<f32>, confidence: Vec<f32>) -> Self {
        let image = |data| FloatImage {
            width: output.width(),
            height: output.height(),
            data,
        };
        Self {
            range_m: image(range_m),
            confidence: image(confidence),
        }
    }
}

/// Why an estimator could not produce depth for a frame.
#[derive(Debug, thiserror::Error)]
pub enum EstimatorError {
    #[error("estimator got {got} images for a rig of {expected} cameras")]
    ImageCount { got: usize, expected: usize },
    #[error("camera '{camera}': image is {width}x{height}; ERP images must be twice as wide as tall and of even width")]
    BadImageSize {
        camera: String,
        width: u32,
        height: u32,
    },
    #[error("camera '{camera}': {problem}")]
    BadImage { camera: String, problem: String },
    #[error("estimator config field '{field}': {problem}")]
    BadConfig { field: String, problem: String },
    #[error("unknown estimator '{name}' (known: {known})")]
    UnknownEstimator { name: String, known: String },
    #[error("{0}")]
    Geometry(#[from] mode360_core::geometry::GeometryError),
    #[error("{0}")]
    Model(#[from] mode360_model::model::ModelError),
}

/// A depth estimator. Implementations may cache per-rig work (sampling tables) between calls.
pub trait DepthEstimator: Send {
    /// Short name used on the command line and in reports (`photometric`, `ssmode`).
    fn name(&self) -> &str;

    /// Range of every pixel of `output` (an ERP grid in the rig's output frame) from `images`,
    /// one per camera of `rig`, in rig order.
    fn estimate(
        &mut self,
        rig: &Rig,
        images: &[RgbImage],
        output: ErpGrid,
    ) -> Result<DepthEstimate, EstimatorError>;

    /// The blocked part of each camera's view (rig order, [`lens_mask::LensMask`]) to treat as
    /// unseen from the next [`Self::estimate`] on, while the rig has that many cameras; an
    /// empty slice clears them. Estimators that cannot use masks ignore them.
    fn set_lens_masks(&mut self, masks: &[Option<lens_mask::LensMask>]) {
        let _ = masks;
    }
}

/// The depth estimators the node and the tools can run (`--estimator`, the node's `estimator`
/// parameter).
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize,
)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "snake_case")]
pub enum EstimatorKind {
    /// Learning-free photometric plane sweep over the rig's views.
    Photometric,
    /// The SSMODE network with trained weights (default: the shipped ones). The default
    /// estimator: ahead of the sweep on every held-out row of issue 19 (models/README.md).
    #[default]
    Ssmode,
    /// PSMODE, the paper's two-stage method: SSMODE's network on each camera pair in its GEER
    /// frame, then the pairs fused (`estimator::psmode`). Its weights are the stage-1
    /// network's (default: models/psmode_stage1.safetensors, SSMODE fine-tuned on pairs).
    Psmode,
}

impl EstimatorKind {
    /// Every kind, in the order help texts list them.
    pub const ALL: [Self; 3] = [Self::Photometric, Self::Ssmode, Self::Psmode];

    /// The name on the command line and in reports.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Photometric => photometric::PHOTOMETRIC_NAME,
            Self::Ssmode => ssmode::SSMODE_NAME,
            Self::Psmode => psmode::PSMODE_NAME,
        }
    }

    /// Whether this estimator loads a weights file.
    pub fn has_weights(self) -> bool {
        matches!(self, Self::Ssmode | Self::Psmode)
    }

    /// The shipped weights this estimator loads when none are given, located
    /// ([`ssmode::locate_weights`]): SSMODE's default, PSMODE's stage 1
    /// ([`ssmode::PSMODE_STAGE1_WEIGHTS_PATH`]); SSMODE's default for the others, which
    /// have none ([`Self::has_weights`]).
    pub fn default_weights_path(self) -> PathBuf {
        match self {
            Self::Psmode => {
                ssmode::locate_weights(std::path::Path::new(ssmode::PSMODE_STAGE1_WEIGHTS_PATH))
            }
            Self::Ssmode | Self::Photometric => ssmode::default_weights_path(),
        }
    }
}

impl std::fmt::Display for EstimatorKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::str::FromStr for EstimatorKind {
    type Err = EstimatorError;

    fn from_str(name: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|k| k.as_str() == name)
            .ok_or_else(|| EstimatorError::UnknownEstimator {
                name: name.to_string(),
                known: Self::ALL.map(Self::as_str).join(", "),
            })
    }
}

/// An estimator and, for SSMODE and PSMODE, its weights file (`None`: the shipped weights), the
/// device its network runs on and, for PSMODE, the camera pairs it matches.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EstimatorSpec {
    pub kind: EstimatorKind,
    pub weights: Option<PathBuf>,
    /// Where SSMODE runs (`--device`, the node's `device`); the photometric sweep runs on the
    /// CPU only, and asking it for another device is an error at [`Self::build`].
    pub device: ComputeDevice,
    /// The camera pairs PSMODE matches (ignored by the others).
    pub pairs: psmode::PairChoice,
    /// PSMODE's fusion network (stage 2): `None` or `consensus` no network (per pixel the range
    /// the pairs agree on), `none` no network (the most confident pair per pixel), else a file
    /// such as the shipped `models/psmode_fusion.safetensors` ([`psmode::fusion_weights_path`]).
    pub fusion_weights: Option<PathBuf>,
    /// PSMODE's stage-1 input width where the output is at least that wide (`None`:
    /// [`psmode::DEFAULT_PAIR_WIDTH`]; [`psmode::TRAINED_PAIR_WIDTH`]: the width the network
    /// was trained at); an error at [`Self::build`] for the other estimators.
    pub pair_width: Option<usize>,
    /// SSMODE's second pass for near obstacles at this input width (`None`: off;
    /// [`near_pass`]); an error at [`Self::build`] for the other estimators.
    pub near_pass_width: Option<usize>,
    /// What SSMODE's second pass is (the network again, or the photometric sweep); used only
    /// with `near_pass_width`.
    pub near_pass_source: near_pass::NearPassSource,
    /// SSMODE's readout settings where they replace the weights file's (else the defaults);
    /// an error at [`Self::build`] for the other estimators.
    pub readout: ReadoutOverrides,
}

impl EstimatorSpec {
    /// `kind` with its default settings.
    pub fn new(kind: EstimatorKind) -> Self {
        Self {
            kind,
            ..Self::default()
        }
    }

    /// `kind` with `weights` (an error at [`Self::build`] for an estimator without weights, so
    /// that weights given to the wrong estimator are not silently ignored).
    pub fn with_weights(kind: EstimatorKind, weights: Option<PathBuf>) -> Self {
        Self {
            kind,
            weights,
            ..Self::default()
        }
    }

    /// The same estimator on `device`.
    pub fn on_device(self, device: ComputeDevice) -> Self {
        Self { device, ..self }
    }

    /// The weights file SSMODE will load (the shipped one when none was given), located as
    /// [`ssmode::locate_weights`] says; `None` for estimators without weights.
    pub fn weights_path(&self) -> Option<PathBuf> {
        self.kind.has_weights().then(|| match &self.weights {
            Some(path) => ssmode::locate_weights(path),
            None => self.kind.default_weights_path(),
        })
    }

    /// The settings of this spec that belong to one estimator: what each is, its owner and,
    /// where it was given, the value as the error shows it.
    fn owned_settings(&self) -> [OwnedSetting; 4] {
        use EstimatorKind::{Psmode, Ssmode};
        [
            OwnedSetting {
                field: "fusion_weights",
                owner: Psmode,
                what: "a fusion network",
                given: self
                    .fusion_weights
                    .as_ref()
                    .map(|p| p.display().to_string()),
            },
            OwnedSetting {
                field: "pair_width",
                owner: Psmode,
                what: "a camera-pair width",
                given: self.pair_width.map(|w| format!("pair width {w}")),
            },
            OwnedSetting {
                field: "near_pass_width",
                owner: Ssmode,
                what: "a near pass",
                given: self.near_pass_width.map(|w| format!("width {w}")),
            },
            OwnedSetting {
                field: "readout",
                owner: Ssmode,
                what: "readout settings (far-plane probability, far field, near mode, edge \
                       refinement)",
                given: (!self.readout.is_empty()).then(|| "readout overrides".to_string()),
            },
        ]
    }

    /// Refuses a setting given to an estimator that does not have it, so that it is never
    /// silently ignored: the error names the field, the owner and what was given.
    fn check_owned_settings(&self) -> Result<(), EstimatorError> {
        let Some(setting) = self
            .owned_settings()
            .into_iter()
            .find(|s| s.owner != self.kind && s.given.is_some())
        else {
            return Ok(());
        };
        Err(EstimatorError::BadConfig {
            field: setting.field.to_string(),
            problem: format!(
                "only {} has {} (got {} for {})",
                setting.owner.as_str().to_uppercase(),
                setting.what,
                setting.given.unwrap_or_default(),
                self.kind
            ),
        })
    }

    /// Builds the estimator (for SSMODE on a CUDA device: opens it, or says why not).
    pub fn build(&self) -> Result<Box<dyn DepthEstimator>, EstimatorError> {
        if self.kind == EstimatorKind::Photometric && self.device != ComputeDevice::Cpu {
            return Err(EstimatorError::BadConfig {
                field: "device".to_string(),
                problem: format!(
                    "the photometric estimator runs on the CPU only (asked for {}); use \
                     --estimator ssmode for the GPU",
                    self.device
                ),
            });
        }
        self.check_owned_settings()?;
        match (self.kind, &self.weights) {
            (EstimatorKind::Photometric, None) => Ok(Box::new(photometric::PhotometricSweep::new(
                photometric::PhotometricConfig::default(),
            )?)),
            (EstimatorKind::Photometric, Some(path)) => Err(EstimatorError::BadConfig {
                field: "weights".to_string(),
                problem: format!(
                    "the photometric estimator has no weights (got {})",
                    path.display()
                ),
            }),
            (EstimatorKind::Ssmode, weights) => {
                let path = weights.clone().unwrap_or_else(ssmode::default_weights_path);
                Ok(match self.near_pass_width {
                    None => Box::new(ssmode::SsmodeEstimator::load_configured(
                        path,
                        self.device,
                        None,
                        &self.readout,
                    )?),
                    Some(width) => Box::new(near_pass::NearPassEstimator::load_on(
                        path,
                        self.device,
                        width,
                        self.near_pass_source,
                        &self.readout,
                    )?),
                })
            }
            (EstimatorKind::Psmode, weights) => Ok(Box::new(psmode::PsmodeEstimator::load_on(
                weights
                    .clone()
                    .unwrap_or_else(|| EstimatorKind::Psmode.default_weights_path()),
                psmode::fusion_weights_path(self.fusion_weights.as_deref()).as_deref(),
                self.device,
                self.pairs.clone(),
                self.pair_width.unwrap_or(psmode::DEFAULT_PAIR_WIDTH),
            )?)),
        }
    }
}

/// A setting only one estimator has ([`EstimatorSpec::check_owned_settings`]).
struct OwnedSetting {
    /// The spec's field, as the error names it.
    field: &'static str,
    /// The estimator the setting belongs to.
    owner: EstimatorKind,
    /// What the setting is, after "only OWNER has".
    what: &'static str,
    /// The value given, as the error shows it; `None` where it was left unset.
    given: Option<String>,
}

/// The estimator called `name`, with its default settings (SSMODE: the shipped weights).
pub fn by_name(name: &str) -> Result<Box<dyn DepthEstimator>, EstimatorError> {
    EstimatorSpec::with_weights(name.parse()?, None).build()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_setting_given_to_an_estimator_without_it_is_refused_by_name() {
        use EstimatorKind::{Psmode, Ssmode};
        let given: [(&str, EstimatorKind, EstimatorSpec); 4] = [
            (
                "fusion_weights",
                Psmode,
                EstimatorSpec {
                    fusion_weights: Some(PathBuf::from("fusion.safetensors")),
                    ..EstimatorSpec::default()
                },
            ),
            (
                "pair_width",
                Psmode,
                EstimatorSpec {
                    pair_width: Some(512),
                    ..EstimatorSpec::default()
                },
            ),
            (
                "near_pass_width",
                Ssmode,
                EstimatorSpec {
                    near_pass_width: Some(512),
                    ..EstimatorSpec::default()
                },
            ),
            (
                "readout",
                Ssmode,
                EstimatorSpec {
                    readout: ReadoutOverrides {
                        refine_radius_cells: Some(0),
                        ..ReadoutOverrides::default()
                    },
                    ..EstimatorSpec::default()
                },
            ),
        ];
        for (field, owner, spec) in given {
            for kind in EstimatorKind::ALL {
                let result = EstimatorSpec {
                    kind,
                    ..spec.clone()
                }
                .check_owned_settings();
                if kind == owner {
                    assert!(result.is_ok(), "{field} for {kind}: {result:?}");
                    continue;
                }
                let e = result.expect_err(field).to_string();
                let owner_name = owner.as_str().to_uppercase();
                assert!(
                    e.contains(field) && e.contains(&owner_name) && e.contains(kind.as_str()),
                    "{field} for {kind}: {e}"
                );
            }
        }
        for kind in EstimatorKind::ALL {
            assert!(EstimatorSpec::new(kind).check_owned_settings().is_ok());
        }
    }

    #[test]
    fn kinds_round_trip_through_their_names() {
        for kind in EstimatorKind::ALL {
            assert_eq!(kind.to_string().parse::<EstimatorKind>().unwrap(), kind);
            let yaml = serde_yaml::to_string(&kind).unwrap();
            assert_eq!(yaml.trim(), kind.as_str());
        }
        let e = "sgbm".parse::<EstimatorKind>().unwrap_err().to_string();
        assert!(
            e.contains("sgbm") && e.contains("photometric, ssmode, psmode"),
            "{e}"
        );
    }

    #[test]
    fn weights_belong_to_ssmode_only() {
        let spec = EstimatorSpec::with_weights(EstimatorKind::Photometric, Some("w.st".into()));
        assert_eq!(spec.weights_path(), None);
        let e = spec
            .build()
            .err()
            .expect("photometric with weights")
            .to_string();
        assert!(e.contains("weights") && e.contains("w.st"), "{e}");
        let ssmode = EstimatorSpec::new(EstimatorKind::Ssmode);
        assert_eq!(ssmode.weights_path(), Some(ssmode::default_weights_path()));
        // PSMODE's stage 1: SSMODE's network fine-tuned on pairs, shipped apart
        let psmode = EstimatorSpec::new(EstimatorKind::Psmode);
        let stage1 = psmode.weights_path().expect("psmode has weights");
        assert!(
            stage1.ends_with(ssmode::PSMODE_STAGE1_WEIGHTS_PATH),
            "{stage1:?}"
        );
        assert_ne!(Some(stage1), ssmode.weights_path());
        let missing = EstimatorSpec::with_weights(EstimatorKind::Ssmode, Some("/no/w.st".into()));
        let e = missing.build().err().expect("missing weights").to_string();
        assert!(e.contains("/no/w.st"), "{e}");
    }

    #[test]
    fn a_cuda_device_is_opened_or_refused_with_what_was_found() {
        let cuda = ComputeDevice::Cuda { ordinal: 0 };
        let photometric = EstimatorSpec::new(EstimatorKind::Photometric).on_device(cuda);
        let e = photometric
            .build()
            .err()
            .expect("photometric on CUDA")
            .to_string();
        assert!(e.contains("CPU only") && e.contains("cuda:0"), "{e}");
        // the shipped weights exist, so only the device can fail (here: no GPU, or no feature)
        let ssmode = EstimatorSpec::new(EstimatorKind::Ssmode).on_device(cuda);
        if let Err(e) = ssmode.build() {
            let e = e.to_string();
            assert!(
                e.contains("CUDA device cuda:0") && e.contains("found"),
                "{e}"
            );
        }
    }
}
