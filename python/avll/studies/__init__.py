"""Studies on measured data, run as ``avll study NAME ...``.

* ``avll study openacc PATH --out DIR --json OUT.json``: every follower of native
  OpenACC files (e.g. ZalaZone) calibrated in closed loop, the calibrated time gap
  against the known ACC setting, and the measured against the predicted
  amplification of the predecessor's speed oscillations
  (:func:`avll.studies.openacc.openacc_study`).
"""

from __future__ import annotations

import argparse

__all__ = ["register_cli"]


def register_cli(sub: argparse._SubParsersAction) -> None:
    """Registers ``avll study`` and its studies."""
    from . import openacc

    p = sub.add_parser("study", help="studies on measured data (openacc)",
                       description="Studies on measured data; see `avll study NAME -h`.")
    studies = p.add_subparsers(dest="study", required=True, metavar="STUDY")
    openacc.register_cli(studies)
