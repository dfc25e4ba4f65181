//! What every MuJoCo env ([`crate::reacher`], [`crate::pusher`] and the locomotion envs
//! through [`crate::locomotion`]) does the same way: loading an MJCF model, and MuJoCo
//! warnings, which end the episode as [`EnvError::Simulation`].

use mujoco_rs::prelude::{MjData, MjModel};

use crate::env::EnvError;

/// The MuJoCo state an env owns, with its model.
pub(crate) type Data = MjData<Box<MjModel>>;

/// [`EnvError::Model`] with `reason`.
pub(crate) fn model_error(reason: impl Into<String>) -> EnvError {
    EnvError::Model {
        reason: reason.into(),
    }
}

/// Parses the MJCF model `xml`; MuJoCo's message is the [`EnvError::Model`] reason.
pub(crate) fn load_model(xml: &str) -> Result<MjModel, EnvError> {
    MjModel::from_xml_string(xml).map_err(|e| model_error(e.to_string()))
}

/// Allocates the state of `model`.
pub(crate) fn new_data(model: MjModel) -> Result<Data, EnvError> {
    MjData::try_new(Box::new(model)).map_err(|e| model_error(e.to_string()))
}

/// MuJoCo warning counters, by warning type, since the last reset.
pub(crate) fn warning_counts(data: &Data) -> Vec<i32> {
    data.warning().iter().map(|w| w.number).collect()
}

/// Errors when MuJoCo raised any warning since the last reset; `steps` (env steps of
/// the episode) goes into the message.
pub(crate) fn check_warnings(data: &Data, steps: usize) -> Result<(), EnvError> {
    match data.warning().iter().position(|w| w.number > 0) {
        Some(index) => Err(EnvError::Simulation {
            reason: format!(
                "MuJoCo warning type {index} raised {} time(s) by step {steps} (info {}); \
                 the model is unstable or misconfigured",
                data.warning()[index].number,
                data.warning()[index].lastinfo
            ),
        }),
        None => Ok(()),
    }
}
