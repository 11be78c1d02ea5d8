//! The concatenated-run arrays shared by every batched binding (costs, GA, effects):
//! run `r` is `offsets[r]..offsets[r+1]` of every series; `upper` is an (R, 4) array
//! of kg, kv, Tg, Gmin per run.

use super::{slice1, slice2};
use crate::rollout::{RunRef, Upper};
use numpy::{PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

/// A series that must have `total` samples (the length of `a`).
pub(crate) fn series<'a>(
    name: &str,
    arr: &'a PyReadonlyArray1<'_, f64>,
    total: usize,
) -> PyResult<&'a [f64]> {
    let s = slice1(name, arr)?;
    if s.len() != total {
        return Err(PyValueError::new_err(format!(
            "{name}: has length {} but `a` has {total}",
            s.len()
        )));
    }
    Ok(s)
}

fn optional<'a>(
    name: &str,
    s: &'a Option<PyReadonlyArray1<'_, f64>>,
    total: usize,
) -> PyResult<Option<&'a [f64]>> {
    s.as_ref().map(|arr| series(name, arr, total)).transpose()
}

/// Checks the offsets against the runs' count and total length.
pub(crate) fn check_offsets(offsets: &[usize], runs: usize, total: usize) -> PyResult<()> {
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

/// Splits the concatenated arrays into borrowed runs, checking every length.
#[allow(clippy::too_many_arguments)]
pub(crate) fn runs_from_arrays<'a>(
    offsets: &[usize],
    dt: &'a PyReadonlyArray1<'_, f64>,
    a: &'a PyReadonlyArray1<'_, f64>,
    command: &'a Option<PyReadonlyArray1<'_, f64>>,
    lead_x: &'a Option<PyReadonlyArray1<'_, f64>>,
    lead_v: &'a Option<PyReadonlyArray1<'_, f64>>,
    v: &'a Option<PyReadonlyArray1<'_, f64>>,
    x: &'a Option<PyReadonlyArray1<'_, f64>>,
    upper: &'a Option<PyReadonlyArray2<'_, f64>>,
) -> PyResult<Vec<RunRef<'a>>> {
    let a = slice1("a", a)?;
    let total = a.len();
    let (command, lead_x, lead_v, v, x) = (
        optional("command", command, total)?,
        optional("lead_x", lead_x, total)?,
        optional("lead_v", lead_v, total)?,
        optional("v", v, total)?,
        optional("x", x, total)?,
    );
    let dts = slice1("dt", dt)?;
    let r = dts.len();
    check_offsets(offsets, r, total)?;
    let uppers: Vec<Upper> = match upper {
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
            let (ur, uc, us) = slice2("upper", u)?;
            if ur != r || uc != 4 {
                return Err(PyValueError::new_err(format!(
                    "upper: must have shape ({r}, 4) (kg, kv, Tg, Gmin per run), got ({ur}, {uc})"
                )));
            }
            us.chunks(4)
                .map(|c| Upper {
                    kg: c[0],
                    kv: c[1],
                    tg: c[2],
                    gmin: c[3],
                })
                .collect()
        }
    };
    let part = |s: Option<&'a [f64]>, k: usize| s.map(|s| &s[offsets[k]..offsets[k + 1]]);
    Ok((0..r)
        .map(|k| RunRef {
            dt: dts[k],
            command: part(command, k),
            lead_x: part(lead_x, k),
            lead_v: part(lead_v, k),
            a: &a[offsets[k]..offsets[k + 1]],
            v: part(v, k),
            x: part(x, k),
            upper: uppers[k],
        })
        .collect())
}
