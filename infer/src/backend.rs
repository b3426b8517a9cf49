//! The CPU backends the project can run on. `flex` is the default because it
//! measured faster (see the README's backend table); `ndarray` stays
//! selectable. A GPU device works the same way through `Device::default()`.

use burn::prelude::*;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum CpuBackend {
    #[default]
    Flex,
    Ndarray,
}

impl CpuBackend {
    pub fn device(self) -> Device {
        match self {
            Self::Flex => Device::flex(),
            #[allow(deprecated)]
            Self::Ndarray => Device::ndarray(),
        }
    }
}
