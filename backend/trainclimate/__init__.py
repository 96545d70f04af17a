"""trainclimate: data-driven predictive HVAC energy management for SBB Regio-Dosto coaches.

Subpackages (see docs/architecture.md): ``sim`` (the half-coach thermal simulator of the paper's
Section II), ``analysis`` (KPIs and reports).
"""

__version__ = "0.1.0"
