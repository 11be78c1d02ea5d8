//! The run set: measured runs packed once into Rust (`avll._core.RunSet`) and reused
//! by every batched call (costs, batched simulation, calibration, bootstrap,
//! diagnosis). Run `r` is `offsets[r]..offsets[r+1]` of every series; `upper` is an
//! (R, 4) array of kg, kv, Tg, Gmin per run; `exo` maps exogenous signal names
//! (e.g. `"grade"`) to concatenated series.
//!
//! A run set is a view: the packed arrays are shared (`Arc`) and `take(indices)`
//! gives another view on some of the runs (folds, resamples, candidate subsets)
//! without copying a sample.

use super::slice1;
use crate::sim::{RunRef, Upper};
use numpy::{PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use std::collections::BTreeMap;
use std::sync::Arc;

/// Measured runs packed once (owned, contiguous), shared by the batched functions:
/// a view of some of the runs (`index`, into the packed ones) of shared packed data.
#[pyclass(frozen, module = "avll._core")]
pub struct RunSet {
    data: Arc<Packed>,
    index: Vec<usize>,
}

/// The packed arrays of every run.
struct Packed {
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
        let data = Packed {
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
        };
        Ok(Self {
            data: Arc::new(data),
            index: (0..r).collect(),
        })
    }

    /// Number of runs.
    fn __len__(&self) -> usize {
        self.index.len()
    }

    /// Total number of samples over all runs.
    #[getter]
    fn total(&self) -> usize {
        self.len_total()
    }

    /// Run boundaries: run `r` is `offsets[r]:offsets[r+1]` of the view's runs laid
    /// end to end (as the batched simulation returns them).
    #[getter]
    fn offsets(&self) -> Vec<usize> {
        let o = &self.data.offsets;
        let mut out = Vec::with_capacity(self.index.len() + 1);
        out.push(0);
        for &k in &self.index {
            out.push(out[out.len() - 1] + o[k + 1] - o[k]);
        }
        out
    }

    /// The runs of this view as indices into the packed runs.
    #[getter]
    fn index(&self) -> Vec<usize> {
        self.index.clone()
    }

    /// Names of the exogenous series carried.
    #[getter]
    fn exo_names(&self) -> Vec<String> {
        self.data.exo.iter().map(|(k, _)| k.clone()).collect()
    }

    /// Another view on runs `indices` of this one (repeats allowed), sharing the
    /// packed arrays (nothing is copied).
    fn take(&self, indices: Vec<usize>) -> PyResult<Self> {
        let n = self.index.len();
        if let Some(&bad) = indices.iter().find(|&&i| i >= n) {
            return Err(PyValueError::new_err(format!(
                "indices: run index {bad} is out of range 0..{n}"
            )));
        }
        Ok(Self {
            data: Arc::clone(&self.data),
            index: indices.iter().map(|&i| self.index[i]).collect(),
        })
    }

    /// Whether `other` shares this run set's packed arrays.
    fn shares(&self, other: &Self) -> bool {
        Arc::ptr_eq(&self.data, &other.data)
    }

    fn __repr__(&self) -> String {
        format!(
            "RunSet({} runs, {} samples, exo={:?})",
            self.index.len(),
            self.len_total(),
            self.exo_names()
        )
    }
}

impl RunSet {
    /// Borrowed runs (of this view, in its order).
    pub(crate) fn refs(&self) -> Vec<RunRef<'_>> {
        let d = &*self.data;
        let o = &d.offsets;
        fn part<'a>(s: &'a Option<Vec<f64>>, o: &[usize], k: usize) -> Option<&'a [f64]> {
            s.as_ref().map(|s| &s[o[k]..o[k + 1]])
        }
        self.index
            .iter()
            .map(|&k| RunRef {
                dt: d.dt[k],
                command: part(&d.command, o, k),
                lead_x: part(&d.lead_x, o, k),
                lead_v: part(&d.lead_v, o, k),
                a: &d.a[o[k]..o[k + 1]],
                v: part(&d.v, o, k),
                x: part(&d.x, o, k),
                upper: d.upper[k],
                exo: d
                    .exo
                    .iter()
                    .map(|(n, s)| (n.as_str(), &s[o[k]..o[k + 1]]))
                    .collect(),
            })
            .collect()
    }

    /// Total samples of the view's runs.
    pub(crate) fn len_total(&self) -> usize {
        let o = &self.data.offsets;
        self.index.iter().map(|&k| o[k + 1] - o[k]).sum()
    }
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<RunSet>()
}
