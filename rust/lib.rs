//! avll: models of the lower-level (actuator) controller of automated vehicles.
//!
//! The plain-Rust core (no Python needed: `cargo test`) holds the models, the exact
//! discretization, the one step kernel with its rollouts and batched costs
//! ([`sim`]), the genetic algorithm and the one calibration driver ([`optimize`])
//! and the stability engine. The PyO3 layer in [`bindings`] (feature `python`) only converts
//! arrays, validates, releases the GIL and calls the core.

pub mod effects;
pub mod error;
pub mod model;
pub mod optimize;
pub mod parallel;
pub mod sim;
pub mod stability;

pub use optimize::ga;
pub use sim::discretize;

#[cfg(feature = "python")]
mod bindings;
