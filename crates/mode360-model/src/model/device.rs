//! Where the network runs: the CPU or one CUDA GPU, as chosen by `--device cpu|cuda:N` and the
//! node's `device` parameter.
//!
//! Opening a CUDA device needs a binary built with the `cuda` cargo feature and a GPU the
//! driver can see; otherwise [`ComputeDevice::open`] returns a [`DeviceError`] that names CUDA
//! and says what was found instead (never a panic). On the CPU the model's ops run their fast
//! custom kernels; elsewhere their device-generic composites (see [`super::ops`]).

use std::fmt;
use std::str::FromStr;

use candle_core::Device;

/// The spelling of the CPU device.
pub const CPU_NAME: &str = "cpu";
/// The prefix of a CUDA device, `cuda:N`.
pub const CUDA_PREFIX: &str = "cuda";

/// A device the network can run on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum ComputeDevice {
    /// The CPU, with the ops' custom kernels.
    #[default]
    Cpu,
    /// The CUDA GPU with this index (`cuda:0` is the first the driver lists).
    Cuda { ordinal: usize },
}

/// A device that cannot be parsed or opened.
#[derive(Debug, thiserror::Error)]
pub enum DeviceError {
    #[error("device '{text}': {problem} (expected cpu or cuda:N, e.g. cuda:0)")]
    Parse { text: String, problem: String },
    #[error(
        "CUDA device {device} requested, but this mode360 was built without CUDA support (the \
         `cuda` cargo feature); found only the CPU. Use --device cpu, or build with \
         `--features cuda` (scripts/build_cuda.sh)"
    )]
    NotBuilt { device: ComputeDevice },
    #[error("CUDA device {device} could not be opened: {problem}; found {found}")]
    Unavailable {
        device: ComputeDevice,
        problem: String,
        found: String,
    },
}

impl ComputeDevice {
    /// Whether this is a CUDA device.
    pub fn is_cuda(self) -> bool {
        matches!(self, Self::Cuda { .. })
    }

    /// The candle device, opened. CUDA needs the `cuda` feature and a GPU with that index.
    pub fn open(self) -> Result<Device, DeviceError> {
        match self {
            Self::Cpu => Ok(Device::Cpu),
            Self::Cuda { ordinal } => open_cuda(self, ordinal),
        }
    }

    /// The device a candle tensor lives on, in these terms (`None` for other backends).
    pub fn of(device: &Device) -> Option<Self> {
        match device.location() {
            candle_core::DeviceLocation::Cpu => Some(Self::Cpu),
            candle_core::DeviceLocation::Cuda { gpu_id } => Some(Self::Cuda { ordinal: gpu_id }),
            candle_core::DeviceLocation::Metal { .. } => None,
        }
    }
}

#[cfg(not(feature = "cuda"))]
fn open_cuda(device: ComputeDevice, _ordinal: usize) -> Result<Device, DeviceError> {
    Err(DeviceError::NotBuilt { device })
}

#[cfg(feature = "cuda")]
fn open_cuda(device: ComputeDevice, ordinal: usize) -> Result<Device, DeviceError> {
    Device::new_cuda(ordinal).map_err(|e| DeviceError::Unavailable {
        device,
        // the first line: candle appends a backtrace when RUST_BACKTRACE is set
        problem: e.to_string().lines().next().unwrap_or_default().to_string(),
        found: cuda_devices_found(),
    })
}

/// What the CUDA driver reports, for error messages: how many GPUs, or why none.
#[cfg(feature = "cuda")]
fn cuda_devices_found() -> String {
    use candle_core::cuda_backend::cudarc::driver::{result, CudaContext};
    if let Err(e) = result::init() {
        return format!("no usable CUDA driver ({e})");
    }
    match CudaContext::device_count() {
        Ok(0) => "no CUDA device (the driver lists none)".to_string(),
        Ok(1) => "1 CUDA device (cuda:0)".to_string(),
        Ok(n) => format!("{n} CUDA devices (cuda:0 to cuda:{})", n - 1),
        Err(e) => format!("no CUDA device count ({e})"),
    }
}

impl fmt::Display for ComputeDevice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Cpu => f.write_str(CPU_NAME),
            Self::Cuda { ordinal } => write!(f, "{CUDA_PREFIX}:{ordinal}"),
        }
    }
}

impl FromStr for ComputeDevice {
    type Err = DeviceError;

    /// `cpu`, `cuda:N`, or `cuda` for `cuda:0`.
    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let bad = |problem: &str| DeviceError::Parse {
            text: text.to_string(),
            problem: problem.to_string(),
        };
        let lower = text.trim().to_ascii_lowercase();
        if lower == CPU_NAME {
            return Ok(Self::Cpu);
        }
        let Some(rest) = lower.strip_prefix(CUDA_PREFIX) else {
            return Err(bad("unknown device"));
        };
        let ordinal = match rest.strip_prefix(':') {
            None if rest.is_empty() => 0,
            None => return Err(bad("unknown device")),
            Some(index) => index
                .parse::<usize>()
                .map_err(|_| bad("the CUDA device index must be a whole number from 0"))?,
        };
        Ok(Self::Cuda { ordinal })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn devices_round_trip_through_their_names() {
        for d in [
            ComputeDevice::Cpu,
            ComputeDevice::Cuda { ordinal: 0 },
            ComputeDevice::Cuda { ordinal: 3 },
        ] {
            assert_eq!(d.to_string().parse::<ComputeDevice>().unwrap(), d);
        }
        assert_eq!(
            "cuda".parse::<ComputeDevice>().unwrap(),
            ComputeDevice::Cuda { ordinal: 0 }
        );
        assert_eq!(
            " CPU ".parse::<ComputeDevice>().unwrap(),
            ComputeDevice::Cpu
        );
        assert_eq!(ComputeDevice::of(&Device::Cpu), Some(ComputeDevice::Cpu));
    }

    #[test]
    fn bad_names_say_what_is_expected() {
        for text in ["gpu", "cuda:", "cuda:-1", "cuda:x", "cuda0", "", "cpu:0"] {
            let e = text.parse::<ComputeDevice>().unwrap_err().to_string();
            assert!(e.contains(&format!("'{text}'")), "{e}");
            assert!(e.contains("cpu or cuda:N"), "{e}");
        }
        let e = "cuda:x".parse::<ComputeDevice>().unwrap_err().to_string();
        assert!(e.contains("whole number"), "{e}");
    }

    #[test]
    fn the_cpu_always_opens() {
        assert!(matches!(ComputeDevice::Cpu.open(), Ok(Device::Cpu)));
    }

    /// Without a GPU (this machine, CI) asking for CUDA is an error naming CUDA and what was
    /// found, whether or not the binary was built with the `cuda` feature.
    #[test]
    fn cuda_without_a_gpu_is_a_clear_error() {
        let device = ComputeDevice::Cuda { ordinal: 0 };
        match device.open() {
            // a GPU host running the tests: nothing to check here
            Ok(d) => assert!(d.is_cuda()),
            Err(e) => {
                let text = e.to_string();
                assert!(text.contains("CUDA device cuda:0"), "{text}");
                assert!(text.contains("found"), "{text}");
                if cfg!(feature = "cuda") {
                    assert!(matches!(e, DeviceError::Unavailable { .. }), "{text}");
                } else {
                    assert!(matches!(e, DeviceError::NotBuilt { .. }), "{text}");
                    assert!(text.contains("without CUDA support"), "{text}");
                    assert!(text.contains("found only the CPU"), "{text}");
                }
            }
        }
    }
}
