"""Analysis of the blind realism study (thesis sections 4.5.4-4.5.5, Figures 4.17-4.20).

Reads study folders only (``DATA/<subject>/session.json``, ``trials.csv``, optional traces);
imports none of the other packages. Modules: ``load`` (validation), ``stats`` (tests),
``pipeline`` (all tables), ``figures``, ``traces`` (Figure 4.20 reader), ``report``
(``python -m analysis report``), ``synthetic`` (generated study folders). See docs/analysis.md.
"""
