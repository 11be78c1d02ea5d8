//! The run set: measured runs packed once into Rust (`avll._core.RunSet`) and reused
//! by every batched call (costs, batched simulation, calibration, bootstrap,
//! diagnosis). Run `r` is `offsets[r]..offsets[r+1]` of every series; `upper` is an
//! (R, 4) array of kg, kv, Tg, Gmin per run; `exo` maps exogenous signal names
//! (e.g. `"grade"`) to concatenated series.

use super::slice1;
use crate::sim::{RunRef, Upper};
use numpy::{PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use std::collections::BTreeMap;

/// Measured runs packed once (owned, contiguous), shared by the batched functions.
#[pyclass(frozen, module = "avll._core")]
pub struct RunSet {
    offsets: Vec<usize>,
    dt: Vec<f64>,
    a: Vec<f64>,
    command: Option<Vec<f64>>,
    lead_x: Option<Vec<f64>>,
    lead_v: Option<Vec<f64>>,
    v: Option<Vec<f64>>,
    x: Option<Vec<f64>>,
    upper: Vec<Upper>,
    exo: Vec<(String, Vec<f64>)>,
}

fn owned(
    name: &str,
    s: &Option<PyReadonlyArray1<'_, f64>>,
    total: usize,
) -> PyResult<Option<Vec<f64>>> {
    s.as_ref()
        .map(|arr| {
            let v = slice1(name, arr)?;
            if v.len() != total {
                return Err(PyValueError::new_err(format!(
                    "{name}: has length {} but `a` has {total}",
                    v.len()
                )));
            }
            Ok(v.to_vec())
        })
        .transpose()
}

/// Checks the offsets against the runs' count and total length.
fn check_offsets(offsets: &[usize], runs: usize, total: usize) -> PyResult<()> {
    if offsets.len() != runs + 1
        || offsets[0] != 0
        || offsets[runs] != total
        || offsets.windows(2).any(|w| w[0] > w[1])
    {
        return Err(PyValueError::new_err(format!(
            "offsets: must be {} non-decreasing values from 0 to {total} (one more than dt)",
            runs + 1
        )));
    }
    Ok(())
}

#[pymethods]
impl RunSet {
    /// Packs concatenated runs (every array is copied once).
    #[new]
    #[pyo3(signature = (offsets, dt, a, command=None, lead_x=None, lead_v=None, v=None, x=None, upper=None, exo=BTreeMap::new()))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        offsets: Vec<usize>,
        dt: PyReadonlyArray1<'_, f64>,
        a: PyReadonlyArray1<'_, f64>,
        command: Option<PyReadonlyArray1<'_, f64>>,
        lead_x: Option<PyReadonlyArray1<'_, f64>>,
        lead_v: Option<PyReadonlyArray1<'_, f64>>,
        v: Option<PyReadonlyArray1<'_, f64>>,
        x: Option<PyReadonlyArray1<'_, f64>>,
        upper: Option<PyReadonlyArray2<'_, f64>>,
        exo: BTreeMap<String, PyReadonlyArray1<'_, f64>>,
    ) -> PyResult<Self> {
        let a = slice1("a", &a)?.to_vec();
        let total = a.len();
        let dt = slice1("dt", &dt)?.to_vec();
        let r = dt.len();
        check_offsets(&offsets, r, total)?;
        let upper = match upper {
            None => vec![
                Upper {
                    kg: 0.0,
                    kv: 0.0,
                    tg: 0.0,
                    gmin: 0.0
                };
                r
            ],
            Some(u) => {
                let shape = u.shape().to_vec();
                let s = u.as_slice().map_err(|_| {
                    PyValueError::new_err("upper: must be a C-contiguous float64 array")
                })?;
                if shape != [r, 4] {
                    return Err(PyValueError::new_err(format!(
                        "upper: must have shape ({r}, 4) (kg, kv, Tg, Gmin per run), got {shape:?}"
                    )));
                }
                s.chunks(4)
                    .map(|c| Upper {
                        kg: c[0],
                        kv: c[1],
                        tg: c[2],
                        gmin: c[3],
                    })
                    .collect()
            }
        };
        let mut ex = Vec::with_capacity(exo.len());
        for (k, arr) in &exo {
            let s = owned(&format!("exo[{k:?}]"), &Some(arr.clone()), total)?;
            ex.push((k.clone(), s.unwrap_or_default()));
        }
        Ok(Self {
            command: owned("command", &command, total)?,
            lead_x: owned("lead_x", &lead_x, total)?,
            lead_v: owned("lead_v", &lead_v, total)?,
            v: owned("v", &v, total)?,
            x: owned("x", &x, total)?,
            offsets,
            dt,
            a,
            upper,
            exo: ex,
        })
    }

    /// Number of runs.
    fn __len__(&self) -> usize {
        self.dt.len()
    }

    /// Total number of samples over all runs.
    #[getter]
    fn total(&self) -> usize {
        self.a.len()
    }

    /// Run boundaries: run `r` is `offsets[r]:offsets[r+1]`.
    #[getter]
    fn offsets(&self) -> Vec<usize> {
        self.offsets.clone()
    }

    /// Names of the exogenous series carried.
    #[getter]
    fn exo_names(&self) -> Vec<String> {
        self.exo.iter().map(|(k, _)| k.clone()).collect()
    }

    fn __repr__(&self) -> String {
        format!(
            "RunSet({} runs, {} samples, exo={:?})",
            self.dt.len(),
            self.a.len(),
            self.exo_names()
        )
    }
}

impl RunSet {
    /// Borrowed runs.
    pub(crate) fn refs(&self) -> Vec<RunRef<'_>> {
        let o = &self.offsets;
        fn part<'a>(s: &'a Option<Vec<f64>>, o: &[usize], k: usize) -> Option<&'a [f64]> {
            s.as_ref().map(|s| &s[o[k]..o[k + 1]])
        }
        (0..self.dt.len())
            .map(|k| RunRef {
                dt: self.dt[k],
                command: part(&self.command, o, k),
                lead_x: part(&self.lead_x, o, k),
                lead_v: part(&self.lead_v, o, k),
                a: &self.a[o[k]..o[k + 1]],
                v: part(&self.v, o, k),
                x: part(&self.x, o, k),
                upper: self.upper[k],
                exo: self
                    .exo
                    .iter()
                    .map(|(n, s)| (n.as_str(), &s[o[k]..o[k + 1]]))
                    .collect(),
            })
            .collect()
    }

    /// Total samples.
    pub(crate) fn len_total(&self) -> usize {
        self.a.len()
    }
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<RunSet>()
}
