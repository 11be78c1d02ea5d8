"""The cross-validated residual loop (:func:`avll.diagnose.effect_loop`) on measured
data, per vehicle, with a three-way split (calibration, validation, untouched test):

* :mod:`avll.studies.loops.carma`: CARMA cruise stretches (speed command);
* :mod:`avll.studies.loops.openacc`: OpenACC AstaZero pairs and ZalaZone cars (closed
  loop behind the recorded predecessor);
* :mod:`avll.studies.loops.table`: the table row of one loop result, shared by both.

Each runs as ``python -m avll.studies.loops.NAME`` (one strict JSON per case into
``--out``); ``python -m docs.gen --only loop-carma,loop-openacc`` runs them and writes
the docs' tables from the JSON.
"""
