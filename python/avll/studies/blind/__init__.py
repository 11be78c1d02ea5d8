"""Blind tests of the diagnosis loop (:func:`avll.diagnose.effect_loop`) on synthetic
data whose truth is known:

* :mod:`avll.studies.blind.library`: the library-like generator
  :mod:`avll.synth_effects` (the effects in the library's own form);
* :mod:`avll.studies.blind.physical`: the physical generator :mod:`avll.synth_blind`
  (every effect realised in a form the library does not use);
* :mod:`avll.studies.blind.stability`: do the loop's findings fix the stability
  conclusions (:func:`avll.effect_stability.effect_stability` of the fitted models
  against the true vehicle's platoon)?

Their tables are fragments of the docs (``python -m docs.gen --only
blind,blind-physical,blind-stability``); each module also runs as
``python -m avll.studies.blind.NAME`` and prints its table.
"""
