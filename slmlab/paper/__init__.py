"""The paper's method, §3–§6: Wang, Zhao, Wang, Micron 83 (2016) 93–109.

``distortion``
    §3, Eqs 1–6: the row and column corrections of each view (Table 1, Figs 3–6);
``alignment``
    §4, Eqs 7–16: the views' rotation and offset, the disparity and its parabolic distortion (Table 2,
    Figs 7–8);
``chain``
    §5, Eqs 17–32: the corrections, alignment, θX and Models 0–2 as one chain of estimates;
``evaluation``
    §5.2–§6: residual elements, the RA1–RA5 intervals and the S coefficients;
``tables``, ``reference``
    the paper's tables in our terms, and the numbers it reports.
"""

from .reference import paper_reference

__all__ = ["paper_reference"]
