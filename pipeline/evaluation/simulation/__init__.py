"""The paper's section 5.3 simulation: hand-specified GP classes and tracks (``scenarios``), the
paper's claims checked on them (``claims``) and the model-confidence regime sweep (``sweep``)."""
