"""The stages of the diagnosis, in the order :func:`..engine.diagnose` runs them.

- :mod:`.nominal`: admit the data; calibrate G and d; the candidate record and the nominal fit.
- :mod:`.where`: scan the residual for significant locations (also the final scan's scan).
- :mod:`.selection`: forward selection of the candidate variants (which), with onsets.
- :mod:`.relinearize`: after a large effect, the record rebuilt at its model's G and d and the selection rerun.
- :mod:`.final_scan`: the final joint fit, its scan and the verdict.
- :mod:`.how_far`: the effect reports (shrink, G and d shifts, aliases: :mod:`.aliases`), the gap before and after.
- :mod:`.held_out`: fit on the first part of the run, apply to the rest.
- :mod:`.naming`: the naming rule (families, effects that stand).
- :mod:`.corrected`: G and d re-calibrated under the model extended with the named effects.
- :mod:`.plots`: the plot data of the report.

Each stage is a function of typed values (frozen dataclasses) returning the next; the candidate
record (``Nominal.full``) is the shared fitting workspace that selection and the final model refine.
"""
