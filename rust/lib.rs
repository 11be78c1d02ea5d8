//! avll: models of the lower-level (actuator) controller of automated vehicles.
//!
//! The plain-Rust core (no Python needed: `cargo test`) holds the models, the exact
//! discretization, the rollouts and batched costs, the genetic algorithm and the
//! stability engine. The PyO3 layer in [`bindings`] (feature `python`) only converts
//! arrays, validates, releases the GIL and calls the core.

pub mod discretize;
pub mod effects;
pub mod error;
pub mod ga;
pub mod model;
pub mod parallel;
pub mod rollout;
pub mod stability;

#[cfg(feature = "python")]
mod bindings;
