"""Multi-parametric programming: the program (``program``), the solver's front door
(``solve``), the mp-LP explorer, the mp-QP active-set search and its compiled kernel, the
explicit solution (``solution``) and region merging (``merge``)."""
