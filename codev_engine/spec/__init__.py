"""The spec: the problem's frozen data (``problem``), the TOML parser (``parse``), the
expression language of nonlinear dynamics (``expr``) and the values of choice fields
(``choices``)."""
