//! Optimisation: the genetic algorithm with its Nelder–Mead local search
//! ([`ga`]) and the one calibration driver on the Eq. 6 cost ([`calibrate`]).

pub mod calibrate;
pub mod ga;
pub mod resample;
