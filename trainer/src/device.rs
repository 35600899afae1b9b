//! Where the networks run: the CPU (burn's Flex backend), or a CUDA GPU when built with the `cuda` feature.

use std::fmt;
use std::str::FromStr;

use burn::tensor::Device;

/// A compute device as a command line names it: `cpu`, `cuda` (the first GPU) or `cuda:N`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Accelerator {
    #[default]
    Cpu,
    Cuda(usize),
}

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DeviceError {
    #[error("device '{0}': expected cpu, cuda or cuda:N")]
    Unknown(String),
    #[error("device {0}: this dynforge was built without CUDA (build it with `cargo build --release --features cuda`)")]
    NotBuilt(Accelerator),
}

impl FromStr for Accelerator {
    type Err = DeviceError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim() {
            "cpu" => Ok(Accelerator::Cpu),
            "cuda" => Ok(Accelerator::Cuda(0)),
            other => other
                .strip_prefix("cuda:")
                .and_then(|n| n.parse().ok())
                .map(Accelerator::Cuda)
                .ok_or_else(|| DeviceError::Unknown(s.to_string())),
        }
    }
}

impl fmt::Display for Accelerator {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Accelerator::Cpu => write!(f, "cpu"),
            Accelerator::Cuda(n) => write!(f, "cuda:{n}"),
        }
    }
}

impl Accelerator {
    /// The burn device; a GPU only where this build has its backend.
    pub fn device(self) -> Result<Device, DeviceError> {
        match self {
            Accelerator::Cpu => Ok(Device::flex()),
            #[cfg(feature = "cuda")]
            Accelerator::Cuda(n) => Ok(Device::cuda(n)),
            #[cfg(not(feature = "cuda"))]
            Accelerator::Cuda(_) => Err(DeviceError::NotBuilt(self)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn devices_parse_as_a_command_line_names_them() {
        assert_eq!("cpu".parse(), Ok(Accelerator::Cpu));
        assert_eq!("cuda".parse(), Ok(Accelerator::Cuda(0)));
        assert_eq!("cuda:3".parse(), Ok(Accelerator::Cuda(3)));
        for bad in ["gpu", "cuda:", "cuda:x", "cuda:-1"] {
            assert_eq!(bad.parse::<Accelerator>(), Err(DeviceError::Unknown(bad.into())), "{bad}");
        }
        assert_eq!(Accelerator::Cuda(2).to_string(), "cuda:2");
        assert!(Accelerator::Cpu.device().is_ok());
        #[cfg(not(feature = "cuda"))]
        assert_eq!(Accelerator::Cuda(0).device().err(), Some(DeviceError::NotBuilt(Accelerator::Cuda(0))));
    }
}
