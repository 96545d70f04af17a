"""trainclimate: data-driven predictive HVAC energy management for SBB Regio-Dosto coaches.

Subpackages: ``sim`` (the half-coach thermal simulator of the paper's Section II), ``data`` (fleet
logs and the data pipeline of Section III.A), ``analysis`` (KPIs and reports).
"""

__version__ = "0.1.0"
