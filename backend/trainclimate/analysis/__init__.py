"""Analysis: KPIs, savings and reports, shared by the CLI and the service."""
