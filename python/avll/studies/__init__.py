"""Studies on measured data (the commands are in :mod:`avll.cli.study` and
:mod:`avll.cli.calibrate`).

* :mod:`avll.studies.fielddata`: the CARMA and OpenACC AstaZero calibration studies
  (run by ``avll reproduce --data``) and their loaders' helpers (``read_carma``,
  ``split_launch_cruise``, ``read_astazero_pairs``);
* :mod:`avll.studies.openacc` (``avll study openacc``): native OpenACC files (e.g.
  ZalaZone), closed-loop calibration per car, the calibrated time gap against the
  ACC setting, measured against predicted string stability.
"""

from __future__ import annotations

__all__: list[str] = []
