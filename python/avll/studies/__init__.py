"""Studies on measured data, run as ``avll study NAME ...`` (the commands are in
:mod:`avll.cli.study`).

* :mod:`avll.studies.openacc`: native OpenACC files (e.g. ZalaZone), closed-loop
  calibration per car, the calibrated time gap against the ACC setting, measured
  against predicted string stability.
"""

from __future__ import annotations

from .._compat import moved as _moved

__all__: list[str] = []

__getattr__ = _moved(__name__, {"register_cli": "avll.cli.study:register"})
