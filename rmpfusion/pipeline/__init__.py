"""An experiment as stages (collect, fit, evaluate, report) over a validated run configuration."""

# Nothing is re-exported: each stage's module is imported on demand, so that importing the package stays cheap.
__all__: list[str] = []
