//! Lower-level controller models.
//!
//! Every base model reduces to the same linear description ([`Linear`]): a strictly
//! proper rational part of order one or two, a dead time and an inner feedback gain,
//!
//! ```text
//!   G(s)    = (b1 s + b0) e^{-Td s} / (a2 s^2 + a1 s + 1)
//!   G_fb(s) = G(s) / (1 - K G(s))          (u_ref = u + K y)
//! ```
//!
//! One file per model holds its parameter names, validation and reduction to
//! [`Linear`]; the registry [`ModelKind`] maps the Python-side names onto them.
//! A new base model is one file plus one line in `MODELS` below.

pub mod first_order;
pub mod proposed;
pub mod second_order;

use crate::error::{AvllError, Result};

/// The linear description shared by all base models.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Linear {
    /// Numerator `b1 s + b0`.
    pub b1: f64,
    pub b0: f64,
    /// Denominator `a2 s^2 + a1 s + 1` (a2 = 0 for a first-order part).
    pub a2: f64,
    pub a1: f64,
    /// Dead time (s).
    pub td: f64,
    /// Inner feedback gain K (u_ref = u + K y).
    pub k: f64,
}

impl Linear {
    /// Order of the rational part (1 or 2).
    pub fn order(&self) -> usize {
        if self.a2 != 0.0 {
            2
        } else {
            1
        }
    }

    /// Static gain of the closed inner loop, `b0 / (1 - K b0)`.
    pub fn dc_gain(&self) -> f64 {
        self.b0 / (1.0 - self.k * self.b0)
    }
}

/// A base lower-level model: named parameters reduced to [`Linear`].
pub trait BaseModel {
    /// Short name used by the Python layer and the CLI ("first", "second", "proposed").
    const NAME: &'static str;
    /// Parameter names in the paper's notation, in array order.
    const PARAMS: &'static [&'static str];
    /// Validates `p` (already checked for length) and reduces it.
    fn linear(p: &[f64]) -> Result<Linear>;
}

macro_rules! registry {
    ($($variant:ident => $ty:ty),+ $(,)?) => {
        /// The registered base models.
        #[derive(Debug, Clone, Copy, PartialEq, Eq)]
        pub enum ModelKind { $($variant),+ }

        impl ModelKind {
            pub const ALL: &'static [ModelKind] = &[$(ModelKind::$variant),+];

            pub fn name(self) -> &'static str {
                match self { $(ModelKind::$variant => <$ty as BaseModel>::NAME),+ }
            }

            pub fn params(self) -> &'static [&'static str] {
                match self { $(ModelKind::$variant => <$ty as BaseModel>::PARAMS),+ }
            }

            fn reduce(self, p: &[f64]) -> Result<Linear> {
                match self { $(ModelKind::$variant => <$ty as BaseModel>::linear(p)),+ }
            }
        }
    };
}

registry! {
    FirstOrder => first_order::FirstOrderLag,
    SecondOrder => second_order::SecondOrder,
    Proposed => proposed::Proposed,
}

impl ModelKind {
    /// Looks a model up by its short name.
    pub fn from_name(name: &str) -> Result<Self> {
        ModelKind::ALL
            .iter()
            .copied()
            .find(|m| m.name() == name)
            .ok_or_else(|| {
                let known: Vec<_> = ModelKind::ALL.iter().map(|m| m.name()).collect();
                AvllError::new(
                    "model",
                    format!("unknown model {name:?}; known: {}", known.join(", ")),
                )
            })
    }

    pub fn n_params(self) -> usize {
        self.params().len()
    }

    /// Checks the parameter vector and reduces it to [`Linear`].
    pub fn linear(self, p: &[f64]) -> Result<Linear> {
        let names = self.params();
        if p.len() != names.len() {
            return Err(AvllError::new(
                "params",
                format!(
                    "model {:?} takes {} parameters ({}), got {}",
                    self.name(),
                    names.len(),
                    names.join(", "),
                    p.len()
                ),
            ));
        }
        for (x, n) in p.iter().zip(names) {
            crate::error::check_finite(n, *x)?;
        }
        self.reduce(p)
    }
}

/// Kind of command the lower level receives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CommandKind {
    /// Command acceleration; the response is the acceleration (the paper's experiment).
    Acceleration,
    /// Command speed; the response is the speed (e.g. the CARMA data).
    Speed,
}

impl CommandKind {
    pub fn from_name(name: &str) -> Result<Self> {
        match name {
            "acceleration" => Ok(Self::Acceleration),
            "speed" => Ok(Self::Speed),
            _ => Err(AvllError::new(
                "command_kind",
                format!("must be 'acceleration' or 'speed', got {name:?}"),
            )),
        }
    }
}
